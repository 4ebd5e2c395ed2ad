"""Light paths through several media at once (paths.PathInputs.others, csrc/paths.c): the
twins agree; a medium cut into two overlapping halves of its density, on grids of different
size and offset, deposits what the whole does on each half's lattice; light from one medium
is shadowed by the other; bad other media raise."""
import dataclasses

import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.paths import PathInputs, PathMedium, from_power, trace_paths_media_np
from mpp_render.precompute.lattice import lattice_shape

needs_c = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")

CAMERA = np.array([0.0, -7.5, 0.8])


def grid(n, vox, lo):
    """(w2i (3,4), i2w (3,3), lattice shape, lattice points (LX,LY,LZ,3) m) of an n^3 grid of
    voxel side ``vox`` whose first voxel centre is at ``lo`` (m), lattice stride 2."""
    ls = lattice_shape((n, n, n), 2)
    w2i = np.concatenate([np.eye(3) / vox, (-np.asarray(lo, float) / vox)[:, None]], axis=1)
    idx = np.stack(np.meshgrid(*[np.arange(s) * 2 for s in ls], indexing="ij"), -1)
    pts = idx * vox + np.asarray(lo, float)
    return w2i, np.eye(3) * vox, ls, pts


def towards(pts):
    v = CAMERA - pts
    return np.ascontiguousarray(v / np.linalg.norm(v, axis=-1, keepdims=True))


def whole_and_halves(n_paths=40000, sigma_t=2.0, albedo=0.9, g=0.3):
    """(the whole medium's PathInputs, the same paths in one half with the other half as an
    other medium, the other half's PathMedium): a homogeneous 2.4 m cube, its first
    scatterings at one point, and its density cut in two halves of 0.5 each, one on the
    whole's grid, the other on a grid of other voxels (0.06 m against 0.05 m), shifted and
    reaching beyond it."""
    n, vox = 48, 0.05
    lo = np.full(3, -0.5 * (n - 1) * vox)
    w2i, i2w, ls, pts = grid(n, vox, lo)
    w, cdf = from_power(np.ones((1, 3)))
    whole = PathInputs(np.ones((n, n, n), np.float32), w2i, i2w, np.full(3, albedo * sigma_t),
                       np.full(3, sigma_t), g, 2, towards(pts), np.array([[0.1, -0.2, 0.05]]),
                       w, np.array([[0.0, 0.0, 1.0]]), cdf, max(sigma_t, 10.0), n_paths, 3)
    # the other half: 0.06 m voxels over [-1.33, 1.37] m, but with density only over the
    # whole's cube (so the media are the same), 0.5 each
    n2, vox2 = 46, 0.06
    lo2 = np.full(3, -1.3)
    w2i2, _, ls2, pts2 = grid(n2, vox2, lo2)
    c2 = lo2[0] + vox2 * np.arange(n2)
    edge = 0.5 * n * vox
    inside = (np.abs(c2) < edge)
    dens2 = (inside[:, None, None] & inside[None, :, None]
             & inside[None, None, :]).astype(np.float32)
    # the whole's cube is [-1.2, 1.2]; the second grid's voxels straddle its faces, so the
    # second half is on the voxels whose centres lie within it (what a voxeliser would keep)
    other = PathMedium(0.5 * dens2, w2i2, np.full(3, albedo * sigma_t), np.full(3, sigma_t), g, 2,
                       towards(pts2), max(sigma_t * 0.5, 1.0 / (2 * vox2)))
    half = dataclasses.replace(whole, density=0.5 * whole.density, others=(other,),
                               rate=max(sigma_t * 0.5, 10.0))
    return whole, half, other


def test_twins_agree_with_another_medium():
    rng = np.random.default_rng(2)
    n, vox = 16, 0.1
    w2i, i2w, ls, pts = grid(n, vox, np.zeros(3))
    w2i2, _, ls2, pts2 = grid(12, 0.13, np.full(3, 0.4))
    starts = rng.random((5, 3)) * 1.4
    d = rng.normal(size=(5, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    w, cdf = from_power(rng.random((5, 3)) + 0.1)
    other = PathMedium(rng.random((12, 12, 12)).astype(np.float32), w2i2, np.array([0.5, 0.9, 1.2]),
                       np.array([1.0, 1.3, 1.6]), -0.4, 2, towards(pts2), 4.0)
    inp = PathInputs(rng.random((n, n, n)).astype(np.float32), w2i, i2w, np.array([1.0, 1.5, 2.0]),
                     np.array([2.0, 2.0, 2.5]), 0.6, 2, towards(pts), starts, w, d, cdf, 5.0, 3000,
                     5, others=(other,), moments=True)
    a = trace_paths_media_np(inp)
    b = kernels.trace_paths_media(inp, threads=2)
    assert len(a) == len(b) == 2
    for x, y in zip(a, b):
        assert x[..., :3].sum() > 0.0 and x.shape == y.shape
        assert np.abs(x - y).max() <= 1e-9 * np.abs(x).max()
    # the same bits for any thread count
    c = kernels.trace_paths_media(inp, threads=1)
    assert all(np.array_equal(x, y) for x, y in zip(b, c))


def test_two_halves_deposit_what_the_whole_does():
    """Each half's M (deposits over its own tent mass, half the whole's) equals the whole's:
    the paths scatter in either half as in the whole and deposit on both lattices."""
    whole, half, other = whole_and_halves()
    ref = kernels.trace_paths(whole, threads=2)[..., :3]
    own, cross = kernels.trace_paths_media(half, threads=2)
    # the whole's M over 0.5 m of its centre (the lattice's sum there; the tent mass of a
    # half is half the whole's, so each half's deposits are half the whole's)
    np.testing.assert_allclose(2.0 * own.sum(), ref.sum(), rtol=0.02)
    # the other half's deposits: half the light's track length weighted by the density, as
    # the first half's (its lattice's points see the camera from other places: the phase
    # function, read at each, differs a little)
    np.testing.assert_allclose(2.0 * cross.sum(), ref.sum(), rtol=0.03)


def test_an_other_medium_shadows_and_scatters():
    """A dense absorbing slab (the other medium) between the light's first scatterings and
    half the grid takes light from that half; with albedo 1 it sends it on instead, so that
    more reaches the far side than with albedo 0."""
    whole, half, other = whole_and_halves(n_paths=20000)
    base = kernels.trace_paths(dataclasses.replace(whole, others=()), threads=2)[..., 0]
    n2 = other.density.shape[0]
    slab = np.zeros_like(other.density)
    slab[:, :, n2 // 2 + 2:n2 // 2 + 6] = 1.0      # 0.24 m of density 1 above the start
    ratios = {}
    for albedo in (0.0, 1.0):
        blocker = dataclasses.replace(other, density=slab, sigma_t=np.full(3, 20.0),
                                      sigma_s=np.full(3, 20.0 * albedo), rate=20.0)
        got = kernels.trace_paths_media(dataclasses.replace(whole, others=(blocker,)),
                                        threads=2)[0][..., 0]
        top = base.shape[2] // 2 + 6
        ratios[albedo] = got[:, :, top:].sum() / base[:, :, top:].sum()
    print(ratios)
    assert ratios[0.0] < 3.0 * np.exp(-20.0 * 0.24)     # the slab's optical depth 4.8
    assert 5.0 * ratios[0.0] < ratios[1.0] < 1.0


@needs_c
def test_bad_other_media_raise():
    whole, half, other = whole_and_halves(n_paths=10)
    for change in (dict(rate=0.0), dict(rate=np.nan), dict(stride=0), dict(g=np.nan),
                   dict(rate=1e12), dict(towards=np.zeros((2, 2, 3))),
                   dict(sigma_t=np.zeros(3)), dict(density=np.ones((4, 4), np.float32)),
                   dict(w2i=np.eye(3))):
        with pytest.raises(ValueError):
            kernels.trace_paths_media(dataclasses.replace(half, others=(
                dataclasses.replace(other, **change),)))
    with pytest.raises(ValueError):
        kernels.trace_paths_media(dataclasses.replace(half, others=(other,) * 8))


@needs_c
def test_spoiled_other_media_finish():
    """NaN, inf, negative and huge densities and maps in an other medium end paths or give
    non-finite sums; they never hang or crash."""
    rng = np.random.default_rng(6)
    whole, half, other = whole_and_halves(n_paths=40)
    for _ in range(20):
        dens = other.density.copy()
        dens.reshape(-1)[rng.integers(0, dens.size, 50)] = rng.choice(
            [np.nan, np.inf, -1.0, 1e30], 50)
        w2i = other.w2i.copy()
        if rng.random() < 0.3:
            w2i[rng.integers(3), rng.integers(4)] = rng.choice([np.nan, np.inf, 1e300])
        spoiled = dataclasses.replace(other, density=dens, w2i=w2i)
        try:
            kernels.trace_paths_media(dataclasses.replace(half, seed=int(rng.integers(1 << 30)),
                                                          others=(spoiled,)))
        except ValueError:       # a map the span check refuses
            pass


def test_media_on_the_same_box_leave_it_together():
    """Two halves on the very same grid (boxes whose faces coincide): a path leaves both at
    once (a path left inside one of them by rounding had flown on outside, colliding with its
    edge voxels, and deposited there far too much); each half holds half the whole's."""
    whole, half, _ = whole_and_halves(n_paths=20000)
    same = PathMedium(half.density, half.w2i, half.sigma_s, half.sigma_t, half.g, half.stride,
                      half.towards, half.rate)
    ref = kernels.trace_paths(whole, threads=2)[..., :3].sum()
    own, other = kernels.trace_paths_media(dataclasses.replace(half, others=(same,)), threads=2)
    np.testing.assert_allclose(2.0 * own[..., :3].sum(), ref, rtol=0.02)
    np.testing.assert_allclose(2.0 * other[..., :3].sum(), ref, rtol=0.02)
    a = trace_paths_media_np(dataclasses.replace(half, others=(same,), n_paths=300))
    b = kernels.trace_paths_media(dataclasses.replace(half, others=(same,), n_paths=300))
    for x, y in zip(a, b):
        assert np.abs(x - y).max() <= 1e-9 * np.abs(x).max()
