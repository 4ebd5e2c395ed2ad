"""Rays against the surfaces' triangles: the compiled kernel (csrc/intersect.c) and its numpy
twin (kernels_np.intersect_triangles) agree, on random meshes and on the grounds and boxes
of the scenes; bad calls raise."""
import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.scene import Surface
from mpp_render.surfaces import intersect, prepare_surfaces

needs_c = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")


def scene_surfaces(rng, n_random=300):
    """A 20 m ground, a unit box on it and ``n_random`` small random triangles above it."""
    ground = Surface("ground", np.array([[-10, -10, 0], [10, -10, 0], [10, 10, 0],
                                         [-10, 10, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))
    c = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    box = Surface("box", c, faces)
    v = rng.uniform(-3, 3, (n_random, 3, 3)) * [1, 1, 0.3] + [0, 0, 2]
    v[:, 1:] = v[:, :1] + rng.normal(scale=0.4, size=(n_random, 2, 3))
    bits = Surface("bits", v.reshape(-1, 3), np.arange(3 * n_random).reshape(-1, 3))
    return prepare_surfaces([ground, box, bits])


def rays(rng, n):
    o = rng.uniform(-4, 4, (n, 3)) + [0, 0, 4]
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    tmax = np.where(rng.random(n) < 0.3, rng.uniform(0.5, 5, n), np.inf)
    return o, d, tmax


@needs_c
def test_kernel_and_numpy_twin_agree():
    rng = np.random.default_rng(3)
    ss = scene_surfaces(rng)
    o, d, tmax = rays(rng, 20000)
    t_c, k_c = intersect(ss, o, d, tmax)
    t_n, k_n = kernels.intersect(o, d, tmax, ss.triangles, backend="numpy")
    assert np.mean(k_c >= 0) > 0.3 and np.any(np.isfinite(tmax) & (k_c < 0))
    np.testing.assert_array_equal(k_c, k_n)
    np.testing.assert_allclose(t_c, t_n, rtol=1e-12, atol=0)
    assert np.all(t_c[k_c < 0] == tmax[k_c < 0])
    assert np.all(t_c[k_c >= 0] < tmax[k_c >= 0])


def test_ground_hits_are_exact():
    rng = np.random.default_rng(1)
    ss = scene_surfaces(rng, n_random=0)
    o = np.array([[2.5, 3.0, 5.0], [0.5, 0.5, 5.0], [0.5, 0.5, 0.5], [2.0, 2.0, 5.0]])
    d = np.array([[0, 0, -1.0], [0, 0, -1.0], [0, 0, 1.0], [0, 0, -1.0]])
    t, k = intersect(ss, o, d, np.array([np.inf, np.inf, np.inf, 4.0]))
    np.testing.assert_allclose(t[:3], [5.0, 4.0, 0.5])
    assert k[0] in (0, 1) and k[1] >= 2 and k[2] >= 2 and k[3] == -1 and t[3] == 4.0


@needs_c
def test_bad_calls_raise_and_odd_rays_miss():
    tri = scene_surfaces(np.random.default_rng(2), 10).triangles
    o = np.zeros((3, 3))
    d = np.array([[0, 0, -1.0], [np.nan, 0, 0], [0, 0, 0]])
    t, k = kernels.intersect(o + [0, 0, 1], d, np.full(3, np.inf), tri, backend="c")
    assert k[0] >= 0 and k[1] == -1 and k[2] == -1
    for bad in ((o, d, np.ones(2), tri), (o, d[:, :2], np.ones(3), tri),
                (o, d, np.ones(3), tri[:, :8])):
        with pytest.raises(ValueError):
            kernels._c.intersect(*[np.ascontiguousarray(x, np.float64) for x in bad])
    empty = kernels.intersect(o, d, np.ones(3), np.zeros((0, 9)), backend="c")
    assert np.all(empty[1] == -1) and np.all(empty[0] == 1.0)
