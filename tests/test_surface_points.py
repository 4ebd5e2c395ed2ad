"""Points on the surfaces where light paths start (pathstarts.surface_points): a ground far
wider than the reach sphere gets its points inside the sphere, and the areas the points stand
for add up, in the mean, to the area inside the sphere, small triangles included; drawn
denser near the medium (``scale``), they still do, while most of them lie near it."""
import dataclasses

import numpy as np
import pytest

from mpp_render.precompute.pathstarts import surface_points
from mpp_render.scene import Surface
from mpp_render.surfaces import prepare_surfaces


def square(half, z=0.0, n=1, albedo=0.5):
    """A square of side 2 ``half`` at height ``z``, cut into n x n cells of two triangles."""
    g = np.linspace(-half, half, n + 1)
    x, y = np.meshgrid(g, g, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], axis=1)
    k = np.arange((n + 1) * n).reshape(n + 1, n)[:n]
    a = (k // n) * (n + 1) + k % n
    tris = np.concatenate([np.stack([a, a + n + 1, a + n + 2], -1).reshape(-1, 3),
                           np.stack([a, a + n + 2, a + 1], -1).reshape(-1, 3)])
    return Surface("sq", v, tris, np.full(3, albedo), np.zeros(3))


def test_a_wide_ground_gets_its_points_inside_the_reach_sphere():
    ss = prepare_surfaces([square(500.0, z=-1.0)])
    centre, radius = np.array([3.0, -2.0, 0.5]), 4.0
    p, tri, w = surface_points(ss, centre, radius, 4096, np.random.default_rng(1))
    # its two triangles each draw over the sphere's disc and keep what falls in them: half;
    # drawn over the whole ground, 4096 points would put 0.1 in the sphere
    assert len(p) > 0.45 * 4096
    assert np.all(np.linalg.norm(p - centre, axis=1) <= radius + 1e-9)
    np.testing.assert_allclose(p[:, 2], -1.0)
    disc = np.pi * (radius ** 2 - 1.5 ** 2)
    assert np.all(w == w[0])
    assert w.sum() == pytest.approx(disc, rel=0.05)


def test_the_points_stand_for_the_area_inside_the_sphere():
    """A fine mesh (5 000 triangles) seen by 1 000 draws: most triangles get none, yet the
    areas the points stand for add up to the area inside the sphere in the mean of 40 seeds
    (within 1 %), and with no albedo nothing is drawn where albedo_min is 0."""
    ss = prepare_surfaces([square(2.0, n=50)])
    centre, radius = np.array([0.5, 0.0, 0.3]), 1.5
    inside = np.pi * (radius ** 2 - 0.3 ** 2)
    got = [surface_points(ss, centre, radius, 1000, np.random.default_rng(s)) for s in range(40)]
    totals = [w.sum() for _, _, w in got]
    assert np.mean(totals) == pytest.approx(inside, rel=0.01)
    dark = prepare_surfaces([square(2.0, n=4, albedo=0.0)])
    assert surface_points(dark, centre, radius, 100, np.random.default_rng(0),
                          albedo_min=0.0) is None


@pytest.mark.parametrize("n", [1, 50])
def test_points_denser_near_the_medium_integrate_its_light_with_less_noise(n):
    """With ``scale`` r0 the density per area follows (r0^2 / (r0^2 + d^2))^(3/2): over a
    sphere 40 r0 wide, on a ground of two triangles or of 5 000 (cut into pieces across
    which the density changes little), the weighted points integrate a 1/d^3 falloff (the
    light a surface sends into the medium) to its exact value in the mean of 40 seeds
    (within 3 of its standard errors), with under a tenth of the spread between seeds of
    uniform points, and a third of the points lie within 2 r0 of the centre, against
    under 1 % drawn uniformly."""
    ss = prepare_surfaces([square(40.0, z=-0.5, n=n)])
    centre, radius, r0 = np.array([1.0, -2.0, 0.5]), 40.0, 1.0
    falloff = lambda p: 1.0 / (1.0 + np.sum((p - centre) ** 2, axis=1)) ** 1.5
    # the integral of the falloff over the plane 1 m below the centre, out to the sphere
    exact = 2.0 * np.pi * (1.0 / np.sqrt(2.0) - 1.0 / np.sqrt(1.0 + radius ** 2))

    def spread(scale):
        got = [surface_points(ss, centre, radius, 2000, np.random.default_rng(s), scale=scale)
               for s in range(40)]
        each = np.array([np.sum(w * falloff(p)) for p, _, w in got])
        near = np.mean([np.mean(np.linalg.norm(p - centre, axis=1) < 2.0 * r0)
                        for p, _, _ in got])
        return each, near

    each, near = spread(r0)
    flat, near_flat = spread(None)
    assert abs(each.mean() - exact) < 3.0 * each.std(ddof=1) / np.sqrt(len(each))
    assert each.std() < 0.1 * flat.std()
    assert near > 0.3 and near_flat < 0.01


def test_a_ground_falls_short_of_the_furnace_by_what_it_does_not_reflect():
    """pathstarts.sky_ground_starts: in the furnace a ground sends the sky's radiance L_w
    back; a grey one of albedo R sends R L_w, so its deficit is a fictitious emission
    pi (1 - R) L_w per area, from the side that faces the medium, over a wider reach than
    the lights' surface points (GROUND_REACH); a black ground counts whole, and with the
    surfaces' bounce off a grey one too; a white one or a dark sky has none."""
    from mpp_render.media import prepare
    from mpp_render.precompute.pathstarts import (GROUND_REACH, SURFACE_REACH, Surroundings,
                                                  sky_ground_starts, surface_reach)
    from mpp_render.scene import Medium

    n = 16
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([1.0 / n] * 3)
    i2w[:3, 3] = [-0.5 + 0.5 / n, -0.5 + 0.5 / n, 0.2 + 0.5 / n]
    pm = prepare(Medium("cube", np.full((n, n, n), 1.0, np.float32), i2w, np.full(3, 8.0),
                        np.full(3, 2.0), 0.0))
    sky = np.array([0.2, 0.3, 0.4])
    centre, radius, scale = surface_reach(pm, GROUND_REACH)
    assert radius == pytest.approx(GROUND_REACH / SURFACE_REACH * surface_reach(pm)[1])
    for albedo in (0.5, 0.0):
        ground = prepare_surfaces([square(2.0 * radius, z=0.0, albedo=albedo)])
        around = Surroundings([pm], None, ground, 0.02, True)
        p, power, normals, jitter = sky_ground_starts(pm, around, 4, sky)
        # the points and the area each stands for, as surface_points draws them
        q, _, w = surface_points(ground, centre, radius, 16384,
                                 np.random.default_rng([4, 6151]), albedo_min=-1.0,
                                 scale=scale)
        assert len(p) == len(w) and jitter > 0.0
        assert np.hypot(p[:, 0], p[:, 1]).max() > 0.5 * radius   # far out, and
        assert np.mean(np.hypot(p[:, 0], p[:, 1]) < 2.0) > 0.2    # mostly near the medium
        np.testing.assert_allclose(normals, np.tile([0.0, 0.0, 1.0], (len(p), 1)))
        np.testing.assert_allclose(power / w[:, None],
                                   np.tile(np.pi * (1.0 - albedo) * sky, (len(p), 1)))
        # with the surfaces' bounce off a ground reflects nothing: all of it counts
        off = sky_ground_starts(pm, dataclasses.replace(around, bounce=False), 4, sky)
        np.testing.assert_allclose(off[1] / w[:, None], np.tile(np.pi * sky, (len(p), 1)))
    white = Surroundings([pm], None, prepare_surfaces([square(30.0, albedo=1.0)]), 0.02, True)
    assert sky_ground_starts(pm, white, 4, sky) is None
    assert sky_ground_starts(pm, around, 4, np.zeros(3)) is None
    assert sky_ground_starts(pm, dataclasses.replace(around, surfaces=None), 4, sky) is None


def test_a_surfaces_share_of_a_uniform_sky_counts_its_specular_layer():
    """surfaces.sky_albedo / mean_sky_albedo: a Lambertian surface reflects its base colour
    of a uniform sky in every direction; a black dielectric one (F0 0.04, roughness 1)
    reflects little along its normal and more towards grazing (the Fresnel), and its mean is
    the cosine-weighted mean of its directional albedo (checked against 20 000 cosine-drawn
    directions)."""
    from mpp_render.surfaces import mean_sky_albedo, sky_albedo

    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    ss = prepare_surfaces([Surface("matte", v, tris, np.array([0.2, 0.5, 0.7])),
                           Surface("black", v, tris, np.zeros(3), specular=0.04,
                                   roughness=1.0)])
    mean = mean_sky_albedo(ss)
    np.testing.assert_allclose(mean[:2], np.tile([0.2, 0.5, 0.7], (2, 1)), rtol=1e-9)
    rng = np.random.default_rng(3)
    u1, u2 = rng.random(20000), rng.random(20000)
    up = np.stack([np.sqrt(u1) * np.cos(2 * np.pi * u2), np.sqrt(u1) * np.sin(2 * np.pi * u2),
                   np.sqrt(1.0 - u1)], axis=1)
    black = sky_albedo(ss, np.full(20000, 2), -up)   # rays coming down onto it
    assert 0.01 < mean[2, 0] < 0.05
    assert black[:, 0].mean() == pytest.approx(mean[2, 0], rel=0.02)
    normal, grazing = sky_albedo(ss, np.array([2, 2]), np.array([[0.0, 0.0, -1.0],
                                                                  [0.995, 0.0, -0.0999]]))
    assert grazing[0] > 3.0 * normal[0] > 0.0
    np.testing.assert_allclose(sky_albedo(ss, np.array([0]), np.array([[0.6, 0.0, -0.8]]))[0],
                               [0.2, 0.5, 0.7], rtol=1e-9)


def test_a_lit_ground_sends_into_the_medium_what_every_layer_reflects():
    """pathstarts.surface_starts: a ground under a sun at 60 degrees from the vertical and a
    cube of medium above it.  Each point's power over the area it stands for is the sun's
    irradiance times the cosine times the directional albedo towards the sun of every layer
    (surfaces.sky_albedo): the base colour for a Lambertian ground; for a black glossy one
    (F0 0.04) the specular layer's share, which its diffuse albedo (0) would leave out."""
    from mpp_render.media import prepare
    from mpp_render.precompute.pathstarts import Surroundings, surface_reach, surface_starts
    from mpp_render.scene import Light, Medium
    from mpp_render.surfaces import sky_albedo

    n = 8
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([1.0 / n] * 3)
    i2w[:3, 3] = [-0.5 + 0.5 / n, -0.5 + 0.5 / n, 0.2 + 0.5 / n]
    pm = prepare(Medium("cube", np.full((n, n, n), 0.01, np.float32), i2w, np.full(3, 1.0),
                        np.zeros(3), 0.0))
    d = np.array([np.sin(np.pi / 3), 0.0, -np.cos(np.pi / 3)])
    sun = Light("SUN", "sun", np.full(3, 2.0), direction=d)
    v = np.array([[-30, -30, 0], [30, -30, 0], [30, 30, 0], [-30, 30, 0]], float)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    for surface in (Surface("matte", v, tris, np.array([0.2, 0.5, 0.7])),
                    Surface("glossy", v, tris, np.zeros(3), specular=0.04, roughness=0.4)):
        ss = prepare_surfaces([surface])
        p, power, normals, _ = surface_starts(pm, sun, Surroundings([pm], None, ss, 0.02), 5)
        centre, radius, scale = surface_reach(pm)
        w = surface_points(ss, centre, radius, 16384, np.random.default_rng(5),
                           albedo_min=-1.0, scale=scale)[2]
        far = np.hypot(p[:, 0], p[:, 1]) > 3.0          # out of the cube's (thin) shadow
        want = 2.0 * 0.5 * sky_albedo(ss, np.zeros(1, np.int64), d[None, :])[0]
        assert far.sum() > 100 and want.max() > 0.0
        np.testing.assert_allclose(power[far] / w[far, None], np.tile(want, (far.sum(), 1)),
                                   rtol=1e-6)
    np.testing.assert_allclose(2.0 * 0.5 * np.array([0.2, 0.5, 0.7]),
                               2.0 * 0.5 * sky_albedo(prepare_surfaces([Surface(
                                   "m", v, tris, np.array([0.2, 0.5, 0.7]))]),
                                   np.zeros(1, np.int64), d[None, :])[0], rtol=1e-9)
