"""Unit tests of the numeric core (no Blender): transmittance, phase, lights, kernels."""
import math

import numpy as np
import pytest

from mpp_render import kernels, kernels_np
from mpp_render.lights import incident, spot_attenuation
from mpp_render.media import prepare, trilinear
from mpp_render.phase import hg, sample_hg
from mpp_render.render import render
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, World


def box_medium(size=2.0, n=16, sigma_s=(1.0, 1.0, 1.0), sigma_a=(0.0, 0.0, 0.0), g=0.0,
               source="VDB", centre=(0.0, 0.0, 0.0)):
    """A homogeneous cube of side ``size`` (m) centred at ``centre``, voxel values at the
    cell centres of an n^3 grid."""
    vox = size / n
    i2w = np.eye(4)
    i2w[:3, :3] *= vox
    i2w[:3, 3] = np.asarray(centre) - size / 2 + vox / 2
    return Medium("box", np.ones((n, n, n), np.float32), i2w, np.array(sigma_s, float),
                  np.array(sigma_a, float), g, source=source)


def test_phase_normalised_and_sampling_matches_density():
    mu = np.linspace(-1, 1, 200001)
    for g in (-0.9, -0.3, 0.0, 0.5, 0.95):
        integral = 2 * np.pi * np.trapz(hg(mu, g), mu)
        assert abs(integral - 1.0) < 1e-3, (g, integral)
        rng = np.random.default_rng(1)
        axis = np.tile([0.0, 0.0, 1.0], (200000, 1))
        w = sample_hg(rng.random(200000), rng.random(200000), g, axis)
        assert np.allclose(np.linalg.norm(w, axis=1), 1.0)
        # mean cosine of HG is g
        assert abs(w[:, 2].mean() - g) < 0.01, g


def test_optical_depth_homogeneous_slab_matches_beer_lambert():
    m = prepare(box_medium(sigma_s=(0.5, 1.0, 2.0), sigma_a=(0.5, 0.0, 0.0), source="MESH"))
    pts = np.array([[0.0, 0.0, -5.0], [0.3, -0.2, -5.0]])
    dirs = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    tau = kernels_np.optical_depth(pts, dirs, np.array([10.0, 10.0]), [m.grid], [m.w2i],
                                   [m.sigma_t], [m.threshold], 0.01)
    # through 2 m of sigma_t = (1, 1, 2)
    assert np.allclose(tau, [[2.0, 2.0, 4.0]] * 2, rtol=2e-3)
    assert np.allclose(np.exp(-tau), np.exp(-np.array([2.0, 2.0, 4.0])), rtol=5e-3)



@pytest.mark.parametrize("backend", ["numpy", "c"])
def test_optical_depth_places_a_sharp_surface_within_a_step(backend):
    """A step about one voxel long whose midpoints land on a mesh volume's face used to drop
    (or add) half a segment on every ray: the light's transmittance in fog_beam came out 2 %
    too high.  From points inside a sharp box towards its face, with steps of any length up
    to two voxels, the optical depth must be sigma_t times the distance to the face."""
    if backend == "c" and kernels.backend() != "c":
        pytest.skip("compiled kernels not built")

    def fn(*args):
        return kernels.optical_depth(*args, backend=backend)

    m = prepare(box_medium(size=2.0, n=16, sigma_s=(1.0, 1.0, 1.0), source="MESH"))
    depth = np.linspace(0.05, 1.95, 39)  # distance inside from the face at x = -1
    pts = np.stack([depth - 1.0, np.full_like(depth, 0.1), np.full_like(depth, -0.03)], 1)
    dirs = np.tile([-1.0, 0.0, 0.0], (len(pts), 1))
    t_exit = depth + 1.5 * 2.0 / 16  # past the face, into the padding (as the renderer does)
    for step in (0.9 * 0.125, 0.125, 1.37 * 0.125, 2 * 0.125):
        tau = fn(pts, dirs, t_exit, [m.grid], [m.w2i], [m.sigma_t], [m.threshold], step)
        assert np.allclose(tau[:, 0], depth, atol=1e-6), (step, np.abs(tau[:, 0] - depth).max())

@pytest.mark.skipif(kernels.backend() != "c", reason="compiled kernels not built")
def test_c_optical_depth_matches_numpy_twin():
    rng = np.random.default_rng(3)
    med = box_medium(n=12)
    med.density = rng.random((12, 12, 12)).astype(np.float32) * 3
    m = prepare(med)
    m2 = prepare(box_medium(n=7, source="MESH", centre=(0.5, 0.2, 0.0)))
    pts = rng.uniform(-2, 2, (500, 3))
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = rng.uniform(0, 5, 500)
    args = ([m.grid, m2.grid], [m.w2i, m2.w2i], [m.sigma_t, m2.sigma_t * 2],
            [m.threshold, m2.threshold], 0.05)
    a = kernels_np.optical_depth(pts, d, t, *args)
    b = kernels.optical_depth(pts, d, t, *args, backend="c")
    assert np.all(np.abs(a - b) <= 1e-4 * np.maximum(np.abs(a), 1e-3))


def _thick_rays(seed=4, scale=1.0):
    """A chromatic smoke box (extinction 10-50 per m per unit density, ``scale`` times), rays
    through it."""
    rng = np.random.default_rng(seed)
    med = box_medium(n=12, sigma_s=(40.0, 20.0, 8.0), sigma_a=(10.0, 5.0, 2.0))
    med.density = (scale * (0.2 + rng.random((12, 12, 12)) * 2)).astype(np.float32)
    m = prepare(med)
    pts = rng.uniform(-1.2, 1.2, (400, 3))
    d = rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = rng.uniform(0, 4, 400)
    return m, pts, d, t, ([m.grid], [m.w2i], [m.sigma_t], [m.threshold], 0.05)


@pytest.mark.parametrize("backend", ["numpy", "c"])
def test_optical_depth_stops_where_every_channel_is_opaque(backend):
    """kernels.optical_depth's stop: a ray whose depth (times the stop matrix) stays below the
    stop depth in some channel is marched to its end as without it; one that reaches it in
    every channel ends with at least the stop depth, at most its whole depth."""
    if backend == "c" and kernels.backend() != "c":
        pytest.skip("compiled kernels not built")
    m, pts, d, t, args = _thick_rays()
    full = kernels.optical_depth(pts, d, t, *args, backend=backend)
    # the callers' channels: the depth's own, scaled, and one that mixes them
    for stop in (np.eye(3), np.diag([1.0, 0.5, 2.0]), np.array([[1, 0, 0], [0, 0, 0], [0, 1, 1.0]])):
        depth = 8.0
        got = kernels.optical_depth(pts, d, t, *args, stop=stop, stop_depth=depth, backend=backend)
        opaque = np.all(full @ stop >= depth, axis=1)
        assert 50 < opaque.sum() < len(pts) - 50, opaque.sum()   # both kinds of rays
        assert np.array_equal(got[~opaque], full[~opaque])
        assert np.all(got[opaque] @ stop >= depth)
        assert np.all(got[opaque] <= full[opaque] * (1 + 1e-12))
        # they ended early: within one step of the stop, far short of their whole depth
        step_most = 0.05 * float(np.max(m.sigma_t)) * float(m.grid.max()) * np.abs(stop).sum(0).max()
        assert np.all((got[opaque] @ stop).min(axis=1) < depth + step_most)
        assert np.mean(got[opaque].sum(1)) < 0.7 * np.mean(full[opaque].sum(1))


@pytest.mark.skipif(kernels.backend() != "c", reason="compiled kernels not built")
def test_optical_depth_stop_twins_agree_and_refuse_bad_input():
    m, pts, d, t, args = _thick_rays(5)
    stop = np.diag([1.0, 0.5, 2.0])
    a = kernels_np.optical_depth(pts, d, t, *args, stop=stop, stop_depth=8.0)
    b = kernels.optical_depth(pts, d, t, *args, stop=stop, stop_depth=8.0, backend="c")
    below = ~np.all(a @ stop >= 8.0, axis=1)
    assert below.sum() > 50
    assert np.all(np.abs(a[below] - b[below]) <= 1e-4 * np.maximum(np.abs(a[below]), 1e-3))
    assert np.all(b[~below] @ stop >= 8.0 * (1 - 1e-9))
    for backend in ("numpy", "c"):
        for bad in (dict(stop=stop, stop_depth=0.0), dict(stop=stop, stop_depth=-1.0),
                    dict(stop=stop, stop_depth=float("nan")),
                    dict(stop=-stop, stop_depth=8.0), dict(stop=stop * np.nan, stop_depth=8.0)):
            with pytest.raises(ValueError):
                kernels.optical_depth(pts, d, t, *args, backend=backend, **bad)
    with pytest.raises(ValueError):
        kernels._c.optical_depth(pts, d, t, *args, 0.5, None, 4, False, np.eye(2), 8.0)


def test_density_lengths_end_at_the_opaque_depth_and_keep_the_world_light():
    """lightdepth.density_lengths told the extinction ends its rays at OPAQUE_DEPTH; the world
    light through a medium of that depth and more is the same to 1e-15."""
    from mpp_render.precompute.lightdepth import OPAQUE_DEPTH, density_lengths
    m, pts, d, t, _ = _thick_rays(6, scale=4.0)
    full = density_lengths([m], pts, d, t, 0.05)
    cut = density_lengths([m], pts, d, t, 0.05, sig_t=np.asarray(m.sigma_t)[None, :])
    tau_full, tau_cut = full @ m.sigma_t[None, :], cut @ m.sigma_t[None, :]
    opaque = tau_full.min(axis=1) >= OPAQUE_DEPTH
    assert opaque.sum() > 20
    assert np.array_equal(cut[~opaque], full[~opaque])
    assert np.all(tau_cut[opaque].min(axis=1) >= OPAQUE_DEPTH)
    assert np.all(cut[opaque] <= full[opaque]) and np.mean(cut[opaque] < full[opaque]) > 0.5
    # what the world light makes of them: the transmittance and the collided part's ratio
    assert np.max(np.abs(np.exp(-tau_cut) - np.exp(-tau_full))) < 1e-15


def test_trilinear_is_exact_for_linear_fields_and_zero_outside():
    x, y, z = np.meshgrid(np.arange(5.0), np.arange(6.0), np.arange(7.0), indexing="ij")
    grid = (2 * x - y + 0.5 * z + 1).astype(np.float32)
    rng = np.random.default_rng(0)
    idx = rng.uniform(0, [4, 5, 6], (100, 3))
    want = 2 * idx[:, 0] - idx[:, 1] + 0.5 * idx[:, 2] + 1
    assert np.allclose(trilinear(grid, idx), want, rtol=1e-5)
    assert np.all(trilinear(grid, np.array([[-0.5, 1, 1], [4.5, 1, 1]])) == 0)


def test_point_light_inverse_square_and_spot_cone():
    L = Light("POINT", "p", np.array([100.0, 50.0, 0.0]), position=np.zeros(3))
    pts = np.array([[1.0, 0, 0], [0, 2.0, 0], [0, 0, -4.0]])
    d, e = incident(L, pts)
    want = 100.0 / (4 * np.pi) / np.array([1.0, 4.0, 16.0])
    assert np.allclose(e[:, 0], want) and np.allclose(e[:, 1], want / 2)
    assert np.allclose(d, pts / np.linalg.norm(pts, axis=1, keepdims=True))
    # spot along -Z, 60 degree cone, blend 0.5
    S = Light("SPOT", "s", np.ones(3), spot_size=math.radians(60), spot_blend=0.5)
    ang = np.radians([0.0, 10.0, 25.0, 29.9, 30.1, 60.0])
    dirs = np.stack([np.sin(ang), np.zeros_like(ang), -np.cos(ang)], axis=1)
    att = spot_attenuation(S, dirs)
    ch = math.cos(math.radians(30))
    x = np.clip((np.cos(ang) - ch) / ((1 - ch) * 0.5), 0, 1)
    assert np.allclose(att, x * x * (3 - 2 * x))
    assert att[0] == 1.0 and att[-1] == 0.0 and att[4] == 0.0


def test_sphere_spot_averages_its_cone_over_the_disc():
    """A spot with a radius (fog_beam's: 0.1 m, 8 degrees, blend 0.1) is lit through its cone
    from every point of its disc.  The 8-point lattice estimate has the mean of one random
    point (unbiased irradiance, and the phase function seen from the lit part of the disc),
    far less noise in the penumbra, and is the one-point estimate where the cone is the same
    over the whole disc."""
    m = np.eye(4)
    m[:3, :3] = [[0, 0, -1.0], [0, 1, 0], [1, 0, 0]]  # local -Z along world +X
    L = Light("SPOT", "s", np.full(3, 2000.0), position=np.zeros(3), direction=np.array([1.0, 0, 0]),
              matrix=m, radius=0.1, spot_size=math.radians(8), spot_blend=0.1)
    from mpp_render.lights import light_sample, pack_light
    rec = pack_light(L)
    k = 300
    u = (np.arange(k) + 0.5) / k
    u1, u2 = (a.ravel() for a in np.meshgrid(u, u))
    view = np.array([-0.4, 0.916, 0.0]) / np.linalg.norm([-0.4, 0.916, 0.0])
    one, eight = {}, {}
    pts = {"axis": (1.5, 0, 0), "penumbra": (1.5, 0.1, 0), "edge": (1.5, -0.15, 0.05),
           "dark": (1.5, 0.6, 0), "lit_far": (40.0, 0.5, 0)}
    for n, store in ((1, one), (8, eight)):
        for name, p in pts.items():
            d, e = light_sample(rec, np.tile(np.array(p, float), (len(u1), 1)), u1, u2, disc_points=n)[:2]
            store[name] = (d, e[:, 0])
    for name in ("axis", "penumbra", "edge"):
        (d1, e1), (d8, e8) = one[name], eight[name]
        assert e8.mean() == pytest.approx(e1.mean(), rel=2e-3), name
        p1 = (hg(-(d1 @ view), 0.85) * e1).mean()
        p8 = (hg(-(d8 @ view), 0.85) * e8).mean()
        assert p8 == pytest.approx(p1, rel=0.01), name  # one random direction: 8-11 % off
    for name in ("penumbra", "edge"):
        assert eight[name][1].std() < 0.3 * one[name][1].std(), name
    for name in ("dark", "lit_far"):  # the cone is the same over the disc: one point
        np.testing.assert_array_equal(eight[name][1], one[name][1])
        np.testing.assert_array_equal(eight[name][0], one[name][0])
    assert one["dark"][1].max() == 0.0 and one["lit_far"][1].min() > 0.0


def test_sun_irradiance_is_constant():
    L = Light("SUN", "s", np.array([3.0, 3.0, 3.0]), direction=np.array([0.0, 0.0, -1.0]))
    d, e = incident(L, np.random.default_rng(0).normal(size=(10, 3)))
    assert np.allclose(e, 3.0) and np.allclose(d, [0, 0, -1])


def test_area_light_irradiance_far_field():
    # a 0.1 m square facing -Z, 10 W: far away on axis E = P / (pi A) * A / d^2 = P/(pi d^2)
    L = Light("AREA", "a", np.full(3, 10.0), matrix=np.eye(4), size_x=0.1, size_y=0.1)
    u = np.random.default_rng(0).random((4000, 2))
    pts = np.tile([0.0, 0.0, -5.0], (4000, 1))
    _, e = incident(L, pts, u)
    assert abs(e[:, 0].mean() - 10.0 / (np.pi * 25.0)) < 1e-3 * 10 / (np.pi * 25)
    # nothing behind the emitter
    _, e = incident(L, -pts, u)
    assert np.all(e == 0)


def slab_scene(width=24, height=16, samples=4, film_transparent=False, **medium):
    cam = Camera("ORTHO", np.eye(4), width, height, (-1.5, 1.5, -1.0, 1.0))
    cam.cam_to_world[:3, 3] = [0, 0, 5]
    med = box_medium(**medium)
    return SceneDescription(cam, [], [med], world=World(np.array([0.5, 1.0, 2.0])),
                            settings=Settings(samples=samples, film_transparent=film_transparent))


def test_render_transmittance_of_a_cube_is_beer_lambert():
    desc = slab_scene(sigma_s=(0.5, 0.5, 0.5), sigma_a=(0.0, 0.25, 0.5), source="MESH")
    out = render(desc)
    T = out.passes["Transmittance"]
    centre = T[5:11, 6:18]          # pixels wholly inside the cube's silhouette (|x|,|y|<1)
    assert np.allclose(centre, np.exp(-2 * np.array([0.5, 0.75, 1.0])), rtol=2e-3)
    assert np.allclose(T[:, :2], 1.0) and np.allclose(T[:, -2:], 1.0)   # outside the cube
    comb = out.passes["Combined"]
    # no lights: combined = background seen through the cube + world light scattered
    assert np.all(comb[..., :3] >= T * np.array([0.5, 1.0, 2.0]) - 1e-6)
    assert np.all(comb[..., 3] == 1.0)
    for p in out.passes.values():
        assert np.all(np.isfinite(p))


def test_render_single_scattering_of_thin_cube_under_sun():
    # optically thin: single scattering ~ sigma_s * p * E * length, sun from the camera side
    desc = slab_scene(sigma_s=(0.01, 0.01, 0.01), source="MESH")
    desc.world.color[:] = 0
    desc.lights = [Light("SUN", "sun", np.full(3, 2.0), direction=np.array([0.0, 0.0, -1.0]))]
    out = render(desc)
    s = out.passes["Volume Single"][5:11, 6:18]
    # scattering angle: light propagates -Z, camera looks along -Z -> toward the camera is +Z,
    # cos between propagation in and out = -1; isotropic phase 1/(4 pi)
    want = 0.01 * 2.0 / (4 * np.pi) * 2.0 * math.exp(-0.01)  # average attenuation ~ e^-0.01
    assert np.allclose(s, want, rtol=0.02)
    depth = out.passes["Depth"]
    # opacity 0.01 reached after ln(1/0.99)/0.01 ~ 1.005 m into the cube starting at 4 m
    assert abs(depth[8, 12, 0] - (4.0 + math.log(1 / 0.99) / 0.01)) < 0.05
    assert np.all(depth[:, 0] >= 1e9)


def test_transparent_film_alpha_from_transmittance():
    desc = slab_scene(film_transparent=True, sigma_s=(1.0, 1.0, 1.0), source="MESH")
    out = render(desc)
    a = out.passes["Combined"][..., 3]
    T = out.passes["Transmittance"].mean(axis=2)
    assert np.allclose(a, 1 - T, atol=1e-6)
    assert a[8, 12] > 0.8 and a[8, 0] == 0.0


def test_same_seed_same_image_any_thread_count():
    a = render(slab_scene(sigma_s=(1, 1, 1)))
    desc = slab_scene(sigma_s=(1, 1, 1))
    desc.settings.threads = 1
    b = render(desc)
    for k in a.passes:
        assert np.array_equal(a.passes[k], b.passes[k]), k


def test_emissive_cube_glows_as_the_integral_says():
    # no lights, black world: a homogeneous cube emitting e per metre shows
    # L = e (1 - exp(-sigma_t L)) / sigma_t through its 2 m depth
    desc = slab_scene(sigma_s=(0.5, 0.5, 0.5), sigma_a=(0.5, 0.5, 0.5), source="MESH")
    desc.world.color[:] = 0
    desc.media[0].emission = np.array([0.3, 0.6, 0.9])
    out = render(desc)
    want = np.array([0.3, 0.6, 0.9]) * (1 - math.exp(-2.0)) / 1.0
    e = out.passes["Emission"][5:11, 6:18]
    assert np.allclose(e, want, rtol=5e-3)
    assert np.allclose(out.passes["Combined"][5:11, 6:18, :3], e + out.passes["Volume Multiple"][5:11, 6:18]
                       + out.passes["Volume Single"][5:11, 6:18], rtol=1e-5)
    assert np.all(out.passes["Emission"][:, :2] == 0)


def test_without_the_compiled_kernels_the_render_says_so_once(monkeypatch):
    """No compiled module: the render still runs (on the numpy twins), the first render's
    warnings say so, the next one's do not."""
    monkeypatch.setattr(kernels, "_c", None)
    monkeypatch.setattr(kernels, "_fallback_said", False)
    assert kernels.backend() == "numpy"
    desc = slab_scene(width=8, height=6, samples=1, sigma_s=(0.5, 0.5, 0.5))
    first, second = render(desc), render(desc)
    assert first.warnings.count(kernels.FALLBACK_MESSAGE) == 1
    assert kernels.FALLBACK_MESSAGE not in second.warnings
    assert first.stats["backend"] == "numpy"
    assert first.passes["Transmittance"].min() < 0.9
    np.testing.assert_array_equal(first.passes["Combined"], second.passes["Combined"])


def test_each_medium_kind_answers_for_itself():
    """A density grid, a mesh volume (a threshold) and the world's fog: what the stages ask
    of a medium (does it fill all space, is it of one density, what lies beyond its grid,
    what density the light paths see) each kind answers itself."""
    grid = np.zeros((6, 6, 6), np.float32)
    grid[1:5, 1:5, 1:5] = 0.5
    vdb = prepare(Medium("vdb", grid, np.eye(4), np.ones(3), np.zeros(3), 0.0))
    mesh = prepare(Medium("mesh", grid, np.eye(4), np.ones(3), np.zeros(3), 0.0, source="MESH"))
    fog = prepare(Medium("world", np.ones((4, 4, 4), np.float32), np.eye(4), np.ones(3),
                         np.zeros(3), 0.0, source="WORLD"))
    assert [m.kind for m in (vdb, mesh, fog)] == ["grid", "mesh", "fog"]
    assert [m.endless for m in (vdb, mesh, fog)] == [False, False, True]
    assert [m.uniform for m in (vdb, mesh, fog)] == [False, True, False]
    assert [m.outside_density for m in (vdb, mesh, fog)] == [0.0, 0.0, 1.0]
    assert np.all(fog.path_density() == 1.0)           # no padding ramp for the paths
    assert fog.grid.min() == 0.0                        # the march's grid has one
    assert set(np.unique(mesh.path_density())) <= {0.0, 1.0}
    assert vdb.path_density().max() == pytest.approx(0.5)


def test_a_spots_irradiance_near_its_lamp_is_the_discs_mean(monkeypatch):
    """lights.incident of a spot with a radius (p_spot_in_fogbox's: 0.05 m, 25 degrees, blend
    0.2) at voxel centres round the lamp: within SPOT_NEAR radii, where its disc spans a wide
    angle across the cone, the mean over the disc lattice's stratified shifts is point by
    point within 8 % of the disc's integral (a 40 x 40 grid of shifts; the sum of absolute
    differences over the sum; 19 % with one shift per point, the same for every seed) and
    within 1.5 % summed over the points, and the same with the compiled sampler."""
    from mpp_render import kernels, lights
    from mpp_render.lights import SPOT_NEAR, incident, light_sample, pack_light
    m = np.eye(4)
    pos = np.array([-1.0, 0.5, 3.7])
    L = Light("SPOT", "s", np.full(3, 3000.0), position=pos, direction=np.array([0, 0, -1.0]),
              matrix=m, radius=0.05, spot_size=math.radians(25), spot_blend=0.2)
    rec = pack_light(L)
    g = np.arange(-6, 7) * 0.0625 + 0.03125
    x = np.stack([a.ravel() for a in np.meshgrid(g, g, g, indexing="ij")], 1) + pos
    r = np.linalg.norm(x - pos, axis=1)
    x = x[(r > L.radius) & (r < SPOT_NEAR * L.radius)]
    grid = 40
    conv = np.zeros(len(x))
    for i in range(grid):
        for j in range(grid):
            conv += light_sample(rec, x, np.full(len(x), (i + 0.5) / grid),
                                 np.full(len(x), (j + 0.5) / grid))[1][:, 0]
    conv /= grid * grid
    assert conv.sum() > 0.0
    e = incident(L, x)[1][:, 0]
    assert e.sum() == pytest.approx(conv.sum(), rel=0.015)
    assert np.abs(e - conv).sum() < 0.08 * conv.sum()
    with monkeypatch.context() as mp:
        mp.setattr(lights, "SPOT_NEAR", 0.0)   # one shift per point
        one = incident(L, x)[1][:, 0]
    assert np.abs(e - conv).sum() < 0.4 * np.abs(one - conv).sum()
    if kernels._c is not None:
        ec = incident(L, x, sample=kernels.light_sample)[1][:, 0]
        np.testing.assert_allclose(ec, e, rtol=1e-8, atol=1e-9 * e.max())
