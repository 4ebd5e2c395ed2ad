"""The light sweep (kernels light_sweep, precompute.sweep_light): optical depth to a light for
every voxel by following the light's rays slab by slab.  Its C and numpy twins agree, chunks
partition the voxels, and the result matches Beer-Lambert and the exact per-voxel march."""
import contextlib

import numpy as np
import pytest

from mpp_render import kernels, kernels_np
from mpp_render.precompute import lattice, precompute
from mpp_render.precompute import lightdepth as P
from mpp_render.media import prepare
from mpp_render.scene import Light, Medium, Surface
from mpp_render.surfaces import prepare_surfaces

needs_c = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")


def smooth_cloud(n=18, seed=2, offset=(0.0, 0.0, 0.0)):
    """A ball of smooth fBm-like density (a few sine octaves, like a simulated cloud)."""
    rng = np.random.default_rng(seed)
    x = (np.arange(n) + 0.5) / n * 2 - 1
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    noise = np.zeros_like(X)
    for octave in range(3):
        k, ph = 2.0 ** octave * 1.5, rng.uniform(0, 2 * np.pi, 3)
        noise += np.sin(k * np.pi * X + ph[0]) * np.sin(k * np.pi * Y + ph[1]) * \
            np.sin(k * np.pi * Z + ph[2]) / 2 ** octave
    d = np.clip(1 - np.sqrt(X ** 2 + Y ** 2 + Z ** 2), 0, None) * (1 + 0.5 * noise)
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([2.0 / n, 2.2 / n, 1.8 / n])
    i2w[:3, 3] = np.asarray(offset) - 1.0
    return Medium("cloud", d.astype(np.float32), i2w, np.array([3.0, 2.0, 1.0]), np.full(3, 0.5), 0.3)


def sharp_box(n=12, centre=(0.3, -0.2, 0.1), size=1.2):
    i2w = np.eye(4)
    i2w[:3, :3] *= size / n
    i2w[:3, 3] = np.asarray(centre) - size / 2 + size / n / 2
    return Medium("box", np.ones((n, n, n), np.float32), i2w, np.full(3, 2.0), np.full(3, 0.5), 0.0,
                  source="MESH")


def lights():
    spot = np.eye(4)
    spot[:3, 3] = [0.4, 0.3, 3.0]
    area = np.eye(4)
    area[:3, 3] = [-0.5, 0.5, 2.5]
    return [Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.3, 0.2, -0.93])),
            Light("SUN", "low sun", np.full(3, 3.0), direction=np.array([-0.9, 0.35, -0.25])),
            Light("POINT", "outside", np.full(3, 50.0), position=np.array([2.5, -1.0, 0.5])),
            Light("POINT", "inside", np.full(3, 50.0), position=np.array([0.05, 0.1, -0.07])),
            Light("SPOT", "spot", np.full(3, 300.0), position=spot[:3, 3], matrix=spot),
            Light("AREA", "area", np.full(3, 80.0), matrix=area)]


def sweep_args(media, pm, light, pyr, L, init, p_lo, p_hi, out, step):
    grids, w2is, sig, thr = P.kernel_arrays(media)
    return (out, 1, pm.i2w[:3], pyr.axis, pyr.sign, pyr.i_first, pyr.i_last, pyr.coef, L, pyr.cone,
            init, p_lo, p_hi, P._sub_steps(pm, pyr, step), grids, w2is, sig, thr)


@needs_c
@pytest.mark.parametrize("li", range(6))
def test_twins_agree_and_chunks_partition_the_voxels(li):
    media = [prepare(smooth_cloud()), prepare(sharp_box())]
    light = lights()[li]
    rng = np.random.default_rng(li)
    for pm in media:
        pyramids, L = P.sweep_pyramids(pm, light)
        assert pyramids
        whole = np.full(pm.grid.shape + (4,), np.nan, np.float32)
        step = min(m.voxel_size for m in media)
        for pyr in pyramids:
            init = rng.uniform(0, 2, (pyr.n_p, pyr.n_q, 3))
            a = whole.copy()
            kernels_np.light_sweep(*sweep_args(media, pm, light, pyr, L, init, 0, pyr.n_p - 1, a, step))
            # (the twin takes the job's fields in the kernel's order; kernels.light_sweep a SweepJob)
            b = whole.copy()
            cuts = sorted(set([0, pyr.n_p - 1] + list(rng.integers(1, pyr.n_p - 1, 3))))
            for lo, hi in zip(cuts, cuts[1:]):
                args = sweep_args(media, pm, light, pyr, L, init, lo, hi, b, step)
                kernels.light_sweep(b, 1, kernels.SweepJob(*args[2:]), backend="c")
            mine = ~np.isnan(a[..., 1])
            assert np.array_equal(mine, ~np.isnan(b[..., 1]))  # the same voxels, once each
            assert np.allclose(a[mine][:, 1:4], b[mine][:, 1:4], rtol=1e-4, atol=1e-5)
            whole = np.where(mine[..., None], a, whole)
        # the pyramids together cover every voxel (a local light's own voxel aside)
        assert np.isnan(whole[..., 1]).sum() <= 1


@pytest.mark.parametrize("backend", ["numpy", "c"])
def test_homogeneous_box_under_a_sun_is_beer_lambert(backend):
    if backend == "c" and kernels._c is None:
        pytest.skip("compiled kernels not built")
    box = sharp_box(n=16, centre=(0.0, 0.0, 0.0), size=2.0)
    pm = prepare(box)
    w = np.array([0.35, -0.2, -0.915])
    w /= np.linalg.norm(w)
    sun = Light("SUN", "sun", np.ones(3), direction=w)
    f = np.zeros(pm.grid.shape + (4,), np.float32)
    with kernels.numpy_backend() if backend == "numpy" else contextlib.nullcontext():
        assert P.sweep_light([pm], pm, sun, f, 1, pm.voxel_size) is True
    ijk = np.stack(np.meshgrid(*[np.arange(s) for s in pm.grid.shape], indexing="ij"), -1).reshape(-1, 3)
    x = ijk @ pm.i2w[:3, :3].T + pm.i2w[:3, 3]
    # distance from x to the cube's surface (|x|_inf = 1) travelling towards the sun (-w)
    with np.errstate(divide="ignore"):
        t = np.min(np.where(-w > 0, (1 - x) / -w, (-1 - x) / -w), axis=1)
    # where the rays of the neighbouring columns leave through the same face, the optical
    # depth is linear across them and the interpolation exact: exit points 2 voxels clear of
    # the face's edges, start points clear of the faces
    # and the voxel a voxel clear of the side faces (the columns around it are inside too;
    # within that voxel the kink at the face is interpolated, see docs/performance.md)
    exit_pt = x + t[:, None] * -w
    clear = np.sum(np.abs(exit_pt) < 1 - 2.0 * pm.voxel_size, axis=1) == 2
    inside = clear & np.all(np.abs(x[:, :2]) < 1 - 1.01 * pm.voxel_size, axis=1) & (np.abs(x[:, 2]) < 1)
    assert inside.sum() > 500
    tau = f.reshape(-1, 4)[:, 1]
    assert np.allclose(tau[inside], 2.5 * t[inside], rtol=1e-3, atol=1e-4)
    assert np.all(tau[x[:, 2] > 1.0] == 0)  # the padding above the cube faces the sun


def test_point_light_inside_a_homogeneous_medium():
    n = 20
    i2w = np.eye(4)
    i2w[:3, :3] *= 2.0 / n
    i2w[:3, 3] = -1 + 1.0 / n
    pm = prepare(Medium("fog", np.ones((n, n, n), np.float32), i2w, np.full(3, 1.0), np.zeros(3)))
    c = np.array([0.13, -0.21, 0.07])
    f = np.zeros(pm.grid.shape + (4,), np.float32)
    assert P.sweep_light([pm], pm, Light("POINT", "p", np.ones(3), position=c), f, 1, pm.voxel_size)
    ijk = np.stack(np.meshgrid(*[np.arange(s) for s in pm.grid.shape], indexing="ij"), -1).reshape(-1, 3)
    x = ijk @ pm.i2w[:3, :3].T + pm.i2w[:3, 3]
    # voxels whose columns (a voxel around) all lie in the unit density
    inner = np.all(np.abs(x) < 1 - 1.4 * pm.voxel_size, axis=1)
    dist = np.linalg.norm(x - c, axis=1)
    tau = f.reshape(-1, 4)[:, 1]
    # the columns carry the exact distance; between columns at most a voxel (h) apart the
    # bilinear interpolation of the convex distance overshoots by about h^2 / (8 r)
    bound = 1.5 * pm.voxel_size ** 2 / (8 * dist) + 1e-5
    assert np.all(np.abs(tau[inner] - dist[inner]) <= bound[inner])


@pytest.mark.parametrize("li", range(6))
@pytest.mark.parametrize("combo", ["cloud", "box", "both"])
def test_sweep_matches_the_exact_march_on_a_cloud_and_a_box(li, combo):
    """Transmittance to each light against a fine exact march from every voxel, weighted by
    density: a smooth cloud, a sharp box (its surface layer marches exactly) and the two
    overlapping (the cloud's voxels beside the box's faces march exactly; the box's shadow
    edges in the cloud are interpolated over a voxel, which bounds the largest error)."""
    media = {"cloud": [prepare(smooth_cloud(n=24))], "box": [prepare(sharp_box())],
             "both": [prepare(smooth_cloud(n=24)), prepare(sharp_box())]}[combo]
    step = min(m.voxel_size for m in media)
    light = lights()[li]
    for pm in media:
        flat, pts = lattice.needed_points(pm)
        exact = P.light_optical_depth(media, light, pts, step / 4)
        f = np.zeros(pm.grid.shape + (4,), np.float32)
        assert P.sweep_light(media, pm, light, f, 1, step) is True
        got = f.reshape(-1, 4)[flat, 1:4]
        assert np.all(np.isfinite(got)) and np.all(got >= 0)
        w = kernels_np.density_from(pm.grid.reshape(-1)[flat], pm.threshold)
        dT = np.abs(np.exp(-got) - np.exp(-exact))
        mean = np.sum(w[:, None] * dT) / (3 * w.sum())
        assert mean < (0.003 if combo == "both" else 0.002), (mean, pm.medium.name)
        if combo != "both":
            assert dT[w > 0].max() < (0.05 if pm.sharp else 0.02), pm.medium.name


def test_surfaces_shadow_the_sweep_as_the_exact_march():
    """A roof over a cloud: the voxels it hides from the light carry SHADOW_TAU exactly where
    the per-voxel march puts it, also on a ground plane through a voxel layer."""
    pm = prepare(smooth_cloud(n=16))
    roof = Surface("roof", np.array([[-0.4, -0.4, 0.3], [0.5, -0.4, 0.3], [0.5, 0.5, 0.3],
                                     [-0.4, 0.5, 0.3]]), np.array([[0, 1, 2], [0, 2, 3]]))
    z = pm.i2w[2, 3] + 3 * pm.i2w[2, 2]  # exactly on the fourth voxel layer
    ground = Surface("ground", np.array([[-3, -3, z], [3, -3, z], [3, 3, z], [-3, 3, z]]),
                     np.array([[0, 1, 2], [0, 2, 3]]))
    surf = prepare_surfaces([roof, ground])
    for light in (Light("SUN", "sun", np.ones(3), direction=np.array([0.2, 0.1, -0.97])),
                  Light("POINT", "pt", np.ones(3), position=np.array([2.1, 0.0, 0.6]))):
        flat, pts = lattice.needed_points(pm)
        exact = P.light_optical_depth([pm], light, pts, pm.voxel_size / 4, surfaces=surf)
        f = np.zeros(pm.grid.shape + (4,), np.float32)
        assert P.sweep_light([pm], pm, light, f, 1, pm.voxel_size, surfaces=surf,
                             needed=(flat, pts)) is True
        got = f.reshape(-1, 4)[flat, 1:4]
        shadowed = exact[:, 0] >= P.SHADOW_TAU
        assert 0.1 < shadowed.mean() < 0.9
        assert np.array_equal(got[:, 0] >= P.SHADOW_TAU, shadowed)
        dT = np.abs(np.exp(-got) - np.exp(-exact))
        assert dT.max() < 0.05


@needs_c
def test_light_sweep_rejects_bad_input():
    pm = prepare(smooth_cloud(n=6))
    sun = lights()[0]
    (pyr,), L = P.sweep_pyramids(pm, sun)
    init = np.zeros((pyr.n_p, pyr.n_q, 3))
    out = np.zeros(pm.grid.shape + (4,), np.float32)
    good = list(sweep_args([pm], pm, sun, pyr, L, init, 0, pyr.n_p - 1, out, pm.voxel_size))
    f64 = (2, 7, 8, 10)
    kernels._c.light_sweep(*[kernels._f64(x) if i in f64 else x for i, x in enumerate(good)])
    bad = {1: 2, 3: 3, 4: 0, 5: -1, 6: pm.grid.shape[pyr.axis], 11: -1, 12: pyr.n_p, 13: 0,
           10: np.zeros((1, pyr.n_q, 3)), 0: np.zeros(pm.grid.shape + (4,), np.float64),
           7: np.array([0, 0, 0, 0, 0.0, 0.0]), 14: [pm.grid.astype(np.float64)]}
    for i, v in bad.items():
        args = [kernels._f64(x) if j in f64 else x for j, x in enumerate(good)]
        args[i] = v
        with pytest.raises(ValueError):
            kernels._c.light_sweep(*args)
    ro = out.copy()
    ro.flags.writeable = False
    with pytest.raises(ValueError):
        kernels.light_sweep(ro, 1, kernels.SweepJob(*good[2:]), backend="c")
    nan_init = init.copy()
    nan_init[0, 0, 0] = np.nan
    args = list(good)
    args[10] = nan_init
    with pytest.raises(ValueError):
        kernels.light_sweep(args[0], 1, kernels.SweepJob(*args[2:]), backend="c")


def test_lights_that_cannot_be_swept_fall_back_to_the_exact_march():
    """A point light astronomically far away is not swept (sweep_light returns None); the
    precompute then marches from every needed voxel, as before the sweep."""
    from mpp_render.scene import Camera, World
    pm = prepare(smooth_cloud(n=10))
    far = Light("POINT", "far", np.full(3, 1e30), position=np.array([1e12, 0.0, 0.0]))
    f = np.zeros(pm.grid.shape + (4,), np.float32)
    assert P.sweep_light([pm], pm, far, f, 1, pm.voxel_size) is False
    cam = Camera("ORTHO", np.eye(4), 4, 4, (-1, 1, -1, 1))
    pre = precompute([pm], [far], World(np.zeros(3)), cam)
    flat, pts = lattice.needed_points(pm)
    got = pre.fields[0].reshape(-1, pre.layout.channels)[flat, 1:4]
    want = P.light_optical_depth([pm], far, pts, pm.voxel_size)
    assert np.allclose(got, want, rtol=1e-5, atol=1e-6) and got.max() > 0.1


def test_voxels_near_sharp_surfaces_as_a_full_interpolation_finds_them():
    """precompute.near_sharp_surfaces interpolates another medium's grid only where its box
    reaches: the voxels it finds are those of interpolating every voxel, for a cloud beside a
    sharp box and for two overlapping sharp boxes; and a sweep handed them gives the field
    it computes itself."""
    from mpp_render.media import trilinear
    cloud, box = prepare(smooth_cloud(n=24)), prepare(sharp_box())
    other = prepare(sharp_box(n=10, centre=(-0.2, 0.3, 0.0), size=1.0))
    for pm, media in ((cloud, [cloud, box]), (box, [box, other]), (other, [box, other])):
        got = P.near_sharp_surfaces(pm, media)
        want = np.zeros(pm.grid.shape, bool)
        if pm.sharp:
            inside = pm.grid >= pm.threshold
            want |= inside & lattice.dilate(~inside)
        ijk = np.stack(np.meshgrid(*[np.arange(n, dtype=np.float64) for n in pm.grid.shape],
                                   indexing="ij"), -1).reshape(-1, 3)
        world = ijk @ pm.i2w[:3, :3].T + pm.i2w[:3, 3]
        for m in media:
            if m is pm or not m.sharp:
                continue
            ins = (trilinear(m.grid, world @ m.w2i[:, :3].T + m.w2i[:, 3]) >= m.threshold)
            ins = ins.reshape(pm.grid.shape)
            want |= lattice.dilate(ins) & lattice.dilate(~ins)
        assert got.size > 0 and np.array_equal(got, np.flatnonzero(want))
    step = min(m.voxel_size for m in (cloud, box))
    light = lights()[0]
    a = np.zeros(cloud.grid.shape + (4,), np.float32)
    b = np.zeros_like(a)
    assert P.sweep_light([cloud, box], cloud, light, a, 1, step) is True
    assert P.sweep_light([cloud, box], cloud, light, b, 1, step,
                         sharp=P.near_sharp_surfaces(cloud, [cloud, box])) is True
    assert np.array_equal(a, b)


def dense_blocks(n=14, seed=6, density=6.0):
    """Blocks of dense smoke two to four voxels wide scattered in an empty grid (a third-party
    VDB's sharp features): voxels of density*sigma_t*voxel = 2.6 optical depth."""
    rng = np.random.default_rng(seed)
    d = np.zeros((n, n, n), np.float32)
    for _ in range(10):
        lo = rng.integers(2, n - 6, 3)
        hi = lo + rng.integers(2, 5, 3)
        d[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = density
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.1
    i2w[:3, 3] = -0.65
    return Medium("blocks", d, i2w, np.full(3, 3.5), np.full(3, 0.8), 0.4)


def test_lit_voxels_by_optically_thick_ones_march_their_depth():
    """near_thick_cells: a density grid's lit voxels within a voxel of an optically thick one
    (none in a mesh volume or where Tuning.cell_tau is 0).  There the sweep's columns,
    interpolated slab after slab, smooth the blocks' shadows: its depths miss a fine march's
    by more than 0.05 somewhere; marched (the default cell_tau), within 0.01 everywhere."""
    from mpp_render.scene import Tuning
    pm = prepare(dense_blocks())
    sun = Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.45, 0.3, -0.84]))
    f = np.zeros(pm.grid.shape + (4,), np.float32)
    assert P.sweep_light([pm], pm, sun, f, 1, pm.voxel_size, tuning=Tuning(cell_tau=0.0)) is True
    flat = P.near_thick_cells(pm, f[..., 1], Tuning().cell_tau)
    assert flat.size > 100
    assert P.near_thick_cells(pm, f[..., 1], 0.0).size == 0
    assert P.near_thick_cells(prepare(sharp_box()), np.zeros((14,) * 3), 0.05).size == 0
    exact = P.light_optical_depth([pm], sun, lattice.grid_points(pm, flat), 0.002)[:, 0]
    swept = f.reshape(-1, 4)[flat, 1]
    assert np.abs(swept - exact).max() > 0.05
    g = np.zeros_like(f)
    assert P.sweep_light([pm], pm, sun, g, 1, pm.voxel_size) is True
    assert np.abs(g.reshape(-1, 4)[flat, 1] - exact).max() < 0.01
    lit = f[..., 1] < P.THICK_LIT
    assert np.array_equal(g[~lit], f[~lit])      # the rest as swept
