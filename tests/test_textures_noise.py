"""Properties of the numpy Noise / Wave textures and lookup3 hashes (no bpy).

The bpy comparison lives in tests/blender/test_textures_bpy.py; here: the vectorised
hashes against a scalar pure-Python lookup3 written from Bob Jenkins' description, and
properties of the noise (range, continuity, fractional detail, per-point arrays).
"""
import struct

import numpy as np
import pytest

from mpp_render.textures import hash as th

M = 0xFFFFFFFF


# ---- scalar reference lookup3 (written independently, plain Python ints) -----------------

def _rot(x, k):
    return ((x << k) | (x >> (32 - k))) & M


def _final(a, b, c):
    c ^= b; c = (c - _rot(b, 14)) & M
    a ^= c; a = (a - _rot(c, 11)) & M
    b ^= a; b = (b - _rot(a, 25)) & M
    c ^= b; c = (c - _rot(b, 16)) & M
    a ^= c; a = (a - _rot(c, 4)) & M
    b ^= a; b = (b - _rot(a, 14)) & M
    c ^= b; c = (c - _rot(b, 24)) & M
    return c


def _mix(a, b, c):
    a = (a - c) & M; a ^= _rot(c, 4); c = (c + b) & M
    b = (b - a) & M; b ^= _rot(a, 6); a = (a + c) & M
    c = (c - b) & M; c ^= _rot(b, 8); b = (b + a) & M
    a = (a - c) & M; a ^= _rot(c, 16); c = (c + b) & M
    b = (b - a) & M; b ^= _rot(a, 19); a = (a + c) & M
    c = (c - b) & M; c ^= _rot(b, 4); b = (b + a) & M
    return a, b, c


def ref_hash(*keys):
    """lookup3 ``hashword`` specialised as Blender does for 1-4 keys."""
    n = len(keys)
    keys = [k & M for k in keys]
    a = b = c = (0xDEADBEEF + (n << 2) + 13) & M
    if n == 4:
        a = (a + keys[0]) & M; b = (b + keys[1]) & M; c = (c + keys[2]) & M
        a, b, c = _mix(a, b, c)
        a = (a + keys[3]) & M
        return _final(a, b, c)
    if n >= 3:
        c = (c + keys[2]) & M
    if n >= 2:
        b = (b + keys[1]) & M
    a = (a + keys[0]) & M
    return _final(a, b, c)


def fbits(x):
    return struct.unpack("<I", struct.pack("<f", x))[0]


def ref_hash_float(*xs):
    h = ref_hash(*[fbits(x) for x in xs])
    return float(np.float32(h) * (np.float32(1.0) / np.float32(4294967295.0)))


# ---- hashes ------------------------------------------------------------------------------

def test_lookup3_known_values():
    # lookup3 hashword(k, n, 0) for n = 1..4 keys, as Blender specialises it; literals
    # pinned from the scalar reference above so that a change in either side is noticed
    # (the bpy test checks the float hashes bit for bit against Blender's White Noise).
    assert [ref_hash(0), ref_hash(1), ref_hash(1, 2), ref_hash(1, 2, 3), ref_hash(1, 2, 3, 4)] \
        == [0x9519DC65, 0x4AD7C6A0, 0x1037CB9D, 0xB8D17A0A, 0x0584DEC1]
    assert int(th.hash_uint(0)) == 0x9519DC65
    assert int(th.hash_uint(1)) == 0x4AD7C6A0
    assert int(th.hash_uint2(1, 2)) == 0x1037CB9D
    assert int(th.hash_uint3(1, 2, 3)) == 0xB8D17A0A
    assert int(th.hash_uint4(1, 2, 3, 4)) == 0x0584DEC1
    assert th.hash_uint(np.array([0, 1], np.uint32)).dtype == np.uint32


def test_uint_to_float_maps_to_closed_unit_interval():
    u = th.uint_to_float(np.array([0, 1, 0x80000000, 0xFFFFFFFF], np.uint32))
    assert u.dtype == np.float32
    assert u[0] == 0.0 and u[-1] == 1.0 and u[2] == 0.5


@pytest.mark.parametrize("nkeys", [1, 2, 3, 4])
def test_integer_hash_matches_scalar_reference(nkeys):
    rng = np.random.default_rng(nkeys)
    keys = rng.integers(0, 2**32, size=(64, nkeys), dtype=np.uint64).astype(np.uint32)
    keys[0] = 0
    keys[1] = 0xFFFFFFFF
    fn = [th.hash_uint, th.hash_uint2, th.hash_uint3, th.hash_uint4][nkeys - 1]
    got = fn(*[keys[:, i] for i in range(nkeys)])
    want = [ref_hash(*[int(v) for v in row]) for row in keys]
    assert got.tolist() == want


def test_integer_hash_wraps_negative_ints_like_c():
    x = np.array([-1, -2, -1000], np.int64)
    assert th.hash_uint2(x, x).tolist() == [ref_hash(int(v) & M, int(v) & M) for v in x]


def test_float_hashes_match_scalar_reference():
    rng = np.random.default_rng(7)
    p = (rng.normal(size=(50, 4)) * 100).astype(np.float32)
    p[0] = [0.0, -0.0, 1.0, -1.0]
    for n, fn in [(2, th.hash_float2_to_float), (3, th.hash_float3_to_float),
                  (4, th.hash_float4_to_float)]:
        got = fn(p[:, :n])
        want = [ref_hash_float(*map(float, row[:n])) for row in p]
        np.testing.assert_array_equal(got, np.float32(want))
    got = th.hash_float_to_float(p[:, 0])
    np.testing.assert_array_equal(got, np.float32([ref_hash_float(float(v)) for v in p[:, 0]]))
    # -0.0 and 0.0 have different bit patterns, so different hashes
    assert th.hash_float_to_float(np.float32(0.0)) != th.hash_float_to_float(np.float32(-0.0))


def test_vector_float_hashes_compose_as_blender():
    rng = np.random.default_rng(3)
    p = rng.uniform(-10, 10, size=(20, 4)).astype(np.float32)
    x, y, z, w = (p[:, i] for i in range(4))
    one, two = np.ones_like(x), 2 * np.ones_like(x)
    st = np.stack
    np.testing.assert_array_equal(
        th.hash_float3_to_float3(p[:, :3]),
        st([th.hash_float3_to_float(p[:, :3]), th.hash_float4_to_float(st([x, y, z, one], -1)),
            th.hash_float4_to_float(st([x, y, z, two], -1))], -1))
    np.testing.assert_array_equal(
        th.hash_float4_to_float4(p),
        st([th.hash_float4_to_float(st(v, -1)) for v in
            ([x, y, z, w], [w, x, y, z], [z, w, x, y], [y, z, w, x])], -1))
    np.testing.assert_array_equal(
        th.hash_float4_to_float3(p),
        st([th.hash_float4_to_float(st(v, -1)) for v in
            ([x, y, z, w], [z, x, w, y], [w, z, y, x])], -1))
    np.testing.assert_array_equal(
        th.hash_float2_to_float2(p[:, :2]),
        st([th.hash_float2_to_float(p[:, :2]), th.hash_float3_to_float(st([x, y, one], -1))], -1))
    np.testing.assert_array_equal(
        th.hash_float_to_float3(x),
        st([th.hash_float_to_float(x), th.hash_float2_to_float(st([x, one], -1)),
            th.hash_float2_to_float(st([x, two], -1))], -1))
    h = th.hash_float2_to_float3(p[:, :2])
    assert h.shape == (20, 3) and h.dtype == np.float32
    assert (h >= 0).all() and (h <= 1).all()


def test_float_hash_range_and_uniformity():
    x = np.arange(20000, dtype=np.float32) * np.float32(0.37)
    h = th.hash_float_to_float(x)
    assert h.dtype == np.float32 and h.min() >= 0.0 and h.max() <= 1.0
    assert abs(h.mean() - 0.5) < 0.01
    hist, _ = np.histogram(h, bins=10, range=(0, 1))
    assert hist.min() > 1800 and hist.max() < 2200


# ---- Perlin noise and the Noise Texture --------------------------------------------------

from mpp_render.textures import noise as nz  # noqa: E402
from mpp_render.textures.noise import noise_texture  # noqa: E402
from mpp_render.textures.wave import wave_texture  # noqa: E402

TYPES = ["FBM", "MULTIFRACTAL", "HYBRID_MULTIFRACTAL", "RIDGED_MULTIFRACTAL", "HETERO_TERRAIN"]


def _pts(n=4000, lo=-4.0, hi=4.0, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(lo, hi, (n, 3)).astype(np.float32), rng.uniform(lo, hi, n).astype(
        np.float32)


@pytest.mark.parametrize("d", [1, 2, 3, 4])
def test_perlin_signed_range_and_statistics(d):
    rng = np.random.default_rng(d)
    p = rng.uniform(-50, 50, (50000, d)).astype(np.float32)
    v = nz.perlin_signed(p)
    assert v.dtype == np.float32 and v.shape == (50000,)
    assert np.abs(v).max() <= 1.0          # Blender's scale factors keep it in [-1, 1]
    assert np.abs(v).max() > 0.7           # ... and use most of that range
    assert abs(float(v.mean())) < 0.01
    assert 0.2 < float(v.std()) < 0.4
    u = nz.perlin(p)
    np.testing.assert_allclose(u, v / 2 + 0.5, atol=1e-7)


@pytest.mark.parametrize("d", [1, 2, 3, 4])
def test_perlin_is_zero_on_the_lattice_and_continuous(d):
    rng = np.random.default_rng(10 + d)
    ints = rng.integers(-1000, 1000, (500, d)).astype(np.float32)
    assert np.abs(nz.perlin_noise(ints)).max() == 0.0
    # continuity across cell borders: |dn| <= L |dp| with a modest Lipschitz constant
    p = rng.uniform(-20, 20, (5000, d)).astype(np.float32)
    p[:1000] = np.round(p[:1000]) - 1e-4     # just below a lattice plane
    eps = np.float32(2e-4)
    dv = np.abs(nz.perlin_signed(p + eps) - nz.perlin_signed(p))
    assert dv.max() < 20 * float(eps)


def test_negative_integer_positions_use_blenders_floor_fraction():
    # BLI's floor_fraction gives (i - 1, 1.0) at negative integers: same noise value (0)
    x = np.array([[-3.0], [-1.0], [3.0]], np.float32)
    assert np.abs(nz.perlin_noise(x)).max() == 0.0
    # just around a negative integer the noise is continuous
    a = nz.perlin_signed(np.array([[-2.0 - 1e-4], [-2.0], [-2.0 + 1e-4]], np.float32))
    assert np.abs(np.diff(a)).max() < 1e-3


def test_large_coordinates_wrap_and_avoid_the_integer_lattice():
    # |x| >= 1e6: every float32 there is an integer, where Perlin noise would be 0;
    # Blender adds 0.5 after the fmod, so the noise is not identically zero there
    x = np.array([[1.0e6], [2.5e6], [-3.0e6], [1.0e7]], np.float32)
    assert np.abs(nz.perlin_signed(x)).min() > 0.0
    # below 1e6 the period is 100000 for positions that survive the float rounding
    p = np.array([[12.5, 7.25, 3.0]], np.float32)  # fmod keeps the sign: same-sign shift
    np.testing.assert_array_equal(nz.perlin_signed(p), nz.perlin_signed(p + np.float32(2e5)))


@pytest.mark.parametrize("dims", ["1D", "2D", "3D", "4D"])
def test_fbm_normalized_range_and_color(dims):
    v, w = _pts()
    fac, col = noise_texture(v, w=w, dimensions=dims, detail=3.0)
    assert fac.shape == (4000,) and fac.dtype == np.float32
    assert col.shape == (4000, 3) and col.dtype == np.float32
    assert fac.min() >= 0.0 and fac.max() <= 1.0
    assert abs(float(fac.mean()) - 0.5) < 0.03
    np.testing.assert_array_equal(col[:, 0], fac)
    # the two extra channels are other noise values (Blender's random offsets)
    assert np.abs(col[:, 1] - fac).mean() > 0.05 and np.abs(col[:, 2] - col[:, 1]).mean() > 0.05
    assert noise_texture(v, w=w, dimensions=dims, color=False)[1] is None


def test_dimensions_use_only_their_coordinates():
    v, w = _pts(500)
    v2 = v.copy()
    v2[:, 2] += 1.37
    w2 = w + 0.71
    f1 = lambda dims, vv, ww: noise_texture(vv, w=ww, dimensions=dims, distortion=0.5)[0]  # noqa
    np.testing.assert_array_equal(f1("1D", v, w), f1("1D", v2 * 3, w))
    np.testing.assert_array_equal(f1("2D", v, w), f1("2D", v2, w2))
    np.testing.assert_array_equal(f1("3D", v, w), f1("3D", v, w2))
    assert np.abs(f1("3D", v, w) - f1("3D", v2, w)).max() > 0.05
    assert np.abs(f1("4D", v, w) - f1("4D", v, w2)).max() > 0.05


@pytest.mark.parametrize("noise_type", ["FBM", "MULTIFRACTAL", "HETERO_TERRAIN"])
@pytest.mark.parametrize("normalize", [True, False])
def test_fractional_detail_blends_the_next_octave_linearly(noise_type, normalize):
    v, _ = _pts(2000)
    kw = dict(dimensions="3D", noise_type=noise_type, normalize=normalize, roughness=0.6,
              lacunarity=2.3, offset=0.4, color=False)
    f2 = noise_texture(v, detail=2.0, **kw)[0].astype(np.float64)
    f3 = noise_texture(v, detail=3.0, **kw)[0].astype(np.float64)
    for t in (0.25, 0.5, 0.9):
        ft = noise_texture(v, detail=2.0 + t, **kw)[0]
        np.testing.assert_allclose(ft, (1 - t) * f2 + t * f3, atol=2e-6)
    assert np.abs(f3 - f2).max() > 1e-3


def test_ridged_multifractal_ignores_the_fractional_detail():
    v, _ = _pts(1000)
    kw = dict(noise_type="RIDGED_MULTIFRACTAL", offset=1.0, gain=2.0, color=False)
    np.testing.assert_array_equal(noise_texture(v, detail=2.0, **kw)[0],
                                  noise_texture(v, detail=2.7, **kw)[0])


def test_detail_and_roughness_are_clamped_like_blender():
    v, w = _pts(800)
    f = lambda **k: noise_texture(v, w=w, color=False, **k)[0]  # noqa: E731
    np.testing.assert_array_equal(f(detail=20.0), f(detail=15.0))
    np.testing.assert_array_equal(f(detail=-3.0), f(detail=0.0))
    np.testing.assert_array_equal(f(roughness=-0.5, detail=4.0), f(roughness=0.0, detail=4.0))
    # detail 0: a single octave, no lacunarity or roughness dependence
    np.testing.assert_array_equal(f(detail=0.0, lacunarity=3.0), f(detail=0.0, roughness=0.1))


@pytest.mark.parametrize("noise_type", TYPES)
@pytest.mark.parametrize("dims", ["1D", "3D", "4D"])
def test_per_point_arrays_equal_scalar_calls(noise_type, dims):
    """Every numeric input given per point (each point drawing one of 5 parameter sets,
    which differ in every input) equals the scalar calls on each point subset."""
    v, w = _pts(600, seed=3)
    sets = [dict(detail=0.0, roughness=0.3, lacunarity=1.7, offset=0.0, gain=0.5,
                 distortion=0.0, scale=2.0),
            dict(detail=1.5, roughness=0.8, lacunarity=2.5, offset=0.7, gain=2.0,
                 distortion=0.8, scale=-4.0),
            dict(detail=3.0, roughness=0.5, lacunarity=2.0, offset=1.0, gain=1.0,
                 distortion=-0.3, scale=5.0),
            dict(detail=6.25, roughness=0.65, lacunarity=2.2, offset=0.3, gain=1.5,
                 distortion=1.5, scale=1.0),
            dict(detail=2.75, roughness=1.2, lacunarity=3.1, offset=-0.2, gain=0.9,
                 distortion=0.2, scale=0.5)]
    pick = np.random.default_rng(4).integers(0, len(sets), 600)
    arrays = {k: np.asarray([s_[k] for s_ in sets], np.float32)[pick] for k in sets[0]}
    fac, col = noise_texture(v, w=w, dimensions=dims, noise_type=noise_type, **arrays)
    for i, scal in enumerate(sets):
        sel = pick == i
        f1, c1 = noise_texture(v[sel], w=w[sel], dimensions=dims, noise_type=noise_type, **scal)
        np.testing.assert_array_equal(fac[sel], f1)
        np.testing.assert_array_equal(col[sel], c1)


@pytest.mark.parametrize("noise_type", TYPES)
def test_noise_texture_is_continuous_in_position(noise_type):
    v, _ = _pts(3000, seed=9)
    eps = np.float32(1e-4)
    kw = dict(noise_type=noise_type, detail=3.5, distortion=0.6, offset=0.5, color=False)
    a = noise_texture(v, **kw)[0]
    b = noise_texture(v + eps, **kw)[0]
    # scale 5 and 4-5 octaves at lacunarity 2: a generous Lipschitz bound
    assert np.abs(a - b).max() < 2000 * float(eps)
    assert np.isfinite(a).all()


def test_hybrid_multifractal_stops_at_small_weight():
    v, _ = _pts(1000)
    # gain 0: weight becomes 0 after the first octave, so detail does not matter
    kw = dict(noise_type="HYBRID_MULTIFRACTAL", gain=0.0, offset=0.2, color=False)
    np.testing.assert_array_equal(noise_texture(v, detail=0.0, **kw)[0],
                                  noise_texture(v, detail=7.5, **kw)[0])


def test_bad_enums_raise():
    v, _ = _pts(4)
    with pytest.raises(ValueError):
        noise_texture(v, dimensions="5D")
    with pytest.raises(ValueError):
        noise_texture(v, noise_type="PERLIN")
    with pytest.raises(ValueError):
        wave_texture(v, wave_profile="SQUARE")


# ---- Wave Texture ------------------------------------------------------------------------

def test_wave_bands_closed_form_without_distortion():
    v, _ = _pts(3000)
    p = (v.astype(np.float64) * 5 + 1e-6) * 0.999999
    for direction, n in (("X", 20 * p[:, 0]), ("Y", 20 * p[:, 1]), ("Z", 20 * p[:, 2]),
                         ("DIAGONAL", 10 * p.sum(1))):
        fac, col = wave_texture(v, bands_direction=direction, phase_offset=0.3)
        np.testing.assert_allclose(fac, 0.5 + 0.5 * np.sin(n + 0.3 - np.pi / 2), atol=2e-4)
        np.testing.assert_array_equal(col, np.repeat(fac[:, None], 3, 1))


def test_wave_rings_and_profiles():
    v, _ = _pts(3000)
    p = (v.astype(np.float64) * 5 + 1e-6) * 0.999999
    r = {"X": np.hypot(p[:, 1], p[:, 2]), "Y": np.hypot(p[:, 0], p[:, 2]),
         "Z": np.hypot(p[:, 0], p[:, 1]), "SPHERICAL": np.linalg.norm(p, axis=1)}
    for direction, rr in r.items():
        t = 20 * rr / (2 * np.pi)
        saw = wave_texture(v, wave_type="RINGS", rings_direction=direction, wave_profile="SAW")[0]
        tri = wave_texture(v, wave_type="RINGS", rings_direction=direction, wave_profile="TRI")[0]
        frac = t - np.floor(t)
        ok = (frac > 1e-3) & (frac < 1 - 1e-3)      # away from the saw's jump
        np.testing.assert_allclose(saw[ok], frac[ok], atol=2e-4)
        np.testing.assert_allclose(tri, 2 * np.abs(t - np.floor(t + 0.5)), atol=2e-4)
        assert saw.min() >= 0 and saw.max() < 1 and tri.min() >= 0 and tri.max() <= 1


def test_wave_distortion_uses_fbm_and_per_point_inputs():
    v, _ = _pts(1500)
    rng = np.random.default_rng(2)
    dist = np.where(rng.random(1500) < 0.5, 0.0, 4.0).astype(np.float32)
    detail = rng.uniform(0, 6, 1500).astype(np.float32)
    fac = wave_texture(v, distortion=dist, detail=detail, detail_scale=2.0)[0]
    plain = wave_texture(v)[0]
    np.testing.assert_array_equal(fac[dist == 0], plain[dist == 0])
    assert np.abs(fac[dist != 0] - plain[dist != 0]).mean() > 0.05
    # the distortion term is distortion * (2 fbm - 1) added to the band phase
    p = (v * np.float32(5) + np.float32(1e-6)) * np.float32(0.999999)
    on = dist != 0
    n = nz.fbm(p[on] * np.float32(2.0), detail[on], 0.5, 2.0, True)
    phase = p[on, 0] * 20 + 4.0 * (2 * n.astype(np.float64) - 1)
    np.testing.assert_allclose(fac[on], 0.5 + 0.5 * np.sin(phase - np.pi / 2), atol=2e-4)
