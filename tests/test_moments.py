"""The traced paths' moments (paths.py, "Moments"): what a surface's gather reads of the
multiply scattered light, towards the surface and not towards the camera.  The twins agree,
the moments are exact where the answer is known (isotropic scattering), their
Henyey-Greenstein closure comes close to the exact M towards directions other than the
camera's where the camera's M is off by factors, and the march reads them only for gathers,
only where a scene has surfaces."""
import dataclasses

import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.kernels import MarchInputs, MarchResult
from mpp_render.kernels_np import read_level
from mpp_render.march import MarchContext, pack_lights
from mpp_render.media import prepare
from mpp_render.paths import MOMENT_CHANNELS, trace_paths_np
from mpp_render.precompute import precompute
from mpp_render.scene import Tuning, Camera, Light, Medium, Surface, World
from test_paths import cube_case, half_empty_case

needs_c = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")


def with_moments(inp):
    return dataclasses.replace(inp, moments=True)


@needs_c
def test_twins_agree_with_moments_and_the_camera_channels_stay():
    inp = half_empty_case()
    a = trace_paths_np(with_moments(inp))
    b = kernels.trace_paths(with_moments(inp), threads=2)
    assert a.shape[-1] == b.shape[-1] == MOMENT_CHANNELS
    assert np.abs(a[..., 3:]).max() > 0.0
    assert np.abs(a - b).max() <= 1e-9 * np.abs(a).max()
    np.testing.assert_array_equal(b[..., :3], kernels.trace_paths(inp, threads=2))


def test_isotropic_scattering_has_no_first_moment_and_its_m0_converges_to_m():
    """With g = 0 the phase function is 1 / (4 pi) whatever the direction: M1 is 0, and M0,
    whose deposits go whole to one lattice corner drawn by the trilinear shares, has the
    camera's M (the shares themselves) as its mean: their sums agree, and their difference
    point by point falls as 1 / sqrt(paths)."""
    gaps = []
    for n_paths in (4000, 64000):
        inp, _ = cube_case(g=0.0, n_paths=n_paths)
        m = kernels.trace_paths(with_moments(inp), threads=2)
        assert np.all(m[..., 6:] == 0.0)
        assert abs(m[..., 3:6].sum() / m[..., :3].sum() - 1.0) < 0.01
        gaps.append(np.abs(m[..., 3:6] - m[..., :3]).sum() / m[..., :3].sum())
    assert gaps[1] < gaps[0] / 2.5, gaps


def exact_towards(inp, v):
    """The deposits towards the one direction ``v`` at every lattice point: the camera's
    channels with the camera at infinity along v."""
    tw = np.ascontiguousarray(np.broadcast_to(np.asarray(v, np.float64), inp.towards.shape))
    return kernels.trace_paths(dataclasses.replace(inp, towards=tw), threads=2)[..., :3]


@pytest.mark.parametrize("g,tol,apart", [(0.3, 0.02, 1.1), (0.6, 0.08, 2.0)])
def test_the_lobe_of_the_moments_comes_close_to_the_exact_m_in_every_direction(g, tol, apart):
    """In a cube lit at one point (the light going +x), the lattice's sum of the moments'
    lobe read towards v (kernels_np.read_level) against the exact deposits towards v, for
    the light's direction, its opposite and across it; the camera's M read for another
    direction (what the gathers read before) is off by a factor."""
    inp, _ = cube_case(g=g, albedo=0.95, n_paths=40000)
    m = kernels.trace_paths(with_moments(inp), threads=2)
    level = np.ascontiguousarray(m[..., 3:], np.float32)
    shape = level.shape[:3]
    idx = np.stack(np.meshgrid(*[np.arange(s - 1) for s in shape], indexing="ij"),
                   -1).reshape(-1, 3).astype(np.float64)
    exact = {}
    for v in ([1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.6, 0.8, 0.0]):
        v = np.array(v)
        ex = exact_towards(inp, v)
        exact[tuple(v)] = ex[:-1, :-1, :-1].sum()
        read = read_level(level, idx, np.broadcast_to(-v, idx.shape)).sum()
        assert abs(read / exact[tuple(v)] - 1.0) < tol, (v, read / exact[tuple(v)])
    # the light's own direction against its opposite: the camera's M of one is no stand-in
    # for the other
    assert exact[(1.0, 0.0, 0.0)] > apart * exact[(-1.0, 0.0, 0.0)]


def slab_over_ground(with_ground=True):
    """A forward-scattering slab (g 0.6) 1 m above a grey ground under a sun from above, seen
    from the side."""
    grid = np.ones((12, 12, 6), np.float32)
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.1
    i2w[:3, 3] = [-0.55, -0.55, 1.0]
    media = [prepare(Medium("slab", grid, i2w, np.full(3, 4.0), np.full(3, 0.2), 0.6))]
    lights = [Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.0, 0.0, -1.0]))]
    cam = Camera("PERSP", np.eye(4), 8, 8, (-0.5, 0.5, -0.5, 0.5))
    cam.cam_to_world[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]   # looking along +y
    cam.cam_to_world[:3, 3] = [0.0, -6.0, 1.3]
    surfaces = None
    if with_ground:
        from mpp_render.surfaces import prepare_surfaces
        v = np.array([[-4.0, -4, 0], [4, -4, 0], [4, 4, 0], [-4, 4, 0]])
        surfaces = prepare_surfaces([Surface("ground", v, np.array([[0, 1, 2], [0, 2, 3]]),
                                             np.full(3, 0.5))])
    return media, lights, cam, surfaces


def test_moments_are_made_only_where_surfaces_gather():
    media, lights, cam, ground = slab_over_ground()
    for surfaces in (None, ground):
        pre = precompute(media, lights, World(np.zeros(3)), cam, n_dirs=8, multiple=True,
                         multiple_paths=4000, surfaces=surfaces)
        msf = pre.multiple[0][0]
        assert msf.traced
        ctx = MarchContext(media, pre.fields, pre.layout, lights, 0.05, pre.multiple, camera=cam)
        same_step = MarchContext(media, pre.fields, pre.layout, lights, 0.05, pre.multiple,
                                 camera=cam, tuning=Tuning(gather_step=1.0))
        gathers = ctx.for_gathers()
        assert gathers is ctx.for_gathers()                       # made once
        assert gathers.step == 0.05 * ctx.tuning.gather_step     # the gathers' longer steps
        if surfaces is None:
            assert msf.moments is None and not gathers.gathers
            assert same_step.for_gathers() is same_step          # nothing to change
        else:
            assert msf.moments.shape == msf.levels[0].shape[:3] + (12,)
            assert gathers.gathers and same_step.for_gathers().gathers
            assert same_step.for_gathers().step == 0.05


@needs_c
def test_the_gathers_read_the_light_scattered_towards_the_ground():
    """Rays from the ground under the slab, looking up: the march twins agree on the moments'
    lobe, and it is brighter than the camera's M (light scattered sideways, towards the
    camera) read along the same rays: the sun's light goes on downwards."""
    media, lights, cam, ground = slab_over_ground()
    pre = precompute(media, lights, World(np.zeros(3)), cam, n_dirs=8, multiple=True,
                     multiple_paths=20000, surfaces=ground)
    camera_ctx = MarchContext(media, pre.fields, pre.layout, lights, 0.05, pre.multiple,
                              camera=cam)
    gather_ctx = camera_ctx.for_gathers()
    rng = np.random.default_rng(2)
    n = 400
    o = np.zeros((n, 3))
    o[:, :2] = rng.uniform(-0.4, 0.4, (n, 2))
    d = rng.normal(size=(n, 3)) * 0.2
    d[:, 2] = 1.0
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    res = {}
    for name, ctx in (("camera", camera_ctx), ("gather", gather_ctx)):
        inputs = MarchInputs(o, d, np.full(n, 0.9), np.full(n, 1.7), np.ones(n),
                             rng.integers(0, 2**32, n, dtype=np.uint32), pre.fields,
                             [m.w2i for m in media], [m.sigma_s for m in media],
                             [m.sigma_t for m in media], [m.g for m in media],
                             [m.threshold for m in media], [m.voxel_size for m in media],
                             pack_lights(lights, pre.layout), -1, 0.05, 0.01, 1e10,
                             ctx.multiple)
        a = kernels.march(inputs, backend="numpy")
        b = kernels.march(inputs, backend="c")
        for x, y, field in zip(a, b, MarchResult._fields):
            assert np.all(np.abs(x - y) <= 1e-4 * np.maximum(np.abs(x), 1e-6)), (name, field)
        res[name] = b.multiple.mean()
    assert res["camera"] > 0.0
    assert res["gather"] > 1.3 * res["camera"], res
