"""The world's fog (worldfog.py) without Blender: its grid over the view frustum, the
analytic attenuation and tail, and renders through the core."""
import numpy as np
import pytest

from mpp_render import worldfog
from mpp_render.camera import primary_rays
from mpp_render.media import prepare
from mpp_render.precompute.lightdepth import soft_visibility
from mpp_render.render import render
from mpp_render.scene import (Camera, Light, Medium, SceneDescription, Settings, Surface,
                              World)
from mpp_render.surfaces import prepare_surfaces


def fog(sigma_s=(0.1, 0.1, 0.1), sigma_a=(0.0, 0.0, 0.0), emission=(0.0, 0.0, 0.0), g=0.0):
    return Medium("world 'W'", np.ones((1, 1, 1), np.float32), np.eye(4), np.array(sigma_s, float),
                  np.array(sigma_a, float), g, emission=np.array(emission, float), source="WORLD")


def camera(width=32, height=24, location=(0.0, -8.0, 0.0)):
    """A PERSP camera at ``location`` looking along +y (Blender's 90 degree X rotation)."""
    c2w = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
    c2w[:3, 3] = location
    return Camera("PERSP", c2w, width, height, (-0.36, 0.36, -0.27, 0.27), 0.1, 100.0)


def point(position=(0.0, 0.0, 0.0), power=500.0):
    return Light("POINT", "pt", np.full(3, power), position=np.array(position, float))


def test_grid_covers_the_frustum_up_to_the_lights():
    cam = camera()
    desc = SceneDescription(cam, lights=[point((0.0, 2.0, 0.0))])
    box = worldfog.bounded_medium(desc, fog(), resolution=40)
    assert box.depth == pytest.approx(10.0 * worldfog.CONTENT_MARGIN)   # light at depth 10 m
    m = box.medium
    assert m.source == "WORLD" and max(m.density.shape) <= 40 and np.all(m.density == 1)
    pm = prepare(m)
    # every camera ray stays inside the data box (density 1) from the near clip to the depth
    g = np.linspace(0, 1, 5)
    px, py = np.meshgrid(g * cam.width, g * cam.height)
    o, d, tmin, tmax, axial = primary_rays(cam, px.ravel(), py.ravel())
    for t in (tmin, box.depth / axial):
        idx = (o + d * t[:, None]) @ pm.w2i[:, :3].T + pm.w2i[:, 3]
        assert np.all(idx >= 1.0) and np.all(idx <= np.array(pm.grid.shape) - 2.0)
    # no content: the grid reaches where the camera's transmittance is e^-TAU_VIEW
    far = worldfog.bounded_medium(SceneDescription(cam), fog(sigma_s=(0.1, 0.2, 0.5)), resolution=40)
    assert far.depth == pytest.approx(worldfog.TAU_VIEW / 0.1)


def test_optical_depth_lights_and_background():
    f = fog(sigma_s=(0.2, 0.0, 0.1), sigma_a=(0.0, 0.0, 0.1))
    tau = worldfog.optical_depth(f.sigma_s + f.sigma_a, np.array([0.0, 5.0, np.inf]))
    np.testing.assert_allclose(tau, [[0, 0, 0], [1.0, 0, 1.0], [worldfog.FOG_TAU_MAX, 0, worldfog.FOG_TAU_MAX]])
    w = worldfog.effective_world(World(np.array([1.0, 2.0, 3.0]), volume=f), f)
    np.testing.assert_allclose(w.color, [0.0, 2.0, 0.0])
    sun = Light("SUN", "sun", np.array([3.0, 3.0, 3.0]))
    pt = point()
    out = worldfog.effective_lights([sun, pt], f)
    np.testing.assert_allclose(out[0].strength, [0.0, 3.0, 0.0])
    assert out[1] is pt


def brute_force_tail(f, light, o, d, s0, s1, n=200000):
    s = s0 + (np.arange(n) + 0.5) / n * (s1 - s0)
    x = o + d * s[:, None]
    v = light.position - x
    r = np.linalg.norm(v, axis=1)
    e = light.strength[None, :] / (4 * np.pi) / (r * r)[:, None]
    cos = np.einsum("ij,j->i", -v / r[:, None], -d)   # propagation direction . direction to camera
    g = f.g
    p = (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * cos) ** 1.5)
    st = f.sigma_s + f.sigma_a
    integrand = f.sigma_s * p[:, None] * e * np.exp(-st * r[:, None]) * np.exp(-st * (s - s0)[:, None])
    return integrand.sum(axis=0) * (s1 - s0) / n


def test_tail_matches_a_brute_force_integral():
    f = fog(sigma_s=(0.08, 0.08, 0.04), sigma_a=(0.02, 0.05, 0.02), emission=(0.1, 0.2, 0.0), g=0.4)
    light = point((1.0, 3.0, 0.5), 800.0)
    o = np.array([[0.0, -8.0, 0.0], [0.0, -8.0, 0.0]])
    d = np.array([[0.0, 1.0, 0.0], [0.3, 0.95, 0.05]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    s0 = np.array([12.0, 12.0])
    s1 = np.array([40.0, np.inf])
    single, emitted, trans, _ = worldfog.tail(f, [light], o, d, s0, s1)
    st = f.sigma_s + f.sigma_a
    ref0 = brute_force_tail(f, light, o[0], d[0], 12.0, 40.0)
    ref1 = brute_force_tail(f, light, o[1], d[1], 12.0, 12.0 + 60.0 / st.min())
    np.testing.assert_allclose(single[0], ref0, rtol=0.01)
    np.testing.assert_allclose(single[1], ref1, rtol=0.01)
    np.testing.assert_allclose(emitted[0], f.emission * -np.expm1(-st * 28.0) / st, rtol=1e-12)
    np.testing.assert_allclose(emitted[1], f.emission / st, rtol=1e-12)
    np.testing.assert_allclose(trans[0], np.exp(-st * 28.0))
    assert np.all(trans[1] == 0)
    # nothing where the stretch is empty
    single, emitted, trans, _ = worldfog.tail(f, [light], o, d, s0, s0 - 1.0)
    assert np.all(single == 0) and np.all(emitted == 0) and np.all(trans == 1)


def test_tail_reads_the_far_multiple_scattering():
    """With a far field of constant M, the tail's multiple scattering is sigma_s M (1 -
    e^(-sigma_t L)) / sigma_t over a stretch of length L (and sigma_s M / sigma_t to
    infinity, where the box holds the whole stretch); without one it is 0."""
    f = fog(sigma_s=(0.08, 0.08, 0.04), sigma_a=(0.02, 0.05, 0.02))
    m = np.array([0.5, 1.0, 2.0])
    i2w = np.eye(4) * 2.0
    i2w[:3, 3] = -400.0
    i2w[3, 3] = 1.0
    far = worldfog.FarField(np.linalg.inv(i2w)[:3], np.broadcast_to(m, (401, 401, 401, 3)))
    o = np.array([[0.0, -8.0, 0.0], [0.0, -8.0, 0.0]])
    d = np.array([[0.0, 1.0, 0.0], [0.3, 0.95, 0.05]])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    s0 = np.array([12.0, 12.0])
    s1 = np.array([40.0, np.inf])
    st = f.sigma_s + f.sigma_a
    multi = worldfog.tail(f, [], o, d, s0, s1, far=far)[3]
    np.testing.assert_allclose(multi[0], f.sigma_s * m * -np.expm1(-st * 28.0) / st, rtol=1e-3)
    np.testing.assert_allclose(multi[1], f.sigma_s * m / st, rtol=2e-3)
    assert np.all(worldfog.tail(f, [point()], o, d, s0, s1)[3] == 0)


def test_the_frame_reads_the_far_field_with_the_compiled_trilinear_to_the_same_values():
    """tiles passes kernels.trilinear to the tail (FarField.read): on a far field that varies
    voxel to voxel it gives media.trilinear's multiple scattering within 1e-12, and a read
    that returns something else shows in the tail."""
    from mpp_render import kernels
    f = fog(sigma_s=(0.08, 0.08, 0.04), sigma_a=(0.02, 0.05, 0.02), g=0.5)
    rng = np.random.default_rng(3)
    i2w = np.eye(4) * 2.0
    i2w[:3, 3] = -20.0
    i2w[3, 3] = 1.0
    far = worldfog.FarField(np.linalg.inv(i2w)[:3], rng.random((21, 21, 21, 3), np.float32))
    n = 64
    o = np.tile([0.0, -8.0, 0.0], (n, 1))
    d = rng.normal(size=(n, 3)) * 0.2 + [0.0, 1.0, 0.0]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    s0, s1 = np.full(n, 2.0), np.full(n, 25.0)
    ref = worldfog.tail(f, [point()], o, d, s0, s1, far=far)[3]
    got = worldfog.tail(f, [point()], o, d, s0, s1, far=far, trilinear=kernels.trilinear)[3]
    assert ref.max() > 0.0
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=0.0)
    half = worldfog.tail(f, [point()], o, d, s0, s1, far=far,
                         trilinear=lambda g, idx: 0.5 * kernels.trilinear(g, idx))[3]
    np.testing.assert_allclose(half, 0.5 * ref, rtol=1e-12)


def test_the_frame_samples_the_tails_lights_with_the_compiled_twin():
    """tiles passes kernels.light_sample to the tail: a point light with a radius and a spot
    give lights.light_sample's single scattering within 1e-9, and a sampler that returns
    something else shows in the tail."""
    from mpp_render import kernels
    from mpp_render.lights import light_sample
    f = fog(sigma_s=(0.08, 0.08, 0.04), sigma_a=(0.02, 0.05, 0.02), g=0.5)
    m = np.eye(4)
    m[:3, 3] = [1.0, 6.0, 3.0]
    spot = Light("SPOT", "s", np.array([500.0, 400.0, 300.0]), position=m[:3, 3].copy(),
                 direction=np.array([0.0, 0.0, -1.0]), matrix=m, spot_size=0.9, spot_blend=0.3,
                 radius=0.4)
    lamp = point((-1.0, 8.0, 0.5), 800.0)
    lamp.radius = 0.3
    rng = np.random.default_rng(4)
    n = 64
    o = np.tile([0.0, -8.0, 0.0], (n, 1))
    d = rng.normal(size=(n, 3)) * 0.2 + [0.0, 1.0, 0.0]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    s0, s1 = np.full(n, 2.0), np.full(n, 25.0)
    ref = worldfog.tail(f, [spot, lamp], o, d, s0, s1)[0]
    got = worldfog.tail(f, [spot, lamp], o, d, s0, s1, light_sample=kernels.light_sample)[0]
    assert ref.max() > 0.0
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12 * ref.max())

    def dimmed(*a, **k):
        wi, e, wc, dc, ds = light_sample(*a, **k)
        return wi, 0.5 * e, wc, dc, ds
    half = worldfog.tail(f, [spot, lamp], o, d, s0, s1, light_sample=dimmed)[0]
    np.testing.assert_allclose(half, 0.5 * ref, rtol=1e-12)


def test_a_lamp_in_fog_lights_the_fog_beyond_its_grid():
    """The traced paths of a lamp in the fog leave a far field (worldfog.FarField) on a
    frustum box to the fog's view depth: its M is positive beyond the fog's grid, falls with
    the distance from the lamp, and the tail of a ray through it gains multiple scattering."""
    from mpp_render.cache import precompute_cached, Cache
    from mpp_render.render import with_world_fog
    f = fog(sigma_s=(0.1, 0.1, 0.1), sigma_a=(0.01, 0.01, 0.01))
    desc = SceneDescription(camera(16, 12), lights=[point((0.0, 0.0, 0.5), 800.0)],
                            world=World(volume=f),
                            settings=Settings(samples=1, voxel_resolution=24))
    media = []
    world, lights, fog_pm = with_world_fog(desc, f, media, [])
    pre = precompute_cached(media, lights, world, desc.camera, n_dirs=4, seed=0, multiple=True,
                            multiple_resolution=12, multiple_paths=20000, cache=Cache(0))
    far = worldfog.far_field(pre.multiple[0])
    assert far is not None
    o = np.array([[0.0, -8.0, 0.5]] * 3)
    d = np.array([[0.0, 1.0, 0.0]] * 3)
    x = o + d * np.array([[14.0], [30.0], [60.0]])     # beyond the grid (12.5 m deep)
    m = far.read(x)
    assert np.all(m[0] > 0) and np.all(m[0] > m[1]) and np.all(m[1] > m[2])
    s0 = worldfog.tail_start(fog_pm, o[:1], d[:1])
    multi = worldfog.tail(f, lights, o[:1], d[:1], s0, np.array([np.inf]), far=far)[3]
    assert np.all(multi > 0)


def wall(y=0.0, half=1.0, emission=(1.0, 1.0, 1.0), albedo=(0.0, 0.0, 0.0)):
    v = np.array([[-half, y, -half], [half, y, -half], [half, y, half], [-half, y, half]], float)
    return Surface("wall", v, np.array([[0, 1, 2], [0, 2, 3]]), np.array(albedo, float),
                   np.array(emission, float))


def test_absorbing_fog_in_front_of_an_emitter_renders_exp_minus_sigma_d():
    f = fog(sigma_s=(0, 0, 0), sigma_a=(0.0, 0.05, 0.2))
    desc = SceneDescription(camera(), surfaces=[wall()], world=World(np.ones(3), volume=f),
                            lights=[Light("SUN", "sun", np.full(3, 4.0))],
                            settings=Settings(samples=1, multiple=False, voxel_resolution=24))
    out = render(desc)
    comb = out.passes["Combined"][..., :3]
    d = 8.0 - desc.camera.clip_start   # camera rays start at the near clip, as in Cycles
    np.testing.assert_allclose(comb[12, 16], np.exp(-np.array([0.0, 0.05, 0.2]) * d), rtol=1e-3)
    np.testing.assert_allclose(comb[0, 0], [1.0, 0.0, 0.0], atol=1e-6)   # sky: red channel clear
    assert np.all(np.isfinite(comb))


def test_point_light_in_fog_is_continuous_across_the_grid_end():
    """A point light near the camera in thin fog: the image varies smoothly where camera rays
    leave the grid and the tail takes over, and the tail carries part of the glow."""
    f = fog(sigma_s=(0.05, 0.05, 0.05))
    # 16 samples: at 4 a pixel's noise alone made a 5-7 % step in one seed of four
    # (seeds 0-5 at 16: every step under 0.4 % of the peak, rising)
    desc = SceneDescription(camera(48, 8), lights=[point((0.0, -5.0, 0.0), 300.0)],
                            world=World(volume=f),
                            settings=Settings(samples=16, multiple=False, voxel_resolution=32))
    out = render(desc)
    img = out.passes["Volume Single"][..., 0]
    assert np.all(np.isfinite(img)) and img.min() > 0
    row = img[4]
    # the glow falls off smoothly from the centre to the sides (no step at the grid's end)
    left = row[:24]
    assert np.all(np.diff(left) > -0.02 * left.max())
    import mpp_render.worldfog as wf
    orig = wf.tail
    try:
        wf.tail = lambda *a, **k: (lambda r: (0 * r[0], r[1], r[2], r[3]))(orig(*a, **k))
        without = render(desc).passes["Volume Single"][..., 0]
    finally:
        wf.tail = orig
    assert 0.01 < 1 - without.mean() / img.mean() < 0.5


def test_surface_shadow_on_the_fog_grid_is_prefiltered():
    """Visibility of a light past a plate, on the fog's grid: 0 or 1 away from the shadow's
    edge, fractions on it, and a floor right under a voxel does not shadow it."""
    cam = camera()
    desc = SceneDescription(cam, lights=[point((0.0, 0.0, 5.0))])
    pm = prepare(worldfog.bounded_medium(desc, fog(), resolution=24).medium)
    plate = wall(y=0.0, half=1.0)
    plate.vertices = np.array([[-1, -1, 2.0], [1, -1, 2.0], [1, 1, 2.0], [-1, 1, 2.0]])
    flat = np.arange(pm.grid.size)
    ijk = np.stack(np.unravel_index(flat, pm.grid.shape), axis=1).astype(float)
    pts = ijk @ pm.i2w[:3, :3].T + pm.i2w[:3, 3]
    vis = soft_visibility(prepare_surfaces([plate]), desc.lights[0], pm, flat, pts)
    below = (np.abs(pts[:, 0]) < 0.5) & (np.abs(pts[:, 1]) < 0.5) & (pts[:, 2] < 1.0)
    assert np.all(vis[below] == 0)
    far = ((np.abs(pts[:, 0]) > 3.0) & (pts[:, 2] > -1.0)) | (pts[:, 2] > 3.0)
    assert np.all(vis[far] == 1)
    assert np.any((vis > 0) & (vis < 1))


def test_forward_scattering_fog_spreads_its_peak_with_multiple_scattering():
    """World fog with a forward peak (g 0.7) and multiple scattering on: the forward peak's
    light (precompute.source.peak_light) is made on the fog's own grid, beyond it from the fog's
    analytic depth; the render is finite and the peak's light adds to Volume Multiple."""
    f = fog(sigma_s=(0.2, 0.2, 0.2), sigma_a=(0.02, 0.02, 0.02), g=0.7)
    m = np.array([[0.0, 0, -1, -6], [0, 1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 1]])  # -Z along +x
    spot = Light("SPOT", "spot", np.full(3, 800.0), position=np.array([-6.0, 0.0, 0.0]),
                 direction=np.array([1.0, 0.0, 0.0]), matrix=m, spot_size=np.radians(20.0),
                 spot_blend=0.1)
    desc = SceneDescription(camera(32, 16), lights=[spot], world=World(volume=f),
                            settings=Settings(samples=2, multiple=True, voxel_resolution=32,
                                              multiple_paths=0))   # the walk's peak light
    out = render(desc)
    ms = out.passes["Volume Multiple"][..., :3]
    assert np.all(np.isfinite(ms)) and ms.mean() > 0
    import mpp_render.precompute.run as pc
    orig = pc.peak_light
    try:   # the peak's light taken away: less multiply scattered light
        pc.peak_light = lambda *a, **k: (lambda r: (0 * r[0], r[1]))(orig(*a, **k))
        without = render(desc).passes["Volume Multiple"][..., :3]
    finally:
        pc.peak_light = orig
    print("with", ms.mean(), "without", without.mean())
    assert without.mean() < 0.95 * ms.mean()


def test_a_varying_fog_is_boxed_to_the_depth_its_own_extinction_needs():
    """worldfog.field_depth: a uniform fog of sigma_t 0.1 / m ends where the central ray's
    optical depth reaches TAU_VIEW (70 m); a fog only inside a ball of radius 2 m, 10 m ahead,
    just past the ball; no fog at all, at the near clip; the camera's clip end bounds a thin
    fog."""
    cam = camera()          # at (0, -8, 0) looking along +y, clip 0.1 - 100 m
    step = 100.0 / worldfog.FIELD_STEPS
    uniform = worldfog.field_depth(cam, lambda p: np.full(len(p), 0.1))
    assert worldfog.TAU_VIEW / 0.1 <= uniform <= worldfog.TAU_VIEW / 0.1 + 2 * step
    ball = worldfog.field_depth(
        cam, lambda p: np.where(np.linalg.norm(p - [0.0, 2.0, 0.0], axis=1) < 2.0, 1.0, 0.0))
    assert 10.0 + 1.9 <= ball <= 12.0 + 2 * step
    assert worldfog.field_depth(cam, lambda p: np.zeros(len(p))) == pytest.approx(0.1 + 1e-3)
    assert worldfog.field_depth(cam, lambda p: np.full(len(p), 1e-4)) <= 100.0 + 1e-9


def test_the_far_boxs_tent_mass_is_what_lies_inside_it_and_above_the_ground():
    """lightpaths.far_lattice: voxels at the Multiple Scattering Resolution along the box's
    longest side; a point's tent mass is a voxel's volume inside the box, 7/8 of it on a
    face and (7/8)^3 at a corner (nothing is deposited beyond); under a ground 0, and a point
    the ground passes through holds the part of its tent above it."""
    from types import SimpleNamespace
    from mpp_render.precompute.lightpaths import far_lattice
    from mpp_render.precompute.pathstarts import Surroundings
    f = fog(sigma_s=(0.2, 0.2, 0.2))
    pm = SimpleNamespace(medium=f, sigma_t=np.full(3, 0.2))
    cam = camera(16, 12)
    lat = far_lattice(pm, cam, None, 24, nodal=False)
    assert max(lat.shape) == 24
    v3 = lat.h ** 3
    m = lat.tent_mass[..., 0]
    assert m[1:-1, 1:-1, 1:-1] == pytest.approx(v3)
    assert m[0, 5, 5] == pytest.approx(7 / 8 * v3)
    assert m[-1, -1, -1] == pytest.approx((7 / 8) ** 3 * v3)
    assert lat.offsets is None
    assert far_lattice(pm, cam, None, 48, nodal=False).shape[0] > lat.shape[0]
    idx = np.stack(np.meshgrid(*[np.arange(s) for s in lat.shape], indexing="ij"), -1)
    i2w = np.linalg.inv(np.vstack([lat.w2i, [0, 0, 0, 1]]))
    z = (idx @ i2w[:3, :3].T + i2w[:3, 3])[..., 2]
    level = float(np.unique(np.round(z, 9))[len(np.unique(np.round(z, 9))) // 3])
    ground_z = level + 0.05 * lat.h      # just above a layer of points
    ss = prepare_surfaces([Surface("ground", np.array([[-500.0, -500, ground_z],
                                                       [500, -500, ground_z],
                                                       [500, 500, ground_z],
                                                       [-500, 500, ground_z]]),
                                   np.array([[0, 1, 2], [0, 2, 3]]), np.full(3, 0.5))])
    around = Surroundings([], np.full(3, 0.2), ss, 0.1)
    cut = far_lattice(pm, cam, around, 24, nodal=True)
    mc = cut.tent_mass[..., 0]
    deep = z < ground_z - 1.6 * cut.h
    high = z > ground_z + 1.6 * cut.h
    on = np.abs(z - level) < 1e-6
    assert deep.any() and high.any() and on.any()
    assert np.all(mc[deep] == 0.0)
    np.testing.assert_allclose(mc[high], m[high])
    assert np.all(mc[on] > 0.3 * m[on]) and np.all(mc[on] < 0.7 * m[on])
    # the ground's points' centroids lie above them: the nodal values move them down to it
    up = cut.offsets[on] @ np.linalg.solve(cut.i2w, np.array([0.0, 0.0, 1.0]))
    assert np.all(cut.offsets[high & (idx[..., 0] > 0) & (idx[..., 0] < cut.shape[0] - 1)
                              & (idx[..., 1] > 0) & (idx[..., 1] < cut.shape[1] - 1)
                              & (idx[..., 2] > 0) & (idx[..., 2] < cut.shape[2] - 1)] == 0.0)
    assert np.all(up > 0.0)
