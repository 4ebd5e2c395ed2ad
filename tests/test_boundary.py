"""Light leaving through a medium's surface (precompute/boundary.py) and the light pyramid's
source on its lattice (precompute.source.restricted_source): docs/method.md, "Escape through the
surface"."""
import numpy as np

from mpp_render import pyramid
from mpp_render.precompute import boundary, lattice, source
from mpp_render.media import PreparedMedium, prepare
from mpp_render.scene import Light, Medium


def test_outside_distance_is_the_euclidean_distance_within_reach():
    rng = np.random.default_rng(1)
    occ = rng.random((14, 11, 9)) < 0.04
    occ[7, 5, 4] = True
    h = 0.3
    got = boundary.outside_distance(occ, h, reach=30)
    pts = np.argwhere(occ)
    idx = np.stack(np.meshgrid(*[np.arange(s) for s in occ.shape], indexing="ij"), -1)
    want = np.sqrt(((idx[..., None, :] - pts) ** 2).sum(-1).min(-1)) * h
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    # a short reach is exact up to it and never below it beyond
    short = boundary.outside_distance(occ, h, reach=2)
    near = want <= 2 * h
    np.testing.assert_allclose(short[near], want[near], atol=1e-9)
    assert np.all(short[~near] >= 2 * h - 1e-9)


def test_extrapolation_length():
    assert boundary.extrapolation_length(8.0, 0.4, 0.0) == boundary.MILNE_EXTRAPOLATION / 8.4
    # forward scattering reaches further out: the transport coefficient is sigma_s (1 - g)
    assert abs(boundary.extrapolation_length(8.0, 0.4, 0.8) - 0.7104 / (1.6 + 0.4)) < 1e-12
    assert boundary.extrapolation_length(0.0, 0.0, 0.5) == float("inf")


class _Medium:
    """What boundary.survival reads of a prepared medium: the index <-> world maps (its
    methods PreparedMedium's)."""

    def __init__(self, spacing=0.1):
        self.i2w = np.eye(4)
        self.i2w[:3, :3] *= spacing
        self.w2i = np.linalg.inv(self.i2w)[:3, :]

    to_world = PreparedMedium.to_world
    to_index = PreparedMedium.to_index


def test_survival_ramps_from_the_surface_to_the_extrapolated_boundary():
    """Inside the medium a level keeps everything; outside, 1 - dist / z_b, nothing beyond
    z_b; a medium filling the lattice loses nothing."""
    med, h = _Medium(0.1), 0.1
    occ = np.zeros((33, 9, 9), bool)
    occ[:17] = True   # the medium fills x <= 1.6 m
    z_b = 0.5
    keep = boundary.survival(med, occ, 1, h, z_b, [0.0] * 4, None)
    k1 = keep(1, (17, 5, 5))   # level 1: points every 2 lattice cells
    x = np.arange(17) * 2 * h
    want = np.clip(1.0 - np.maximum(x - 1.6, 0.0) / z_b, 0.0, 1.0)
    np.testing.assert_allclose(k1[:, 2, 2], want, atol=1e-6)
    assert np.all(k1[x <= 1.6] == 1.0) and np.all(k1[x >= 1.6 + z_b] == 0.0)
    full = boundary.survival(med, np.ones((9, 9, 9), bool), 1, h, z_b, [0.0] * 4, None)
    assert np.all(full(2, (3, 3, 3)) == 1.0)


def face_pyramid(direction, drift, z_b=0.3):
    """First scatterings in a layer just inside the face x = 3.2 m of a medium filling
    0 <= x <= 3.2 m, spread by the pyramid with the loss through that face for paths drifting
    ``drift`` 2^k / 8 m on level k along ``direction``: the levels' powers."""
    med, h = _Medium(0.1), 0.1
    occ = np.zeros((49, 17, 17), bool)
    occ[:33] = True
    base = np.zeros((49, 17, 17, 3), np.float32)
    base[31:33] = 1.0
    drifts = [drift * 2.0 ** k / 8.0 for k in range(5)]
    keep = boundary.survival(med, occ, 1, h, z_b, drifts,
                             lambda x: np.tile(direction, (len(x), 1)))
    lev = pyramid.build(base, max_levels=5, keep=keep)
    return np.array([lv.sum() * 8.0 ** k for k, lv in enumerate(lev)])


def test_paths_heading_into_the_medium_are_lost_less():
    """Light entering through a face that scatters forward drifts inwards: its levels keep
    more than those of light that drifts out through the face, and more than the paths that
    do not drift; every level loses some, and each a larger part than the finer one."""
    none = face_pyramid(np.array([1.0, 0.0, 0.0]), 0.0)
    inward = face_pyramid(np.array([-1.0, 0.0, 0.0]), 0.4)
    outward = face_pyramid(np.array([1.0, 0.0, 0.0]), 0.4)
    no_loss = face_pyramid(np.array([1.0, 0.0, 0.0]), 0.0, z_b=1e9)
    print("level power: no loss", no_loss.round(1), "none", none.round(1),
          "inward", inward.round(1), "outward", outward.round(1))
    # the levels whose lattice resolves the drift (level 4's points lie 1.6 m apart)
    assert np.all(inward[1:4] > 1.05 * none[1:4]) and np.all(none[1:4] > 1.05 * outward[1:4])
    assert np.all(none[1:] < no_loss[1:]) and np.all(np.diff(none / no_loss) < 0)


def _lit_cube(n=10, stride_light="SUN"):
    rng = np.random.default_rng(4)
    dens = (rng.random((n, n, n)) * 3.0).astype(np.float32)
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.1
    pm = prepare(Medium("m", dens, i2w, np.array([2.0, 1.5, 1.0]), np.full(3, 0.2), 0.3))
    if stride_light == "SUN":
        d = np.array([0.3, -0.2, -1.0])
        light = Light("SUN", "sun", np.array([3.0, 2.0, 1.0]), direction=d / np.linalg.norm(d))
    else:
        light = Light("POINT", "lamp", np.full(3, 50.0), position=np.array([0.2, 0.4, 1.7]))
    grid = pm.grid.shape
    tau = (rng.random(grid + (3,)) * 2.0).astype(np.float32)
    fld = np.concatenate([pm.grid[..., None], tau], axis=-1)
    return pm, fld, light


def voxel_source(pm, fld, light):
    from mpp_render.lights import incident
    _, pts = lattice.lattice_points(pm, pm.grid.shape, 1)
    _, e = incident(light, pts)
    v = fld.reshape(-1, fld.shape[-1]).astype(np.float64)
    return (v[:, :1] * pm.sigma_s[None, :]) * e * np.exp(-v[:, 1:4])


def test_lattice_source_keeps_the_voxels_power():
    """On a coarser lattice the source's power (sum x cell volume) is the voxels' (a point
    read of the lattice missed or doubled the layer a light lights at a face); at stride 1
    it is the voxels' source itself."""
    for kind in ("SUN", "POINT"):
        pm, fld, light = _lit_cube(stride_light=kind)
        q = voxel_source(pm, fld, light)
        vol = abs(np.linalg.det(pm.i2w[:3, :3]))
        for stride in (2, 3, 5):
            shape = tuple((s - 1 + stride - 1) // stride + 1 for s in pm.grid.shape)
            got = source.restricted_source(pm, fld, light, 1, stride, shape, chunk=3)
            assert got.shape == (int(np.prod(shape)), 3)
            np.testing.assert_allclose(got.sum(0) * vol * stride ** 3, q.sum(0) * vol, rtol=1e-9)
            assert np.all(got >= 0)
        one = source.restricted_source(pm, fld, light, 1, 1, pm.grid.shape)
        np.testing.assert_allclose(one, q, rtol=1e-12, atol=0)


def test_the_lattice_source_is_the_same_on_any_number_of_threads():
    """restricted_source's chunks of planes on a pool write their own planes: the source and
    the voxels' sums bit for bit the same on 1, 2 and 3 workers, the chunks in any order."""
    for kind in ("SUN", "POINT"):
        pm, fld, light = _lit_cube(stride_light=kind)
        shape = tuple((s - 1 + 1) // 2 + 1 for s in pm.grid.shape)
        got = []
        for threads in (1, 2, 3):
            vox = np.zeros(pm.grid.shape[:3], np.float32)
            got.append((source.restricted_source(pm, fld, light, 1, 2, shape, chunk=2,
                                                 voxels=vox, threads=threads), vox))
        assert got[0][0].max() > 0.0 and got[0][1].max() > 0.0
        for rows, vox in got[1:]:
            assert np.array_equal(rows, got[0][0]) and np.array_equal(vox, got[0][1])
