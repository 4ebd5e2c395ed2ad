"""A mesh volume's sharp surface in the traced paths (paths.density_at, csrc/paths.c) and in
their first-scattering source (precompute.source.surface_band_source): the twins agree on
the thresholded trilinear density, the cells' inside parts hold a sphere's volume, and a
dense cube under a sun scatters the power the closed form gives, which its voxel centres
alone miss."""
import dataclasses

import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.media import prepare
from mpp_render.paths import PathInputs, PathMedium, from_power, trace_paths_media_np
from mpp_render.precompute import lightpaths, precompute
from mpp_render.precompute.lattice import lattice_shape
from mpp_render.precompute.lightpaths import cell_volume, sharp_fraction
from mpp_render.scene import Camera, Light, Medium, World


def ortho_camera():
    c2w = np.eye(4)
    c2w[:3, 3] = [0.0, 0.0, 20.0]
    return Camera("ORTHO", c2w, 16, 16, (-1.0, 1.0, -1.0, 1.0))


def random_paths_setup(rng, n, vox):
    """(towards, w2i, weights, cdf, dirs) of a random trace on an n^3 grid of voxel ``vox``
    (m) at the origin: random unit directions to the camera on its stride-2 lattice, and 5
    starts' powers and directions, drawn from ``rng`` in that order."""
    ls = lattice_shape((n, n, n), 2)
    tow = rng.normal(size=ls + (3,))
    tow /= np.linalg.norm(tow, axis=-1, keepdims=True)
    w2i = np.concatenate([np.eye(3) / vox, np.zeros((3, 1))], 1)
    w, cdf = from_power(rng.random((5, 3)) + 0.1)
    d = rng.normal(size=(5, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    return tow, w2i, w, cdf, d


def test_twins_agree_through_a_sharp_surface():
    rng = np.random.default_rng(3)
    n, vox = 16, 0.1
    tow, w2i, w, cdf, d = random_paths_setup(rng, n, vox)
    other = PathMedium(rng.random((n, n, n)).astype(np.float32), w2i, np.full(3, 1.5),
                       np.full(3, 2.0), 0.2, 2, tow, 4.0, threshold=0.4)
    inp = PathInputs(rng.random((n, n, n)).astype(np.float32), w2i, np.eye(3) * vox,
                     np.array([1.0, 1.5, 2.0]), np.array([2.0, 2.0, 2.5]), 0.6, 2, tow,
                     rng.random((5, 3)) * 1.4, w, d, cdf, 5.0, 2000, 5, others=(other,),
                     threshold=0.5, start_source=rng.random((n, n, n)).astype(np.float32),
                     start_peak=np.ones(5))
    a = trace_paths_media_np(inp)
    b = kernels.trace_paths_media(inp, threads=2)
    for x, y in zip(a, b):
        assert x.sum() > 0.0
        assert np.abs(x - y).max() <= 1e-9 * np.abs(x).max()
    # the threshold changes the medium the paths see
    plain = kernels.trace_paths_media(dataclasses.replace(inp, threshold=-1.0), threads=2)
    assert not np.allclose(plain[0], b[0])


def test_the_cells_inside_parts_hold_a_spheres_volume():
    n, vox, r = 40, 0.05, 0.77
    grid = sphere_ramp(n, vox, r)   # 0.5 on the sphere
    frac = sharp_fraction(grid, 0.5)
    assert frac.min() >= 0.0 and frac.max() <= 1.0
    assert np.any((frac > 0.0) & (frac < 1.0))
    assert frac.sum() * vox ** 3 == pytest.approx(4.0 / 3.0 * np.pi * r ** 3, rel=0.01)


def dense_cube(n=50, vox=0.02, sigma_t=40.0, albedo=0.9):
    """A 1 m mesh cube of density 1 (source MESH: a sharp surface at the grid's threshold,
    here halfway between its last voxel and the padding), sigma_t x voxel = 0.8."""
    i2w = np.eye(4)
    i2w[:3, :3] *= vox
    i2w[:3, 3] = -0.5 * (n - 1) * vox
    return Medium("cube", np.ones((n, n, n), np.float32), i2w, np.full(3, albedo * sigma_t),
                  np.full(3, (1.0 - albedo) * sigma_t), 0.3, source="MESH")


def test_a_dense_cube_scatters_the_suns_power(monkeypatch):
    """A sun straight down on a 1 m cube of optical depth 40: its first scatterings carry
    E x 1 m^2 x albedo x (1 - e^-40).  The source read at the voxels' centres is 2.6 % low
    (the lit layer's exp(-tau) falls by e^-0.8 across a voxel); the surface voxels' points
    and the cells' depth factor bring it within 1 %."""
    totals = {}
    orig = lightpaths.source_and_density

    def capture(pm, fld, light, channel, stride, **kw):
        got = orig(pm, fld, light, channel, stride, **kw)
        centre = orig(pm, fld, light, channel, stride, **{**kw, "depth": None})
        totals["points"] = float(got[0].sum(axis=0)[0] * cell_volume(pm, stride))
        totals["centres"] = float(centre[0].sum(axis=0)[0] * cell_volume(pm, stride))
        return got

    monkeypatch.setattr(lightpaths, "source_and_density", capture)
    sun = Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.0, 0.0, -1.0]))
    precompute([prepare(dense_cube())], [sun], World(), ortho_camera(), multiple=True,
               multiple_paths=2000, multiple_resolution=25)
    exact = 3.0 * 1.0 * 0.9 * (1.0 - np.exp(-40.0))
    print(totals, exact)
    assert totals["points"] == pytest.approx(exact, rel=0.01)
    assert abs(totals["centres"] / exact - 1.0) > 0.02


def sphere_ramp(n=40, vox=0.05, r=0.77):
    """(n,n,n) float32: 1 inside a sphere of radius r (m), 0 outside, a one-voxel ramp
    through 0.5 on its surface (a mesh volume's voxelisation)."""
    c = (np.arange(n) - 0.5 * (n - 1)) * vox
    x, y, z = np.meshgrid(c, c, c, indexing="ij")
    return np.clip(0.5 + (r - np.sqrt(x * x + y * y + z * z)) / vox, 0.0, 1.0).astype(np.float32)


def test_cell_classes_agree_with_the_trilinear_threshold():
    rng = np.random.default_rng(11)
    grid = sphere_ramp()
    grid[3, 4, 5] = np.nan
    grid[20, 20, 20] = np.inf
    grid[30, 20, 20] = 0.5            # a voxel exactly at the threshold
    cells = kernels.cell_classes(grid, 0.5)
    assert cells.shape == (39, 39, 39) and cells.dtype == np.uint8
    assert {0, 1, 2} <= set(np.unique(cells).tolist())
    for idx in [(3, 4, 5), (2, 3, 4), (20, 20, 20), (19, 19, 19), (29, 19, 19)]:
        assert cells[idx] == 2, idx   # a non-finite voxel or one at the threshold: read it
    # at random points of the cells of class 0 and 1 the trilinear value is on that side
    i0 = np.argwhere(cells < 2)[rng.integers(0, int((cells < 2).sum()), 4000)]
    fr = rng.random((len(i0), 3))
    v = np.zeros(len(i0))
    for o in np.ndindex(2, 2, 2):
        w = np.prod(np.where(np.asarray(o) == 1, fr, 1.0 - fr), axis=1)
        v += w * grid[tuple((i0 + np.asarray(o)).T)].astype(np.float64)
    np.testing.assert_array_equal((v >= 0.5).astype(np.uint8), cells[tuple(i0.T)])
    # no map where there is no sharp surface, or no cell
    assert kernels.cell_classes(grid, -1.0).size == 0
    assert kernels.cell_classes(grid, 0.0).size == 0
    assert kernels.cell_classes(np.ones((1, 5, 5), np.float32), 0.5).size == 0


@pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")
def test_the_tracer_finds_the_same_bits_with_and_without_the_cells(monkeypatch):
    """The cells' classes only spare the tracer reads: its deposits are the same bits with
    them as without, and the numpy twin (which reads every cell) agrees."""
    rng = np.random.default_rng(5)
    n, vox = 40, 0.05
    grid = sphere_ramp(n, vox)
    grid[10, 12, 20] = np.nan
    tow, w2i, w, cdf, d = random_paths_setup(rng, n, vox)
    other = PathMedium(np.roll(grid, 3, axis=0), w2i, np.full(3, 1.5), np.full(3, 2.0), 0.2, 2,
                       tow, 20.0, threshold=0.5)
    inp = PathInputs(grid, w2i, np.eye(3) * vox, np.full(3, 1.6), np.full(3, 2.0), 0.6, 2, tow,
                     0.6 + rng.random((5, 3)) * 0.8, w, d, cdf, 20.0, 3000, 7, others=(other,),
                     threshold=0.5)
    with_cells = kernels.trace_paths_media(inp, threads=2)
    twin = trace_paths_media_np(inp)
    monkeypatch.setattr(kernels, "cell_classes", lambda *a: np.zeros((0, 0, 0), np.uint8))
    without = kernels.trace_paths_media(inp, threads=2)
    for a, b, t in zip(with_cells, without, twin):
        assert a.sum() > 0.0
        np.testing.assert_array_equal(a, b)
        assert np.abs(a - t).max() <= 1e-9 * np.abs(t).max()
    # a map of the wrong shape is refused, not read out of bounds
    monkeypatch.setattr(kernels, "cell_classes", lambda *a: np.zeros((3, 3, 3), np.uint8))
    with pytest.raises(ValueError, match="cells"):
        kernels.trace_paths_media(inp, threads=1)
