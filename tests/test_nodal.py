"""The traced paths' lattice values at the lattice points (precompute/nodal.py): the tent
centroids' moment weights, the centroids of a medium that ends under the tents, and the
values moved from each centroid to its point, exact for a light that changes linearly and
nothing moved where the density is even."""
import numpy as np
import pytest

from mpp_render.precompute.nodal import (box_tent_moment_weights, centroid_offsets,
                                         nodal_values)
from mpp_render.precompute.source import box_tent_weights, tent_restrict


def restrict3(a, stride, shape):
    for axis in range(3):
        a = tent_restrict(a, axis, stride, shape[axis], boxed=True)
    return a


@pytest.mark.parametrize("stride", [1, 2, 3, 4])
def test_moment_weights_integrate_the_tent_times_its_offset_over_each_voxel(stride):
    """Each weight is ∫ T(u) u / stride over its voxel (a fine midpoint sum); odd in t; the
    weights of box_tent_weights integrate T itself over the same voxels."""
    got = dict(box_tent_moment_weights(stride))
    mass = box_tent_weights(stride)
    assert sorted(got) == sorted(mass) == list(range(-stride, stride + 1))
    s = float(stride)
    for t in got:
        u = np.linspace(t - 0.5, t + 0.5, 200001)
        u = 0.5 * (u[1:] + u[:-1])
        tent = np.maximum(s - np.abs(u), 0.0) / (s * s)
        assert got[t] == pytest.approx(np.mean(tent * u / s), abs=1e-9)
        assert mass[t] == pytest.approx(np.mean(tent), abs=1e-9)
        assert got[t] == pytest.approx(-got[-t], abs=1e-15)


def half_space(n=24, normal=(1.0, 0.4, 0.2), offset=11.3):
    """Density 1 on the voxels x . normal >= offset (voxel index units), else 0."""
    idx = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).astype(float)
    nrm = np.asarray(normal) / np.linalg.norm(normal)
    return (idx @ nrm >= offset).astype(np.float64)


def test_centroids_of_an_even_density_are_the_points_and_of_a_face_lie_inside_it():
    """Inside an even density every tent's centroid is its point; a tent the medium's face
    cuts has its centroid on the medium's side, as a direct sum over its voxels puts it."""
    stride, n = 2, 24
    shape = tuple((n - 1 + stride - 1) // stride + 1 for _ in range(3))
    even = np.ones((n, n, n))
    d = centroid_offsets(even, stride, shape, restrict3(even, stride, shape))
    inner = (slice(1, -2),) * 3   # tents the grid's ends do not cut (13 points on 24 voxels)
    assert np.abs(d[inner]).max() < 1e-12
    rho = half_space(n)
    mass = restrict3(rho, stride, shape)
    d = centroid_offsets(rho, stride, shape, mass)
    nrm = np.array([1.0, 0.4, 0.2]) / np.linalg.norm([1.0, 0.4, 0.2])
    # a direct sum: the voxels' tent weights (separable box tents) times their offsets
    w1 = box_tent_weights(stride)
    m1 = dict(box_tent_moment_weights(stride))
    checked = 0
    full = mass[inner].max()
    cut = np.argwhere((mass > 0.02 * full) & (mass < 0.98 * full))
    cut = cut[np.all((cut >= 1) & (cut < np.array(shape) - 2), axis=1)]
    assert len(cut) > 20
    for y in map(tuple, cut[::max(1, len(cut) // 12)]):
        c = np.array(y) * stride
        num, den = np.zeros(3), 0.0
        for dx in range(-stride, stride + 1):
            for dy in range(-stride, stride + 1):
                for dz in range(-stride, stride + 1):
                    v = c + (dx, dy, dz)
                    if np.any(v < 0) or np.any(v >= n) or rho[tuple(v)] == 0.0:
                        continue
                    w = (w1[dx], w1[dy], w1[dz])
                    m = (m1[dx], m1[dy], m1[dz])
                    den += w[0] * w[1] * w[2]
                    num += [m[0] * w[1] * w[2], w[0] * m[1] * w[2], w[0] * w[1] * m[2]]
        np.testing.assert_allclose(den, mass[y], rtol=1e-12)
        np.testing.assert_allclose(d[y], num / den, atol=1e-12)
        assert d[y] @ nrm > 0.0   # towards the medium
        checked += 1
    assert checked >= 10


def exact_means(rho, stride, shape, value, grad):
    """The tent means of the light S(x) = value + grad . x (x in lattice steps), as the paths'
    deposits estimate them: ∫ ρ t_y S / ∫ ρ t_y = S at the tent's centroid."""
    mass = restrict3(rho, stride, shape)
    d = centroid_offsets(rho, stride, shape, mass)
    y = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), -1).astype(float)
    return mass, d, value + (y + d) @ grad, value + y @ grad


def test_a_linear_light_comes_back_at_the_points_where_the_tent_means_miss_it():
    """A light changing linearly across a tilted face: the tent means hold it at their
    centroids (off by more than the light's change over a step at the face's slivers), the
    nodal values at the points, within 2 % of that change (the least squares' ridge, where
    few neighbours hold medium)."""
    stride, n = 2, 24
    shape = tuple((n - 1 + stride - 1) // stride + 1 for _ in range(3))
    rho = half_space(n)
    grad = np.array([0.8, 0.3, -0.2])   # per lattice step
    mass, d, mean, truth = exact_means(rho, stride, shape, 10.0, grad)
    has = mass > 0.0
    step = np.linalg.norm(grad)
    before = np.abs(mean - truth)[has].max() / step
    got = nodal_values(mean[..., None], d, mass)[..., 0]
    after = np.abs(got - truth)[has].max() / step
    assert before > 0.5
    assert after < 0.02
    # nowhere without mass does anything change
    assert np.all(got[~has] == mean[~has].astype(np.float32))


def test_an_even_density_keeps_its_means_and_channels_are_independent():
    """Where no tent is cut (offsets 0) the values are the means, bit for bit; the channels
    of a light of 3 colours and 12 moments are moved each by its own gradient, the last 9
    (signed) allowed below 0, the first 6 not."""
    rng = np.random.default_rng(3)
    shape = (6, 7, 8)
    mean = rng.uniform(0.5, 2.0, shape + (15,)).astype(np.float32)
    got = nodal_values(mean, np.zeros(shape + (3,)), np.ones(shape), signed=9)
    assert np.array_equal(got, mean)
    stride, n = 2, 24
    shape = tuple((n - 1 + stride - 1) // stride + 1 for _ in range(3))
    rho = half_space(n)
    chans = []
    for k in range(15):
        g = np.array([0.5, -0.2, 0.1]) * (k - 7)   # the signed ones fall steeply
        mass, d, mean_k, truth_k = exact_means(rho, stride, shape, 100.0 if k < 6 else 1.0, g)
        chans.append((mean_k, truth_k))
    mean = np.stack([m for m, _ in chans], -1)
    truth = np.stack([t for _, t in chans], -1)
    got = nodal_values(mean, d, mass, signed=9)
    has = mass > 0.0
    assert np.all(got[has][:, :6] >= 0.0)
    assert np.any(got[has][:, 6:] < 0.0)
    step = np.linalg.norm([0.5, -0.2, 0.1]) * np.abs(np.arange(15) - 7)
    assert np.all(np.abs(got - truth)[has] < 0.02 * step + 1e-4)   # float32 of ~100
    # a light pushed below 0 at the points stops there (a steep fall out of a face)
    steep = np.stack([m for m, _ in chans[:1]] * 3, -1) - 105.0
    low = nodal_values(steep, d, mass)
    moved = has & (np.abs(d).max(axis=-1) > 1e-6)
    assert np.all(low[moved] >= 0.0) and np.any(low[moved] == 0.0)


def test_the_path_lattice_moves_its_means_only_when_asked():
    """PathLattice.of keeps the centroids with ``nodal`` (the default, Tuning.path_nodal) and
    ``mean`` moves the values; without, ``mean`` is the deposits over the tent mass."""
    from test_enclosed import medium
    from mpp_render.precompute.lightpaths import PathLattice
    from mpp_render.scene import Camera, Tuning
    assert Tuning().path_nodal is True
    pm = medium(n=(16, 16, 16))
    cam = Camera("PERSP", np.eye(4), 8, 8, (-0.5, 0.5, -0.5, 0.5))
    cam.cam_to_world[:3, 3] = [0.0, 0.0, 5.0]
    on, off = PathLattice.of(pm, cam, 8), PathLattice.of(pm, cam, 8, nodal=False)
    assert off.offsets is None and on.offsets is not None
    np.testing.assert_array_equal(on.tent_mass, off.tent_mass)
    rng = np.random.default_rng(0)
    acc = rng.uniform(0.0, 1.0, on.tent_mass.shape[:3] + (3,)) * on.tent_mass
    plain = off.mean(acc)
    np.testing.assert_allclose(plain, np.divide(acc, off.tent_mass, out=np.zeros_like(acc),
                                                where=off.tent_mass > 0), rtol=1e-6)
    moved = on.mean(acc)
    cut = np.abs(on.offsets).max(-1) > 1e-6
    assert cut.any()
    np.testing.assert_array_equal(moved[~cut], plain[~cut])
    assert not np.allclose(moved[cut], plain[cut])


def test_the_fit_a_chunk_of_points_at_a_time_is_the_fit_of_all(monkeypatch):
    """The numpy twin (kernels_np.nodal_fit) fits NODAL_CHUNK points at a time (memory): 7 at
    a time gives what all at once do, to float32's rounding."""
    from mpp_render import kernels_np
    stride, n = 2, 24
    shape = tuple((n - 1 + stride - 1) // stride + 1 for _ in range(3))
    rho = half_space(n)
    mass, d, mean, _ = exact_means(rho, stride, shape, 10.0, np.array([0.8, 0.3, -0.2]))
    rng = np.random.default_rng(5)
    noisy = mean[..., None] * rng.uniform(0.9, 1.1, mean.shape + (15,))
    whole = kernels_np.nodal_fit(noisy, d, mass, 9, 0.01)
    monkeypatch.setattr(kernels_np, "NODAL_CHUNK", 7)
    np.testing.assert_allclose(kernels_np.nodal_fit(noisy, d, mass, 9, 0.01), whole,
                               rtol=1e-6, atol=1e-6)


@pytest.mark.skipif(not __import__("mpp_render.kernels", fromlist=["_c"])._c,
                    reason="the compiled kernels are not built")
def test_the_compiled_fit_is_its_numpy_twins():
    """kernels.nodal_fit compiled and in numpy: the same values to float32's rounding on a
    half-space's tents with noisy light and signed channels (some below 0), the light stopped
    at 0, points without mass or offset as they came; bad shapes are refused."""
    from mpp_render import kernels
    stride, n = 2, 24
    shape = tuple((n - 1 + stride - 1) // stride + 1 for _ in range(3))
    mass, d, mean, _ = exact_means(half_space(n), stride, shape, 10.0, np.array([0.8, 0.3, -0.2]))
    rng = np.random.default_rng(9)
    noisy = (mean[..., None] * rng.uniform(0.5, 1.5, mean.shape + (15,))).astype(np.float32)
    noisy[..., 6:] -= 4.0                                 # the signed channels reach below 0
    for signed in (0, 9, 15):
        a = kernels.nodal_fit(noisy, d, mass, signed, 0.01, backend="numpy")
        b = kernels.nodal_fit(noisy, d, mass, signed, 0.01, backend="c")
        assert b.dtype == np.float32 and b.shape == noisy.shape
        np.testing.assert_allclose(b, a, rtol=2e-6, atol=2e-6 * float(np.abs(a).max()))
        assert np.all(b[..., :15 - signed] >= 0.0)
        if signed:
            assert b[..., 15 - signed:].min() < 0.0
    moved = (np.abs(d).max(axis=-1) > 1e-6) & (mass > 0.0)
    assert moved.any() and not moved.all()
    b = kernels.nodal_fit(noisy, d, mass, 9, 0.01, backend="c")
    np.testing.assert_array_equal(b[~moved], noisy[~moved])
    assert np.abs(b[moved] - noisy[moved]).max() > 1e-3
    with pytest.raises(ValueError):
        kernels.nodal_fit(noisy, d[:-1], mass, 0, 0.01, backend="c")
    with pytest.raises(ValueError):
        kernels.nodal_fit(noisy, d, mass, 16, 0.01, backend="c")
    with pytest.raises(ValueError):
        kernels.nodal_fit(noisy, d, mass, 0, 0.0, backend="c")
