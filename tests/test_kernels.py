"""The compiled kernels agree with their numpy twins (relative difference <= 1e-4)."""
import dataclasses
import os

import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.kernels import MarchInputs, MarchResult
from mpp_render.lightrecord import L_CHANNEL, LIGHT_FIELDS
from mpp_render.march import MarchContext, pack_lights
from mpp_render.media import prepare
from mpp_render.precompute import precompute
from mpp_render.scene import Camera, Light, Medium, World
from rays import downward_rays

# rays per march twin case; the sanitizer run (test_sanitizers.py) takes fewer, as there the
# compiled side is what is checked and the numpy twin's time buys nothing
TWIN_RAYS = int(os.environ.get("MPP_TWIN_RAYS", "3000"))

needs_c = pytest.mark.skipif(kernels.backend() != "c" and kernels._c is None,
                             reason="compiled kernels not built")


def random_media(rng, density=2.0):
    a = rng.random((10, 9, 8)).astype(np.float32) * density
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([0.3, 0.35, 0.4])
    i2w[:3, 3] = [-1.4, -1.3, -1.5]
    smooth = Medium("smoke", a, i2w, np.array([2.0, 1.5, 1.0]), np.array([0.2, 0.3, 0.4]), 0.6)
    i2w2 = np.eye(4)
    i2w2[:3, :3] *= 0.2
    i2w2[:3, 3] = [-0.5, -0.6, -0.4]
    sharp = Medium("box", np.ones((6, 7, 5), np.float32), i2w2, np.full(3, 3.0), np.full(3, 0.5),
                   -0.3, source="MESH")
    return [prepare(smooth), prepare(sharp)]


def all_lights():
    spot_m = np.eye(4)
    spot_m[:3, 3] = [0.3, 0.2, 3.0]
    area_m = np.diag([1.0, 2.0, 1.0, 1.0])
    area_m[:3, 3] = [-0.5, 0.5, 2.5]
    return [Light("SUN", "sun", np.array([3.0, 2.5, 2.0]), direction=np.array([0.3, 0.2, -0.93])),
            Light("POINT", "pt", np.array([50.0, 40.0, 30.0]), position=np.array([1.5, -1.0, 0.5]), radius=0.2),
            Light("SPOT", "spot", np.array([300.0, 300, 300]), position=spot_m[:3, 3],
                  direction=np.array([0, 0, -1.0]), matrix=spot_m, spot_size=0.8, spot_blend=0.3,
                  radius=0.3),
            Light("AREA", "area", np.array([80.0, 80, 80]), matrix=area_m, shape="ELLIPSE",
                  size_x=0.5, size_y=0.3),
            Light("POINT", "dark", np.zeros(3), position=np.zeros(3))]


def rect_light():
    """A rectangle just above the media, tilted: sampled in its solid angle (lights.py)."""
    c, s_ = np.cos(0.3), np.sin(0.3)
    rect_m = np.array([[c, 0, s_, 0.1], [0, 1, 0, 0.0], [-s_, 0, c, 0.9], [0, 0, 0, 1.0]])
    return Light("AREA", "rect", np.array([60.0, 50, 40]), matrix=rect_m,
                 position=rect_m[:3, 3].copy(), direction=-rect_m[:3, 2],
                 shape="RECTANGLE", size_x=0.6, size_y=0.4)


def unjittered_lights():
    """A sun, a point and a spot without radius: lights sampled without jitter, so the march
    may lengthen its steps in thin media."""
    spot_m = np.eye(4)
    spot_m[:3, 3] = [0.3, 0.2, 3.0]
    return [Light("SUN", "sun", np.array([3.0, 2.5, 2.0]), direction=np.array([0.3, 0.2, -0.93])),
            Light("POINT", "pt", np.array([50.0, 40.0, 30.0]), position=np.array([1.5, -1.0, 0.5])),
            Light("SPOT", "spot", np.array([300.0, 300, 300]), position=spot_m[:3, 3],
                  direction=np.array([0, 0, -1.0]), matrix=spot_m, spot_size=0.8, spot_blend=0.3)]


def indirect_lights():
    """all_lights with the point and a rectangular area light (in place of the ellipse)
    standing for scattered light (a surface's bounce, scene.Light.indirect)."""
    lights = all_lights()
    lights[3] = rect_light()    # the twins also on a rectangle, sampled in its solid angle
    lights[1].indirect = lights[3].indirect = True
    return lights


def random_march(rng, lights, density: float, n: int):
    """``random_media`` of ``density`` under ``lights`` (a world light too), precomputed with
    multiple scattering, and ``n`` random downward rays through them, the smoke emitting:
    (media, the precompute, MarchInputs)."""
    media = random_media(rng, density)
    cam = Camera("PERSP", np.eye(4), 8, 8, (-0.5, 0.5, -0.5, 0.5))
    cam.cam_to_world[:3, 3] = [0, 0, 6]
    pre = precompute(media, lights, World(np.array([0.2, 0.3, 0.5])), cam, n_dirs=8,
                     multiple=True)
    multiple = MarchContext(media, pre.fields, pre.layout, lights, 0.07, pre.multiple).multiple
    o, d, t0, t1 = downward_rays(rng, n, 2.0, 0.3, 2.5)
    inputs = MarchInputs(o, d, t0, t1, rng.uniform(0.5, 1, n),
                         rng.integers(0, 2**32, n, dtype=np.uint32), pre.fields,
                         [m.w2i for m in media], [m.sigma_s for m in media],
                         [m.sigma_t for m in media], [m.g for m in media],
                         [m.threshold for m in media], [m.voxel_size for m in media],
                         pack_lights(lights, pre.layout), pre.layout.ambient_channel, 0.07, 0.01,
                         1e10, multiple, [np.array([0.1, 0.2, 0.3]), np.zeros(3)])
    return media, pre, inputs


@needs_c
@pytest.mark.parametrize("lights,density", [(all_lights(), 2.0), (unjittered_lights(), 2.0),
                                            (unjittered_lights(), 0.1), (indirect_lights(), 2.0)],
                         ids=["all", "unjittered", "unjittered-thin", "indirect"])
def test_march_twins_agree_on_random_rays(lights, density):
    media, pre, inputs = random_march(np.random.default_rng(5), lights, density, TWIN_RAYS)
    a = kernels.march(inputs, backend="numpy")
    b = kernels.march(inputs, backend="c")
    for x, y, name in zip(a, b, MarchResult._fields):
        assert np.all(np.isfinite(y)), name
        assert np.all(np.abs(x - y) <= 1e-4 * np.maximum(np.abs(x), 1e-6)), name
    # the lamps with a radius and the area lights carry their disc's (emitter's) depth change
    # in this uneven smoke (precompute/discdepth.py): both twins read it, and it changes the
    # light
    from mpp_render.lights import has_extent
    discs = [k for k in (pre.layout.disc_channels or []) if k is not None]
    assert len(discs) == sum(has_extent(lt) for lt in lights)
    if discs:
        assert max(np.abs(f[..., k:k + 3]).max() for f in pre.fields for k in discs) > 1e-3
        bare = [f.copy() for f in pre.fields]
        for f in bare:
            for k in discs:
                f[..., k:k + 3] = 0.0
        z_np = kernels.march(inputs.replace(fields=bare), backend="numpy")
        z_c = kernels.march(inputs.replace(fields=bare), backend="c")
        assert np.all(np.abs(z_np.single - z_c.single)
                      <= 1e-4 * np.maximum(np.abs(z_np.single), 1e-6))
        assert np.abs(z_c.single - b.single).max() > 1e-4 * b.single.max()
    # skipping empty bricks changes nothing but the count of samples taken; longer steps in
    # thin media (adapt_tau) change the samples: the twins still agree, sample for sample
    bricks = [m.bricks for m in media]
    for adapt in (0.0, 0.3):
        skipping = inputs.replace(bricks=bricks, adapt_tau=adapt)
        c_np = kernels.march(skipping, backend="numpy")
        c = kernels.march(skipping, backend="c")
        for x, y, name in zip(c_np, c, MarchResult._fields):
            assert np.all(np.abs(x - y) <= 1e-4 * np.maximum(np.abs(x), 1e-6)), (name, adapt)
        assert np.all(c.steps <= a.steps) and c.steps.sum() < 0.9 * a.steps.sum()
        if adapt == 0:
            skipped = c.steps.sum()
        elif density < 1.0 and len(lights) == 3:
            assert c.steps.sum() < 0.6 * skipped  # the thin smoke takes longer steps
        if adapt == 0:
            for x, y in zip(a[:4], c[:4]):
                assert np.all(np.abs(x - y) <= 1e-4 * np.maximum(np.abs(x), 1e-6))
    assert a.single.max() > 0.01 and a.T.min() < 0.5   # the rays did see the media
    assert a.multiple.max() > 0.01                      # and multiple scattering
    assert a.emission.max() > 0.01                      # and the smoke's emission
    # Russian roulette at low transmittance: the twins agree ray for ray, and it plays
    rr = inputs.replace(roulette=0.2)
    r_np, r_c = kernels.march(rr, backend="numpy"), kernels.march(rr, backend="c")
    for x, y, name in zip(r_np, r_c, MarchResult._fields):
        assert np.all(np.abs(x - y) <= 1e-4 * np.maximum(np.abs(x), 1e-6)), ("roulette", name)
    assert r_c.steps.sum() < a.steps.sum() and np.any(r_c.T.max(axis=1) == 0.0)
    # the disc points of lamps with a radius marched near them (disc_exact): the twins agree,
    # and in this uneven smoke the light differs from the stretched centre's
    from mpp_render.media import disc_reaches
    reach = disc_reaches(media, lights, 4.0)
    dx = inputs.replace(disc_reach=reach)
    d_np, d_c = kernels.march(dx, backend="numpy"), kernels.march(dx, backend="c")
    for x, y, name in zip(d_np, d_c, MarchResult._fields):
        assert np.all(np.abs(x - y) <= 1e-4 * np.maximum(np.abs(x), 1e-6)), ("disc", name)
    if any(reach):
        lit, lit0 = d_c.single + d_c.multiple, b.single + b.multiple
        assert np.abs(lit - lit0).max() > 1e-3 * lit0.max()
    else:
        assert np.array_equal(d_c.single, b.single) and np.array_equal(d_c.multiple, b.multiple)
    # the lights' paths followed cell by cell in the smoke's optically thick cells (cell_tau,
    # cell_walk): the twins agree, and the single scattering changes
    ct = inputs.replace(cell_tau=0.05, cell_walk=8)
    t_np, t_c = kernels.march(ct, backend="numpy"), kernels.march(ct, backend="c")
    for x, y, name in zip(t_np, t_c, MarchResult._fields):
        assert np.all(np.abs(x - y) <= 1e-4 * np.maximum(np.abs(x), 1e-6)), ("cell_tau", name)
    if density > 1.0:
        assert np.abs(t_c.single - b.single).max() > 1e-3 * b.single.max()
    # each ray's stratum of its steps' jitter: the twins agree; the one stratum of one is
    # the whole step (the same bits as none)
    n = len(inputs.keys)
    sb = inputs.replace(jitter_bands=np.random.default_rng(1).integers(0, 4, n), jitter_count=4,
                        jitter_keys=np.arange(n, dtype=np.uint32) // 3)
    s_np, s_c = kernels.march(sb, backend="numpy"), kernels.march(sb, backend="c")
    for x, y, name in zip(s_np, s_c, MarchResult._fields):
        assert np.all(np.abs(x - y) <= 1e-4 * np.maximum(np.abs(x), 1e-6)), ("strata", name)
    assert np.abs(s_c.single - b.single).max() > 1e-3 * b.single.max()
    one = kernels.march(inputs.replace(jitter_bands=np.zeros(n, np.uint32), jitter_count=1,
                                       jitter_keys=inputs.keys), backend="c")
    for x, y in zip(one, b):
        assert np.array_equal(x, y)


@needs_c
def test_the_multiply_scattered_light_a_sample_reads_is_never_below_zero():
    """The sky's multiply scattered light is its collided model less its absorption's traced
    estimate (skydeficit.py), whose noise can take a lattice point below 0 (a forward and
    absorbing sphere, g 0.95, albedo 0.6: pixels of -0.05 in a Volume Multiple of mean
    0.002).  Each sample reads the sum of the lights' and the sky's multiply scattered light
    at least 0: with the world channel below 0 everywhere, how far below changes nothing (the
    samples read none of it; the forward peak's light is added apart); with it below 0 in half
    the grid, the twins give at least 0 and less than with the channel as it was."""
    media, pre, inputs = random_march(np.random.default_rng(7), unjittered_lights(), 2.0, 400)
    am = pre.layout.ambient_multiple_channel
    base = kernels.march(inputs, backend="c").multiple
    assert base.max() > 0.01

    def lowered(depth, half=False):
        fields = [f.copy() for f in inputs.fields]
        for f in fields:
            f[:f.shape[0] // 2 if half else f.shape[0], ..., am:am + 3] += np.float32(depth)
        low = inputs.replace(fields=fields)
        a, b = kernels.march(low, backend="numpy"), kernels.march(low, backend="c")
        assert np.all(np.abs(a.multiple - b.multiple) <= 1e-4 * np.maximum(np.abs(a.multiple), 1e-6))
        assert np.all(b.multiple >= 0.0) and np.all(a.multiple >= 0.0)
        return b.multiple

    deep = lowered(-1e3)
    np.testing.assert_array_equal(deep, lowered(-1e6))
    assert deep.sum() < 0.5 * base.sum()
    half = lowered(-0.2, half=True)
    assert deep.sum() < half.sum() < base.sum()


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_a_thin_mesh_volume_takes_longer_steps_inside_and_short_ones_at_its_surface(backend):
    """adapt_tau inside a mesh volume: a super-step wholly inside (the bricks' least bound 1)
    may lengthen its steps, one that may hold the surface keeps them short.  A thin
    uniform box under a sun: fewer samples, the same light within 1 %, the twins alike."""
    if backend == "c" and kernels._c is None:
        pytest.skip("compiled kernels not built")
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.05
    i2w[:3, 3] = [-1.0, -1.0, -1.0]
    box = prepare(Medium("box", np.ones((41, 41, 41), np.float32), i2w, np.full(3, 0.3),
                         np.full(3, 0.05), 0.4, source="MESH"))
    lights = unjittered_lights()[:1]
    cam = Camera("PERSP", np.eye(4), 8, 8, (-0.5, 0.5, -0.5, 0.5))
    cam.cam_to_world[:3, 3] = [0, 0, 6]
    pre = precompute([box], lights, World(np.zeros(3)), cam, n_dirs=8, multiple=False)
    rng = np.random.default_rng(2)
    n = 400
    o, d, t0, t1 = downward_rays(rng, n, 1.4, 0.1, 1.0)
    inputs = MarchInputs(o, d, t0, t1, np.ones(n), rng.integers(0, 2**32, n, dtype=np.uint32),
                         pre.fields, [box.w2i], [box.sigma_s], [box.sigma_t], [box.g],
                         [box.threshold], [box.voxel_size], pack_lights(lights, pre.layout),
                         -1 if pre.layout.ambient_channel is None else pre.layout.ambient_channel,
                         0.025, 0.01, 1e10, None, None,
                         [box.march_bricks])
    short = kernels.march(inputs, backend=backend)
    long = kernels.march(inputs.replace(adapt_tau=0.1), backend=backend)
    assert long.steps.sum() < 0.7 * short.steps.sum()   # 1.0 while every mesh step was short
    lit = short.single.sum(axis=1) > 0
    assert lit.sum() > n // 4          # the rays do cross the box
    np.testing.assert_allclose(long.single[lit], short.single[lit], rtol=0.01)
    np.testing.assert_allclose(long.T, short.T, rtol=0.01)


def smoke_before_a_lamp(rng, density):
    """(media, lights, precomputed) of one random smoke at ``density`` lit by a lamp behind
    it (from the camera at z = 6) and a sun, without multiple scattering."""
    media = random_media(rng, density)[:1]
    lamp = Light("POINT", "behind", np.array([400.0, 300.0, 200.0]),
                 position=np.array([0.2, 0.1, -1.0]))
    lights = [lamp, all_lights()[0]]
    cam = Camera("PERSP", np.eye(4), 8, 8, (-0.5, 0.5, -0.5, 0.5))
    cam.cam_to_world[:3, 3] = [0, 0, 6]
    pre = precompute(media, lights, World(np.array([0.2, 0.3, 0.5])), cam, n_dirs=8,
                     multiple=False)
    return media, lights, pre


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_the_roulette_keeps_the_mean_and_saves_steps(backend):
    """Tuning.roulette: below the threshold a ray goes on with probability T / roulette (T
    scaled up) or ends: over many random keys the mean of every result is that of the march
    without it, within its standard error, in fewer steps.  The rays cross dense smoke lit
    by a lamp behind it, where the roulette plays before the brightest light."""
    if backend == "c" and kernels._c is None:
        pytest.skip("compiled kernels not built")
    rng = np.random.default_rng(11)
    media, lights, pre = smoke_before_a_lamp(rng, 8.0)
    n = 4000 if backend == "c" else 1500
    o = np.tile([0.1, 0.0, 2.0], (n, 1))
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    t0, t1 = np.full(n, 0.4), np.full(n, 3.6)
    inputs = MarchInputs(o, d, t0, t1, np.ones(n), rng.integers(0, 2**32, n, dtype=np.uint32),
                         pre.fields, [m.w2i for m in media], [m.sigma_s for m in media],
                         [m.sigma_t for m in media], [m.g for m in media],
                         [m.threshold for m in media], [m.voxel_size for m in media],
                         pack_lights(lights, pre.layout), pre.layout.ambient_channel, 0.05, 0.01,
                         1e10, None, [np.array([0.5, 0.5, 0.5])])
    plain = kernels.march(inputs, backend=backend)
    rr = kernels.march(inputs.replace(roulette=0.05), backend=backend)
    assert plain.T.max() < 0.01            # the smoke is nearly opaque along these rays
    for name in ("single", "emission"):   # (T at the end, ~1e-7, ends in 0 on nearly every ray)
        x, y = getattr(plain, name), getattr(rr, name)
        err = np.sqrt(x.var(axis=0) / n + y.var(axis=0) / n)
        assert np.all(np.abs(x.mean(axis=0) - y.mean(axis=0)) <= 4 * err + 1e-12 * x.mean()), name
        assert y.mean() > 0.0
    assert rr.steps.sum() < 0.8 * plain.steps.sum()
    assert np.any(rr.T.max(axis=1) == 0.0) and np.all(np.isfinite(rr.single))


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_a_pixels_samples_on_the_steps_strata_keep_the_mean_with_less_noise(backend):
    """jitter_bands: groups of 4 rays along one line (a pixel's samples), each on its own
    quarter of every step, against 4 drawn on the whole step, in smoke whose light changes
    within a step (a lamp behind it): the same mean within its standard error (each step's
    strata shuffled per pixel, so that one ray's points are no more alike from step to step
    than independent ones), and the groups' means vary less (measured: 0.087 times as
    much)."""
    if backend == "c" and kernels._c is None:
        pytest.skip("compiled kernels not built")
    rng = np.random.default_rng(12)
    media, lights, pre = smoke_before_a_lamp(rng, 4.0)
    groups = 1500
    n = 4 * groups
    o = np.tile([0.1, 0.0, 2.0], (n, 1))
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    inputs = MarchInputs(o, d, np.full(n, 0.4), np.full(n, 3.6), np.ones(n),
                         rng.integers(0, 2**32, n, dtype=np.uint32),
                         pre.fields, [m.w2i for m in media], [m.sigma_s for m in media],
                         [m.sigma_t for m in media], [m.g for m in media],
                         [m.threshold for m in media], [m.voxel_size for m in media],
                         pack_lights(lights, pre.layout), pre.layout.ambient_channel, 0.2, 0.01,
                         1e10)
    whole = kernels.march(inputs, backend=backend).single.sum(axis=1).reshape(groups, 4)
    bands = np.tile(np.arange(4), groups)
    pixels = np.repeat(np.arange(groups, dtype=np.uint32) * 7919, 4)
    strata = kernels.march(inputs.replace(jitter_bands=bands, jitter_count=4, jitter_keys=pixels),
                           backend=backend).single.sum(axis=1).reshape(groups, 4)
    a, b = whole.mean(axis=1), strata.mean(axis=1)
    assert a.mean() > 0.0
    assert b.var() < 0.5 * a.var()
    assert abs(a.mean() - b.mean()) <= 4 * np.sqrt(a.var() / groups + b.var() / groups)


def test_the_steps_strata_are_a_shuffle_of_the_pixels():
    """kernels_np.step_stratum: at every step a bijection of the strata (a pixel's samples
    cover them all); with a power of two the adaptive rounds' first 2^m samples (bit-reversed
    turns) stay on distinct 2^m-ths of the step; over pixels a ray's strata at two steps are
    unrelated."""
    from mpp_render.kernels_np import step_stratum
    from mpp_render.pixelsamples import reverse_bits
    for n in (16, 6, 1):
        for key in (0, 1, 12345):
            for k in range(40):
                got = step_stratum(np.arange(n), np.full(n, key, np.uint32), k, n)
                assert sorted(got.tolist()) == list(range(n))
    turns = reverse_bits(np.arange(16), 4)
    for key in range(50):
        for k in range(10):
            got = step_stratum(turns, np.full(16, key, np.uint32), k, 16)
            for m in (1, 2, 4, 8):
                assert len(set((got[:m] * m // 16).tolist())) == m
    keys = np.arange(20000, dtype=np.uint32)
    b = np.zeros(20000, np.int64)
    s0, s1 = step_stratum(b, keys, 0, 16), step_stratum(b, keys, 1, 16)
    assert abs(np.corrcoef(s0, s1)[0, 1]) < 0.03
    assert np.histogram(s0, bins=16, range=(0, 16))[0].min() > 0.9 * 20000 / 16


@needs_c
def test_march_rejects_bad_input():
    rng = np.random.default_rng(0)
    media = random_media(rng)
    f = [np.zeros(m.grid.shape + (4,), np.float32) for m in media]
    base = [np.zeros((2, 3)), np.tile([0, 0, -1.0], (2, 1)), np.zeros(2), np.ones(2), np.ones(2),
            np.zeros(2, np.uint32), f, [m.w2i for m in media], [m.sigma_s for m in media],
            [m.sigma_t for m in media], [0.0, 0.0], [-1.0, 0.5], [0.1, 0.1],
            np.zeros((0, LIGHT_FIELDS)), -1, 0.1, 0.01, 1e10]
    kernels._c.march(*[kernels._f64(x) if i in (0, 1, 2, 3, 4) else x for i, x in enumerate(base)])
    bad_light = np.zeros((1, LIGHT_FIELDS))
    bad_light[0, L_CHANNEL] = 7   # beyond the 4 channels
    cases = {13: bad_light, 14: 2, 15: 0.0, 10: [1.5, 0.0], 5: np.zeros(3, np.uint32),
             6: [np.zeros((3, 3, 3, 1), np.float64)] * 2}
    for i, bad in cases.items():
        args = list(base)
        args[i] = bad
        with pytest.raises(ValueError):
            kernels._c.march(*args)
    # a ray's jitter stratum beyond the count, or no strata at all
    tail = [None, None, None, 4, 0.0, None, 0.0, None, None, None, 0.0, 0]
    keys = np.zeros(2, np.uint32)
    for bands, count, k in ((np.array([0, 4], np.uint32), 4, keys), (keys, 0, keys),
                            (np.zeros(3, np.uint32), 4, keys), (np.zeros(2, np.int64), 4, keys),
                            (keys, 4, None), (keys, 4, np.zeros(3, np.uint32))):
        with pytest.raises(ValueError):
            kernels._c.march(*base, *tail, bands, count, k)
    kernels._c.march(*base, *tail, np.array([0, 3], np.uint32), 4, keys)


@needs_c
def test_trilinear_twins_agree_and_read_nothing_outside():
    """The compiled trilinear (the pyramid's lookups, the drift, the escape ramp) equals
    media.trilinear exactly: inside, on the last plane and beyond (0), at NaN and at huge
    coordinates (0, no read outside the grid); a float64 grid goes to the numpy twin whole."""
    from mpp_render.media import trilinear
    rng = np.random.default_rng(4)

    def c(grid, idx):
        return kernels.trilinear(grid, idx, backend="c")

    for shape in ((7, 5, 4, 3), (2, 2, 2, 1), (9, 1, 6, 2)):
        g = rng.random(shape).astype(np.float32)
        idx = rng.uniform(-1.5, max(shape[:3]) + 0.5, (4000, 3))
        idx[:4] = [[np.nan, 0, 0], [1e300, 1, 1], [-1e300, 0, 0], [0, np.inf, 0]]
        idx[4] = np.array(shape[:3]) - 1.0                       # the last corner: outside
        idx[5] = np.array(shape[:3]) - 1.0 - 1e-9                # just inside where it can be
        with np.errstate(invalid="ignore"):
            want = trilinear(g, idx)
        got = c(g, idx)
        assert got.shape == want.shape and np.array_equal(got, want)
        assert np.all(got[:5] == 0.0)
        assert np.array_equal(c(g[..., 0].copy(), idx), want[:, 0])
    g64 = rng.random((5, 5, 5, 2))
    pts = rng.uniform(0, 4, (50, 3))
    assert np.array_equal(c(g64, pts), trilinear(g64, pts))
    with pytest.raises(ValueError):
        kernels._c.trilinear(np.zeros((3, 3, 3, 1), np.float32), np.zeros((4, 2)))
    with pytest.raises(ValueError):
        kernels._c.trilinear(np.zeros((3, 3, 3), np.float32), np.zeros((4, 3)))


@pytest.mark.parametrize("backend", ["numpy", pytest.param("c", marks=needs_c)])
def test_an_indirect_lights_single_scattering_is_multiple(backend):
    """A light marked indirect (a surface's bounce) gives the same total, its single
    scattering moved from the single output to the multiple one."""
    rng = np.random.default_rng(8)
    media = random_media(rng)
    cam = Camera("PERSP", np.eye(4), 8, 8, (-0.5, 0.5, -0.5, 0.5))
    cam.cam_to_world[:3, 3] = [0, 0, 6]
    o, d, t0, t1 = downward_rays(rng, 500, 2.0, 0.3, 2.5)
    axial, keys = rng.uniform(0.5, 1, 500), rng.integers(0, 2**32, 500, dtype=np.uint32)
    out = []
    direct = [dataclasses.replace(light, indirect=False) for light in indirect_lights()]
    for lights in (direct, indirect_lights()):
        pre = precompute(media, lights, World(np.zeros(3)), cam, n_dirs=8, multiple=True)
        multiple = MarchContext(media, pre.fields, pre.layout, lights, 0.07, pre.multiple).multiple
        out.append(kernels.march(MarchInputs(
            o, d, t0, t1, axial, keys, pre.fields, [m.w2i for m in media],
            [m.sigma_s for m in media], [m.sigma_t for m in media], [m.g for m in media],
            [m.threshold for m in media], [m.voxel_size for m in media],
            pack_lights(lights, pre.layout), -1, 0.07, 0.01, 1e10, multiple), backend=backend))
    (s0, T0, _, m0, _, _), (s1, T1, _, m1, _, _) = out
    assert np.array_equal(T0, T1)
    assert np.allclose(s0 + m0, s1 + m1, rtol=1e-9, atol=1e-15)
    moved = s0.sum() - s1.sum()
    assert moved > 0.2 * s0.sum() and np.allclose(m1.sum() - m0.sum(), moved, rtol=1e-9)


@needs_c
def test_the_compiled_light_record_is_lightrecords():
    """The C side's light record (csrc/light.h, exported as _kernels.light_layout) has
    mpp_render.lightrecord's layout, field by field."""
    from mpp_render import lightrecord
    assert kernels._c.light_layout() == lightrecord.layout()
    assert lightrecord.layout()["LIGHT_FIELDS"] == 41 and len(lightrecord.layout()) == 25


def test_the_layout_and_the_model_import_no_kernel():
    """lightrecord (the light record), walk (the walk model) and mpp (its closed forms)
    import no kernel module: the
    build, the tests and every stage can read them."""
    import subprocess
    import sys
    from pathlib import Path
    code = ("import sys, mpp_render.lightrecord, mpp_render.walk, mpp_render.mpp; "
            "bad = [m for m in sys.modules if m.startswith('mpp_render.kernels') or "
            "m.startswith('mpp_render._kernels')]; assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).resolve().parents[1])


def test_numpy_backend_holds_in_every_thread_and_a_call_can_name_its_backend():
    """kernels.numpy_backend() puts every kernel call in the block on the numpy twins, also in
    worker threads (precompute and the render's tiles run there); afterwards the backend is
    what it was.  A call's own ``backend`` names one; an unknown name is an error."""
    from concurrent.futures import ThreadPoolExecutor
    before = kernels.backend()
    with kernels.numpy_backend():
        assert kernels.backend() == "numpy"
        with ThreadPoolExecutor(2) as pool:
            assert pool.submit(kernels.backend).result() == "numpy"
    assert kernels.backend() == before
    grid, idx = np.ones((2, 2, 2), np.float32), np.full((1, 3), 0.5)
    assert kernels.trilinear(grid, idx, backend="numpy")[0] == 1.0
    with pytest.raises(ValueError):
        kernels.trilinear(grid, idx, backend="cuda")


def _thick_step_single(up: int, cell_tau: float, backend: str, walk: int = 8) -> float:
    """The mean single scattering of vertical rays through an optically thick step of density
    (empty above, 1.5 from the middle voxel down, 0.4 m voxels, extinction 4 / m: 2.4 across
    a voxel) under a slanting sun from above, the grid given as its ``up`` times finer
    trilinear resampling (the same density field)."""
    n = 9
    coarse = np.zeros((n, n, n), np.float32)
    coarse[:, :, :n // 2 + 1] = 1.5
    from mpp_render.media import trilinear
    fn = (n - 1) * up + 1
    g = np.stack(np.meshgrid(*[np.arange(fn) / up] * 3, indexing="ij"), -1).reshape(-1, 3)
    fine = np.reshape(trilinear(coarse.astype(np.float64), np.minimum(g, n - 1 - 1e-9)),
                      (fn,) * 3).astype(np.float32)
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.4 / up
    i2w[:3, 3] = -1.6
    med = prepare(Medium("step", fine, i2w, np.full(3, 3.2), np.full(3, 0.8), 0.0))
    sun = [Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.35, 0.2, -0.915]))]
    cam = Camera("PERSP", np.eye(4), 8, 8, (-0.5, 0.5, -0.5, 0.5))
    cam.cam_to_world[:3, 3] = [0, 0, 6]
    pre = precompute([med], sun, World(np.zeros(3)), cam, n_dirs=8, multiple=False)
    rng = np.random.default_rng(4)
    m = 400
    o = np.column_stack([rng.uniform(-0.9, 0.9, (m, 2)), np.full(m, 4.0)])
    d = np.tile([0.0, 0.0, -1.0], (m, 1))
    inputs = MarchInputs(o, d, np.full(m, 2.0), np.full(m, 6.0), np.ones(m),
                         rng.integers(0, 2**32, m, dtype=np.uint32), pre.fields, [med.w2i],
                         [med.sigma_s], [med.sigma_t], [med.g], [med.threshold],
                         [med.voxel_size], pack_lights(sun, pre.layout), -1, 0.01, 0.01, 1e10,
                         cell_tau=cell_tau, cell_walk=walk)
    return float(kernels.march(inputs, backend=backend).single.mean())


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_light_entering_an_optically_thick_voxel_is_followed_cell_by_cell(backend):
    """Sunlight entering a step of density whose voxels are 2.4 deep: the depth read
    trilinearly between the voxel centres leaves the step's lit layer a fifth dark against the
    same density resampled eight times finer (each cell thin, read trilinearly); with the
    sun's path followed through the thick cells (cell_tau, cell_walk 8) or read on the next
    plane of centres along its main axis alone (cell_walk 0), the coarse grid's light is
    within 1 % of the fine one's, where twice finer is still 3 % off."""
    if backend == "c" and kernels._c is None:
        pytest.skip("compiled kernels not built")
    fine = _thick_step_single(8, 0.0, backend)
    plain = _thick_step_single(1, 0.0, backend)
    plane = _thick_step_single(1, 0.05, backend)
    assert plain < 0.85 * fine
    assert abs(plane / fine - 1.0) < 0.01
    assert abs(_thick_step_single(1, 0.05, backend, walk=0) / fine - 1.0) < 0.01
    assert abs(_thick_step_single(2, 0.0, backend) / fine - 1.0) > 0.03   # still converging


def test_the_walk_through_thick_cells_has_a_compiled_twin_for_the_precompute():
    """kernels.walk_tau (the paths' source of the voxels beside thick ones): the compiled
    walk and kernels_np._walk_tau agree on random points of an uneven, optically thick grid,
    for a sun and a lamp inside the grid, with and without an extinction density per channel;
    in the thick cells the walk's depth differs from the trilinear read it starts from; bad
    channels and cell counts are refused with a ValueError, not read past the grid."""
    if kernels._c is None or not hasattr(kernels._c, "walk_depth"):
        pytest.skip("compiled kernels not built")
    rng = np.random.default_rng(11)
    n = 12
    dens = rng.gamma(0.6, 2.0, (n, n, n)).astype(np.float32)
    dens[:, :, :3] = 0.0                                    # an empty layer
    depth = np.cumsum(dens[:, :, ::-1], axis=2)[:, :, ::-1] * 0.4   # any smooth field
    ext = dens[..., None] * np.array([1.0, 0.7, 1.3], np.float32)
    grid = np.concatenate([dens[..., None], np.repeat(depth[..., None], 3, -1), ext],
                          axis=-1).astype(np.float32)
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.25
    i2w[:3, 3] = -1.5
    w2i = np.linalg.inv(i2w)[:3]
    sig = np.array([3.0, 3.5, 2.5])
    m = 500
    idx = rng.uniform(0.0, n - 1.0, (m, 3))
    x = idx @ i2w[:3, :3].T + i2w[:3, 3]
    from mpp_render.media import trilinear
    tau0 = trilinear(grid.astype(np.float64), idx)[:, 1:4]
    for lamp in (None, np.array([0.2, -0.1, 0.3])):
        if lamp is None:
            w = np.tile(np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93]), (m, 1))
            dist = np.full(m, np.inf)
        else:
            v = lamp - x
            dist = np.linalg.norm(v, axis=1)
            w = v / np.maximum(dist, 1e-12)[:, None]
        for xc in (-1, 4):
            args = (grid, w2i, sig, xc, 1, x, w, dist, tau0, float(sig.max()), 0.25, 0.25, 4)
            c = kernels.walk_tau(*args, backend="c")
            p = kernels.walk_tau(*args, backend="numpy")
            assert np.all(np.isfinite(c))
            assert np.allclose(c, p, rtol=1e-9, atol=1e-12), (xc, np.abs(c - p).max())
            assert np.abs(c - tau0).max() > 0.05          # the walk did change the depth
    with pytest.raises(ValueError):
        kernels._c.walk_depth(grid, w2i, sig, -1, 5, x, w, dist, tau0, 3.5, 0.25, 0.25, 4)
    with pytest.raises(ValueError):
        kernels._c.walk_depth(grid, w2i, sig, 6, 1, x, w, dist, tau0, 3.5, 0.25, 0.25, 4)
    with pytest.raises(ValueError):
        kernels._c.walk_depth(grid, w2i, sig, -1, 1, x, w, dist, tau0, 3.5, 0.25, 0.25, -1)
    with pytest.raises(ValueError):
        kernels._c.walk_depth(grid, w2i, sig, -1, 1, x, w[:-1], dist, tau0, 3.5, 0.25, 0.25, 4)
