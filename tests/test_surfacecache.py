"""The surfaces' gathered light on a grid over the image (mpp_render/surfacecache.py): the
grid, its bilinear reading, what it refuses to read across, its filter, and a frame that
reads it against one that gathers per sample."""
import math

import numpy as np
import pytest

from mpp_render.render import render
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, Surface, World
from mpp_render.surfacecache import COS_NORMAL, Grid, SurfaceCache


def plane_cache(grid, incident_of_x, z=0.0, surface=0):
    """A cache whose grid points lie on the plane z (x, y their pixel coordinates / 10 m),
    facing +z, with incident light incident_of_x(x, y) (RGB the same)."""
    px, py = grid.pixels()
    c = SurfaceCache.empty(grid)
    pts = np.stack([px / 10.0, py / 10.0, np.full(len(px), z)], axis=1)
    val = incident_of_x(pts[:, 0], pts[:, 1])
    c.fill(np.arange(len(px)), pts, np.tile([0.0, 0.0, 1.0], (len(px), 1)),
           np.full(len(px), surface), np.repeat(val[:, None], 3, axis=1))
    return c


def test_the_grid_spans_the_image():
    g = Grid.over(1920, 1080, 241)
    assert g.spacing == pytest.approx(8.0) and g.nx == 241 and g.ny == 136
    px, py = g.pixels()
    assert px[0] == 0 and py[0] == 0 and px[g.nx - 1] == pytest.approx(1920.0)
    assert py.max() >= 1080.0
    assert Grid.over(10, 10, 1).nx == 2   # at least the two corners


def test_bilinear_reading_is_exact_on_a_linear_light():
    """Weights sum to 1 and reproduce a light linear over the plane wherever a sample falls,
    the image's edges included."""
    g = Grid.over(64, 48, 9)
    c = plane_cache(g, lambda x, y: 1.0 + 0.3 * x - 0.2 * y)
    rng = np.random.default_rng(1)
    px, py = rng.uniform(0, 64, 500), rng.uniform(0, 48, 500)
    _, w = g.corners(px, py)
    assert np.allclose(w.sum(axis=1), 1.0) and np.all(w >= 0)
    pts = np.stack([px / 10, py / 10, np.zeros(500)], axis=1)
    inc, ok = c.lookup(px, py, pts, np.tile([0.0, 0.0, 1.0], (500, 1)), np.zeros(500, int))
    assert ok.all()
    assert np.allclose(inc[:, 1], 1.0 + 0.3 * pts[:, 0] - 0.2 * pts[:, 1], rtol=1e-12)


def test_the_cache_is_not_read_across_surfaces_normals_or_steps():
    """A sample on another surface, with a normal turned beyond COS_NORMAL, or on a parallel
    plane 0.5 m off the grid's (a step) is refused (ok False, nothing read), so it gathers
    itself; one on the grid's own plane is read."""
    g = Grid.over(32, 32, 5)
    c = plane_cache(g, lambda x, y: np.ones_like(x))
    px, py = np.array([10.0, 10.0, 10.0, 10.0]), np.array([12.0, 12.0, 12.0, 12.0])
    on = np.array([1.0, 1.2, 0.0])
    tilt = math.acos(COS_NORMAL) * 1.2
    normals = np.array([[0, 0, 1.0], [0, 0, 1.0], [math.sin(tilt), 0, math.cos(tilt)],
                        [0, 0, 1.0]])
    points = np.stack([on, on, on, on + [0, 0, 0.5]])
    inc, ok = c.lookup(px, py, points, normals, np.array([0, 1, 0, 0]))
    assert ok.tolist() == [True, False, False, False]
    assert np.allclose(inc[0], 1.0) and np.all(inc[1:] == 0.0)
    # a grid point whose ray met nothing (surface -1) is refused too
    c.surface[c.grid.corners(px[:1], py[:1])[0][0, 0]] = -1
    assert not c.lookup(px[:1], py[:1], points[:1], normals[:1], np.array([0]))[1][0]


def test_the_filter_keeps_constants_and_edges_and_cuts_the_noise():
    g = Grid.over(200, 200, 101)
    # two surfaces, left and right of x = 5 m, each of its own constant light
    c = plane_cache(g, lambda x, y: np.where(x < 5.0, 1.0, 3.0))
    left = c.point[:, 0] < 5.0
    c.surface[~left] = 1
    c.smooth(2)
    assert np.allclose(c.incident[left], 1.0) and np.allclose(c.incident[~left], 3.0)
    # independent noise of one grid point: the binomial 3 x 3's 0.375 of its deviation
    rng = np.random.default_rng(4)
    noisy = plane_cache(g, lambda x, y: 1.0 + rng.normal(0.0, 0.1, len(x)))
    noisy.smooth(1)
    inner = noisy.incident.reshape(g.ny, g.nx, 3)[1:-1, 1:-1, 0]
    assert inner.std() / 0.1 == pytest.approx(0.375, abs=0.03)
    assert inner.mean() == pytest.approx(1.0, abs=0.003)


def test_a_frame_reading_the_cache_matches_one_gathering_per_sample():
    """A ground under a glowing, scattering layer lit by a sun, seen in perspective with a
    post standing on it (an edge the cache must not read across): the frame that reads the
    cache and the one that gathers per sample agree within their noise, pixel blocks of
    4 x 4, and the cache's gathers are fewer."""
    n = (16, 16, 4)
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([4.0 / n[0], 4.0 / n[1], 0.6 / n[2]])
    i2w[:3, 3] = [-2.0 + 2.0 / n[0], -2.0 + 2.0 / n[1], 0.4 + 0.3 / n[2]]
    layer = Medium("layer", np.ones(n, np.float32), i2w, np.full(3, 1.5), np.full(3, 0.3), 0.3,
                   emission=np.full(3, 0.05), source="MESH")
    ground = Surface("ground", np.array([[-6, -6, 0], [6, -6, 0], [6, 6, 0], [-6, 6, 0.0]]),
                     np.array([[0, 1, 2], [0, 2, 3]]), np.full(3, 0.6))
    post = Surface("post", np.array([[0.3, -0.1, 0], [0.5, -0.1, 0], [0.5, -0.1, 1.2],
                                     [0.3, -0.1, 1.2]]),
                   np.array([[0, 1, 2], [0, 2, 3]]), np.full(3, 0.8))
    cam = Camera("PERSP", np.eye(4), 32, 24, (-0.6, 0.6, -0.45, 0.45))
    look = np.array([[1, 0, 0], [0, 0.8, 0.6], [0, -0.6, 0.8]], float).T   # 37 degrees down
    cam.cam_to_world[:3, :3] = look
    cam.cam_to_world[:3, 3] = [0.0, -5.0, 3.2]
    sun = Light("SUN", "sun", np.full(3, 2.0), direction=np.array([0.3, 0.2, -0.93]))

    def frame(cache, seed):
        st = Settings(samples=16, noise_threshold=0.0, multiple=False, seed=seed,
                      surface_cache=cache)
        return render(SceneDescription(cam, [sun], [layer], surfaces=[ground, post],
                                       world=World(np.full(3, 0.1)), settings=st))

    def blocks(o):
        img = o.passes["Combined"][..., :3]
        return img.reshape(6, 4, 8, 4, 3).mean(axis=(1, 3))

    ref = [blocks(frame(False, s)) for s in (1, 2)]
    got = blocks(frame(True, 3))
    noise = np.sqrt(np.mean((ref[0] - ref[1]) ** 2) / 2)
    err = np.sqrt(np.mean((got - 0.5 * (ref[0] + ref[1])) ** 2))
    scale = np.mean(ref)
    print("cache vs per-sample: rel rms %.4f, per-sample seeds' rel noise %.4f"
          % (err / scale, noise / scale))
    assert err <= 3.0 * noise + 0.01 * scale, (err / scale, noise / scale)
    assert abs(got.mean() / np.mean(ref) - 1.0) < 0.02
