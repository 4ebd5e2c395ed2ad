"""Opaque surfaces: intersection, diffuse shading, shadows on surfaces and in media."""
import math

import numpy as np

from mpp_render.render import render
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, Surface, World
from mpp_render.surfaces import intersect, prepare_surfaces


def quad(z, half, albedo=0.5, name="plane", centre=(0.0, 0.0)):
    cx, cy = centre
    v = np.array([[cx - half, cy - half, z], [cx + half, cy - half, z],
                  [cx + half, cy + half, z], [cx - half, cy + half, z]], float)
    return Surface(name, v, np.array([[0, 1, 2], [0, 2, 3]]), np.full(3, albedo))


def test_intersect_closest_hit():
    ss = prepare_surfaces([quad(0.0, 1.0), quad(1.0, 0.5, name="upper")])
    o = np.array([[0.0, 0.0, 5.0], [0.9, 0.0, 5.0], [3.0, 0.0, 5.0], [0.0, 0.0, -1.0]])
    d = np.tile([0.0, 0.0, -1.0], (4, 1))
    t, tri = intersect(ss, o, d, np.full(4, 100.0))
    assert np.allclose(t[:2], [4.0, 5.0]) and tri[2] == -1 and tri[3] == -1
    assert tri[0] >= 2 and tri[1] < 2   # the upper quad's triangles come second


def top_down_scene(surfaces, media=(), sun_dir=(0.0, 0.0, -1.0)):
    cam = Camera("ORTHO", np.eye(4), 20, 20, (-2.0, 2.0, -2.0, 2.0))
    cam.cam_to_world[:3, 3] = [0, 0, 10]
    sun = Light("SUN", "sun", np.full(3, 3.0), direction=np.asarray(sun_dir, float))
    return SceneDescription(cam, [sun], list(media), surfaces=list(surfaces),
                            world=World(np.zeros(3)), settings=Settings(samples=4))


def test_lambertian_plane_under_sun_and_its_shadow():
    blocker = quad(1.0, 0.5, albedo=0.0, name="blocker")
    out = render(top_down_scene([quad(0.0, 3.0), blocker],
                                sun_dir=(math.sin(0.3), 0.0, -math.cos(0.3))))
    img = out.passes["Combined"][..., :3]
    # unshadowed ground: albedo / pi * E * cos
    want = 0.5 / math.pi * 3.0 * math.cos(0.3)
    assert np.allclose(img[1, 1], want, rtol=1e-6)
    # the blocker (|x| < 0.5, 1 m up, albedo 0) is black; the sun propagates towards +x, so
    # its shadow on the ground covers x in [-0.19, 0.81]; pixel column 13 sees x in [0.6, 0.8]
    assert np.all(img[10, 10] == 0.0)
    assert np.allclose(img[10, 3], want, rtol=1e-6)
    assert np.all(img[10, 13] == 0.0)
    assert np.all(out.passes["Depth"][1, 1] == 10.0)


def test_surface_casts_volumetric_shadow():
    n = 10
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.4
    i2w[:3, 3] = [-1.8, -1.8, 0.2]
    med = Medium("fog", np.ones((n, n, 3), np.float32), i2w, np.full(3, 0.2), np.zeros(3), 0.0)
    lit = render(top_down_scene([], [med]))
    shaded = render(top_down_scene([quad(2.0, 1.0, albedo=0.0, name="roof")], [med]))
    a = lit.passes["Volume Single"]
    b = shaded.passes["Volume Single"]
    assert a[10, 10].min() > 0
    # under the roof (which also hides the fog from the camera) -> nothing; far from it, as
    # before up to the jitter (the surfaces draw their own random numbers)
    assert np.all(b[10, 10] == 0)
    assert np.allclose(b[1, 1], a[1, 1], rtol=0.03)
    # a tilted sun puts fog beside the roof into its shadow: darker than without the roof
    tilt = (np.sin(0.5), 0.0, -np.cos(0.5))
    a = render(top_down_scene([], [med], sun_dir=tilt)).passes["Volume Single"]
    b = render(top_down_scene([quad(2.0, 1.0, albedo=0.0, name="roof")], [med],
                              sun_dir=tilt)).passes["Volume Single"]
    assert np.all(b[10, 16] < 0.8 * a[10, 16])


def test_principled_coat_adds_gloss_towards_the_mirror_direction():
    tilt = (np.sin(0.3), 0.0, -np.cos(0.3))
    matte = render(top_down_scene([quad(0.0, 3.0)], sun_dir=tilt)).passes["Combined"]
    coated = quad(0.0, 3.0)
    coated.specular, coated.roughness = 0.04, 0.3
    glossy = render(top_down_scene([coated], sun_dir=tilt)).passes["Combined"]
    # half vector 0.15 rad from the normal: a clear highlight, and never darker than matte
    assert np.all(glossy[..., :3] >= matte[..., :3] - 1e-7)
    assert glossy[10, 10, 0] > 1.05 * matte[10, 10, 0]
