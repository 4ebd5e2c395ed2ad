"""The camera's multiply scattered light from the paths' lobe, fitted to their deposits
(precompute/lobefit.py), and the tracer's halves and share of moments it reads
(kernels.trace_paths_media): the lobe is the march's HG closure, the fit keeps a lobe in
linear proportion to the deposits exactly, takes noise off where the lobe holds, gives the
deposits back where they have no noise, converges to a many-path reference as paths are
added on a traced cube, and an isotropic medium keeps its deposits."""
import dataclasses

import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.paths import trace_paths_media_np
from mpp_render.phase import hg
from mpp_render.precompute.lobefit import box_sum, fitted, lobe, lobe_ratio

from test_paths import cube_case, small_cube_under_a_sun

needs_c = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")


def test_the_lobe_is_the_marchs_hg_closure():
    """moments of light flowing along G with |G| = 0.6 (M1 = M0 G): towards v the lobe is
    4 pi M0 HG(v . G / |G|; |G|), per channel; no light, no lobe."""
    rng = np.random.default_rng(3)
    m0 = rng.random((3, 2, 2, 3)) + 0.1
    axis = rng.normal(size=(3, 2, 2, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    G = 0.6 * axis
    moments = np.concatenate([m0] + [m0 * G[..., j:j + 1] for j in range(3)], axis=-1)
    v = rng.normal(size=(3, 2, 2, 3))
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    want = 4 * np.pi * m0 * hg(np.sum(axis * v, -1), 0.6)[..., None]
    np.testing.assert_allclose(lobe(moments, v), want, rtol=1e-12)
    moments[0, 0, 0, :3] = 0.0
    assert np.all(lobe(moments, v)[0, 0, 0] == 0.0)


@needs_c
@pytest.mark.parametrize("grey", [True, False])
def test_the_compiled_fit_is_its_twin_bit_for_bit(grey):
    """kernels.lobe_ratio (csrc/lobefit.c) against kernels_np.lobe_ratio on a lattice with
    holes in the lobe and the weights, grey and chromatic: the same bits."""
    from mpp_render import kernels_np
    rng = np.random.default_rng(11)
    shape = (13, 9, 11)
    md = rng.random(shape + (3,))
    mc = (md + 0.2 * rng.random(shape + (3,))) * (rng.random(shape + (3,)) > 0.1)
    if grey:
        md[..., 1] = md[..., 2] = md[..., 0]
        mc[..., 1] = mc[..., 2] = mc[..., 0]
    u = rng.random(shape) * (rng.random(shape) > 0.2)
    for r in (1, 3, 20):
        c = kernels.lobe_ratio(md, mc, u, r, 1 if grey else 3, backend="c")
        n = kernels_np.lobe_ratio(md, mc, u, r, 1 if grey else 3)
        assert np.array_equal(c, n), r
    assert np.array_equal(lobe_ratio(md, mc, u, 3), n if r == 3 else
                          kernels_np.lobe_ratio(md, mc, u, 3, 1 if grey else 3))


def test_box_sum_is_each_windows_sum():
    rng = np.random.default_rng(4)
    x = rng.random((6, 5, 7, 2))
    got = box_sum(x, 2)
    p = np.pad(x, [(2, 2)] * 3 + [(0, 0)])
    want = np.zeros_like(x)
    for i in range(6):
        for j in range(5):
            for k in range(7):
                want[i, j, k] = p[i:i + 5, j:j + 5, k:k + 5].sum(axis=(0, 1, 2))
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


def lobe_case(rng, noise, shape=(14, 12, 10)):
    """(true M, lobe M_c, deposits, first, second, weights): a lobe whose level is off by a
    factor that changes linearly across the lattice (1.3 - 0.04 x), and deposits that are the
    truth plus two halves' independent noise of relative size ``noise``."""
    X = np.stack(np.meshgrid(*[np.arange(n, dtype=np.float64) for n in shape], indexing="ij"), -1)
    mc = (1.0 + 0.5 * np.sin(0.7 * X[..., :1]) * np.cos(0.5 * X[..., 1:2])
          + 0.2 * X[..., 2:3] / shape[2]) * np.array([1.0, 0.8, 0.5])
    truth = mc * (1.3 - 0.04 * X[..., :1])
    first = truth * (1.0 + noise * rng.normal(size=truth.shape))
    second = truth * (1.0 + noise * rng.normal(size=truth.shape))
    return truth, mc, 0.5 * (first + second), first, second, np.ones(shape)


def moments_of(mc, towards):
    """Moments whose HG closure towards ``towards`` is isotropic (|G| = 0): M0 = mc / 4 pi."""
    m0 = mc / (4 * np.pi)
    return np.concatenate([m0, np.zeros(m0.shape[:3] + (9,))], axis=-1)


def test_a_lobe_in_linear_proportion_to_the_deposits_is_kept_exactly():
    """The local-linear fit: where the deposits are the lobe times a linear function of the
    position, the fitted light is the deposits (every window, the lattice's edges too)."""
    truth, mc, _, _, _, u = lobe_case(np.random.default_rng(5), 0.0)
    np.testing.assert_allclose(lobe_ratio(truth, mc, u, 3), truth, rtol=1e-5)
    # a point the lobe holds none of (its moments from a share of the paths missed it)
    # keeps its deposits
    holed = mc.copy()
    holed[5, 4, 3] = 0.0
    assert np.array_equal(lobe_ratio(truth, holed, u, 3)[5, 4, 3], truth[5, 4, 3])
    # without noise in the deposits (the halves agree) the fit returns them, whatever the lobe
    wrong = mc * np.exp(np.sin(np.arange(mc.shape[0]))[:, None, None, None])
    tw = np.zeros(mc.shape[:3] + (3,))
    tw[..., 2] = 1.0
    got = fitted(truth, moments_of(wrong, tw), tw, u, truth - truth, 3)
    np.testing.assert_allclose(got, truth, rtol=1e-6)


def edge_on_case():
    """(deposits, lobe, weights): a lattice whose weight the camera sees lies in the plane
    x = 5 (a lit face seen edge on: the points behind it weigh 1e-9 of it), with the ratio of
    the deposits to the lobe 1 in that plane and noise of 100 behind it, where the camera
    cannot see."""
    shape = (12, 9, 10)
    mc = np.ones(shape + (3,))
    md = np.ones(shape + (3,))
    md[:5] = 100.0
    u = np.full(shape, 1e-9)
    u[5] = 1.0
    return md, mc, u


def test_a_point_off_the_plane_the_window_sees_is_not_extrapolated():
    """In a window whose weight lies in one plane, the point one step off it takes the
    window's mean ratio, not the line through the plane and the unseen noise behind it (which
    gave 100 times the light: p_haze_sun_ground's haze at density 40 and albedo 0.9, its top
    face seen edge on, had pixels 8 over Cycles' 0.2); in the plane the fit holds."""
    md, mc, u = edge_on_case()
    got = lobe_ratio(md, mc, u, 3)
    assert np.all(np.abs(got[6] - 1.0) < 1e-3), got[6].max()
    assert np.all(np.abs(got[5] - 1.0) < 1e-3)
    # a window spread along every axis keeps its line however far its corner lies
    truth, mc2, _, _, _, u2 = lobe_case(np.random.default_rng(5), 0.0)
    np.testing.assert_allclose(lobe_ratio(truth, mc2, u2, 3), truth, rtol=1e-5)


@needs_c
def test_the_compiled_fit_is_its_twin_off_the_plane():
    """The two twins take the same branch, with the same bits, where a window's weight lies
    in a plane."""
    from mpp_render import kernels_np
    md, mc, u = edge_on_case()
    md = md * (1.0 + 0.1 * np.random.default_rng(4).random(md.shape))
    for r in (1, 3):
        assert np.array_equal(kernels.lobe_ratio(md, mc, u, r, 3, backend="c"),
                              kernels_np.lobe_ratio(md, mc, u, r, 3))


def test_noise_is_taken_off_where_the_lobe_holds_and_the_deposits_kept_where_not():
    """Deposits 20 % noisy about a truth the lobe follows up to a linear factor: the fitted
    light is within a fifth of the deposits' error of the truth.  Where the lobe is wrong by
    more than the noise (a 50 % step across the lattice), the fit moves to the deposits
    there (its error at most the deposits' own plus a third)."""
    rng = np.random.default_rng(6)
    truth, mc, md, first, second, u = lobe_case(rng, 0.2)
    tw = np.zeros(mc.shape[:3] + (3,))
    tw[..., 2] = 1.0
    got = fitted(md, moments_of(mc, tw), tw, u, first - second, 3)
    err_d = np.sqrt(np.mean((md - truth) ** 2))
    err_f = np.sqrt(np.mean((got - truth) ** 2))
    print(f"deposits {err_d:.4f}, fitted {err_f:.4f}")
    assert err_f < 0.2 * err_d
    step = mc * np.where(np.arange(mc.shape[0])[:, None, None, None] < 7, 1.0, 1.5)
    truth2, md2 = truth * 1.0, None
    first2 = step * (1.3 - 0.0) * (1.0 + 0.02 * rng.normal(size=truth.shape))
    second2 = step * 1.3 * (1.0 + 0.02 * rng.normal(size=truth.shape))
    md2 = 0.5 * (first2 + second2)
    truth2 = step * 1.3
    got2 = fitted(md2, moments_of(mc, tw), tw, u, first2 - second2, 3)
    e_d = np.sqrt(np.mean((md2 - truth2) ** 2))
    e_f = np.sqrt(np.mean((got2 - truth2) ** 2))
    print(f"step: deposits {e_d:.4f}, fitted {e_f:.4f}")
    assert e_f <= 1.34 * e_d


@needs_c
def test_the_halves_and_the_moments_share_of_the_tracer():
    """kernels.trace_paths_media: with ``halves`` the full deposits are the same bits as
    without, the first half's deposits are the numpy twin's over those paths and the rest the
    twin's over the others; with moment_share 0.25 the moments are those of the first
    quarter of each block's paths, scaled to all, on both backends."""
    inp, _ = cube_case(n=16, n_paths=3000, g=0.8)
    inp = dataclasses.replace(inp, moments=True)
    full, (first, k) = kernels.trace_paths_media(inp, threads=2, halves=True)
    assert np.array_equal(full[0], kernels.trace_paths_media(inp, threads=2)[0])
    assert 0 < k < inp.n_paths
    rest = trace_paths_media_np(inp, paths=(k, inp.n_paths))[0][..., :3]
    scale = np.abs(full[0][..., :3]).max()
    assert np.abs(trace_paths_media_np(inp, paths=(0, k))[0][..., :3] - first).max() <= 1e-9 * scale
    assert np.abs(first + rest - full[0][..., :3]).max() <= 1e-9 * scale
    quarter = dataclasses.replace(inp, moment_share=0.25)
    got = kernels.trace_paths_media(quarter, threads=2)[0]
    cuts = np.linspace(0, inp.n_paths, kernels.PATH_BLOCKS + 1).astype(np.int64)
    ends = kernels.moment_ends(quarter, cuts)
    assert np.all(ends - cuts[:-1] == np.ceil(0.25 * np.diff(cuts)))
    want = sum(trace_paths_media_np(inp, paths=(a, e))[0][..., 3:] for a, e in zip(cuts, ends))
    want = want * (inp.n_paths / float(np.sum(ends - cuts[:-1])))
    assert np.array_equal(got[..., :3], full[0][..., :3])
    np.testing.assert_allclose(got[..., 3:], want, rtol=1e-9, atol=1e-9 * np.abs(want).max())
    np_got = kernels.trace_paths_media(quarter, backend="numpy")[0]
    np.testing.assert_allclose(np_got, got, rtol=1e-9, atol=1e-9 * np.abs(got).max())
    # the numpy twin's blocks: the same halves, each path traced once
    np_full, (np_first, np_k) = kernels.trace_paths_media(inp, backend="numpy", halves=True)
    assert np_k == k
    np.testing.assert_allclose(np_first, first, rtol=1e-9, atol=1e-9 * scale)
    np.testing.assert_allclose(np_full[0], full[0], rtol=1e-9, atol=1e-9 * np.abs(full[0]).max())


def cube(g=0.9):
    """(camera, sun, medium, field) of a 16^3 cube under a sun
    (test_paths.small_cube_under_a_sun), the field the sun's depth at its voxels."""
    from mpp_render.media import prepare
    from mpp_render.precompute.lightdepth import light_optical_depth
    from mpp_render.scene import Medium
    cam, sun, i2w = small_cube_under_a_sun()
    pm = prepare(Medium("m", np.ones((16, 16, 16), np.float32), i2w, np.full(3, 3.8),
                        np.full(3, 0.2), g))
    shape = pm.grid.shape[:3]
    tau = light_optical_depth([pm], sun, pm.to_world(np.argwhere(np.ones(shape)).astype(
        np.float64)), 0.5 * pm.voxel_size)
    fld = np.zeros(shape + (4,), np.float32)
    fld[..., 0] = pm.grid[..., 0] if pm.grid.ndim == 4 else pm.grid
    fld[..., 1:] = tau.reshape(shape + (3,))
    return cam, sun, pm, fld


def traced_m(n_paths, seed, window, g=0.9, around=None, scene=None):
    """M towards the camera of ``cube(g)`` (or ``scene``, one) from ``n_paths`` paths at
    ``seed``, fitted over ``window`` (0: the deposits), with the Surroundings ``around`` or
    none."""
    from mpp_render.precompute.lightpaths import traced_multiple
    cam, sun, pm, fld = cube(g) if scene is None else scene
    got = traced_multiple(pm, fld, sun, 1, cam, n_paths, 8, seed=seed, lobe_window=window,
                          around=around)
    return np.asarray(got[2], np.float64)


@needs_c
def test_the_fit_converges_to_many_paths_with_paths_added(monkeypatch):
    """A cube of g 0.9 under a sun, M towards the camera on its lattice: against the
    deposits of 16 x 40 000 paths (the reference; the cap of paths per lattice point lifted),
    the fitted light of 40 000 paths is closer than their deposits, and the fitted light of
    4 x 40 000 closer than that of 40 000 (two seeds each); an isotropic cube's M is its
    deposits, the same bits."""
    from mpp_render.precompute import lightpaths
    monkeypatch.setattr(lightpaths, "PATHS_PER_POINT", 10 ** 6)
    ref = traced_m(16 * 40_000, 99, 0)
    live = ref > 0.02 * ref.max()

    def err(m):
        return float(np.sqrt(np.mean(((m - ref) / ref.max())[live] ** 2)))
    dep = np.mean([err(traced_m(40_000, s, 0)) for s in (1, 2)])
    fit1 = np.mean([err(traced_m(40_000, s, 3)) for s in (1, 2)])
    fit4 = np.mean([err(traced_m(160_000, s, 3)) for s in (1, 2)])
    print(f"deposits {dep:.4f}, fitted {fit1:.4f}, fitted x4 {fit4:.4f}")
    assert fit1 < dep and fit4 < fit1
    assert np.array_equal(traced_m(20_000, 1, 3, g=0.0), traced_m(20_000, 1, 0, g=0.0))


@needs_c
def test_the_lattices_depth_to_the_camera_is_made_once_and_changes_nothing(monkeypatch):
    """The lights' lobe fits and the sky deficit's on one lattice share its optical depth to
    the camera (pathstarts.Surroundings.camera_depth): made once for two traces of the same
    medium, and the fitted light the same bits as without the Surroundings keeping it."""
    from mpp_render.precompute import lightpaths
    from mpp_render.precompute.pathstarts import Surroundings
    made = []
    real = lightpaths._camera_depth
    monkeypatch.setattr(lightpaths, "_camera_depth", lambda *a: made.append(1) or real(*a))
    scene = cube()
    around = Surroundings([], None, None, 0.05)
    a = traced_m(20_000, 1, 3, around=around, scene=scene)
    b = traced_m(20_000, 2, 3, around=around, scene=scene)
    assert len(made) == 1
    assert np.array_equal(a, traced_m(20_000, 1, 3, scene=scene))
    assert np.array_equal(b, traced_m(20_000, 2, 3, scene=scene))
    assert len(made) == 3
