"""Empty and constant space: the brick bounds (media.brick_bounds) bound every point's density,
and the kernels that walk them (optical depth, the march) give what they give without them."""
import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.media import BRICK, brick_bounds, density_from, prepare, trilinear
from mpp_render.scene import Medium

needs_c = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")


def blocky(shape, rng, sharp=False):
    """Empty space, constant blocks (aligned or not with the bricks) and noisy blobs."""
    d = np.zeros(shape, np.float32)
    value = 1.0 if sharp else rng.choice([0.7, 2.0])
    for _ in range(4):
        size = rng.integers(np.array(shape) // 4, np.array(shape) * 2 // 3)
        lo = rng.integers(0, np.array(shape) - size)
        sl = tuple(slice(a, a + b) for a, b in zip(lo, size))
        d[sl] = value
    if not sharp:  # noise in one corner
        blob = rng.random(shape) < 0.05
        blob[shape[0] // 3:] = False
        d[blob] = rng.random(blob.sum()).astype(np.float32) * 3
    return d


def boxed_media(rng, sharps, shapes, shift=0.0):
    """Prepared media of ``blocky`` grids, smooth or sharp per ``sharps``, medium k of
    ``shapes[k]`` voxels in a box near the origin moved by k ``shift`` along every axis."""
    media = []
    for k, (sharp, n) in enumerate(zip(sharps, shapes)):
        i2w = np.eye(4)
        i2w[:3, :3] = np.diag(rng.uniform(0.05, 0.09, 3))
        i2w[:3, 3] = rng.uniform(-1.2, -0.6, 3) + k * shift
        media.append(prepare(Medium(f"m{k}", blocky(n, rng, sharp), i2w, rng.uniform(0.5, 3, 3),
                                    np.full(3, 0.2), 0.0, source="MESH" if sharp else "VDB")))
    return media


@pytest.mark.parametrize("sharp", [False, True])
@pytest.mark.parametrize("brick", [BRICK, 3, 8])
def test_brick_bounds_hold_every_point(sharp, brick):
    rng = np.random.default_rng(7 + brick)
    shape = (40, 34, 44)
    g = np.zeros(tuple(s + 2 for s in shape), np.float32)
    g[1:-1, 1:-1, 1:-1] = blocky(shape, rng, sharp)
    thr = 0.5 - 1e-9 if sharp else -1.0
    b = brick_bounds(g, thr, brick)
    assert b.shape == tuple(-(-(n - 1) // brick) for n in g.shape) + (2,)
    assert np.all(b[..., 0] <= b[..., 1])
    idx = rng.uniform(0, np.array(g.shape) - 1, (200000, 3))
    # also points a rounding error off the brick faces
    near = rng.random(len(idx)) < 0.3
    idx[near] = np.round(idx[near] / brick) * brick + rng.normal(0, 1e-9, (near.sum(), 3))
    idx = np.clip(idx, 0, np.array(g.shape) - 1 - 1e-9)
    rho = density_from(trilinear(g, idx), thr)
    cell = np.minimum(np.floor(idx / brick).astype(int), np.array(b.shape[:3]) - 1)
    lo, hi = b[cell[:, 0], cell[:, 1], cell[:, 2]].T
    assert np.all(rho <= hi + 1e-6) and np.all(rho >= lo - 1e-6)
    assert (hi == 0).mean() > 0.05 and ((lo == hi) & (hi > 0)).mean() > 0.01  # both kinds occur


@needs_c
def test_optical_depth_is_the_same_with_bricks():
    rng = np.random.default_rng(3)
    media = boxed_media(rng, (False, True, False), ((30, 26, 34), (20, 22, 18), (30, 26, 34)))
    m = 4000
    p = rng.uniform(-1.5, 1.5, (m, 3))
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = rng.uniform(0, 4, m)
    for sub in ([0], [1], [0, 1, 2]):
        ms = [media[i] for i in sub]
        args = (p, d, t, [x.grid for x in ms], [x.w2i for x in ms], [x.sigma_t for x in ms],
                [x.threshold for x in ms])
        for step in (0.02, 0.07):
            a = kernels.optical_depth(*args, step, backend="c")
            b = kernels.optical_depth(*args, step, bricks=[x.bricks for x in ms], backend="c")
            assert np.allclose(a, b, rtol=1e-12, atol=1e-12), (sub, step)
            assert a.max() > 0.5 and (a == 0).mean() > 0.05


def test_optical_depth_clipped_to_the_media_is_the_twins_and_the_exit_distance():
    """``clip`` cuts each ray where it leaves the last medium's box: the same as handing the
    kernel the exit distance of media.union_interval, in both twins."""
    from mpp_render import kernels_np
    from mpp_render.precompute.lightdepth import _exit_distance
    rng = np.random.default_rng(11)
    media = boxed_media(rng, (False, True), [(20, 18, 22)] * 2, shift=0.5)
    m = 2000
    p = rng.uniform(-2, 2, (m, 3))
    d = rng.normal(size=(m, 3))
    d[:50, 1] = 0.0  # rays parallel to a face
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    limit = np.where(rng.random(m) < 0.5, np.inf, rng.uniform(0, 3, m))
    args = ([x.grid for x in media], [x.w2i for x in media], [x.sigma_t for x in media],
            [x.threshold for x in media], 0.03)
    want = kernels_np.optical_depth(p, d, _exit_distance(media, p, d, limit), *args)
    got_np = kernels_np.optical_depth(p, d, limit, *args, clip=True)
    assert np.allclose(got_np, want, rtol=1e-9, atol=1e-12)
    if kernels._c is not None:
        got_c = kernels.optical_depth(p, d, limit, *args, clip=True, backend="c")
        assert np.allclose(got_c, want, rtol=1e-4, atol=1e-9)
    assert want.max() > 0.3 and (want == 0).mean() > 0.05


@pytest.mark.parametrize("backend", ["c", "numpy"])
def test_the_media_interval_is_the_twins(backend):
    """kernels.union_interval (the tiles' rays through the media's boxes) is
    media.union_interval: rays that cross one box, several, none, run parallel to a face or
    start inside, with finite and endless ends, on every medium layout."""
    if backend == "c" and kernels._c is None:
        pytest.skip("compiled kernels not built")
    from mpp_render.media import union_interval
    rng = np.random.default_rng(12)
    media = boxed_media(rng, (False, True, False), [(20, 18, 22)] * 3, shift=0.4)
    m = 5000
    p = rng.uniform(-2.5, 2.5, (m, 3))
    d = rng.normal(size=(m, 3))
    d[:300, 1] = 0.0                      # parallel to a face
    d[300:400, :2] = 0.0                  # along an axis
    d *= rng.uniform(0.5, 2.0, (m, 1))    # any length
    lo = np.where(rng.random(m) < 0.5, 0.0, rng.uniform(-1, 1, m))
    hi = np.where(rng.random(m) < 0.5, np.inf, rng.uniform(0, 4, m))
    for sub in ([0], [1, 2], [0, 1, 2]):
        ms = [media[i] for i in sub]
        want = union_interval(ms, p, d, lo, hi)
        got = kernels.union_interval(ms, p, d, lo, hi, backend=backend)
        for w, g in zip(want, got):
            assert np.array_equal(np.isfinite(w), np.isfinite(g)), sub
            f = np.isfinite(w)
            np.testing.assert_allclose(g[f], w[f], rtol=1e-12, atol=1e-12, err_msg=str(sub))
        crossed = want[1] > want[0]
        assert np.array_equal(got[1] > got[0], crossed)
        assert 0.05 < crossed.mean() < 0.95       # rays that cross and rays that miss


@pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")
def test_the_compiled_interval_refuses_inputs_of_the_wrong_shape():
    """_kernels.union_interval checks every buffer's shape against the rays' and the media's
    counts: a clear error, never a read past an array."""
    c = kernels._c
    n = 8
    o, d, t = np.zeros((n, 3)), np.ones((n, 3)), np.zeros(n)
    w, last = np.zeros((2, 3, 4)), np.ones((2, 3))
    c.union_interval(o, d, t, t, w, last)                       # the right shapes pass
    bad = [(o[:, :2], d, t, t, w, last), (o, d[:5], t, t, w, last), (o, d, t[:5], t, w, last),
           (o, d, t, t[:5], w, last), (o, d, t, t, np.zeros((2, 3, 3)), last),
           (o, d, t, t, w, np.ones((3, 3))), (o, d, t, t, w.astype(np.float32), last)]
    for args in bad:
        with pytest.raises((ValueError, TypeError, BufferError)):
            c.union_interval(*args)
