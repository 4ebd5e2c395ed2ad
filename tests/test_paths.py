"""Traced light paths for multiple scattering (paths.py, csrc/paths.c): the twins agree, the
estimate keeps energy where the answer is known in closed form, its second order matches an
independent quadrature of the double-scattering integral, it converges as paths are added,
it does not depend on the thread count, and bad input raises instead of crashing."""
import dataclasses
import time

import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.cancel import Cancelled
from mpp_render.paths import (MAX_RATE_SPAN, PathInputs, from_power, path_keys, rate_span,
                              start_positions, trace_paths_np)
from mpp_render.precompute.lattice import lattice_shape
from rays import path_twins

needs_c = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")


def cube_case(n=48, stride=2, vox=0.05, sigma_t=2.0, albedo=0.9, g=0.3, n_paths=20000,
              light=(-0.2, 0.1, -0.3), camera=(0.0, -7.5, 0.8), max_collisions=4096, seed=1):
    """(PathInputs, lattice points (LX,LY,LZ,3) m): a homogeneous cube of n^3 voxels of side
    ``vox`` (m) centred on the origin, its first scatterings (1 W, the light propagating
    along +x) at the one point ``light``, seen from ``camera``."""
    ls = lattice_shape((n, n, n), stride)
    half = 0.5 * (n - 1) * vox
    i2w = np.eye(3) * vox
    w2i = np.concatenate([np.eye(3) / vox, np.full((3, 1), half / vox)], axis=1)
    idx = np.stack(np.meshgrid(*[np.arange(s) * stride for s in ls], indexing="ij"), -1)
    pts = idx * vox - half
    v = np.asarray(camera) - pts
    towards = v / np.linalg.norm(v, axis=-1, keepdims=True)
    starts = np.asarray([light], np.float64)
    w, cdf = from_power(np.ones((1, 3)))
    dirs = np.array([[1.0, 0.0, 0.0]])
    rate = max(sigma_t, 1.0 / (stride * vox))
    return PathInputs(np.ones((n, n, n), np.float32), w2i, i2w, np.full(3, albedo * sigma_t),
                      np.full(3, sigma_t), g, stride, np.ascontiguousarray(towards), starts, w,
                      dirs, cdf, rate, n_paths, seed, max_collisions), pts


def test_twins_agree_on_a_chromatic_grid():
    rng = np.random.default_rng(1)
    n, stride, vox = 20, 2, 0.1
    ls = lattice_shape((n, n, n), stride)
    tow = rng.normal(size=ls + (3,))
    tow /= np.linalg.norm(tow, axis=-1, keepdims=True)
    starts = rng.random((6, 3)) * 1.8
    d = rng.normal(size=(6, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    w, cdf = from_power(rng.random((6, 3)) + 0.1)
    inp = PathInputs(rng.random((n, n, n)).astype(np.float32), np.concatenate(
        [np.eye(3) / vox, np.zeros((3, 1))], 1), np.eye(3) * vox, np.array([1.0, 1.5, 2.0]),
        np.array([2.0, 2.0, 2.5]), 0.6, stride, tow, starts, w, d, cdf, 5.0, 2000, 5)
    path_twins(inp)


@needs_c
@pytest.mark.parametrize("moments", [False, True])
def test_deposits_after_the_first_collision(moments):
    """min_collisions 1 counts only the deposits of light that has scattered at least once:
    the twins agree, and it is the trace to the end less the same paths' first flights
    (max_collisions 1), which it replaces with one trace; min_collisions 2 leaves out the
    second flights as well, so less is deposited."""
    inp, _ = cube_case(n=24, n_paths=3000, seed=4)
    inp = dataclasses.replace(inp, moments=moments)
    after = dataclasses.replace(inp, min_collisions=1)
    every = kernels.trace_paths(inp, threads=2)
    first = kernels.trace_paths(dataclasses.replace(inp, max_collisions=1), threads=2)
    c = kernels.trace_paths(after, threads=2)
    twin = trace_paths_np(after)
    assert c[..., :3].sum() > 0.05 * every[..., :3].sum()
    assert np.abs(c - twin).max() <= 1e-9 * np.abs(c).max()
    assert np.abs(c - (every - first)).max() <= 1e-9 * np.abs(every).max()
    later = kernels.trace_paths(dataclasses.replace(inp, min_collisions=2), threads=2)
    assert later[..., :3].sum() < 0.99 * c[..., :3].sum()


def half_empty_case(n_paths=4000):
    """A 20^3 grid whose voxels with i < 10 are empty, chromatic, first scatterings at lattice
    points on the boundary plane and beside it (their tents reach both halves)."""
    rng = np.random.default_rng(3)
    n, stride, vox = 20, 2, 0.1
    ls = lattice_shape((n, n, n), stride)
    tow = rng.normal(size=ls + (3,))
    tow /= np.linalg.norm(tow, axis=-1, keepdims=True)
    dens = rng.random((n, n, n)).astype(np.float32) + 0.5
    dens[:10] = 0.0
    starts = np.array([[0.9, 1.0, 1.0], [1.0, 0.6, 1.2], [0.9, 1.4, 0.4]])  # i = 9, 10, 9
    d = np.array([[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.6, 0.8, 0.0]])
    w, cdf = from_power(np.array([[1.0, 1.0, 1.0], [0.5, 0.7, 0.9], [1.0, 0.2, 0.4]]))
    return PathInputs(dens, np.concatenate([np.eye(3) / vox, np.zeros((3, 1))], 1),
                      np.eye(3) * vox, np.array([1.0, 1.5, 2.0]), np.array([2.0, 2.0, 2.5]),
                      0.6, stride, tow, starts, w, d, cdf, 5.0, n_paths, 7)


def test_lattice_starts_land_in_the_medium():
    """A lattice start's tent offset is drawn again where it lands in an empty voxel: the
    light that first scatters beside a surface starts inside the medium, not outside it."""
    inp = half_empty_case()
    keys = path_keys(inp.seed, inp.n_paths)
    k = np.arange(inp.n_paths) % 3
    pos = start_positions(inp, keys, k)
    # the first draws: the same keys over a grid with no empty voxel
    full = dataclasses.replace(inp, density=np.ones_like(inp.density))
    first = start_positions(full, keys, k)
    out = np.floor(pos[:, 0] / 0.1 + 0.5) < 10
    out_first = np.floor(first[:, 0] / 0.1 + 0.5) < 10
    assert out_first.mean() > 0.4          # a tent of 2 voxels about i = 9 or 10
    assert out.mean() < 0.2 * out_first.mean()
    # a start that no draw puts in the medium keeps its first draw; the others moved in
    np.testing.assert_array_equal(pos[out], first[out])
    assert np.all(np.abs(pos - inp.starts[k]) <= 2 * 0.1 + 1e-12)   # within the tent
    # an emitting voxel (lobe 2) emits whatever the density: its starts are not moved
    glow = dataclasses.replace(inp, lobe=2)
    np.testing.assert_array_equal(start_positions(glow, keys, k), first)


def test_twins_agree_where_starts_are_drawn_again():
    inp = half_empty_case()
    path_twins(inp)


def graded_source(inp, rate=1.5):
    """``inp`` with a first-scattering source that falls as exp(-rate i) along x (i the
    voxel index) inside the medium, and each start's peak under its tent."""
    from mpp_render.precompute.lightpaths import tent_peak
    n = inp.density.shape[0]
    q = (np.exp(-rate * np.arange(n))[:, None, None] * (inp.density > 0)).astype(np.float32)
    shape = lattice_shape(inp.density.shape, inp.stride)
    lat = np.floor(inp.starts / 0.1 / inp.stride + 0.5).astype(int)   # the nearest points
    peak = tent_peak(q, inp.stride, shape)[lat[:, 0], lat[:, 1], lat[:, 2]]
    return dataclasses.replace(inp, start_source=q, start_peak=peak)


def test_lattice_starts_follow_the_voxels_source():
    """With a source, a first scattering's start is rejection-sampled within its lattice
    point's tent: the voxels it lands in are distributed as tent x source."""
    from mpp_render.precompute.source import box_tent_weights
    inp = graded_source(dataclasses.replace(half_empty_case(), density=np.ones((20, 20, 20),
                                                                              np.float32)))
    n = 40000
    keys = path_keys(11, n)
    k = np.ones(n, np.int64)                       # the start at lattice point (5, 3, 6)
    pos = start_positions(inp, keys, k)
    i = np.floor(pos[:, 0] / 0.1 + 0.5).astype(int)
    w = box_tent_weights(2)
    expect = np.array([w[t] * np.exp(-1.5 * (10 + t)) for t in range(-2, 3)])
    expect /= expect.sum()
    got = np.array([np.mean(i == 10 + t) for t in range(-2, 3)])
    np.testing.assert_allclose(got, expect, atol=0.01)
    # the tent alone (no source) would put a quarter of them at i >= 10
    assert got[3:].sum() < 0.1


def test_twins_agree_with_a_start_source():
    inp = graded_source(half_empty_case())
    path_twins(inp)


@needs_c
def test_a_start_source_of_the_wrong_shape_raises():
    inp = graded_source(half_empty_case())
    with pytest.raises(ValueError, match="start_source"):
        kernels.trace_paths(dataclasses.replace(inp, start_source=inp.start_source[:5]))
    with pytest.raises(ValueError, match="start_source"):
        kernels.trace_paths(dataclasses.replace(inp, start_peak=inp.start_peak[:1]))


@needs_c
def test_same_bits_for_any_thread_count():
    inp, _ = cube_case(n_paths=5000)
    ref = kernels.trace_paths(inp, threads=1)
    for t in (2, 3, 8):
        assert np.array_equal(kernels.trace_paths(inp, threads=t), ref)


@pytest.mark.parametrize("max_collisions, expected", [(1, 1.0 / 2.0), (4096, 1.0 / 0.4)])
def test_isotropic_track_length_in_a_large_medium(max_collisions, expected):
    """g = 0: the deposits times 4 pi are the scattered light's track length per watt, 1 /
    sigma_t for the first flights alone and 1 / sigma_a for every flight (infinite medium;
    the cube's faces are 7.4 diffusion lengths 1 / sqrt(3 sigma_a sigma_t) from the
    source)."""
    inp, _ = cube_case(n=96, vox=0.1, sigma_t=2.0, albedo=0.8, g=0.0, n_paths=20000,
                       light=(0.0, 0.0, 0.0), max_collisions=max_collisions)
    got = kernels.trace_paths(inp).sum(axis=(0, 1, 2)) * 4.0 * np.pi
    assert got == pytest.approx(np.full(3, expected), rel=0.03)


def test_second_order_matches_the_point_source_closed_form():
    """A point of first scattering whose light leaves isotropically (g = 0 at the first
    scattering): the first flights' light at x is e^{-sigma_t r} / (4 pi r^2) W/m^2, and M(x)
    that times p(w . v).  The tracer's lattice values, away from the source, match it."""
    inp, pts = cube_case(n=48, stride=2, vox=0.05, sigma_t=1.0, albedo=0.9, g=0.0,
                         n_paths=400000, light=(0.0, 0.0, 0.0), max_collisions=1)
    inp = PathInputs(**{**inp.__dict__, "g": 0.0})
    acc = kernels.trace_paths(inp)
    vol = (inp.stride * 0.05) ** 3
    m = acc[..., 0] / vol
    r = np.linalg.norm(pts, axis=-1)
    exact = np.exp(-1.0 * r) / (4.0 * np.pi * np.maximum(r, 1e-9) ** 2) / (4.0 * np.pi)
    # shells 0.3-0.9 m from the source (off the lattice's smoothing of the 1/r^2 peak)
    for lo, hi in ((0.3, 0.5), (0.5, 0.7), (0.7, 0.9)):
        sel = (r >= lo) & (r < hi)
        assert m[sel].mean() == pytest.approx(exact[sel].mean(), rel=0.04), (lo, hi)


def test_error_falls_as_paths_are_added():
    inp, _ = cube_case(n=32, stride=2, vox=0.06, n_paths=320000, seed=9)
    ref = kernels.trace_paths(inp)
    errs = []
    for n in (5000, 80000):
        got = kernels.trace_paths(PathInputs(**{**inp.__dict__, "n_paths": n, "seed": 3}))
        errs.append(np.sqrt(np.mean((got - ref) ** 2)))
    assert errs[1] < 0.4 * errs[0], errs


def test_rate_span_guards_dense_grids():
    i2w = np.eye(3) * 0.01
    assert rate_span(100.0, i2w, (100, 100, 100)) == pytest.approx(100.0 * np.sqrt(3.0))
    assert not rate_span(1e9, i2w, (100, 100, 100)) <= MAX_RATE_SPAN


@needs_c
def test_bad_input_raises():
    inp, _ = cube_case(n=8, n_paths=10)
    args = dict(inp.__dict__)
    for change in (dict(rate=0.0), dict(rate=np.nan), dict(stride=0), dict(g=np.nan),
                   dict(rate=1e12), dict(towards=np.zeros((2, 2, 2, 2))),
                   dict(weights=np.ones((2, 3))), dict(cdf=np.ones(3)),
                   dict(sigma_t=np.zeros(3)), dict(density=np.ones((4, 4), np.float32)),
                   dict(min_collisions=-1)):
        with pytest.raises(ValueError):
            kernels.trace_paths(PathInputs(**{**args, **change}))


@needs_c
def test_spoiled_values_finish():
    """NaN, inf and huge values in the grid, the maps and the starts end paths or give
    non-finite sums; they never hang or crash."""
    rng = np.random.default_rng(4)
    for _ in range(20):
        inp, _ = cube_case(n=10, n_paths=50, seed=int(rng.integers(1 << 30)))
        d = dict(inp.__dict__)
        dens = d["density"].copy()
        dens.reshape(-1)[rng.integers(0, dens.size, 20)] = rng.choice(
            [np.nan, np.inf, -1.0, 1e30], 20)
        d["density"] = dens
        if rng.random() < 0.5:
            d["starts"] = np.array([[np.nan, 0.0, np.inf]])
        if rng.random() < 0.3:
            w2i = d["w2i"].copy()
            w2i[rng.integers(3), rng.integers(4)] = rng.choice([np.nan, np.inf, 1e300])
            d["w2i"] = w2i
        kernels.trace_paths(PathInputs(**d))


@needs_c
def test_esc_stops_the_paths_between_chunks():
    inp, _ = cube_case(n_paths=200000)
    calls = []

    def esc():
        calls.append(1)
        return len(calls) > 2
    with pytest.raises(Cancelled):
        kernels.trace_paths(inp, threads=2, should_cancel=esc)
    assert len(calls) == 3                  # stopped at the first yes
    assert kernels.trace_paths(inp, threads=2, should_cancel=lambda: False).shape[-1] == 3


class _StopFirst:
    """kernels._c with its trace_paths called with the stop flag already set."""

    def __init__(self, c):
        self.c, self.calls = c, 0

    def __getattr__(self, name):
        return getattr(self.c, name)

    def trace_paths(self, *args):
        self.calls += 1
        self.args = args
        stop = args[-1]
        stop[0] = 1
        return self.c.trace_paths(*args)


@needs_c
def test_the_compiled_tracer_reads_the_stop_flag(monkeypatch):
    inp, _ = cube_case(n_paths=5000)
    assert kernels.trace_paths(inp).any()
    proxy = _StopFirst(kernels._c)
    monkeypatch.setattr(kernels, "_c", proxy)
    out = kernels.trace_paths(inp)          # the flag set before any path: none traced
    assert proxy.calls == 1 and not out.any()
    # how many paths it traces between reads of the flag, as the module states it (the
    # robustness report quotes it)
    assert isinstance(proxy.c.STOP_EVERY, int) and 1 <= proxy.c.STOP_EVERY <= 256
    for bad in (np.zeros(0, np.uint8), np.zeros(1, np.float32), np.zeros((1, 1), np.uint8)):
        with pytest.raises(ValueError, match="stop"):
            proxy.c.trace_paths(*proxy.args[:-1], bad)


@needs_c
@pytest.mark.parametrize("blocks, threads", [(1, 1), (4, 2)])
def test_esc_stops_a_long_call_of_the_tracer(monkeypatch, blocks, threads):
    """One compiled call per block (no chunks to stop between): Esc at the first poll still
    ends the running calls within a few paths, far sooner than the trace would take (without
    the stop flag, the running blocks would finish: the whole trace, or half of it)."""
    monkeypatch.setattr(kernels, "PATH_CHUNK", 1 << 30)
    monkeypatch.setattr(kernels, "PATH_BLOCKS", blocks)
    inp, _ = cube_case(n_paths=150000, sigma_t=6.0)
    t0 = time.perf_counter()
    kernels.trace_paths(inp, threads=threads)
    whole = time.perf_counter() - t0
    t0 = time.perf_counter()
    with pytest.raises(Cancelled):
        kernels.trace_paths(inp, threads=threads, should_cancel=lambda: True)
    stopped = time.perf_counter() - t0
    assert whole > 0.1, whole               # a trace long enough to measure the stop in
    assert stopped < 0.2 * whole, (stopped, whole)


def small_cube_under_a_sun():
    """(camera, sun, i2w) of a 2 m cube of 16^3 voxels at the origin, seen from 5 m above."""
    from mpp_render.scene import Camera, Light
    cam = Camera("PERSP", np.eye(4), 4, 4, (-1, 1, -1, 1))
    cam.cam_to_world[:3, 3] = [0.0, 0.0, 5.0]
    sun = Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.3, 0.2, -0.93]))
    i2w = np.eye(4)
    i2w[:3, :3] *= 2.0 / 16
    i2w[:3, 3] = -1.0 + 1.0 / 16
    return cam, sun, i2w


def test_a_medium_too_dense_for_paths_keeps_the_walk():
    """Optical size beyond paths.PATHS_MAX_SPAN: the precompute keeps the walk (on the medium
    itself, since the layout has no forward-peak channels with paths on) and the multiply
    scattered light is there, finite; a thinner medium is traced."""
    from mpp_render.media import prepare
    from mpp_render.precompute import precompute
    from mpp_render.scene import Medium, World
    cam, sun, i2w = small_cube_under_a_sun()
    for sigma, traced in ((700.0, False), (5.0, True)):   # 2400 and 17 along the diagonal
        pm = prepare(Medium("m", np.ones((16, 16, 16), np.float32), i2w, np.full(3, 0.9 * sigma),
                            np.full(3, 0.1 * sigma), 0.6))
        pre = precompute([pm], [sun], World(), cam, multiple=True, multiple_paths=20000,
                         multiple_resolution=8)
        msf = pre.multiple[0][0]
        assert msf.traced == traced and pre.layout.beam_channels is None
        assert all(np.all(np.isfinite(lev)) for lev in msf.levels)
        assert max(float(lev.max()) for lev in msf.levels) > 0.0


def test_more_paths_reach_a_small_medium(monkeypatch):
    """lightpaths.path_budget: a medium whose lattice holds few points takes at most
    PATHS_PER_POINT paths a point at the default Paths, and more Paths raise that cap in
    proportion (below the default the cap stays; Paths still caps the total), so that an
    artist's larger Paths adds paths to a small VDB too; the precompute traces what it gives."""
    from mpp_render.media import prepare
    from mpp_render.precompute import lightpaths, precompute
    from mpp_render.scene import MULTIPLE_PATHS, Medium, World
    budget, per = lightpaths.path_budget, lightpaths.PATHS_PER_POINT
    assert budget(MULTIPLE_PATHS, 20_000) == per * 20_000
    assert budget(4 * MULTIPLE_PATHS, 20_000) == 4 * per * 20_000
    assert budget(MULTIPLE_PATHS // 4, 20_000) == per * 20_000
    assert budget(MULTIPLE_PATHS // 4, 5_000) == per * 5_000
    assert budget(MULTIPLE_PATHS, 10 ** 6) == MULTIPLE_PATHS
    asked = [budget(n, 30_000) for n in (10 ** 5, 10 ** 6, 3 * 10 ** 6, 6 * 10 ** 6, 2 * 10 ** 7)]
    assert asked == sorted(asked) and asked[-1] > asked[2]
    # a part of the Paths asked (the fog glow's deficit paths) keeps the setting's factor
    assert budget(MULTIPLE_PATHS // 2, 20_000, 4 * MULTIPLE_PATHS) == MULTIPLE_PATHS // 2
    assert budget(MULTIPLE_PATHS // 2, 20_000) == per * 20_000
    traced = []
    real = lightpaths._trace_all

    def counting(sets, n_paths, *a, **k):
        traced.append(n_paths)
        return real(sets, n_paths, *a, **k)
    monkeypatch.setattr(lightpaths, "_trace_all", counting)
    cam, sun, i2w = small_cube_under_a_sun()
    pm = prepare(Medium("m", np.ones((16, 16, 16), np.float32), i2w, np.full(3, 4.5),
                        np.full(3, 0.5), 0.6))
    for n in (MULTIPLE_PATHS, 4 * MULTIPLE_PATHS):
        precompute([pm], [sun], World(), cam, multiple=True, multiple_paths=n,
                   multiple_resolution=8)
    assert len(traced) == 2 and traced[1] == 4 * traced[0] and traced[0] < MULTIPLE_PATHS


def test_the_paths_lattice_counts_the_voxels_not_their_padding():
    """precompute.lattice.paths_lattice: at most Resolution points along the medium's longest
    side of voxels, its one-voxel padding left out (walk_lattice counts it: a mesh volume of
    128 voxels, 130 padded, got stride 3 and 44 points at Resolution 64), never finer than
    the voxels."""
    from mpp_render.media import prepare
    from mpp_render.precompute.lattice import paths_lattice, walk_lattice
    from mpp_render.scene import Medium

    def medium(shape):
        i2w = np.eye(4)
        i2w[:3, :3] *= 0.05
        return prepare(Medium("m", np.ones(shape, np.float32), i2w, np.ones(3), np.zeros(3), 0.0))
    mesh = medium((128, 52, 52))
    assert walk_lattice(mesh, 64)[0] == 3
    stride, shape, h = paths_lattice(mesh, 64)
    assert stride == 2 and max(shape) >= 64 and h == pytest.approx(0.1)
    assert paths_lattice(medium((82, 82, 58)), 64)[0] == 2     # 41 points: at most 64
    assert paths_lattice(medium((60, 60, 60)), 64)[0] == 1
    assert paths_lattice(medium((128, 128, 128)), 128)[0] == 1
    assert paths_lattice(medium((3, 3, 3)), 64)[0] == 1


def emitter_lights():
    """An area light (1 m square at z = 0.6 m, facing down) and a sphere lamp (radius 0.3 m
    at the cube's centre) over cube_case's grid."""
    from mpp_render.scene import Light
    m = np.eye(4)
    m[:3, 3] = [0.0, 0.0, 0.6]
    area = Light("AREA", "a", np.full(3, 50.0), matrix=m, direction=np.array([0.0, 0.0, -1.0]),
                 shape="SQUARE", size_x=1.0, size_y=1.0)
    lamp = Light("POINT", "p", np.full(3, 50.0), position=np.zeros(3), radius=0.3)
    return area, lamp


@pytest.mark.parametrize("which", [0, 1])
def test_starts_draw_the_light_from_its_emitter_and_the_twins_agree(which):
    """With the light's record (lightpaths.start_light) each path's first direction is turned
    about the light drawn from the emitter at its start: the twins agree to 1e-9, and with
    g 0.7 the deposits differ from those about the lattice point's one direction."""
    from mpp_render.lights import pack_light
    from mpp_render.precompute.lightpaths import start_light
    light = emitter_lights()[which]
    inp, pts = cube_case(n=24, g=0.7, n_paths=3000, light=(0.05, -0.1, 0.25))
    starts = np.array([[0.05, -0.1, 0.25], [-0.3, 0.2, -0.1], [0.3, 0.3, 0.4]])
    w, cdf = from_power(np.ones((3, 3)))
    dirs = np.tile([0.0, 0.0, -1.0], (3, 1))
    inp = dataclasses.replace(inp, starts=starts, weights=w, cdf=cdf, dirs=dirs,
                              light=start_light(light))
    np.testing.assert_array_equal(inp.light, pack_light(light))
    _, b = path_twins(inp)
    plain = kernels.trace_paths(dataclasses.replace(inp, light=None), threads=2)
    assert np.abs(plain - b).max() > 1e-3 * np.abs(b).max()
    # a record of the wrong size is refused
    with pytest.raises(ValueError, match="light"):
        kernels.trace_paths(dataclasses.replace(inp, light=np.zeros(5)), threads=1)
    # the emitter point drawn among its candidates by their stretched transmittance
    # (start_rate): the twins agree, a rate of 0 is the draw without it, and a dense rate
    # changes the deposits
    rated = dataclasses.replace(inp, start_rate=np.array([8.0, 0.0, 3.0]))
    _, rb = path_twins(rated)
    assert np.abs(rb - b).max() > 1e-3 * np.abs(b).max()
    zero = kernels.trace_paths(dataclasses.replace(inp, start_rate=np.zeros(3)), threads=2)
    np.testing.assert_array_equal(zero, b)
    for bad in (np.array([1.0, -1.0, 0.0]), np.array([1.0, np.nan, 0.0]), np.ones(2)):
        with pytest.raises(ValueError, match="start_rate"):
            kernels.trace_paths(dataclasses.replace(inp, start_rate=bad), threads=1)


def test_the_sun_keeps_its_one_direction():
    from mpp_render.precompute.lightpaths import start_light
    from mpp_render.scene import Light
    assert start_light(Light("SUN", "s", np.ones(3))) is None
    assert start_light(emitter_lights()[1]) is not None


@needs_c
def test_the_estimate_does_not_depend_on_the_tentative_rate():
    """The deposits are the track-length estimate at any rate mu at or above the majorant
    (paths.py): fewer tentative points per lattice spacing (Tuning.path_deposits) change
    the noise, not the mean.  A cube of majorant 2 /m on a lattice of 1/h = 10 /m, traced at
    the majorant, at half and at the whole 1/h and at 2.5/h: the total and each half of the
    lattice (towards and away from the light) agree within 4 standard errors over 4 seeds;
    a deposit weighed by 1 / (1/h) whatever the rate would be off by 2-5x."""
    base, _ = cube_case(n=32, n_paths=20000)
    h = base.stride * base.i2w[0, 0]

    def regions(rate):
        got = []
        for seed in range(4):
            m = kernels.trace_paths(dataclasses.replace(base, rate=rate, seed=seed), threads=2)
            lx = m.shape[0] // 2
            got.append([m.sum(), m[:lx].sum(), m[lx:].sum()])
        got = np.asarray(got)
        return got.mean(axis=0), got.std(axis=0, ddof=1) / np.sqrt(len(got))

    ref, ref_se = regions(1.0 / h)
    majorant = float(np.max(base.sigma_t))   # density 1
    for rate in (majorant * 1.0001, 0.5 / h, 2.5 / h):
        mean, se = regions(rate)
        print(f"rate {rate:.2f}: {np.round(mean / ref, 4)} (se {np.round(se / ref, 4)})")
        assert np.all(np.abs(mean - ref) <= 4.0 * np.hypot(se, ref_se)), (rate, mean, ref)
