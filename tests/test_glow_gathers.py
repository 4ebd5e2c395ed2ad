"""A glowing medium's light as the surfaces' gathers see it (precompute/emissionlight.py
``gathered``, march.MarchContext.for_gathers): the glow's paths keep their moments where
surfaces gather, the gathers read them towards their own points, and the world light's
second copy (layout.FieldLayout.gather_ambient_channel) holds everything but that glow."""
import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.kernels import MarchInputs, MarchResult
from mpp_render.march import MarchContext, pack_lights
from mpp_render.media import prepare
from mpp_render.precompute import precompute
from mpp_render.scene import Camera, Medium, Surface, World

needs_c = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")

N, VOX = 16, 0.1   # a 1.6 m cube of 0.1 m voxels, 0.5 m above the ground


def glowing_cube(g):
    """A homogeneous cube (sigma_t 2 /m, albedo 0.9, anisotropy ``g``) whose central ball
    (radius 0.4 m) emits 2 W/(m^3 sr)."""
    idx = (np.arange(N) - 0.5 * (N - 1)) * VOX
    x, y, z = np.meshgrid(idx, idx, idx, indexing="ij")
    ball = (x * x + y * y + z * z <= 0.16)[..., None] * np.full(3, 2.0)
    i2w = np.eye(4)
    i2w[:3, :3] *= VOX
    i2w[:3, 3] = [idx[0], idx[0], 0.5 + 0.5 * VOX]
    return prepare(Medium("glow", np.ones((N, N, N), np.float32), i2w, np.full(3, 1.8),
                          np.full(3, 0.2), g, emission_grid=ball.astype(np.float32)))


def ground():
    from mpp_render.surfaces import prepare_surfaces
    v = np.array([[-4.0, -4, 0], [4, -4, 0], [4, 4, 0], [-4, 4, 0]])
    return prepare_surfaces([Surface("ground", v, np.array([[0, 1, 2], [0, 2, 3]]),
                                     np.full(3, 0.5))])


def camera(turn):
    """A camera 6 m from the cube's axis at 1.3 m height, looking at it horizontally, turned
    ``turn`` radians about the vertical (0: from -y)."""
    cam = Camera("PERSP", np.eye(4), 8, 8, (-0.5, 0.5, -0.5, 0.5))
    c, s = np.cos(turn), np.sin(turn)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    cam.cam_to_world[:3, :3] = rz @ np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float)
    cam.cam_to_world[:3, 3] = rz @ np.array([0.0, -6.0, 1.3])
    return cam


def contexts(pm, cam, surfaces, paths=60_000):
    pre = precompute([pm], [], World(np.zeros(3)), cam, n_dirs=8, multiple=True,
                     multiple_paths=paths, surfaces=surfaces, seed=3)
    ctx = MarchContext([pm], pre.fields, pre.layout, [], 0.05, pre.multiple, camera=cam,
                       glow_moments=pre.glow_moments)
    return pre, ctx


def up_from_the_ground(ctx, pm, backend, n=300):
    """The mean radiance the media send down to points of the ground under the cube, along
    rays looking up (the gathers' march: single + multiple); with both backends, the
    numpy twin's and the compiled march's results agree."""
    rng = np.random.default_rng(2)
    o = np.zeros((n, 3))
    o[:, :2] = rng.uniform(-0.6, 0.6, (n, 2))
    d = rng.normal(size=(n, 3)) * 0.3
    d[:, 2] = 1.0
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t0, t1 = kernels.union_interval([pm], o, d, np.zeros(n), np.full(n, 1e3))
    inputs = MarchInputs(o, d, t0, t1, np.ones(n), rng.integers(0, 2**32, n, dtype=np.uint32),
                         ctx.fields, [pm.w2i], [pm.sigma_s], [pm.sigma_t], [pm.g],
                         [pm.threshold], [pm.voxel_size], pack_lights(ctx.lights, ctx.layout),
                         -1 if ctx.layout.ambient_channel is None else ctx.layout.ambient_channel,
                         0.05, 0.01, 1e10, ctx.multiple)
    r = kernels.march(inputs, backend=backend)
    return float((r.single + r.multiple).mean()), r


def test_a_glow_keeps_its_moments_only_where_surfaces_gather():
    pm, cam = glowing_cube(0.7), camera(0.0)
    for surfaces in (None, ground()):
        pre, ctx = contexts(pm, cam, surfaces, paths=4000)
        lay = pre.layout
        if surfaces is None:
            assert pre.glow_moments is None and lay.gather_ambient_channel is None
            assert ctx.for_gathers().layout is lay
            continue
        stride, h, moments = pre.glow_moments[0]
        assert moments.shape[-1] == 12 and moments.dtype == np.float32
        assert h == pytest.approx(stride * VOX)
        f = pre.fields[0]
        amb, g_amb = lay.ambient_channel, lay.gather_ambient_channel
        # a black world: the world light's channels hold the glow alone, the gathers' copy
        # (the same less the glow) nothing but float32 rounding
        assert f[..., amb:amb + 3].max() > 0.0
        assert np.abs(f[..., g_amb:g_amb + 6]).max() <= 1e-5 * f[..., amb:amb + 6].max()
        gathers = ctx.for_gathers()
        assert gathers.gathers and gathers is ctx.for_gathers()
        assert len(gathers.lights) == 1 and not np.any(gathers.lights[0].strength)
        assert gathers.layout.ambient_channel == g_amb
        assert gathers.layout.ambient_multiple_channel == lay.gather_ambient_multiple_channel
        assert gathers.layout.light_channels == [None]
        level = gathers.multiple.per_medium[0][0].levels[0]
        np.testing.assert_array_equal(level, moments)


@needs_c
def test_the_gathers_see_the_glow_the_same_from_every_camera():
    """The light a forward-scattering glow (g 0.7) sends down to the ground does not depend
    on where the camera is.  The camera's own E1 and Em (the glow scattered towards the
    camera, which the gathers read before) differ by far more between two cameras a quarter
    turn apart; the gathers' moments are the same paths' whichever the camera."""
    pm = glowing_cube(0.7)
    seen, gathered = [], []
    for turn in (0.0, 0.5 * np.pi):
        pre, ctx = contexts(pm, camera(turn), ground())
        gathers = ctx.for_gathers()
        a, ra = up_from_the_ground(gathers, pm, "numpy")
        b, rb = up_from_the_ground(gathers, pm, "c")
        for x, y, name in zip(ra, rb, MarchResult._fields):
            assert np.all(np.abs(x - y) <= 1e-4 * np.maximum(np.abs(x), 1e-6)), name
        gathered.append(b)
        # the camera's glow read along the same rays (what the gathers read before)
        seen.append(up_from_the_ground(ctx, pm, "c")[0])
    assert min(gathered) > 0.0
    assert abs(gathered[0] - gathered[1]) <= 0.01 * gathered[0], gathered
    assert abs(seen[0] - seen[1]) > 0.05 * seen[0], seen


@needs_c
def test_an_isotropic_glow_reads_the_same_through_its_moments():
    """With g 0 the light scattered towards any point is the same in every direction: the
    gathers' lobe of the moments (their order 0, an eighth of the deposits' corners drawn)
    comes within the paths' noise of the camera's E1 + Em read along the same rays."""
    pm = glowing_cube(0.0)
    pre, ctx = contexts(pm, camera(0.0), ground())
    gathered = up_from_the_ground(ctx.for_gathers(), pm, "c")[0]
    seen = up_from_the_ground(ctx, pm, "c")[0]
    assert gathered == pytest.approx(seen, rel=0.05)
