"""Light that flat surfaces reflect into the media (mpp_render/bounce.py) and the area
light's irradiance integrated over its emitter (lights.area_incident)."""
import math

import numpy as np
import pytest

from mpp_render.bounce import SUB, TILES, bounce_lights, media_corners, plane_of
from mpp_render.lights import light_sample
from mpp_render.lights import incident, irradiance, pack_light
from mpp_render.media import prepare
from mpp_render.render import render
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, Surface, World

from test_core import box_medium
from test_surfaces import quad


def area(shape, size_x=2.0, size_y=0.7, tilt=0.4):
    m = np.eye(4)
    c, s = math.cos(tilt), math.sin(tilt)
    m[:3, :3] = np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) @ np.diag([1.5, 1.0, 1.0])
    m[:3, 3] = (0.2, 0.1, 0.3)
    return Light("AREA", "a", np.array([10.0, 20.0, 30.0]), matrix=m, shape=shape,
                 size_x=size_x, size_y=size_y)


@pytest.mark.parametrize("shape", ["SQUARE", "RECTANGLE", "DISK", "ELLIPSE"])
def test_area_irradiance_is_the_emitters_integral(shape):
    """Against the mean of 400 000 points of the emitter (the march's estimator): within 1 %
    and 0.01 in direction at points 2.5-4 m from its centre; zero behind it."""
    light = area(shape)
    rng = np.random.default_rng(3)
    normal = pack_light(light)[29:32]
    v = rng.normal(0.0, 1.0, (12, 3))
    pts = light.matrix[:3, 3] + v / np.linalg.norm(v, axis=1)[:, None] * rng.uniform(2.5, 4.0, (12, 1))
    d, e = incident(light, pts)
    u = rng.random((400_000, 2))
    for p, dp, ep in zip(pts, d, e):
        dm, em = light_sample(pack_light(light), np.repeat(p[None], len(u), 0), u[:, 0], u[:, 1])[:2]
        if (p - light.matrix[:3, 3]) @ normal <= 0.0:
            assert np.all(ep == 0.0) and np.all(em == 0.0)
            continue
        assert np.allclose(ep, em.mean(axis=0), rtol=0.01)
        mean = (dm * em[:, :1]).sum(axis=0)
        assert np.linalg.norm(dp - mean / np.linalg.norm(mean)) < 0.01


def test_area_irradiance_next_to_a_large_emitter():
    """On the axis of a 2A x 2B rectangle at distance z the solid angle is
    4 atan(AB / (z sqrt(A^2 + B^2 + z^2))): 1 mm above a 4 m square that is 2 pi less
    0.1 %; one point of the emitter read alone gave L A / z^2, 1.6e7 times more."""
    light = Light("AREA", "big", np.full(3, 100.0), matrix=np.diag([4.0, 4.0, 1.0, 1.0]),
                  shape="SQUARE", size_x=1.0)
    L = 100.0 / math.pi / 16.0
    for z in (1e-3, 0.3, 2.0, 50.0):
        d, e = incident(light, np.array([[0.0, 0.0, -z]]))
        omega = 4.0 * math.atan(4.0 / (z * math.sqrt(8.0 + z * z)))
        assert np.allclose(e, L * omega, rtol=1e-9)
        assert np.allclose(d, [[0.0, 0.0, -1.0]], atol=1e-9)


def test_irradiance_alone_is_incidents():
    """lights.irradiance (the precompute's read, without the direction) equals incident's
    irradiance for every kind of light, also in front of and behind an area emitter."""
    pts = np.random.default_rng(5).normal(0.0, 2.0, (500, 3))
    spot = Light("SPOT", "s", np.full(3, 40.0), position=np.array([0.0, 0.0, 3.0]),
                 spot_size=0.6)
    for light in (area("SQUARE"), area("DISK"), spot,
                  Light("POINT", "p", np.array([1.0, 2.0, 3.0]), position=np.ones(3)),
                  Light("SUN", "sun", np.full(3, 2.0), direction=np.array([0.0, 0.0, -1.0]))):
        want = incident(light, pts)[1]
        assert np.any(want > 0) and np.array_equal(irradiance(light, pts), want), light.kind


def flat_ground(half=6.0, albedo=0.5, z=0.0):
    return quad(z, half, albedo=albedo, name="ground")


def thin_box():
    """A 1 m cube 0.5-1.5 m above the ground that attenuates nothing (zero coefficients)."""
    return prepare(box_medium(size=1.0, n=8, sigma_s=(0, 0, 0), centre=(0.0, 0.0, 1.0)), [])


def test_ground_under_the_sun_reflects_albedo_times_irradiance():
    """The rectangles cover the media's footprint (their grid's box) widened by their height
    each side and together carry albedo x E cos x area."""
    sun = Light("SUN", "sun", np.full(3, 3.0), direction=np.array([math.sin(0.3), 0.0, -math.cos(0.3)]))
    box = thin_box()
    lights = bounce_lights([flat_ground()], [sun], [box], 0.05)
    assert len(lights) == TILES * TILES
    total = sum(np.asarray(l.strength) for l in lights)
    corners = media_corners([box])
    side = np.ptp(corners[:, 0]) + 2.0 * corners[:, 2].max()
    assert 3.5 < side < 4.5 and np.ptp(corners[:, 1]) == np.ptp(corners[:, 0])
    assert np.allclose(total, 0.5 * 3.0 * math.cos(0.3) * side * side, rtol=1e-9)
    for l in lights:  # facing up, at the ground
        assert np.allclose(pack_light(l)[29:32], [0, 0, 1]) and abs(l.matrix[2, 3]) < 0.01


def test_what_does_not_bounce():
    sun = Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.0, 0.0, -1.0]))
    box = [thin_box()]
    bent = Surface("bent", np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0.3], [0, 1, 0]], float),
                   np.array([[0, 1, 2], [0, 2, 3]]), np.full(3, 0.5))
    assert plane_of(bent) is None and bounce_lights([bent], [sun], box, 0.05) == []
    assert bounce_lights([flat_ground(albedo=0.0)], [sun], box, 0.05) == []   # black
    metal = flat_ground()
    metal.metallic = 1.0
    assert bounce_lights([metal], [sun], box, 0.05) == []                      # no diffuse part
    ceiling = flat_ground(z=3.0)   # above the box, the sun on its back
    assert bounce_lights([ceiling], [sun], box, 0.05) == []
    dark = Light("SUN", "off", np.zeros(3), direction=np.array([0.0, 0.0, -1.0]))
    assert bounce_lights([flat_ground()], [dark], box, 0.05) == []
    assert bounce_lights([flat_ground()], [sun], [], 0.05) == []


def test_a_turned_square_is_tiled_along_its_sides():
    """A square ground turned 30 degrees about the vertical: the rectangles' sides follow its
    sides (a square's principal axes are any pair), so that none hangs off the mesh."""
    c, s = math.cos(math.pi / 6), math.sin(math.pi / 6)
    ground = flat_ground(half=1.5)
    ground.vertices = np.asarray(ground.vertices) @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])
    o, e1, e2, n = plane_of(ground)
    assert abs(n[2]) == pytest.approx(1.0)
    sides = {round(float(abs(e1 @ np.array(a))), 9) for a in ((c, s, 0), (-s, c, 0))}
    assert sides == {0.0, 1.0}
    sun = Light("SUN", "sun", np.full(3, 2.0), direction=np.array([0.0, 0.0, -1.0]))
    lights = bounce_lights([ground], [sun], [thin_box()], 0.05)
    # the footprint (4 m wide) is wider than the 3 m square: the rectangles cover it all,
    # each a quarter of its 9 m^2
    assert len(lights) == TILES * TILES
    for l in lights:
        assert np.allclose(l.strength, 0.5 * 2.0 * 9.0 / 4, rtol=1e-9)


def test_the_walk_has_no_bounce_under_a_world_volume():
    """With the walk (Light Paths 0), under the world's fog (whose grid spans the view) the
    setting changes nothing: the ground's rectangles would each cost a light's precompute
    over the whole view."""
    from test_worldfog import camera, fog, point
    def go(bounce):
        desc = SceneDescription(camera(12, 8, (0.0, -8.0, 1.0)), lights=[point((0.0, 0.0, 1.0))],
                                surfaces=[flat_ground(half=20.0)], world=World(volume=fog()),
                                settings=Settings(samples=1, surface_bounce=bounce,
                                                  voxel_resolution=24, multiple_resolution=12,
                                                  multiple_paths=0))
        return render(desc).passes["Combined"]
    on = go(True)
    assert np.all(np.isfinite(on)) and on[..., :3].mean() > 0 and np.array_equal(on, go(False))


def test_traced_paths_bring_the_ground_light_into_a_world_fog():
    """With traced paths the lit ground under a lamp in the world's fog sends light back into
    the fog (paths start on it and reflect off it): Volume Multiple gains, Volume Single
    stays the lamp's alone."""
    from test_worldfog import camera, fog, point
    def go(bounce):
        desc = SceneDescription(camera(12, 8, (0.0, -8.0, 1.0)), lights=[point((0.0, 0.0, 1.0))],
                                surfaces=[flat_ground(half=20.0, albedo=0.8)],
                                world=World(volume=fog()),
                                settings=Settings(samples=1, surface_bounce=bounce,
                                                  voxel_resolution=24, multiple_resolution=12,
                                                  multiple_paths=20000))
        return render(desc).passes
    on, off = go(True), go(False)
    assert on["Volume Multiple"][..., :3].mean() > 1.1 * off["Volume Multiple"][..., :3].mean()
    assert np.array_equal(on["Volume Single"], off["Volume Single"])
    assert np.all(np.isfinite(on["Combined"]))


def test_a_ground_with_a_hole_reflects_only_where_it_is():
    """A ground covering only x < 0 (its half of the footprint) reflects half of the whole
    ground's power: its points off the mesh count as dark."""
    sun = Light("SUN", "sun", np.full(3, 2.0), direction=np.array([0.0, 0.0, -1.0]))
    half = Surface("half", np.array([[-6, -6, 0], [0, -6, 0], [0, 6, 0], [-6, 6, 0]], float),
                   np.array([[0, 1, 2], [0, 2, 3]]), np.full(3, 0.5))
    whole = sum(np.asarray(l.strength) for l in bounce_lights([flat_ground()], [sun], [thin_box()], 0.05))
    part = bounce_lights([half], [sun], [thin_box()], 0.05)
    assert np.allclose(sum(np.asarray(l.strength) for l in part), whole / 2, rtol=0.5 / SUB)


def test_the_medium_shadows_the_ground_it_lights():
    """A dense box (optical depth 4) between the sun and the ground takes albedo x E x its
    1 m^2 shadow x (1 - e^-4) from the rectangles' power, within the sampling of their
    irradiance points (35 cm apart)."""
    sun = Light("SUN", "sun", np.full(3, 2.0), direction=np.array([0.0, 0.0, -1.0]))
    dense = prepare(box_medium(size=1.0, n=8, sigma_s=(3, 3, 3), sigma_a=(1, 1, 1),
                               centre=(0.6, 0.6, 1.0)), [])
    clear = prepare(box_medium(size=1.0, n=8, sigma_s=(0, 0, 0), centre=(0.6, 0.6, 1.0)), [])
    lit = sum(np.asarray(l.strength) for l in bounce_lights([flat_ground()], [sun], [clear], 0.05))
    shaded = sum(np.asarray(l.strength) for l in bounce_lights([flat_ground()], [sun], [dense], 0.05))
    want = 0.5 * 2.0 * 1.0 * (1.0 - math.exp(-4.0))
    assert np.all(0.5 * want < lit - shaded) and np.all(lit - shaded < 1.5 * want), (lit - shaded, want)


def test_the_ground_lights_the_smoke_above_it():
    """A scattering box 0.5 m above a grey ground, lit by a sun from above, seen from the
    side (level with the ground): with the bounce on, Volume Multiple gains (the ground's
    light, scattered once and many times, is indirect light) and Volume Single is the sun's
    alone, as without it."""
    cam = Camera("ORTHO", np.eye(4), 16, 12, (-1.5, 1.5, -0.75, 1.5))
    cam.cam_to_world = np.array([[1, 0, 0, 0], [0, 0, -1, -6], [0, 1, 0, 0.5], [0, 0, 0, 1]], float)
    sun = Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.0, 0.0, -1.0]))
    box = box_medium(size=1.0, n=12, sigma_s=(2, 2, 2), sigma_a=(0.2, 0.2, 0.2), centre=(0, 0, 1.0))

    def go(bounce):
        desc = SceneDescription(cam, [sun], [box], surfaces=[flat_ground(albedo=0.8)],
                                world=World(np.zeros(3)),
                                settings=Settings(samples=4, multiple_resolution=12,
                                                  surface_bounce=bounce))
        return render(desc).passes
    on, off = go(True), go(False)
    assert on["Volume Multiple"][..., :3].mean() > 1.05 * off["Volume Multiple"][..., :3].mean()
    single_on, single_off = on["Volume Single"][..., :3].mean(), off["Volume Single"][..., :3].mean()
    assert abs(single_on - single_off) < 0.01 * single_off   # the same up to the march's noise
    assert np.all(np.isfinite(on["Combined"]))
