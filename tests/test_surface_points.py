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


def test_the_sky_lit_ground_sends_its_light_into_a_medium_above_it():
    """pathstarts.sky_surface_starts: a grey ground under a constant sky and a thick cube of
    medium above it.  Far from the cube a point's irradiance is pi L_w (all the sky), so its
    power over the area it stands for is R pi L_w; under the cube, whose shadow the
    directions cross, it is less; with a dark sky, a black ground, no bounce or no sky
    there are no starts."""
    from mpp_render.media import prepare
    from mpp_render.precompute.pathstarts import (Surroundings, sky_surface_starts,
                                                  surface_reach)
    from mpp_render.scene import Medium

    n = 16
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([1.0 / n] * 3)
    i2w[:3, 3] = [-0.5 + 0.5 / n, -0.5 + 0.5 / n, 0.2 + 0.5 / n]
    pm = prepare(Medium("cube", np.full((n, n, n), 1.0, np.float32), i2w, np.full(3, 8.0),
                        np.full(3, 2.0), 0.0))
    ground = prepare_surfaces([square(30.0, z=0.0, albedo=0.5)])
    sky = np.array([0.2, 0.3, 0.4])
    around = Surroundings([pm], None, ground, 0.02, True, sky=sky)
    p, power, normals, jitter = sky_surface_starts(pm, around, seed=4)
    centre, radius, scale = surface_reach(pm)
    w = surface_points(ground, centre, radius, 16384, np.random.default_rng([4, 3571]),
                       albedo_min=0.0, scale=scale)[2]
    assert len(p) == len(w) and jitter > 0.0
    np.testing.assert_allclose(normals, np.tile([0.0, 0.0, 1.0], (len(p), 1)))
    per_area = power / w[:, None]
    full = 0.5 * np.pi * sky
    far = np.hypot(p[:, 0], p[:, 1]) > 6.0
    under = np.hypot(p[:, 0], p[:, 1]) < 0.2
    assert far.sum() > 100 and under.sum() > 50
    np.testing.assert_allclose(per_area[far].mean(axis=0), full, rtol=0.01)
    assert np.all(per_area <= full * (1.0 + 1e-9))
    assert np.all(per_area[under] < 0.8 * full)
    for off in (dict(sky=np.zeros(3)), dict(sky=None), dict(bounce=False)):
        assert sky_surface_starts(pm, dataclasses.replace(around, **off), seed=4) is None
    black = Surroundings([pm], None, prepare_surfaces([square(30.0, albedo=0.0)]), 0.02, True,
                         sky=sky)
    assert sky_surface_starts(pm, black, seed=4) is None

