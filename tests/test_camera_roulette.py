"""The camera's roulette of the lights' paths (paths.py, "The camera's roulette";
precompute/camerareach.py): the twins trace the same paths with it, it keeps the estimate's
mean, it ends paths where the camera cannot see their light (fewer tentative collisions), it
plays once a path (a path that reaches odds q weighs 1 / q, not compounded), bad odds raise,
and the precompute plays it only where the paths' light is the camera's alone."""
import dataclasses

import numpy as np
import pytest

from mpp_render import kernels, paths
from mpp_render.paths import PathInputs, trace_paths_np
from mpp_render.precompute import camerareach
from rays import path_twins
from test_paths import cube_case, needs_c


def deep_case(n_paths=4000, seed=1, floor=0.1):
    """(PathInputs without odds, odds, lattice points): a cube of optical side 38 (albedo 0.99,
    g 0.3) lit at a point 0.5 m in front of its centre, the camera in front (-z); odds
    ``floor`` on the far half of the lattice (z > 0), 1 on the near half."""
    inp, pts = cube_case(n=32, stride=2, vox=0.06, sigma_t=20.0, albedo=0.99, g=0.3,
                         n_paths=n_paths, light=(0.0, 0.0, -0.5), camera=(0.0, 0.0, -7.0),
                         seed=seed)
    odds = np.where(pts[..., 2] > 0.0, floor, 1.0).astype(np.float32)
    return inp, odds, pts


def with_odds(inp, odds, **change):
    return PathInputs(**{**inp.__dict__, "odds": odds, **change})


@needs_c
def test_the_twins_agree_with_the_roulette():
    rng = np.random.default_rng(3)
    inp, odds, _ = deep_case(n_paths=3000)
    spotty = (0.05 + 0.95 * rng.random(odds.shape)).astype(np.float32)
    for o in (odds, spotty):
        path_twins(with_odds(inp, o))
    # odds of 1 everywhere: the same bits as none
    ones = np.ones_like(odds)
    assert np.array_equal(kernels.trace_paths(with_odds(inp, ones)), kernels.trace_paths(inp))


def test_it_keeps_the_mean_and_ends_paths_the_camera_cannot_see(monkeypatch):
    """Far half (odds 0.1) and near half of the lattice, summed over seeds: the same light with
    and without the roulette within the seeds' spread, and fewer tentative collisions."""
    count = counted(monkeypatch)
    sums, events = {}, {}
    for use in (False, True):
        per_seed = []
        count[0] = 0
        for seed in range(6):
            inp, odds, pts = deep_case(n_paths=3000, seed=seed)
            acc = trace_paths_np(with_odds(inp, odds if use else None))[..., 0]
            far = pts[..., 2] > 0.0
            per_seed.append((acc[far].sum(), acc[~far].sum()))
        sums[use] = np.array(per_seed)
        events[use] = count[0]
    assert events[True] < 0.8 * events[False], events
    for region in (0, 1):
        a, b = sums[False][:, region], sums[True][:, region]
        spread = np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
        assert abs(a.mean() - b.mean()) < 4.0 * spread + 1e-12, (region, a.mean(), b.mean())
        assert spread < 0.1 * a.mean()


@needs_c
def test_the_compiled_roulette_keeps_the_mean():
    """Many paths in C: the far half's light (where every path plays) and the whole within
    2 % of the trace without the roulette, the far half from about a tenth of the paths."""
    inp, odds, pts = deep_case(n_paths=200_000, seed=7)
    plain = kernels.trace_paths(inp, threads=2)[..., 0]
    played = kernels.trace_paths(with_odds(inp, odds), threads=2)[..., 0]
    far = pts[..., 2] > 0.0
    assert played[far].sum() == pytest.approx(plain[far].sum(), rel=0.02)
    assert played.sum() == pytest.approx(plain.sum(), rel=0.02)


def counted(monkeypatch):
    """A counter of the numpy twin's tentative collisions: count[0]."""
    count = [0]
    real = paths._collide

    def counting(m, out, tw, g, st, ss, mu, coll, *a, **k):
        count[0] += int(np.count_nonzero(coll))
        return real(m, out, tw, g, st, ss, mu, coll, *a, **k)
    monkeypatch.setattr(paths, "_collide", counting)
    return count


def test_once_a_path_not_compounded(monkeypatch):
    """Odds q everywhere: a path plays at its first real collision alone and half of them go
    on for all their flights (about q of the tentative collisions after the first flight are
    left); played at every collision the paths would end after a few (q^k) and their weights
    would grow as q^-k.  The light stays within the seeds' noise of the plain trace's."""
    count = counted(monkeypatch)
    inp, odds, _ = deep_case(n_paths=2000)
    first = dict(max_collisions=1)
    trace_paths_np(with_odds(inp, None, **first))
    n_first = count[0]
    out = {}
    for q in (None, 0.5):
        count[0] = 0
        o = None if q is None else np.full_like(odds, q)
        out[q] = trace_paths_np(with_odds(inp, o)).sum()
        out[(q, "events")] = count[0] - n_first
    assert out[(None, "events")] > 20 * n_first     # paths of many collisions
    ratio = out[(0.5, "events")] / out[(None, "events")]
    assert 0.4 < ratio < 0.6, ratio
    assert out[0.5] == pytest.approx(out[None], rel=0.1)


@needs_c
def test_bad_odds_raise():
    inp, odds, _ = deep_case(n_paths=10)
    for bad in (np.zeros_like(odds), np.full_like(odds, np.nan), np.full_like(odds, 1.5),
                np.full_like(odds, -0.5), np.ones((2, 2, 2), np.float32)):
        with pytest.raises(ValueError):
            kernels.trace_paths(with_odds(inp, bad))
    # empty odds: none
    empty = np.zeros((0, 0, 0), np.float32)
    assert np.array_equal(kernels.trace_paths(with_odds(inp, empty)), kernels.trace_paths(inp))


def thick_cube(sigma_t=40.0, albedo=0.99, g=0.6, n=16):
    from mpp_render.media import prepare
    from mpp_render.scene import Medium
    i2w = np.eye(4)
    i2w[:3, :3] *= 2.0 / n
    i2w[:3, 3] = -1.0 + 1.0 / n
    return prepare(Medium("m", np.ones((n, n, n), np.float32), i2w,
                          np.full(3, albedo * sigma_t), np.full(3, (1.0 - albedo) * sigma_t), g))


def test_the_odds_follow_the_walks_reach():
    pm = thick_cube()
    reach = camerareach.walk_reach(0.99, 0.6)
    assert reach == pytest.approx(np.sqrt(2.0 / (0.01 * 0.4)))
    tau = np.linspace(0.0, 60.0, 61).reshape(61, 1, 1)
    odds = camerareach.roulette_odds(pm, lambda: tau, 0.1)
    length = camerareach.diffusion_length(0.99, 0.6)
    assert length == pytest.approx(1.0 / np.sqrt(3.0 * 0.01 * (1.0 - 0.99 * 0.6)))
    assert camerareach.diffusion_length(1.0, 0.6) == np.inf
    want = np.maximum(0.1, np.exp(-np.maximum(tau - reach, 0.0) / length))
    # each point the largest within ODDS_STEPS points: here the point that many steps nearer
    # the camera's
    k = camerareach.ODDS_STEPS
    assert k >= 1
    np.testing.assert_allclose(odds[k:], want[:-k], rtol=1e-6)
    assert np.all(odds[:k] == 1.0)
    assert odds.dtype == np.float32 and odds.min() == pytest.approx(0.1)
    assert np.all(odds[tau[:, 0, 0] <= reach + 1.0] == 1.0)
    # nothing to play: no absorption (an infinite reach), an optically small medium, a floor
    # of 1 (switched off), no depth, or depths all within the reach
    assert camerareach.roulette_odds(thick_cube(albedo=1.0), lambda: tau, 0.1) is None
    assert camerareach.roulette_odds(thick_cube(sigma_t=5.0), lambda: tau, 0.1) is None
    assert camerareach.roulette_odds(pm, lambda: tau, 1.0) is None
    assert camerareach.roulette_odds(pm, lambda: None, 0.1) is None
    assert camerareach.roulette_odds(pm, lambda: np.full((4, 4, 4), reach), 0.1) is None
    # a NaN depth plays nothing there, nor next to it
    deep = np.full((5, 5, 5), 50.0)
    deep[0, 0, 0] = np.nan
    odds = camerareach.roulette_odds(pm, lambda: deep, 0.1)
    near = slice(0, k + 1)
    assert np.all(odds[near, near, near] == 1.0) and np.all(odds[k + 1:] == np.float32(0.1))


def test_the_largest_of_the_neighbours():
    rng = np.random.default_rng(2)
    a = rng.random((5, 6, 7))
    got = camerareach.neighbours_largest(a)
    for idx in [(0, 0, 0), (2, 3, 4), (4, 5, 6), (1, 0, 6)]:
        sl = tuple(slice(max(0, i - 1), i + 2) for i in idx)
        assert got[idx] == a[sl].max()
    two = camerareach.neighbours_largest(a, 2)
    for idx in [(0, 0, 0), (2, 3, 4), (4, 5, 6), (1, 0, 6)]:
        sl = tuple(slice(max(0, i - 2), i + 3) for i in idx)
        assert two[idx] == a[sl].max()
    assert np.array_equal(camerareach.neighbours_largest(a, 0), a)
    assert camerareach.neighbours_largest(np.zeros((0, 0, 0))).size == 0


def test_the_precompute_plays_it_where_the_light_is_the_cameras_alone(monkeypatch):
    """lightpaths.traced_multiple: odds on the lattice (some below 1) for a thick absorbing
    cube seen from outside; none where a surface gathers the paths' light (it looks through
    the medium along other directions than the camera's) or with the floor at 1."""
    from mpp_render.precompute import lightpaths, precompute
    from mpp_render.scene import Surface, Tuning, World
    from mpp_render.surfaces import prepare_surfaces
    from test_paths import small_cube_under_a_sun
    got = []
    real = lightpaths._trace_all

    def spy(*a, **k):
        if k.get("max_collisions", paths.MAX_COLLISIONS) == paths.MAX_COLLISIONS:
            got.append(k.get("odds"))
        return real(*a, **k)
    monkeypatch.setattr(lightpaths, "_trace_all", spy)
    cam, sun, _ = small_cube_under_a_sun()
    pm = thick_cube()
    kw = dict(multiple=True, multiple_paths=20000, multiple_resolution=8)
    precompute([pm], [sun], World(), cam, **kw)
    assert got and got[-1] is not None and got[-1].min() < 1.0 and got[-1].max() == 1.0
    got.clear()
    precompute([pm], [sun], World(), cam,
               tuning=dataclasses.replace(Tuning(), camera_roulette=1.0), **kw)
    assert got and all(o is None for o in got)
    got.clear()
    v = np.array([[-30.0, -30.0, -1.5], [30.0, -30.0, -1.5], [30.0, 30.0, -1.5],
                  [-30.0, 30.0, -1.5]])
    ground = prepare_surfaces([Surface("ground", v, np.array([[0, 1, 2], [0, 2, 3]]),
                                       np.full(3, 0.5), np.zeros(3))])
    precompute([pm], [sun], World(), cam, surfaces=ground, **kw)
    assert got and all(o is None for o in got)
