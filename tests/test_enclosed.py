"""Voxels behind the scene's surfaces (precompute/enclosed.py): under a ground and inside a
closed mesh, on grids aligned with the world and turned; and the traced paths' lattice means
leave them out (a lattice point on a ground holds the medium above it, not half of it)."""
import numpy as np
import pytest

from mpp_render.media import prepare
from mpp_render.precompute.enclosed import enclosed_voxels
from mpp_render.precompute.lightpaths import PathLattice
from mpp_render.scene import Camera, Medium, Surface
from mpp_render.surfaces import prepare_surfaces


def ground(z=0.0, half=10.0, up=True):
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    tris = np.array([[0, 1, 2], [0, 2, 3]] if up else [[0, 2, 1], [0, 3, 2]])
    return Surface("ground", v, tris, np.full(3, 0.5))


def cube(centre, half):
    """A closed cube, its normals outwards."""
    c = np.asarray(centre, float)
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half + c
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = []
    for a, b, cc, d in quads:
        for t in ((a, b, cc), (a, cc, d)):
            n = np.cross(v[t[1]] - v[t[0]], v[t[2]] - v[t[0]])
            out = np.dot(n, v[t[0]] - c) > 0
            tris.append(t if out else (t[0], t[2], t[1]))
    return Surface("cube", v, np.array(tris), np.full(3, 0.5))


def medium(n=(20, 16, 24), voxel=0.1, turn=0.0):
    """A grid of ``n`` voxels of ``voxel`` m centred on the origin, turned by ``turn`` radians
    about x then z."""
    c, s = np.cos(turn), np.sin(turn)
    rx = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    i2w = np.eye(4)
    i2w[:3, :3] = rz @ rx * voxel
    i2w[:3, 3] = -i2w[:3, :3] @ ((np.array(n) - 1) / 2.0)
    return prepare(Medium("fog", np.ones(n, np.float32), i2w, np.full(3, 1.0), np.zeros(3), 0.0))


def centres(pm):
    shape = pm.grid.shape[:3]
    idx = np.stack(np.meshgrid(*[np.arange(k) for k in shape], indexing="ij"), -1)
    return idx.reshape(-1, 3) @ np.asarray(pm.i2w)[:3, :3].T + np.asarray(pm.i2w)[:3, 3]


def test_voxels_under_a_ground_and_inside_a_closed_mesh_are_enclosed():
    for turn in (0.0, 0.4):
        pm = medium(turn=turn)
        w = centres(pm)
        ss = prepare_surfaces([ground(z=-0.13), cube((0.3, -0.2, 0.25), 0.3)])
        got = enclosed_voxels(pm, ss).reshape(-1)
        inside = np.all(np.abs(w - [0.3, -0.2, 0.25]) < 0.3, axis=1)
        truth = (w[:, 2] < -0.13) | inside
        assert truth.mean() > 0.2 and inside.sum() > 20
        assert np.mean(got != truth) < 0.005, (turn, np.mean(got != truth))


def test_no_surfaces_or_a_surface_beside_the_grid_encloses_nothing():
    pm = medium()
    assert not enclosed_voxels(pm, None).any()
    assert not enclosed_voxels(pm, prepare_surfaces([ground(z=-5.0)])).any()
    assert not enclosed_voxels(pm, prepare_surfaces([cube((4.0, 0, 0), 0.5)])).any()


def test_the_lattice_mean_by_a_ground_leaves_out_what_lies_under_it():
    """The tent mass of a lattice point on the ground counts the medium above it only; far
    above the ground nothing changes."""
    from mpp_render.precompute.lattice import lattice_points
    pm = medium(n=(16, 16, 16))
    cam = Camera("PERSP", np.eye(4), 8, 8, (-0.5, 0.5, -0.5, 0.5))
    cam.cam_to_world[:3, 3] = [0.0, 0.0, 5.0]
    free = PathLattice.of(pm, cam, 8)
    _, pts = lattice_points(pm, free.shape, free.stride)
    z = pts[:, 2].reshape(free.shape)
    z0 = float(np.unique(z)[len(np.unique(z)) // 2])     # a lattice layer mid-grid
    ss = prepare_surfaces([ground(z=z0 - 0.001)])
    cut = PathLattice.of(pm, cam, 8, enclosed_voxels(pm, ss))
    a, b = free.tent_mass[..., 0], cut.tent_mass[..., 0]
    on = (np.abs(z - z0) < 1e-6) & (a > 0.9 * a.max())   # on the ground, its tent in the fog
    above = (z > z0 + 1.5 * free.h) & (a > 0)
    assert on.sum() >= 4 and above.sum() >= 4
    assert np.all(b[on] < 0.75 * a[on]) and np.all(b[on] > 0.25 * a[on])
    np.testing.assert_allclose(b[above], a[above])
    assert np.all(b[z < z0 - 1.5 * free.h] == 0.0)


def test_the_lattice_rate_follows_the_deposits_per_spacing():
    """PathLattice.of's tentative rate is max(majorant, deposits / h) (Tuning.path_deposits),
    and a rate of no deposits is refused."""
    pm = medium(n=(16, 16, 16))
    cam = Camera("PERSP", np.eye(4), 8, 8, (-0.5, 0.5, -0.5, 0.5))
    cam.cam_to_world[:3, 3] = [0.0, 0.0, 5.0]
    majorant = float(pm.path_density().max()) * float(np.max(pm.sigma_t))
    for k in (0.5, 1.0, 4.0):
        lat = PathLattice.of(pm, cam, 8, deposits=k)
        assert lat.rate == pytest.approx(max(majorant, k / lat.h))
    assert PathLattice.of(pm, cam, 8, deposits=1e-9).rate == pytest.approx(majorant)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError):
            PathLattice.of(pm, cam, 8, deposits=bad)


@pytest.mark.parametrize("sub", [2, 4])
def test_the_part_of_each_voxel_under_a_ground_is_its_cells_part_below_it(sub):
    """enclosed_fraction: under a ground between voxel centres, each voxel holds the part of
    its cell below the ground, to within half a ``sub``-th (the centres of its parts), on a
    grid aligned with the world and on a turned one (whose voxels the plane cuts at a slant:
    their mean part equals the analytic one's mean); all 0 without surfaces."""
    from mpp_render.precompute.enclosed import enclosed_fraction
    pm = medium(n=(12, 10, 14))
    shape = pm.grid.shape[:3]
    z = pm.to_world(np.stack(np.meshgrid(*[np.arange(n) for n in shape],
                                         indexing="ij"), -1).reshape(-1, 3).astype(float))[:, 2]
    z0 = 0.0337
    ss = prepare_surfaces([ground(z=z0)])
    got = enclosed_fraction(pm.grid.shape[:3], pm.i2w, ss, sub).reshape(-1)
    want = np.clip((z0 - (z - 0.05)) / 0.1, 0.0, 1.0)
    assert np.abs(got - want).max() <= 0.5 / sub + 1e-9
    assert np.any((got > 0.0) & (got < 1.0))
    assert not enclosed_fraction(pm.grid.shape[:3], pm.i2w, None, sub).any()
    turned = medium(n=(12, 10, 14), turn=0.3)
    got = enclosed_fraction(turned.grid.shape[:3], turned.i2w, ss, 4)
    under = enclosed_voxels(turned, ss)
    assert got.sum() == pytest.approx(under.sum(), rel=0.05)
    assert np.all(got[under] > 0.0) and np.all(got[~under] < 1.0)
