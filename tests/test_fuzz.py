"""Bounded fuzz of the compiled kernels: random sizes, NaN, inf and huge values never crash.

Run in-process here; ``tests/test_sanitizers.py`` runs this same file against a build with
AddressSanitizer and UndefinedBehaviorSanitizer."""
import os

import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.lightrecord import L_CHANNEL, L_KIND, LIGHT_FIELDS
from mpp_render.media import brick_bounds

pytestmark = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")
ROUNDS = int(os.environ.get("MPP_FUZZ_ROUNDS", "60"))
SPECIAL = np.array([np.nan, np.inf, -np.inf, 1e300, -1e300, 0.0, -0.0, 1e-300])


def spoil(a, rng, frac=0.05):
    a = np.array(a, dtype=np.float64 if a.dtype == np.float64 else a.dtype)
    if a.size:
        m = rng.random(a.shape) < frac
        a[m] = rng.choice(SPECIAL, m.sum()).astype(a.dtype)
    return a


def random_case(rng):
    n = int(rng.integers(0, 40))
    nm = int(rng.integers(0, 3))
    nl = int(rng.integers(0, 4))
    chans = 1 + 3 * nl + 3
    fields, w2is, ss, st, gs, thr, vox = [], [], [], [], [], [], []
    for _ in range(nm):
        shape = tuple(int(x) for x in rng.integers(2, 7, 3)) + (chans,)
        f = (rng.random(shape) * 3).astype(np.float32)
        fields.append(spoil(f, rng, 0.01).astype(np.float32))
        w = np.hstack([np.diag(rng.uniform(0.5, 3, 3)), rng.uniform(-3, 3, (3, 1))])
        w2is.append(spoil(w, rng, 0.02) if rng.random() < 0.3 else w)
        ss.append(rng.uniform(0, 5, 3))
        st.append(ss[-1] + rng.uniform(0, 1, 3))
        gs.append(float(rng.uniform(-0.99, 0.99)))
        thr.append(float(rng.choice([-1.0, 0.5])))
        vox.append(float(rng.uniform(0.01, 1)))
    lights = rng.normal(size=(nl, LIGHT_FIELDS)) * 3
    lights[:, L_KIND] = rng.integers(0, 4, nl)
    lights[:, L_CHANNEL] = 1 + 3 * np.arange(nl)
    lights = spoil(lights, rng, 0.03)
    lights[:, L_KIND] = np.clip(np.nan_to_num(lights[:, L_KIND]), 0, 3).round()
    lights[:, L_CHANNEL] = 1 + 3 * np.arange(nl)
    o = spoil(rng.uniform(-4, 4, (n, 3)), rng)
    d = spoil(rng.normal(size=(n, 3)), rng)
    t0 = spoil(rng.uniform(0, 2, n), rng)
    t1 = spoil(t0 + rng.uniform(0, 6, n), rng)
    return (o, d, t0, t1, np.ones(n), rng.integers(0, 2 ** 32, n, dtype=np.uint32), fields, w2is,
            ss, st, gs, thr, vox, lights, 1 + 3 * nl, float(rng.choice([0.05, 0.3, 1e-3])), 0.01, 1e10)


def test_fuzz_march_and_optical_depth():
    rng = np.random.default_rng(12345)
    for _ in range(ROUNDS):
        args = random_case(rng)
        try:
            s, t, dep = kernels._c.march(*args)[:3]
        except ValueError:
            continue   # rejected input is fine; a crash is not
        # with brick bounds (some spoiled) and longer steps in thin media
        bricks = [spoil(brick_bounds(np.ascontiguousarray(f[..., 0]), th), rng, 0.05).astype(np.float32)
                  for f, th in zip(args[6], args[11])]
        try:
            kernels._c.march(*args, None, None, bricks, 4, float(rng.choice([0.0, 0.1, 5.0])))
        except ValueError:
            pass
        # the pixels' strata of the steps and the lights: random counts and bands (some
        # beyond the count), keys of the wrong length now and then
        n_rays = len(args[0])
        count = int(rng.choice([1, 4, 6, 16, 1 << 24, 0, -3]))
        bands = rng.integers(0, max(count, 1) + int(rng.random() < 0.2), n_rays).astype(np.uint32)
        keys = rng.integers(0, 2 ** 32, n_rays + int(rng.random() < 0.1), dtype=np.uint32)
        try:
            kernels._c.march(*args, None, None, None, 4, 0.0, None, 0.0, None, None, None, 0.0,
                             0, bands, count, keys)
        except (ValueError, OverflowError):
            pass
        n = len(args[0])
        assert len(s) == 24 * n and len(t) == 24 * n and len(dep) == 8 * n
        fields, w2is, st, thr = args[6], args[7], args[9], args[11]
        grids = [np.ascontiguousarray(f[..., 0]) for f in fields]
        brick = int(rng.choice([1, 2, 4]))
        bricks = [spoil(brick_bounds(g, t, brick), rng, 0.05).astype(np.float32)
                  for g, t in zip(grids, thr)]
        # the stop where the rays turn opaque: a random (some spoiled) matrix and depth
        stop = spoil(np.abs(rng.normal(size=(3, 3))) * rng.choice([0.0, 1.0, 1e6]), rng, 0.1)
        depth = float(rng.choice([1e-9, 0.5, 37.0, np.inf, 0.0, -1.0, np.nan]))
        for extra in ((), (bricks, brick), (bricks, brick, True), (None, 4, True),
                      (bricks, brick, True, stop, depth), (None, 4, False, stop, depth)):
            try:
                kernels._c.optical_depth(args[0], args[1], args[3], grids, w2is, st, thr, args[15],
                                         0.5, *extra)
            except ValueError:
                pass


def random_sweep(rng):
    """Arguments of _kernels.light_sweep: valid, extreme but finite, or with one spoiled field."""
    args = random_case(rng)
    grids = [np.ascontiguousarray(f[..., 0]) for f in args[6]]
    w2is = [np.nan_to_num(w, nan=0.5, posinf=3.0, neginf=-3.0) for w in args[7]]
    shape = tuple(int(x) for x in rng.integers(2, 9, 3))
    out = np.zeros(shape + (int(rng.integers(3, 8)),), np.float32)
    axis, sign = int(rng.integers(0, 3)), int(rng.choice([-1, 1]))
    ends = sorted(int(x) for x in rng.integers(0, shape[axis], 2))
    i_first, i_last = ends if sign > 0 else ends[::-1]
    n_p, n_q = int(rng.integers(2, 12)), int(rng.integers(2, 12))
    coef = rng.normal(size=6) * rng.choice([0.5, 10.0, 1e6])
    coef[4], coef[5] = rng.uniform(0.05, 3), 0.0 if rng.random() < 0.5 else rng.uniform(-0.01, 0.01)
    init = rng.uniform(0, 3, (n_p, n_q, 3))
    p_lo = int(rng.integers(0, n_p - 1))
    p_hi = int(rng.integers(p_lo + 1, n_p))
    a2w = np.hstack([np.diag(rng.uniform(0.2, 2, 3)), rng.uniform(-3, 3, (3, 1))])
    call = [out, int(rng.integers(0, out.shape[3] - 2)), a2w, axis, sign, i_first, i_last, coef,
            rng.uniform(-10, 10, 3), int(rng.integers(0, 2)), init, p_lo, p_hi,
            int(rng.integers(1, 4)), grids, w2is, args[9], args[11]]
    if rng.random() < 0.4:  # spoil one thing
        k = int(rng.choice([1, 2, 3, 4, 5, 6, 7, 8, 10, 11, 12, 13]))
        v = call[k]
        if isinstance(v, np.ndarray):
            call[k] = spoil(v, rng, 0.3)
        else:
            call[k] = int(v + rng.choice([-100, -3, -1, 1, 3, 100]))
    return call


def test_fuzz_light_sweep():
    """Random column layouts, grids and spoiled fields: the sweep writes only inside ``out``
    (ASan checks this in test_sanitizers.py) or raises ValueError; most calls run."""
    rng = np.random.default_rng(777)
    ran = 0
    for _ in range(ROUNDS):
        call = random_sweep(rng)
        try:
            kernels._c.light_sweep(*call)
            ran += 1
        except ValueError:
            continue
    assert ran > ROUNDS // 3


def test_fuzz_walk_depth():
    """The compiled walk through thick cells (kernels.walk_tau): random grids down to one
    voxel an axis, spoiled densities, transforms, points, directions and distances, any walk
    length up to 64 cells: it reads only inside the grid (ASan checks this in
    test_sanitizers.py) and returns one depth a point, or raises ValueError."""
    rng = np.random.default_rng(4242)
    ran = 0
    for _ in range(ROUNDS):
        shape = tuple(int(x) for x in rng.integers(1, 7, 3))
        nc = int(rng.integers(4, 9))
        grid = spoil((rng.random(shape + (nc,)) * 4).astype(np.float32), rng, 0.02).astype(np.float32)
        w2i = np.hstack([np.diag(rng.uniform(0.5, 3, 3)), rng.uniform(-3, 3, (3, 1))])
        if rng.random() < 0.3:
            w2i = spoil(w2i, rng, 0.1)
        n = int(rng.integers(0, 30))
        x = spoil(rng.uniform(-3, 3, (n, 3)), rng)
        w = spoil(rng.normal(size=(n, 3)), rng)
        dist = spoil(rng.uniform(0, 5, n), rng)
        tau = spoil(rng.uniform(0, 3, (n, 3)), rng)
        xc = int(rng.choice([-1, 1, nc - 3, nc - 2]))
        c = int(rng.integers(0, nc - 1))
        try:
            out = kernels._c.walk_depth(grid, w2i, spoil(rng.uniform(0, 5, 3), rng, 0.1), xc, c,
                                        x, w, dist, tau, float(rng.uniform(0, 5)),
                                        float(rng.choice([0.01, 0.3, 1.0])),
                                        float(rng.choice([0.0, 0.25, 1e-9])),
                                        int(rng.integers(0, 65)))
        except ValueError:
            continue
        assert len(out) == 8 * 3 * n
        ran += 1
    assert ran > ROUNDS // 3


def test_fuzz_nodal_fit():
    """The compiled nodal fit (kernels.nodal_fit): random lattices down to one point an axis,
    1-16 channels, spoiled means, offsets and masses (NaN, inf, huge), any signed count and
    ridge: it reads only inside the lattice (ASan checks this in test_sanitizers.py) and
    returns the lattice's shape, or raises ValueError; finite inputs give finite values."""
    rng = np.random.default_rng(777)
    ran = 0
    for _ in range(ROUNDS):
        shape = tuple(int(x) for x in rng.integers(1, 7, 3))
        nc = int(rng.integers(1, 17))
        mean = (rng.normal(size=shape + (nc,)) * 3).astype(np.float32)
        d = rng.uniform(-0.6, 0.6, shape + (3,))
        mass = rng.random(shape) * (rng.random(shape) > 0.3)
        clean = rng.random() < 0.4
        if not clean:
            mean = spoil(mean, rng, 0.03).astype(np.float32)
            d, mass = spoil(d, rng, 0.03), spoil(mass, rng, 0.03)
        signed = int(rng.integers(-1, nc + 2))
        ridge = float(rng.choice([0.01, 1e-12, 0.0, -1.0, 1e300]))
        try:
            out = np.frombuffer(kernels._c.nodal_fit(mean, d, mass, signed, ridge), np.float32)
        except ValueError:
            assert signed < 0 or signed > nc or not ridge > 0.0
            continue
        assert out.size == mean.size
        if clean and ridge >= 0.01:
            assert np.all(np.isfinite(out))
        ran += 1
    assert ran > ROUNDS // 3


def test_fuzz_lobe_ratio():
    """The compiled local-linear fit of the paths' lobe (kernels.lobe_ratio): random lattices
    down to one point an axis, windows wider than the lattice, spoiled deposits, lobes and
    weights (NaN, inf, huge), channels 1 or 3 or wrong: it reads only inside the lattice (ASan
    checks this in test_sanitizers.py), returns the lattice's shape or raises ValueError,
    and agrees with its numpy twin bit for bit wherever the twin is finite."""
    from mpp_render import kernels_np
    rng = np.random.default_rng(778)
    ran = 0
    for _ in range(ROUNDS):
        shape = tuple(int(x) for x in rng.integers(1, 8, 3))
        md = rng.random(shape + (3,)) * rng.choice([1.0, 1e-30, 1e30])
        mc = rng.random(shape + (3,)) * (rng.random(shape + (3,)) > 0.2)
        u = rng.random(shape) * (rng.random(shape) > 0.3)
        clean = rng.random() < 0.5
        if not clean:
            md, mc, u = spoil(md, rng, 0.03), spoil(mc, rng, 0.03), spoil(u, rng, 0.03)
        r = int(rng.integers(0, 9))
        ch = int(rng.choice([1, 3, 3, 2]))
        try:
            out = np.frombuffer(kernels._c.lobe_ratio(md, mc, u, r, ch), np.float64)
        except ValueError:
            assert r < 1 or ch not in (1, 3)
            continue
        out = out.reshape(shape + (3,))
        if clean:
            with np.errstate(all="ignore"):
                twin = kernels_np.lobe_ratio(md, mc, u, r, ch)
            fin = np.isfinite(twin)
            assert np.array_equal(out[fin], twin[fin])
        ran += 1
    assert ran > ROUNDS // 3


def test_fuzz_emitter_transmittance():
    """The compiled transmittance over an emitter's nodes (kernels.emitter_transmittance):
    random point and node counts down to none, spoiled points, depths, distances, weights and
    normals (NaN, inf, huge), voxels of every sign: it returns (N,3) or raises ValueError for
    the voxel, and agrees with its numpy twin wherever the input is clean."""
    from mpp_render import lights
    rng = np.random.default_rng(779)
    ran = 0
    for _ in range(ROUNDS):
        n, k = int(rng.integers(0, 30)), int(rng.integers(0, 20))
        x, tau = rng.uniform(-2, 2, (n, 3)), rng.uniform(0, 8, (n, 3))
        dc, pts = rng.uniform(0, 3, n), rng.uniform(-1, 1, (k, 3))
        wa, nrm = rng.uniform(0, 1, k), rng.normal(size=3)
        voxel = float(rng.choice([0.05, 1e-300, 0.0, -1.0, np.nan, np.inf]))
        clean = rng.random() < 0.5
        if not clean:
            x, tau, dc = spoil(x, rng), spoil(tau, rng), spoil(dc, rng)
            pts, wa, nrm = spoil(pts, rng), spoil(wa, rng), spoil(nrm, rng, 0.2)
        try:
            out = np.frombuffer(kernels._c.emitter_transmittance(x, tau, dc, pts, wa, nrm, voxel),
                                np.float64)
        except ValueError:
            assert not (voxel > 0.0 and np.isfinite(voxel))
            continue
        out = out.reshape(n, 3)
        if clean:
            twin = lights.emitter_transmittance(x, tau, dc, pts, wa, nrm, voxel)
            np.testing.assert_allclose(out, twin, rtol=1e-12, atol=1e-300)
        ran += 1
    assert ran > ROUNDS // 4


def test_wrong_types_and_shapes_raise():
    c = kernels._c
    with pytest.raises(ValueError):
        c.optical_depth(np.zeros((2, 2)), np.zeros((2, 3)), np.zeros(2), [], [], [], [], 0.1, 0.5)
    with pytest.raises(ValueError):
        c.optical_depth(np.zeros((2, 3), np.float32), np.zeros((2, 3)), np.zeros(2), [], [], [], [], 0.1, 0.5)
    with pytest.raises(ValueError):
        c.optical_depth(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros(2), [np.zeros((1, 4, 4), np.float32)],
                        [np.zeros((3, 4))], [np.ones(3)], [-1.0], 0.1, 0.5)
    with pytest.raises(ValueError):
        c.optical_depth(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros(2), [], [], [], [], float("nan"), 0.5)
