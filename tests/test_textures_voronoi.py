"""Properties of the numpy Voronoi and Gradient textures (no bpy).

The comparison with Blender itself lives in tests/blender/test_textures_voronoi_bpy.py; here:
the PCG cell hashes against a scalar reference, and properties of the textures that a wrong
implementation would break (F1 <= F2, F1 vanishes at its own feature point, randomness 0 is
the integer lattice, per-point arrays equal scalar calls, continuity in Detail and
Smoothness, distance to edge against the F1/F2 bisector, gradient values at known points).
"""
import numpy as np
import pytest

from mpp_render.textures import pcg
from mpp_render.textures.gradient import GRADIENT_TYPES, gradient_outputs, gradient_texture
from mpp_render.textures.voronoi import voronoi_texture

DIMS = ("1D", "2D", "3D", "4D")
METRICS = ("EUCLIDEAN", "MANHATTAN", "CHEBYCHEV", "MINKOWSKI")


def points(n=400, seed=7, spread=6.0):
    rng = np.random.default_rng(seed)
    vec = rng.uniform(-spread, spread, (n, 3)).astype(np.float32)
    w = rng.uniform(-spread, spread, n).astype(np.float32)
    return vec, w


def coords(vec, w, dims):
    """The node's coordinate before scaling: (N, d)."""
    return {"1D": w[:, None], "2D": vec[:, :2], "3D": vec,
            "4D": np.concatenate([vec, w[:, None]], axis=1)}[dims]


def as_coord(out, dims):
    """F1/F2 feature point as a (N, d) coordinate from the Position / W outputs."""
    if dims == "1D":
        return out["W"][:, None]
    if dims == "4D":
        return np.concatenate([out["Position"], out["W"][:, None]], axis=1)
    return out["Position"][:, :int(dims[0])]


# ---- PCG hashes ---------------------------------------------------------------------------

def _wrap(x):
    x &= 0xFFFFFFFF
    return x - (1 << 32) if x >= 1 << 31 else x


def ref_pcg(v):
    """Scalar PCG 2D/3D/4D on Python ints with explicit int32 wrap-around and arithmetic
    shift (Jarzynski & Olano 2020, the signed form Blender uses)."""
    v = [_wrap(x * 1664525 + 1013904223) for x in v]
    n = len(v)

    def rounds(v):
        if n == 2:
            v[0] = _wrap(v[0] + v[1] * 1664525)
            v[1] = _wrap(v[1] + v[0] * 1664525)
        elif n == 3:
            v[0] = _wrap(v[0] + v[1] * v[2])
            v[1] = _wrap(v[1] + v[2] * v[0])
            v[2] = _wrap(v[2] + v[0] * v[1])
        else:
            v[0] = _wrap(v[0] + v[1] * v[3])
            v[1] = _wrap(v[1] + v[2] * v[0])
            v[2] = _wrap(v[2] + v[0] * v[1])
            v[3] = _wrap(v[3] + v[1] * v[2])
        return v

    v = rounds(v)
    v = [x ^ (x >> 16) for x in v]  # Python >> on negative ints is arithmetic
    v = rounds(v)
    return [x & 0x7FFFFFFF for x in v]


@pytest.mark.parametrize("d", [2, 3, 4])
def test_pcg_matches_scalar_reference(d):
    rng = np.random.default_rng(d)
    keys = rng.integers(-2 ** 31, 2 ** 31, (200, d)).astype(np.int32)
    keys[:5] = [[0] * d, [-1] * d, [1] * d, [2 ** 31 - 1] * d, [-2 ** 31] * d]
    got = {2: pcg.hash_pcg2d_i, 3: pcg.hash_pcg3d_i, 4: pcg.hash_pcg4d_i}[d](keys)
    want = np.array([ref_pcg([int(x) for x in k]) for k in keys])
    np.testing.assert_array_equal(got, want)
    floats = {2: pcg.hash_int2_to_float2, 3: pcg.hash_int3_to_float3,
              4: pcg.hash_int4_to_float4}[d](keys)
    assert floats.dtype == np.float32 and floats.min() >= 0.0 and floats.max() <= 1.0
    np.testing.assert_array_equal(floats, (want.astype(np.float32) * np.float32(2.0 ** -31)))


def test_pcg_colour_variants():
    keys = np.array([[3, -7], [0, 0], [123456, -98765]], np.int32)
    np.testing.assert_array_equal(
        pcg.hash_int2_to_float3(keys),
        pcg.hash_int3_to_float3(np.concatenate([keys, np.zeros((3, 1), np.int32)], 1)))
    k4 = np.array([[1, 2, 3, 4], [-5, 6, -7, 8]], np.int32)
    np.testing.assert_array_equal(pcg.hash_int4_to_float3(k4),
                                  pcg.hash_int4_to_float4(k4)[:, :3])


# ---- Voronoi properties ----------------------------------------------------------------------

@pytest.mark.parametrize("dims", DIMS)
@pytest.mark.parametrize("metric", METRICS)
def test_f1_not_above_f2(dims, metric):
    vec, w = points()
    kw = dict(w=w, dimensions=dims, distance=metric, scale=2.3, exponent=1.3, randomness=0.8)
    f1 = voronoi_texture(vec, feature="F1", **kw)["Distance"]
    f2 = voronoi_texture(vec, feature="F2", **kw)["Distance"]
    assert np.all(f1 <= f2)
    assert np.all(f1 >= 0.0) and np.all(np.isfinite(f2))


@pytest.mark.parametrize("dims", DIMS)
def test_f1_vanishes_at_its_feature_point(dims):
    """Position (and W) give F1's feature point; evaluated there, F1 is 0 and names the same
    point and colour."""
    vec, w = points(200)
    scale = 1.7
    first = voronoi_texture(vec, w=w, dimensions=dims, scale=scale)
    at = as_coord(first, dims)
    vec2 = np.zeros_like(vec)
    w2 = np.zeros_like(w)
    d = at.shape[1]
    if dims == "1D":
        w2 = at[:, 0]
    else:
        vec2[:, :min(d, 3)] = at[:, :3]
        if d == 4:
            w2 = at[:, 3]
    again = voronoi_texture(vec2, w=w2, dimensions=dims, scale=scale)
    assert np.abs(again["Distance"]).max() < 1e-5
    np.testing.assert_allclose(as_coord(again, dims), at, atol=1e-5)
    np.testing.assert_array_equal(again["Color"], first["Color"])


@pytest.mark.parametrize("dims", DIMS)
def test_randomness_zero_is_the_integer_lattice(dims):
    vec, w = points()
    scale = 3.0
    out = voronoi_texture(vec, w=w, dimensions=dims, scale=scale, randomness=0.0)
    c = coords(vec, w, dims).astype(np.float32) * np.float32(scale)
    nearest = np.floor(c + 0.5)
    np.testing.assert_allclose(as_coord(out, dims) * scale, nearest, atol=1e-4)
    np.testing.assert_allclose(out["Distance"], np.linalg.norm(c - nearest, axis=1), atol=1e-5)
    # One colour per lattice point.
    key = [tuple(k) for k in nearest.astype(np.int64)]
    seen = {}
    for k, col in zip(key, out["Color"]):
        assert np.array_equal(seen.setdefault(k, col), col)
    # F2 on a lattice: the second nearest lattice point.
    f2 = voronoi_texture(vec, w=w, dimensions=dims, scale=scale, randomness=0.0,
                         feature="F2")["Distance"]
    frac = c - np.floor(c)
    gap = np.abs(frac - 0.5)  # second nearest: step the axis nearest a half across
    second = np.sqrt(np.sum((0.5 - gap) ** 2, axis=1) - (0.5 - gap.min(axis=1)) ** 2
                     + (0.5 + gap.min(axis=1)) ** 2)
    np.testing.assert_allclose(f2, second, atol=1e-5)


CASES = [
    dict(dimensions="3D", feature="F1"),
    dict(dimensions="2D", feature="F2", distance="MINKOWSKI"),
    dict(dimensions="4D", feature="SMOOTH_F1", distance="MANHATTAN"),
    dict(dimensions="1D", feature="SMOOTH_F1"),
    dict(dimensions="3D", feature="DISTANCE_TO_EDGE", normalize=True),
    dict(dimensions="2D", feature="N_SPHERE_RADIUS"),
    dict(dimensions="3D", feature="F2", normalize=True, distance="CHEBYCHEV"),
]


@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(str(v) for v in c.values()))
def test_per_point_arrays_equal_scalar_calls(case):
    """A linked socket (an (N,) array) gives each point what a scalar call with its value
    gives."""
    vec, w = points(60)
    groups = [dict(scale=1.5, detail=0.0, roughness=0.5, lacunarity=2.0, smoothness=0.7,
                   exponent=0.8, randomness=1.0, w=0.3),
              dict(scale=-2.5, detail=1.6, roughness=0.3, lacunarity=2.7, smoothness=0.0,
                   exponent=2.5, randomness=0.4, w=-1.1),
              dict(scale=4.0, detail=2.25, roughness=0.9, lacunarity=1.6, smoothness=1.0,
                   exponent=1.0, randomness=0.0, w=7.5)]
    which = np.arange(len(vec)) % len(groups)
    arrays = {k: np.array([groups[g][k] for g in which], np.float32) for k in groups[0]}
    together = voronoi_texture(vec, **case, **arrays)
    for g, params in enumerate(groups):
        sel = which == g
        alone = voronoi_texture(vec[sel], **case, **params)
        for name, value in alone.items():
            np.testing.assert_array_equal(together[name][sel], value, err_msg=name)


def test_fractal_detail_is_continuous():
    vec, w = points(300)
    kw = dict(w=w, dimensions="3D", scale=2.0, roughness=0.6, lacunarity=2.2)
    for feature in ("F1", "F2", "DISTANCE_TO_EDGE"):
        for normalize in (False, True):
            a = voronoi_texture(vec, detail=1.0, feature=feature, normalize=normalize, **kw)
            b = voronoi_texture(vec, detail=1.0 + 1e-4, feature=feature, normalize=normalize,
                                **kw)
            for name in a:
                assert np.abs(a[name] - b[name]).max() < 1e-3, (feature, normalize, name)
    # Detail 0 is the first octave alone, whatever roughness and lacunarity.
    a = voronoi_texture(vec, detail=0.0, dimensions="3D", scale=2.0)
    b = voronoi_texture(vec, detail=0.0, dimensions="3D", scale=2.0, roughness=0.9,
                        lacunarity=5.0)
    for name in a:
        np.testing.assert_array_equal(a[name], b[name])


def test_normalized_fractal_stays_in_range():
    vec, w = points(500)
    for dims in DIMS:
        out = voronoi_texture(vec, w=w, dimensions=dims, scale=3.0, detail=2.5, roughness=0.7,
                              normalize=True, feature="F1")
        assert out["Distance"].min() >= 0.0 and out["Distance"].max() <= 1.2
        assert out["Color"].min() >= 0.0 and out["Color"].max() <= 1.0 + 1e-6


@pytest.mark.parametrize("dims", DIMS)
def test_smooth_f1_tends_to_f1(dims):
    vec, w = points(300)
    kw = dict(w=w, dimensions=dims, scale=2.0, randomness=0.9)
    f1 = voronoi_texture(vec, feature="F1", **kw)
    hard = voronoi_texture(vec, feature="SMOOTH_F1", smoothness=0.0, **kw)
    for name in f1:
        np.testing.assert_array_equal(hard[name], f1[name])
    soft = voronoi_texture(vec, feature="SMOOTH_F1", smoothness=1e-3, **kw)
    assert np.abs(soft["Distance"] - f1["Distance"]).max() < 1e-3
    smoother = voronoi_texture(vec, feature="SMOOTH_F1", smoothness=1.0, **kw)
    assert np.all(smoother["Distance"] <= f1["Distance"] + 1e-6)  # a smooth minimum


@pytest.mark.parametrize("dims", ["2D", "3D"])
def test_distance_to_edge_below_the_f1_f2_bisector(dims):
    """The edge distance is a minimum over bisectors, the F1/F2 one among them."""
    vec, w = points(500)
    kw = dict(w=w, dimensions=dims, scale=2.0)
    edge = voronoi_texture(vec, feature="DISTANCE_TO_EDGE", **kw)["Distance"]
    p1 = as_coord(voronoi_texture(vec, feature="F1", **kw), dims).astype(np.float64) * 2.0
    p2 = as_coord(voronoi_texture(vec, feature="F2", **kw), dims).astype(np.float64) * 2.0
    x = coords(vec, w, dims).astype(np.float64) * 2.0
    u = (p2 - p1) / np.linalg.norm(p2 - p1, axis=1, keepdims=True)
    bisector = np.sum(((p1 + p2) / 2 - x) * u, axis=1)
    assert np.all(edge >= -1e-6)
    assert np.all(edge <= bisector + 1e-4)


def test_n_sphere_radius_is_half_a_feature_gap():
    vec, w = points(300)
    out = voronoi_texture(vec, w=w, dimensions="2D", feature="N_SPHERE_RADIUS", scale=1.0,
                          randomness=0.0)
    np.testing.assert_allclose(out["Radius"], 0.5, atol=1e-6)  # lattice spacing 1
    out = voronoi_texture(vec, w=w, dimensions="3D", feature="N_SPHERE_RADIUS", scale=2.0)
    assert set(out) == {"Radius"}
    assert out["Radius"].min() > 0.0 and out["Radius"].max() < np.sqrt(3.0)


def test_outputs_by_feature_and_dimension():
    vec, w = points(10)
    assert set(voronoi_texture(vec, w=w, dimensions="1D")) == {"Distance", "Color", "W"}
    assert set(voronoi_texture(vec, dimensions="2D")) == {"Distance", "Color", "Position"}
    assert set(voronoi_texture(vec, dimensions="4D")) == {"Distance", "Color", "Position", "W"}
    assert set(voronoi_texture(vec, feature="DISTANCE_TO_EDGE")) == {"Distance"}
    out = voronoi_texture(vec, dimensions="2D")
    assert out["Position"].shape == (10, 3) and np.all(out["Position"][:, 2] == 0.0)
    assert voronoi_texture(None, w=w, dimensions="1D")["Distance"].shape == (10,)
    with pytest.raises(ValueError):
        voronoi_texture(vec, feature="F3")


# ---- gradient -------------------------------------------------------------------------------

KNOWN = [
    ("LINEAR", (0.25, 9.0, -3.0), 0.25), ("LINEAR", (-1.0, 0.0, 0.0), 0.0),
    ("LINEAR", (2.0, 0.0, 0.0), 1.0),
    ("QUADRATIC", (0.5, 0.0, 0.0), 0.25), ("QUADRATIC", (-0.5, 0.0, 0.0), 0.0),
    ("EASING", (0.5, 0.0, 0.0), 0.5), ("EASING", (0.25, 0.0, 0.0), 0.15625),
    ("EASING", (1.5, 0.0, 0.0), 1.0),
    ("DIAGONAL", (0.2, 0.4, 7.0), 0.3), ("DIAGONAL", (1.0, 3.0, 0.0), 1.0),
    ("RADIAL", (1.0, 0.0, 0.0), 0.5), ("RADIAL", (0.0, 1.0, 0.0), 0.75),
    ("RADIAL", (0.0, -1.0, 0.0), 0.25), ("RADIAL", (-1.0, 0.0, 0.0), 1.0),
    ("SPHERICAL", (0.0, 0.0, 0.0), 0.999999), ("SPHERICAL", (0.0, 0.6, 0.0), 0.399999),
    ("SPHERICAL", (0.0, 0.0, 1.0), 0.0), ("SPHERICAL", (3.0, 0.0, 0.0), 0.0),
    ("QUADRATIC_SPHERE", (0.3, 0.4, 0.0), 0.499999 ** 2),
    ("QUADRATIC_SPHERE", (1.0, 1.0, 1.0), 0.0),
]


@pytest.mark.parametrize("gtype,point,fac", KNOWN)
def test_gradient_known_values(gtype, point, fac):
    got = gradient_texture(np.array([point], np.float32), gtype)
    assert got.shape == (1,) and got.dtype == np.float32
    assert got[0] == pytest.approx(fac, abs=1e-6)


@pytest.mark.parametrize("gtype", GRADIENT_TYPES)
def test_gradient_range_and_colour(gtype):
    vec, _ = points(500, spread=2.0)
    out = gradient_outputs(vec, gtype)
    assert out["Fac"].min() >= 0.0 and out["Fac"].max() <= 1.0
    np.testing.assert_array_equal(out["Color"], np.repeat(out["Fac"][:, None], 3, axis=1))
    raw = gradient_texture(vec, gtype, clamp=False)
    np.testing.assert_array_equal(np.clip(raw, 0, 1), out["Fac"])


def test_outputs_subset_skips_nothing_it_returns():
    vec, w = points(50)
    full = voronoi_texture(vec, feature="SMOOTH_F1", dimensions="3D", scale=2.0)
    part = voronoi_texture(vec, feature="SMOOTH_F1", dimensions="3D", scale=2.0,
                           outputs=("Distance", "Position"))
    assert set(part) == {"Distance", "Position"}
    for name in part:
        np.testing.assert_array_equal(part[name], full[name])
