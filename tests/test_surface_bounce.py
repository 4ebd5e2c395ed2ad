"""Surface-to-surface light (surfaces.shade's ``bounces``): inside a closed box whose walls
emit radiance Le and reflect with diffuse albedo a, every gather direction hits a wall, so
with one bounce a wall point leaves exactly Le (1 + a), with none Le; and the bounce adds light
only where another surface is in view."""
import numpy as np

from mpp_render.scene import Surface
from mpp_render.surfaces import intersect, prepare_surfaces, shade


def box(albedo, emission, half=1.0):
    """A closed axis-aligned cube of side 2 half (12 triangles)."""
    v = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-half, half)], float)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = np.array([t for a, b, c, d in faces for t in ((a, b, c), (a, c, d))])
    return Surface("box", v, tris, np.full(3, albedo), emission=np.full(3, emission))


def no_media(p, d, t_max):
    return np.zeros((len(p), 3))


def shade_from_centre(ss, n, bounces, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    o = np.zeros((n, 3))
    t, tri = intersect(ss, o, d, np.full(n, np.inf))
    assert np.all(tri >= 0)
    return shade(ss, tri, o + d * t[:, None], d, [], np.zeros(3), no_media, rng, None, bounces)


def test_closed_emitting_box_one_bounce_exact():
    a, le = 0.6, 2.0
    ss = prepare_surfaces([box(a, le)])
    assert np.allclose(shade_from_centre(ss, 500, bounces=0), le)
    assert np.allclose(shade_from_centre(ss, 500, bounces=1), le * (1 + a), rtol=1e-6)
    assert np.allclose(shade_from_centre(ss, 200, bounces=2), le * (1 + a + a * a), rtol=1e-6)


def test_a_lone_plane_gets_no_bounce():
    v = np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], float)
    plane = Surface("ground", v, np.array([[0, 1, 2], [0, 2, 3]]), np.full(3, 0.5), emission=np.full(3, 1.0))
    ss = prepare_surfaces([plane])
    n = 300
    p = np.column_stack([np.random.default_rng(1).uniform(-2, 2, (n, 2)), np.zeros(n)])
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    tri = np.zeros(n, np.int64)
    one = shade(ss, tri, p, d, [], np.zeros(3), no_media, np.random.default_rng(2), None, 1)
    assert np.allclose(one, 1.0)   # its emission; it cannot see itself


def test_a_render_follows_tuning_surface_bounces():
    """A frame taken from inside the closed emitting box, through the renderer (the surface
    cache's gathers and each sample's own): every pixel is Le (1 + a + ... + a^n) for
    ``Tuning.surface_bounces`` = n, whichever gathers it."""
    import dataclasses

    from mpp_render.render import render
    from mpp_render.scene import Camera, SceneDescription, Settings, Tuning, World

    a, le = 0.6, 2.0
    cam = Camera("PERSP", np.eye(4), 16, 12, (-0.6, 0.6, -0.45, 0.45))
    for cache in (True, False):
        for n in (1, 2):
            st = Settings(samples=2, noise_threshold=0.0, multiple=False, surface_cache=cache,
                          tuning=dataclasses.replace(Tuning(), surface_bounces=n))
            out = render(SceneDescription(cam, [], [], surfaces=[box(a, le)],
                                          world=World(np.zeros(3)), settings=st))
            img = out.passes["Combined"][..., :3]
            want = le * sum(a ** k for k in range(n + 1))
            assert np.allclose(img, want, rtol=1e-5), (cache, n, img.min(), img.max(), want)


def test_a_bounce_reads_the_volumes_light_at_its_surface_too():
    """Inside the closed box with dark walls of albedo a, the volumes' light R reaching every
    point from every direction (``media_radiance``, transmittance 1): a wall leaves a R, and
    each bounce reflects what the wall it meets gathers, its own R included:
    a R (1 + a + ... + a^n) for n bounces."""
    a, r = 0.6, 1.5
    ss = prepare_surfaces([box(a, 0.0)])

    def media(p, d, t_max):
        return np.full((len(p), 3), r), np.ones((len(p), 3))

    rng = np.random.default_rng(3)
    n = 300
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    t, tri = intersect(ss, np.zeros((n, 3)), d, np.full(n, np.inf))
    for bounces in (0, 1, 2):
        got = shade(ss, tri, d * t[:, None], d, [], np.zeros(3), no_media, rng, media, bounces)
        assert np.allclose(got, a * r * sum(a ** k for k in range(bounces + 1)), rtol=1e-6)
