"""Light paths beyond the grid and off surfaces (paths.py, csrc/paths.c): the twins agree with
surfaces, an outside fog, cosine starts and chromatic spectral tracking; a fog outside a small
grid gives the deposits of a grid large enough to hold the light; a black wall stops every
path; a white floor under a source sends light back that a black one does not."""
import dataclasses

import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.paths import PathInputs, from_power, trace_paths_np
from mpp_render.precompute.lattice import lattice_shape
from rays import path_twins

needs_c = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")


def box(n, stride, vox, sigma_s, sigma_t, g=0.3, n_paths=4000, starts=((0.0, 0.0, 0.0),),
        dirs=((1.0, 0.0, 0.0),), seed=3, **kw):
    """PathInputs for a homogeneous cube of n^3 voxels (side ``vox`` m) centred on the origin,
    paths from ``starts`` (1 W each) along ``dirs``, the camera far along -y."""
    ls = lattice_shape((n, n, n), stride)
    half = 0.5 * (n - 1) * vox
    idx = np.stack(np.meshgrid(*[np.arange(s) * stride for s in ls], indexing="ij"), -1)
    v = np.array([0.0, -50.0, 1.0]) - (idx * vox - half)
    towards = np.ascontiguousarray(v / np.linalg.norm(v, axis=-1, keepdims=True))
    starts = np.asarray(starts, np.float64)
    w, cdf = from_power(np.ones((len(starts), 3)))
    d = np.asarray(dirs, np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    st = np.broadcast_to(np.asarray(sigma_t, np.float64), (3,)).copy()
    return PathInputs(np.ones((n, n, n), np.float32),
                      np.concatenate([np.eye(3) / vox, np.full((3, 1), half / vox)], axis=1),
                      np.eye(3) * vox,
                      np.broadcast_to(np.asarray(sigma_s, np.float64), (3,)).copy(),
                      st, g, stride, towards, starts, w, d, cdf,
                      max(float(st.max()), 1.0 / (stride * vox)), n_paths, seed, **kw)


def quad(z, size=50.0):
    """Two triangles (2,3,3: corner, edge, edge) of a square of side ``size`` at height z."""
    h = 0.5 * size
    a = np.array([-h, -h, z])
    return np.array([[a, [size, 0, 0], [0, size, 0]],
                     [a + [size, size, 0], [-size, 0, 0], [0, -size, 0]]], np.float64)


def test_twins_agree_with_surfaces_fog_outside_and_cosine_starts():
    rng = np.random.default_rng(4)
    tris = np.concatenate([quad(-0.35), quad(0.6, 0.8)])
    inp = box(16, 2, 0.05, [0.9, 1.2, 1.5], [2.0, 2.5, 3.0], n_paths=1500,
              starts=rng.uniform(-0.3, 0.3, (5, 3)), dirs=rng.normal(size=(5, 3)),
              jitter=0.0, lobe=1, outside=1.0, reach_centre=np.zeros(3), reach_radius=3.0,
              triangles=tris, albedo=np.array([[0.8, 0.5, 0.2]] * 2 + [[0.3, 0.3, 0.3]] * 2))
    path_twins(inp)
    grey = dataclasses.replace(inp, sigma_s=np.full(3, 1.0), sigma_t=np.full(3, 2.0), lobe=0,
                               jitter=1.0)
    a, b = trace_paths_np(grey), kernels.trace_paths(grey)
    assert np.abs(a - b).max() <= 1e-9 * np.abs(a).max()


@needs_c
def test_fog_outside_a_small_grid_gives_the_large_grids_deposits():
    """Paths that leave a small grid into the same fog and come back: the small grid's deposits
    equal those of the same region inside a grid 3x as wide (whose faces the light hardly
    reaches: 4.5 diffusion lengths 1 / sqrt(3 sigma_a sigma_tr), the small one's 0.9)."""
    kw = dict(sigma_s=1.9, sigma_t=2.0, g=0.5, n_paths=40000)
    small = box(17, 2, 0.2, **kw, outside=1.0, reach_centre=np.zeros(3), reach_radius=20.0)
    large = box(81, 2, 0.2, **kw)           # its lattice points 16..24 are the small one's
    inner = (slice(1, 8),) * 3              # lattice points whose tents lie in the small grid
    a = kernels.trace_paths(small)[inner]
    b = kernels.trace_paths(large)[16:25, 16:25, 16:25][inner]
    cut = kernels.trace_paths(box(17, 2, 0.2, **kw))[inner]
    assert a.sum() == pytest.approx(b.sum(), rel=0.02)
    assert cut.sum() < 0.9 * b.sum()   # without the fog outside, light is lost
    mid = (slice(2, 5),) * 3
    assert a[mid].sum() == pytest.approx(b[mid].sum(), rel=0.03)


@needs_c
def test_a_black_wall_stops_every_path():
    inp = box(24, 2, 0.05, 1.8, 2.0, n_paths=5000, starts=[(0.0, 0.0, -0.2)],
              dirs=[(0.0, 0.0, 1.0)], triangles=quad(0.0), albedo=np.zeros((2, 3)))
    out = kernels.trace_paths(inp)
    z = (np.arange(out.shape[2]) * 2 * 0.05 - 0.5 * 23 * 0.05)
    assert out[:, :, z < -0.06].sum() > 0.0
    assert out[:, :, z > 0.06].sum() == 0.0


@needs_c
def test_a_white_floor_returns_light_a_black_one_absorbs():
    """Paths from a source just above a floor under a thin medium: a floor of albedo 1 adds
    light to the medium (the paths it reflects), in proportion to its albedo."""
    base = box(24, 2, 0.05, 0.95, 1.0, n_paths=20000, starts=[(0.0, 0.0, -0.45)],
               dirs=[(0.0, 0.0, -1.0)], lobe=0, g=0.0, triangles=quad(-0.5))
    black = kernels.trace_paths(dataclasses.replace(base, albedo=np.zeros((2, 3)))).sum()
    half = kernels.trace_paths(dataclasses.replace(base, albedo=np.full((2, 3), 0.5))).sum()
    white = kernels.trace_paths(dataclasses.replace(base, albedo=np.ones((2, 3)))).sum()
    assert black < half < white
    # the reflected part grows with the albedo, a little faster than linearly (light that
    # returns to the floor is reflected again)
    assert (white - black) / (half - black) == pytest.approx(2.0, rel=0.25)
    assert (white - black) / (half - black) >= 1.9


def test_bad_surface_and_fog_input_raises():
    if kernels._c is None:
        pytest.skip("compiled kernels not built")
    inp = box(8, 2, 0.1, 1.0, 2.0, n_paths=10)
    for bad in (dict(lobe=4), dict(lobe=-1), dict(jitter=-1.0), dict(outside=np.nan), dict(reach_radius=np.nan),
                dict(triangles=np.zeros((2, 3, 3)), albedo=np.zeros((3, 3)))):
        with pytest.raises(ValueError):
            kernels.trace_paths(dataclasses.replace(inp, **bad))


@needs_c
def test_spoiled_triangles_do_not_crash():
    inp = box(8, 2, 0.1, 1.0, 2.0, n_paths=500, triangles=np.array(
        [[[np.nan, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 0], [np.inf, 0, 0], [0, 1e300, 0]],
         [[0, 0, 0], [0, 0, 0], [0, 0, 0]]]), albedo=np.array([[1, 1, 1], [2, 2, 2], [np.nan] * 3]))
    out = kernels.trace_paths(inp)
    assert out.shape[-1] == 3


def test_twins_agree_with_aimed_surface_starts():
    """Lobe 3 (paths.py, "Starts"): starts on a floor, some inside the reach sphere (the
    cosine lobe alone), most outside it (aimed at it), one with the sphere behind its side
    (only the cosine lobe's share reaches anything); the twins agree."""
    rng = np.random.default_rng(7)
    far = np.column_stack([rng.uniform(-6.0, 6.0, (7, 2)), np.full(7, -0.6)])
    starts = np.vstack([far, [[0.1, 0.0, -0.6]], [[2.0, 0.0, 1.5]]])
    dirs = np.vstack([np.tile([0.0, 0.0, 1.0], (8, 1)), [[1.0, 0.0, 0.0]]])
    inp = box(16, 2, 0.05, [0.9, 1.2, 1.5], [2.0, 2.5, 3.0], n_paths=2000, starts=starts,
              dirs=dirs, jitter=0.02, lobe=3, reach_centre=np.zeros(3), reach_radius=0.8,
              triangles=quad(-0.6), albedo=np.full((2, 3), 0.4))
    path_twins(inp)


@needs_c
def test_aimed_surface_starts_keep_the_light_and_lose_its_noise():
    """A floor's light from four points 4 m off a cube of medium above it (cosine lobes):
    the aimed starts' deposits have the cosine lobe's mean (six seeds each, within their
    scatter) at a fraction of its seed-to-seed spread (measured 0.000028 against 0.00055,
    of a mean 0.0014: the cosine lobe sends few of its paths into the cube)."""
    starts = np.array([[4.0, 0.0, -0.6], [0.0, 4.0, -0.6], [-4.0, 0.0, -0.6], [0.0, -4.0, -0.6]])
    dirs = np.tile([0.0, 0.0, 1.0], (4, 1))

    def sums(lobe):
        out = []
        for seed in range(6):
            inp = box(16, 2, 0.05, 1.9, 2.0, n_paths=20000, starts=starts, dirs=dirs,
                      jitter=0.02, lobe=lobe, reach_centre=np.zeros(3), reach_radius=0.8,
                      seed=seed)
            out.append(kernels.trace_paths(inp).sum())
        return np.array(out)

    plain, aimed = sums(1), sums(3)
    err = np.hypot(plain.std(ddof=1), aimed.std(ddof=1)) / np.sqrt(6)
    assert abs(plain.mean() - aimed.mean()) < 3.0 * err
    assert aimed.std(ddof=1) < 0.2 * plain.std(ddof=1)
