"""The world fog's own glow scattered in the fog (precompute/fogglow.py, worldfog.glow_radiance):
the endless medium's closed form, a ray to infinity through the core's render, and the
unscattered glow missing above a black ground against the exponential integral; a glowing
volume that lights the fog round it."""
import dataclasses

import numpy as np
import pytest

from mpp_render import worldfog
from mpp_render.media import prepare
from mpp_render.precompute.fogglow import fog_glow, surface_view
from mpp_render.precompute.lattice import lattice_points
from mpp_render.precompute.lightpaths import PathLattice
from mpp_render.precompute.pathstarts import Surroundings
from mpp_render.render import render
from mpp_render.scene import SceneDescription, Settings, Surface, World
from mpp_render.surfaces import prepare_surfaces
from test_worldfog import camera, fog

GLOW = dict(sigma_s=(0.16, 0.12, 0.2), sigma_a=(0.04, 0.08, 0.0), emission=(1.0, 0.5, 0.25),
            g=0.3)


def e2(x):
    """The exponential integral E_2(x) = int_0^1 exp(-x / mu) d mu (midpoint rule)."""
    mu = (np.arange(200000) + 0.5) / 200000
    return float(np.mean(np.exp(-x / mu)))


def test_the_endless_glow_is_emission_over_absorption():
    """E1 + Em = e / sigma_a where the fog absorbs, E1 = e / sigma_t; Em is 0 without
    multiple scattering and where the fog absorbs nothing (said by lossless_glow); and a ray
    to infinity through the tail gathers exactly e / sigma_a (e / sigma_t + sigma_s / sigma_t
    of the glow), that is e (1 + albedo) / sigma_t with the glow scattered once."""
    f = fog(**GLOW)
    st = f.sigma_s + f.sigma_a
    e1, em = worldfog.glow_radiance(f, True)
    np.testing.assert_allclose(e1, f.emission / st)
    np.testing.assert_allclose((e1 + em)[:2], f.emission[:2] / f.sigma_a[:2])
    assert em[2] == 0.0 and worldfog.lossless_glow(f)
    assert not worldfog.lossless_glow(fog(sigma_s=(0.1,) * 3, sigma_a=(0.01,) * 3,
                                          emission=(1.0,) * 3))
    assert np.all(worldfog.glow_radiance(f, False)[1] == 0.0)
    o, d = np.zeros((1, 3)), np.array([[0.0, 1.0, 0.0]])
    s0, s1 = np.zeros(1), np.array([np.inf])
    single, emitted, _, multiple = worldfog.tail(f, [], o, d, s0, s1, glow=(e1, em))
    np.testing.assert_allclose((single + emitted + multiple)[0, :2],
                               f.emission[:2] / f.sigma_a[:2])
    once = worldfog.tail(f, [], o, d, s0, s1, glow=worldfog.glow_radiance(f, False))
    np.testing.assert_allclose((once[0] + once[1])[0], f.emission * (1 + f.sigma_s / st) / st)
    assert np.all(once[3] == 0.0)


@pytest.mark.parametrize("multiple", [False, True])
def test_a_ray_through_the_glowing_fog_sees_the_endless_answer(multiple):
    """No surfaces: the core's render of a glowing fog gives e / sigma_a (e (1 + albedo) /
    sigma_t with Volume Bounces 0) through the grid and its tail: the image's mean within 1
    %, every pixel within 4 % (the march's jittered steps through the grid's padding ramp,
    where the tail takes over); the scattered glow in the Volume passes, the emission in
    Emission."""
    f = fog(sigma_s=(0.16, 0.12, 0.08), sigma_a=(0.04, 0.08, 0.12), emission=(1.0, 0.5, 0.25),
            g=0.3)
    st = f.sigma_s + f.sigma_a
    desc = SceneDescription(camera(12, 8), world=World(volume=f),
                            settings=Settings(samples=4, multiple=multiple, voxel_resolution=16,
                                              multiple_paths=20000))
    out = render(desc)
    expect = f.emission / f.sigma_a if multiple else f.emission * (1 + f.sigma_s / st) / st
    got = out.passes["Combined"][..., :3].reshape(-1, 3)
    np.testing.assert_allclose(got.mean(axis=0), expect, rtol=0.01)
    np.testing.assert_allclose(got, np.broadcast_to(expect, got.shape), rtol=0.04)
    np.testing.assert_allclose(out.passes["Emission"].reshape(-1, 3).mean(axis=0), f.emission / st,
                               rtol=0.01)
    assert ("Volume Multiple" in out.passes) == multiple


def ground_scene(g=0.0):
    """An endless glowing fog (sigma_t 0.5 / m) over a black ground 400 m wide at z = -1.5 m,
    the camera at the origin looking along +y: the fog's prepared grid, its path lattice and
    the surroundings the glow's paths see."""
    f = fog(sigma_s=(0.4,) * 3, sigma_a=(0.1,) * 3, emission=(1.0,) * 3, g=g)
    v = np.array([[-200.0, -200.0, -1.5], [200.0, -200.0, -1.5], [200.0, 200.0, -1.5],
                  [-200.0, 200.0, -1.5]])
    ground = Surface("ground", v, np.array([[0, 1, 2], [0, 2, 3]]), np.zeros(3), np.zeros(3))
    cam = camera(16, 12, location=(0.0, 0.0, 0.0))
    desc = SceneDescription(cam, world=World(volume=f), surfaces=[ground])
    pm = prepare(worldfog.bounded_medium(desc, f, resolution=24).medium)
    ss = prepare_surfaces([ground])
    around = Surroundings([], pm.sigma_t, ss, pm.voxel_size)
    return f, pm, cam, around


def test_the_unscattered_glow_misses_what_a_black_ground_hides():
    """Isotropic fog over a black ground: at height h the unscattered glow scattered towards
    the camera is e / sigma_t (1 - E_2(sigma_t h) / 2), the lower half of the sphere seeing
    the ground through sigma_t h / cos of fog; surface_view's h0 within 2 % at 64
    directions, and fog_glow's E1 so."""
    f, pm, cam, around = ground_scene()
    lat = PathLattice.of(pm, cam, 16, around.enclosed(pm))
    h0, h1 = surface_view(pm, lat, around, 64, seed=1, threads=2, should_cancel=None)
    _, pts = lattice_points(pm, lat.shape, lat.stride)
    z = pts[:, 2] + 1.5
    above = z > 0.05
    expect = np.array([0.5 * e2(0.5 * h) for h in z[above]])
    got = h0.reshape(-1, 3)[above, 0]
    np.testing.assert_allclose(got, expect, atol=0.02 * 0.5, rtol=0.03)
    np.testing.assert_allclose(h1, h0)                   # a black ground absorbs it all
    stride, e1, em, cross = fog_glow(pm, cam, 0, 16, False, seed=1, around=around)
    assert em is None and cross == [] and stride == lat.stride
    np.testing.assert_allclose(e1.reshape(-1, 3)[above, 0], 2.0 * (1.0 - expect),
                               atol=0.02, rtol=0.03)


def test_the_glow_beside_a_ground_converges_to_the_endless_answer_far_from_it():
    """With multiple scattering the glow a point receives falls towards a black ground and
    rises towards e / sigma_a (10 here) far above it, never above it; 40 000 paths and 160 000
    (other seeds, other points on the ground) agree within 3 % where the deficit is large
    (the points on a ground 400 m wide are drawn where the fog's reach is:
    pathstarts.surface_points)."""
    f, pm, cam, around = ground_scene(g=0.5)
    st = f.sigma_s + f.sigma_a
    a = fog_glow(pm, cam, 40000, 16, True, seed=2, around=around)
    b = fog_glow(pm, cam, 160000, 16, True, seed=3, around=around)
    lat = PathLattice.of(pm, cam, 16, around.enclosed(pm))
    _, pts = lattice_points(pm, lat.shape, lat.stride)
    z = pts[:, 2] + 1.5
    total_a = (a[1] + a[2]).reshape(-1, 3)[:, 0]
    total_b = (b[1] + b[2]).reshape(-1, 3)[:, 0]
    inf = float(f.emission[0] / f.sigma_a[0])
    assert np.all(total_b <= inf * 1.0001)
    low = (z > 1.0) & (z < 2.0)       # the lattice is 1.46 m apart: a plane 1.38 m above
    high = z > 6.5
    assert total_b[low].mean() < 0.85 * inf
    assert total_b[high].mean() > total_b[low].mean()
    assert total_a[low].mean() == pytest.approx(total_b[low].mean(), rel=0.03)
    assert np.all(a[1] <= f.emission[0] / st[0] * 1.0001)


@pytest.mark.parametrize("sigma_s, sigma_a, g, expect", [
    ((1e4,) * 3, (1e2,) * 3, 0.0, (1e-2, 5e-3, 2.5e-3)),       # optical depth 1e4 per metre
    ((0.5,) * 3, (0.0, 0.1, 0.2), 0.99, (4.0, 5.0, 1.25)),      # lossless red: scattered once
    ((0.2,) * 3, (0.05,) * 3, -0.99, (20.0, 10.0, 5.0)),        # backward scattering
])
def test_stiff_glowing_fogs_give_finite_sensible_images(sigma_s, sigma_a, g, expect):
    """A glowing fog at optical depth 1e4 per metre, with anisotropy near +1 and -1, and one
    that absorbs nothing in red (its glow there scattered once, 2 e / sigma_t, with a
    warning): finite, and the endless answer within 1 % in the image's mean."""
    f = fog(sigma_s=sigma_s, sigma_a=sigma_a, emission=(1.0, 0.5, 0.25), g=g)
    out = render(SceneDescription(camera(8, 6), world=World(volume=f),
                                  settings=Settings(samples=2, voxel_resolution=16,
                                                    multiple_paths=20000)))
    img = out.passes["Combined"][..., :3].reshape(-1, 3)
    assert np.all(np.isfinite(img))
    np.testing.assert_allclose(img.mean(axis=0), expect, rtol=0.01)
    assert any("glows and scatters without absorbing" in w for w in out.warnings) == \
        (min(sigma_a) == 0.0)


def test_a_volume_in_the_glowing_fog_is_lit_by_its_glow():
    """glow_on_medium: a faint cube in the glowing fog (no surfaces) receives the endless
    fog's E1_inf and Em_inf from every side; a dense one (20 / m) is dark at its centre and
    lit at its faces, where more of the glow has scattered in it on its way than not."""
    from mpp_render.precompute.fogglow import glow_on_medium
    from mpp_render.scene import Medium
    f = fog(sigma_s=(0.16,) * 3, sigma_a=(0.04,) * 3, emission=(1.0, 0.5, 0.25), g=0.3)
    cam = camera(16, 12)
    desc = SceneDescription(cam, world=World(volume=f))
    fog_pm = prepare(worldfog.bounded_medium(desc, f, resolution=24).medium)
    e1_inf, em_inf = worldfog.glow_radiance(f, True)
    n = 24
    i2w = np.eye(4) * 0.1
    i2w[:3, 3] = -1.15
    i2w[3, 3] = 1.0
    for density, centre_e1 in ((1e-4, 1.0), (20.0, 0.0)):
        cube = prepare(Medium("cube", np.ones((n, n, n), np.float32), i2w,
                              np.full(3, 0.9 * density), np.full(3, 0.1 * density), 0.0))
        stride, e1, em = glow_on_medium(fog_pm, [cube], cube, cam, 64, 0.05, True, seed=3)
        mid = tuple(s // 2 for s in e1.shape[:3])
        np.testing.assert_allclose(e1[mid], centre_e1 * e1_inf, atol=0.02 * e1_inf[0])
        if density < 1:
            np.testing.assert_allclose(em[mid], em_inf, rtol=0.01)
        else:
            face = e1[1, mid[1], mid[2]]         # a voxel inside a face: lit from outside
            assert np.all(face > 0.05 * e1_inf) and np.all(face > 10.0 * e1[mid] + 1e-6)
            assert np.all(em[1, mid[1], mid[2]] > face)    # scattered on its way in, mostly


def test_a_glowing_volume_lights_the_world_fog_round_it():
    """An absorbing sphere that glows and does not scatter (a fire; 0.3 m, emission 20
    W/(m^3 sr), sigma_a 0.5 per m, voxels of 0.05 m) in a world fog that scatters (sigma_s
    0.2, sigma_a 0.05 per m, g 0) and does not glow: the fog's single scattering of the
    glow (Volume Single; no lamp, no sky) along a row of pixels beside the sphere against
    the line integral of sigma_s T E1, E1 the direct sum over the emitting voxels of e V
    e^-tau / r^2 / (4 pi).  Before, the glow lit only the volumes whose boxes overlapped
    it, and never the fog (the row was 0)."""
    from mpp_render.camera import primary_rays
    from test_emission_light import glowing_ball
    vox, e = 0.05, 20.0
    fire, pts = glowing_ball(absorbing=0.5)
    f = fog(sigma_s=(0.2,) * 3, sigma_a=(0.05,) * 3)
    cam = camera(32, 24)
    out = render(SceneDescription(cam, media=[fire], world=World(volume=f),
                                  settings=Settings(samples=4, multiple=False,
                                                    multiple_paths=200_000)))
    got = out.passes["Volume Single"][12, :, 0]
    power = np.full(len(pts), e * vox ** 3)

    def e1(p):
        d = p[None] - pts
        r = np.linalg.norm(d, axis=1)
        with np.errstate(divide="ignore"):
            face = np.where(d > 0, (0.5 - pts) / d, (-0.5 - pts) / d)
        out_of_box = np.min(np.where(d != 0, face, np.inf), axis=1) * r
        return np.sum(power * np.exp(-0.5 * out_of_box - 0.25 * r) / r ** 2) / (4 * np.pi)

    s = np.linspace(0.1, 40.0, 4000)
    for col in (0, 3, 6, 9, 24, 27, 30):   # rays beside the fire's box
        o, d, _, _, _ = primary_rays(cam, np.array([col + 0.5]), np.array([12.5]), None)
        want = sum(0.2 * np.exp(-0.25 * si) * e1(o[0] + d[0] * si) for si in s) * (s[1] - s[0])
        assert got[col] == pytest.approx(want, rel=0.1), (col, got[col], want)
    dark = dataclasses.replace(fire, emission_grid=np.zeros_like(fire.emission_grid))
    out = render(SceneDescription(cam, media=[dark], world=World(volume=f),
                                  settings=Settings(samples=1, multiple=False)))
    assert np.all(out.passes["Volume Single"] == 0.0)
