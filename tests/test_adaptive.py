"""Adaptive sampling (tiles.FrameMarch.tile, Settings.noise_threshold, pilot.py): a pixel stops
taking samples once its noise is below the threshold; a pixel the pilot finds nothing noisy
around stops after one sample; the threshold means the same at any exposure; a lower
threshold buys more samples; 0 turns it off; the rounds take each pixel's samples in an
order whose prefixes stay stratified."""
import dataclasses

import numpy as np
import pytest

from mpp_render import pilot, tiles
from mpp_render.render import render
from mpp_render.pixelsamples import PixelSamples
from mpp_render.tiles import Accumulator, sample_order

from test_cache import scene


def variant(desc, **settings):
    return dataclasses.replace(desc, settings=dataclasses.replace(desc.settings, **settings))


def base(**kw):
    desc = scene(**kw)
    desc.settings = dataclasses.replace(desc.settings, samples=16, multiple_paths=20000)
    return desc


def test_threshold_zero_takes_every_sample_and_a_quiet_frame_stops_at_the_first_round():
    desc = base()
    assert render(variant(desc, noise_threshold=0.0)).stats["pixel_samples"] == 16
    # the camera turned away from everything: only the constant sky, no noise at all
    away = base()
    away.camera.cam_to_world[:3, :3] = np.diag([1.0, -1.0, -1.0])   # looking up, +Z
    away.surfaces = []
    out = render(variant(away, noise_threshold=0.01))
    assert out.stats["pixel_samples"] == 1           # the pilot saw no noise anywhere
    # and the tiles were cut for one ray a pixel: the 40 x 30 frame is one tile (16 x 16
    # tiles, six of them, at 16 samples in every pixel)
    assert out.stats["tiles"] == 1
    assert render(variant(away, noise_threshold=0.0)).stats["tiles"] == 6
    np.testing.assert_allclose(out.passes["Combined"][..., :3],
                               np.broadcast_to(away.world.color, (30, 40, 3)), rtol=1e-6)
    clear = render(variant(away, noise_threshold=0.01, film_transparent=True)).passes["Combined"]
    assert np.all(clear[..., 3] == 0.0) and np.all(clear[..., :3] == 0.0)   # nothing in front


def test_a_lower_threshold_takes_more_samples_and_no_worse_an_image():
    """With the ground's light gathered by every sample (Surface Light Cache off, the
    estimator whose noise adaptive sampling weighs): more samples where the threshold is
    lower, and at 0.02 within 10 % of every pixel's 16.  With the cache, the same threshold
    takes fewer samples for the same error (the gathers' noise is gone from the ground)."""
    desc = base()
    # an independent reference: other seeds for the paths and the pixels
    ref = render(variant(desc, samples=256, noise_threshold=0.0, seed=5,
                         multiple_paths=320000, surface_cache=False)).passes["Combined"][..., :3]

    def run(th, cache):
        out = render(variant(desc, noise_threshold=th, surface_cache=cache))
        err = float(np.sqrt(np.mean((out.passes["Combined"][..., :3] - ref) ** 2)))
        return out.stats["pixel_samples"], err
    got = [run(th, False) for th in (0.2, 0.02, 0.0)]
    spp = [g[0] for g in got]
    assert 1 <= spp[0] < spp[1] < spp[2] == 16
    assert got[0][1] > got[2][1]                      # more samples, closer to the converged
    assert got[1][1] < 1.1 * got[2][1]                # the threshold holds the error
    cached = run(0.02, True)
    print("threshold 0.02: per-sample gathers", got[1], "the cache", cached)
    assert cached[0] < 0.6 * got[1][0]                # measured 3.98 against 9.20 samples
    assert cached[1] < 1.05 * got[1][1]               # measured 1.016x


def test_the_noise_is_the_standard_error_over_the_root_of_the_mean():
    acc = Accumulator(2, {"Combined": None})
    # pixel 0: samples 1, 3 (mean 2, sample variance 2); pixel 1: constant 5
    vals = np.array([1.0, 3.0, 5.0, 5.0])
    r = {"single": np.repeat(vals[:, None], 3, 1), "multiple": np.zeros((4, 3)),
         "emission": np.zeros((4, 3)), "T": np.zeros((4, 3)), "depth": np.full(4, 1e10)}
    acc.add(np.arange(2), 2, r, np.zeros(4, bool), np.zeros((4, 3)), False)
    noise = acc.noise(np.arange(2))
    np.testing.assert_allclose(noise, [np.sqrt(2.0 / 2) / np.sqrt(2.0 + 1e-4), 0.0])
    # in units of a frame's mean luminance S: sqrt((I + 1e-4 S) S)
    np.testing.assert_allclose(acc.noise(np.arange(2), 4.0),
                               [np.sqrt(2.0 / 2) / np.sqrt((2.0 + 4e-4) * 4.0), 0.0])
    np.testing.assert_allclose(acc.passes(False)["Combined"][:, :3], [[2.0] * 3, [5.0] * 3])


def test_a_noisy_pixel_keeps_its_neighbours_sampling():
    acc = Accumulator(9, {"Combined": None})
    vals = np.full((9, 2), 5.0)
    vals[4] = (1.0, 3.0)                              # the centre of a 3 x 3 tile is noisy
    r = {"single": np.repeat(vals.reshape(-1, 1), 3, 1), "multiple": np.zeros((18, 3)),
         "emission": np.zeros((18, 3)), "T": np.zeros((18, 3)), "depth": np.full(18, 1e10)}
    acc.add(np.arange(9), 2, r, np.zeros(18, bool), np.zeros((18, 3)), False)
    assert tiles.noisy_pixels(acc, np.arange(9), 0.01, 3, 3).tolist() == list(range(9))
    assert tiles.noisy_pixels(acc, np.array([0, 1, 2]), 0.01, 3, 3).tolist() == []


def test_every_round_prefix_is_stratified_over_the_pixel_and_the_gather_bands():
    order = sample_order(16)
    assert sorted(order.tolist()) == list(range(16))
    draws = PixelSamples(16, 50, 3, order)
    offs = draws.offsets(np.arange(50), np.arange(16))
    bands = np.concatenate([draws.bands(np.arange(50), np.arange(16)),
                            draws.step_bands(np.arange(50), np.arange(16))[None]])
    assert len({tuple(bands[d].ravel()) for d in range(3)}) == 3   # each dimension its own
    for n, cells in ((4, 2), (16, 4)):
        first = offs[:, order[:n]]                     # (pixels, n, 2)
        cell = np.floor(first * cells).astype(int)
        for p in range(50):                            # one sample in each of n cells
            assert len({(a, b) for a, b in cell[p]}) == n
            for dim in range(3):                       # and in each of n equal bands
                assert len(set((bands[dim, p, order[:n]] * n // 16).tolist())) == n
    # unbiased: the first 4 samples are spread uniformly over the pixel
    big = PixelSamples(16, 20000, 4, order).offsets(np.arange(20000), order[:4])
    assert abs(big.mean() - 0.5) < 0.01
    assert np.histogram(big[..., 0], bins=8, range=(0, 1))[0].min() > 0.9 * 20000 * 4 / 8


@pytest.mark.parametrize("spp", [1, 4, 9, 16, 6])
def test_each_pixel_draws_its_own_offsets(spp):
    """No two pixels of a tile share their samples' places: a row of pixels straddling an
    edge would be all bright or all dark together (p_area_in_box's lamp, 50 %, 4 spp)."""
    offs = PixelSamples(spp, 4000, 7).offsets(np.arange(4000), np.arange(spp))
    assert offs.shape == (4000, spp, 2) and offs.min() >= 0.0 and offs.max() < 1.0
    first = offs[:, 0, 1]
    assert len(np.unique(first)) == 4000
    # neighbouring pixels' offsets are uncorrelated, and each is uniform over the pixel
    assert abs(np.corrcoef(first[:-1], first[1:])[0, 1]) < 0.05
    assert abs(offs.mean() - 0.5) < 0.01
    k = int(round(np.sqrt(spp)))
    if k * k == spp:                                   # one sample in each stratum
        cells = np.floor(offs * k).astype(int)
        for p in range(0, 4000, 397):
            assert len({(a, b) for a, b in cells[p]}) == spp


def test_one_sample_renders_as_without_adaptive_sampling():
    desc = base()
    a = render(variant(desc, samples=1, noise_threshold=0.01))
    b = render(variant(desc, samples=1, noise_threshold=0.0))
    assert "pilot" not in a.timings                   # nothing to plan
    for k in a.passes:
        np.testing.assert_array_equal(a.passes[k], b.passes[k], err_msg=k)


def test_the_threshold_means_the_same_noise_at_any_exposure():
    """Every light and the sky 50x brighter: the same samples in the same pixels, the image
    50x brighter (Cycles' rule, se <= t sqrt(I), would sample the bright frame more)."""
    def lit(k):
        desc = base(world=(0.2 * k, 0.25 * k, 0.3 * k), power=150.0 * k)
        desc.lights[0] = dataclasses.replace(desc.lights[0], strength=desc.lights[0].strength * k)
        return render(variant(desc, noise_threshold=0.02))
    dim, bright = lit(1.0), lit(50.0)
    assert 1.0 < dim.stats["pixel_samples"] < 16.0
    assert bright.stats["pixel_samples"] == dim.stats["pixel_samples"]
    np.testing.assert_allclose(bright.passes["Combined"][..., :3],
                               50.0 * dim.passes["Combined"][..., :3], rtol=1e-6, atol=1e-9)


def test_the_plan_marks_the_noisy_cells_and_their_neighbours():
    # a 5 x 4 grid of cells of 3 x 3 pixels over a 14 x 11 frame (the last row and column
    # clipped); 4 samples each, luminance 1 everywhere, the cell in row 2, column 1 noisy
    shape, stride, W, H = (4, 5), 3, 14, 11
    n = np.full(20, 4.0)
    lum, lum2 = n * 1.0, n * 1.0
    lum2[2 * 5 + 1] = 4.0 * 1.01                      # one sample's variance 0.01 * 4 / 3
    plan = pilot.plan(lum, lum2, n, shape, 0.01, stride, W, H, samples=16, first=4)
    assert plan.more.shape == (H, W)
    # 19 cells take one sample, the noisy one (need 133) all 16: the tiles are cut for this
    np.testing.assert_allclose(plan.expected, (19 * 1 + 16) / 20)
    np.testing.assert_allclose(plan.scale, 1.0)
    want = np.zeros((H, W), bool)
    want[3:H, 0:9] = True                             # cells (1..3, 0..2)
    np.testing.assert_array_equal(plan.more, want)
    # the same variance 100x brighter (and its variance 10^4x): the same plan
    again = pilot.plan(100 * lum, 1e4 * lum2, n, shape, 0.01, stride, W, H)
    np.testing.assert_array_equal(again.more, want)
    # a non-finite cell (a kernel's failure, reported elsewhere) leaves the scale finite
    bad = lum.copy()
    bad[0] = np.nan
    np.testing.assert_allclose(pilot.plan(bad, lum2, n, shape, 0.01, stride, W, H).scale, 1.0)
    dark = pilot.plan(0 * lum, 0 * lum2, n, shape, 0.01, stride, W, H)   # a black frame
    assert dark.scale > 0.0 and not dark.more.any()
    # below the threshold: nothing marked
    quiet = pilot.plan(lum, lum2, n, shape, 1.0, stride, W, H)
    assert not quiet.more.any()


def test_the_pilot_looks_at_one_pixel_of_each_cell():
    (gh, gw), x, y = pilot.grid(10, 7, 4)
    assert (gh, gw) == (2, 3)
    assert x.tolist() == [2, 6, 9, 2, 6, 9] and y.tolist() == [2, 2, 2, 6, 6, 6]
    offs = pilot.offsets(4, 1000, np.random.default_rng(1))
    assert offs.min() >= 0.0 and offs.max() < 1.0
    rows = np.floor(offs[..., 1] * 4).astype(int)
    assert all(sorted(r) == [0, 1, 2, 3] for r in rows)   # one sample in each row


def test_an_outlier_and_its_neighbours_take_more_samples_and_a_gradient_does_not():
    th, tw = 6, 7
    y, x = np.mgrid[0:th, 0:tw]
    ramp = 1.0 + 0.1 * x + 0.05 * y                   # a smooth gradient: no outlier
    assert not pilot.outliers(ramp.ravel(), tw, th, 1.0, 0.01).any()
    spike = ramp.copy()
    spike[2, 3] += 0.5                                # one sample far off its neighbours'
    odd = pilot.outliers(spike.ravel(), tw, th, 1.0, 0.01).reshape(th, tw)
    assert odd[2, 3] and odd.sum() <= 9
    grown = pilot.grow(odd)
    assert grown[1:4, 2:5].all()
    # the same spike 1000x brighter everywhere: the same pixels (the threshold's own unit)
    np.testing.assert_array_equal(
        pilot.outliers(1000 * spike.ravel(), tw, th, 1000.0, 0.01).reshape(th, tw), odd)
    # a spike within the threshold's allowance is no outlier
    small = ramp.copy()
    small[2, 3] += 0.001
    assert not pilot.outliers(small.ravel(), tw, th, 1.0, 0.1).any()


def test_the_halves_read_independent_samples_as_they_are_and_credit_stratified_ones():
    """pilot.stratified_gain: about 1 for independent samples; for samples stratified as
    the rounds take them (sample p in stratum bitreverse(p)) of a smooth integrand, well
    below 1 yet above the true ratio of the mean's variance to var / n (conservative: the
    halves stand for the coarser strata); 1 where too few pixels are noisy."""
    rng = np.random.default_rng(7)
    p, n = 4000, 8
    iid = rng.random((p, n))
    g_iid = pilot.stratified_gain(iid)
    assert 0.9 < g_iid <= 1.0, g_iid
    rev = tiles.reverse_bits(np.arange(n), 3)
    strat = (rev[None, :] + rng.random((p, n))) / n          # f(u) = u, stratified
    g = pilot.stratified_gain(strat)
    true_ratio = strat.mean(axis=1).var() / (iid.var() / n)
    print("gain", g, "true ratio", true_ratio)
    assert true_ratio < g < 0.5, (g, true_ratio)
    few = np.zeros((p, n))
    few[:pilot.GAIN_PIXELS - 1] = iid[:pilot.GAIN_PIXELS - 1]
    assert pilot.stratified_gain(few) == 1.0


def test_a_tile_keeps_its_samples_luminance_by_the_place_taken():
    """Accumulator keeps each sample's luminance where it was taken (``start``), and its
    noise is the independent estimate times sqrt(gain)."""
    acc = Accumulator(20, {}, samples=4)
    rng = np.random.default_rng(2)
    lums = rng.random((20, 4))
    for start, k in ((0, 1), (1, 3)):
        v = np.repeat(lums[:, start:start + k].reshape(-1, 1), 3, axis=1)
        r = {"single": v, "multiple": 0 * v, "emission": 0 * v, "T": np.ones_like(v),
             "depth": np.full(len(v), 1e10)}
        acc.add(np.arange(20), k, r, np.zeros(len(v), bool), 0 * v, False, start)
    assert np.allclose(acc.taken, lums)
    px = np.arange(20)
    plain = pilot.relative_noise(acc.lum[px], acc.lum2[px], acc.count[px], 1.0)
    gain = pilot.stratified_gain(lums)
    assert np.allclose(acc.noise(px, 1.0), plain * np.sqrt(gain))


@pytest.mark.parametrize("spp, adaptive", [(16, True), (16, False), (6, False), (9, True)])
def test_a_sample_is_drawn_the_same_whichever_round_takes_it(spp, adaptive):
    """PixelSamples draws sample s of pixel p from (tile, p, s) alone: asked for a few
    pixels and samples, or all at once, the same offsets, lens points and gather bands; the
    bands of a pixel are a permutation of 0 .. spp - 1 (a Latin hypercube)."""
    order = sample_order(spp) if adaptive else None
    draws = PixelSamples(spp, 300, 11, order)
    every = np.arange(300), np.arange(spp)
    offs, lens, bands = draws.offsets(*every), draws.lens(*every), draws.bands(*every)
    steps = draws.step_bands(*every)
    some_p, some_s = np.array([5, 17, 299]), np.array([spp - 1, 0, 2])
    np.testing.assert_array_equal(draws.step_bands(some_p, some_s), steps[some_p][:, some_s])
    assert np.all(np.sort(steps, axis=1) == np.arange(spp))
    assert not np.array_equal(steps, bands[0]) and not np.array_equal(steps, bands[1])
    keys = draws.pixel_keys(np.arange(300))
    assert keys.dtype == np.uint32 and len(np.unique(keys)) == 300
    np.testing.assert_array_equal(draws.pixel_keys(some_p), keys[some_p])
    np.testing.assert_array_equal(draws.offsets(some_p, some_s), offs[some_p][:, some_s])
    np.testing.assert_array_equal(draws.lens(some_p, some_s), lens[some_p][:, some_s])
    np.testing.assert_array_equal(draws.bands(some_p, some_s), bands[:, some_p][:, :, some_s])
    for dim in (0, 1):
        assert np.all(np.sort(bands[dim], axis=1) == np.arange(spp))
    assert lens.min() >= 0.0 and lens.max() < 1.0 and abs(lens.mean() - 0.5) < 0.02
    other = PixelSamples(spp, 300, 12, order).offsets(*every)
    assert not np.array_equal(other, offs)          # another tile, other draws


def test_a_tile_holds_the_rays_of_its_march_samples_budget_within_its_bounds():
    assert tiles.tile_rays(None, 4096, 16384, 4e5) == 4096        # no pilot: the least
    assert tiles.tile_rays(0.0, 4096, 16384, 4e5) == 16384        # nothing to march
    assert tiles.tile_rays(40.0, 4096, 16384, 4e5) == 10000       # 4e5 samples / 40 a ray
    assert tiles.tile_rays(1.0, 4096, 16384, 4e5) == 16384
    assert tiles.tile_rays(1e4, 4096, 16384, 4e5) == 4096
    got = [tiles.tile_rays(s, 4096, 16384, 4e5) for s in np.geomspace(1, 1e3, 40)]
    assert all(a >= b for a, b in zip(got, got[1:]))               # dearer rays, smaller tiles


def test_the_pilot_counts_its_gathers_samples_and_dearer_rays_cut_more_tiles():
    from mpp_render.tiles import FrameMarch
    desc = base()
    seen = []
    orig = FrameMarch.pilot_cost

    def spy(chunks):
        seen.append((sum(c[4] for c in chunks), sum(c[5] for c in chunks)))
        return orig(chunks)

    FrameMarch.pilot_cost = staticmethod(spy)
    try:
        with_ground = render(variant(desc, noise_threshold=0.02, surface_cache=False))
        bare = base()
        bare.surfaces = []
        render(variant(bare, noise_threshold=0.02))
        render(variant(desc, noise_threshold=0.02))   # the ground reads the surface cache
    finally:
        FrameMarch.pilot_cost = staticmethod(orig)
    (cam_g, gath_g), (cam_b, gath_b), (cam_c, gath_c) = seen
    assert cam_g > 0 and gath_g > 0          # the ground's gathers march through the cloud
    assert cam_b > 0 and gath_b == 0         # no surface, no gather
    assert cam_c > 0 and gath_c < 0.1 * gath_g   # the cache gathered before the pilot
    # a budget of a few samples a tile: the least rays a tile (4096 would be one tile)
    tun = desc.settings.tuning
    small = render(variant(desc, noise_threshold=0.02, tuning=dataclasses.replace(
        tun, tile_samples=1.0, tile_rays=64, tile_rays_most=16384)))
    large = render(variant(desc, noise_threshold=0.02, tuning=dataclasses.replace(
        tun, tile_samples=1e12, tile_rays=64, tile_rays_most=16384)))
    assert small.stats["tiles"] > large.stats["tiles"] == 1
    assert with_ground.stats["tiles"] == 1   # 40 x 30 pixels: one tile of the default's
