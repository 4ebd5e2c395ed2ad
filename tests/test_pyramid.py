"""The light pyramid blurs with Gaussians of doubling width and looks up any width."""
import numpy as np

from mpp_render import pyramid


def test_levels_blur_a_point_with_doubling_widths():
    n = 65
    base = np.zeros((n, n, n, 1), np.float32)
    base[32, 32, 32] = 1.0
    levels = pyramid.build(base, max_levels=4)
    assert [lv.shape[0] for lv in levels] == [65, 33, 17, 9]
    for k in (1, 2, 3):
        lv = levels[k][..., 0].astype(np.float64)
        c = 32 // 2 ** k
        # along one axis the blurred point is a Gaussian of sd 2^k base spacings
        x = (np.arange(lv.shape[0]) - c) * 2.0 ** k
        prof = lv[:, c, c]
        var = np.sum(prof * x ** 2) / np.sum(prof)
        assert abs(np.sqrt(var) - 2.0 ** k) < 0.08 * 2.0 ** k, (k, np.sqrt(var))
        # the blur keeps the integral (sum times cell volume)
        assert abs(lv.sum() * 8.0 ** k - 1.0) < 0.02


def test_lookup_interpolates_between_levels_and_keeps_constants():
    rng = np.random.default_rng(0)
    base = np.full((33, 33, 33, 3), 2.0, np.float32)
    levels = pyramid.build(base, max_levels=5)
    idx = rng.uniform(12, 20, (50, 3))
    for w in (0.5, 1.0, 3.0, 7.0, 100.0):
        v = pyramid.lookup(levels, idx, np.full(50, w), 1.0)
        # interior points of a constant field stay constant at every width up to the edge
        # losses of the coarsest levels
        if w <= 3.0:
            assert np.allclose(v, 2.0, rtol=5e-3)
        assert np.all(np.isfinite(v)) and np.all(v <= 2.0 + 1e-5)
    # widths below the spacing read the base exactly
    base = rng.random((9, 9, 9, 1)).astype(np.float32)
    levels = pyramid.build(base)
    v = pyramid.lookup(levels, np.array([[4.0, 4.0, 4.0]]), np.array([0.1]), 1.0)
    assert np.isclose(v[0, 0], base[4, 4, 4, 0])


def test_upsample_matches_trilinear():
    from mpp_render.media import trilinear
    from mpp_render.kernels_np import upsample
    rng = np.random.default_rng(2)
    lat = rng.random((5, 6, 4, 3)).astype(np.float32)
    for stride in (1, 2, 3):
        shape = ((5 - 1) * stride + 1, (6 - 1) * stride + 1, (4 - 1) * stride + 1)
        up = upsample(lat, stride, shape)
        ijk = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), -1).reshape(-1, 3)
        want = trilinear(lat, ijk / float(stride))
        # the last lattice point along each axis: trilinear() is zero exactly on the far edge
        inner = np.all(ijk < np.array(shape) - 1, axis=1)
        assert np.allclose(up.reshape(-1, 3)[inner], want[inner], atol=1e-6)


def test_every_level_covers_the_whole_base_lattice():
    # an even count (50) used to drop the last point at each halving: the coarsest level
    # then ended short of the field and a seam appeared where its coverage stopped
    base = np.ones((50, 37, 64, 1), np.float32)
    levels = pyramid.build(base, max_levels=8)
    for k, lv in enumerate(levels):
        for ax in range(3):
            assert (lv.shape[ax] - 1) * 2 ** k >= base.shape[ax] - 1, (k, ax, lv.shape)


def test_upsample_into_twins_agree_and_write_only_the_given_voxels():
    import pytest
    from mpp_render import kernels, kernels_np
    if kernels._c is None:
        pytest.skip("compiled kernels not built")
    rng = np.random.default_rng(4)
    for shape, stride in (((17, 12, 9), 3), ((10, 10, 10), 1), ((9, 14, 5), 4)):
        cshape = tuple((s - 1 + stride - 1) // stride + 1 for s in shape)
        lat = rng.random(cshape + (3,)).astype(np.float32)
        flat = np.flatnonzero(rng.random(int(np.prod(shape))) < 0.6)
        a = np.full(shape + (7,), -1.0, np.float32)
        b = a.copy()
        kernels_np.upsample_into(a, 2, lat, stride, flat)
        kernels.upsample_into(b, 2, lat, stride, flat, backend="c")
        assert np.allclose(a, b, rtol=1e-5, atol=1e-6)
        untouched = np.ones(int(np.prod(shape)), bool)
        untouched[flat] = False
        assert np.all(b.reshape(-1, 7)[untouched] == -1.0) and np.all(b[..., [0, 1, 5, 6]] == -1.0)
    with pytest.raises(ValueError):
        kernels.upsample_into(b, 5, lat, stride, flat, backend="c")      # channels past the field
    with pytest.raises(ValueError):
        kernels.upsample_into(b, 0, lat, stride, np.array([10 ** 9]), backend="c")
    with pytest.raises(ValueError):
        kernels.upsample_into(b, 0, lat, 0, flat, backend="c")


def test_upsample_into_is_geometric_inside_the_medium_and_the_twins_agree():
    """With the lattice points inside the medium marked, a voxel whose points are all inside
    and lit takes the logarithm's interpolation: an exponential fall across the cells comes
    back exactly, where the linear chord reads it too bright; a cell with a point outside, or
    a channel with a dark point, stays linear.  Both twins the same."""
    import pytest
    from mpp_render import kernels, kernels_np
    shape, stride = (13, 9, 7), 4
    cshape = tuple((s - 1 + stride - 1) // stride + 1 for s in shape)
    xi = np.arange(cshape[0]) * stride
    lat = np.zeros(cshape + (3,), np.float32)
    lat[..., 0] = np.exp(-0.9 * xi)[:, None, None]       # falls by e^-3.6 a cell along x
    lat[..., 1] = np.exp(-0.9 * xi)[:, None, None]
    lat[0, ..., 1] = 0.0                                 # channel 1 dark at x = 0
    lat[..., 2] = 2.0
    inside = np.ones(cshape, np.uint8)
    inside[-1, 0, 0] = 0                                 # one point outside the medium
    backends = ["numpy"] + (["c"] if kernels._c is not None else [])
    got = {}
    for backend in backends:
        f = np.zeros(shape + (3,), np.float32)
        if backend == "c":
            kernels.upsample_into(f, 0, lat, stride, None, inside=inside, backend="c")
        else:
            kernels_np.upsample_into(f, 0, lat, stride, None, inside)
        got[backend] = f
    f = got["numpy"]
    x = np.arange(shape[0])
    exact = np.exp(-0.9 * x).astype(np.float32)
    # all inside: exact, and well below the linear chord between the points
    np.testing.assert_allclose(f[:8, 4, 3, 0], exact[:8], rtol=1e-5)
    linear = kernels_np.upsample(lat, stride, shape)
    assert np.all(linear[1:4, 4, 3, 0] > 1.5 * exact[1:4])
    # the cell with a point outside the medium, and the dark channel's first cell: linear
    np.testing.assert_allclose(f[9:12, 0, 0, 0], linear[9:12, 0, 0, 0], rtol=1e-6)
    np.testing.assert_allclose(f[1:4, 4, 3, 1], linear[1:4, 4, 3, 1], rtol=1e-6)
    np.testing.assert_allclose(f[..., 2], 2.0, rtol=1e-6)          # a constant stays so
    if "c" in got:
        np.testing.assert_allclose(got["c"], f, rtol=2e-6, atol=1e-30)
        with pytest.raises(ValueError):
            kernels.upsample_into(np.zeros(shape + (3,), np.float32), 0, lat, stride, None,
                                  inside=np.ones((2, 2, 2), np.uint8), backend="c")


def test_lattice_values_read_what_trilinear_reads():
    """precompute.lattice_values (the density at the pyramid's lattice points) equals
    media.trilinear at those whole-voxel points, zero on the last plane and beyond."""
    from mpp_render.media import trilinear
    from mpp_render.precompute.lattice import lattice_index, lattice_shape, lattice_values
    rng = np.random.default_rng(2)
    for shape, stride in (((20, 17, 9), 2), ((16, 16, 16), 3), ((5, 6, 7), 1)):
        f = rng.random(shape + (5,)).astype(np.float32) + 0.5
        idx = lattice_index(lattice_shape(shape, stride))
        got = lattice_values(f[..., 0], idx, stride)
        assert np.array_equal(got, trilinear(f, idx * float(stride))[:, 0])
        assert np.any(got == 0) and np.any(got > 0)
