"""Adaptive sampling (tiles.FrameMarch.tile, Settings.noise_threshold): a pixel stops taking
samples once its noise is below the threshold; a pixel with nothing noisy in it stops after
the first round; a lower threshold buys more samples; 0 turns it off; the rounds take each
pixel's samples in an order whose prefixes stay stratified."""
import dataclasses

import numpy as np
import pytest

from mpp_render import tiles
from mpp_render.render import render
from mpp_render.tiles import Accumulator, gather_bands, pixel_offsets, sample_order

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
    assert out.stats["pixel_samples"] == away.settings.tuning.adaptive_first
    np.testing.assert_allclose(out.passes["Combined"][..., :3],
                               np.broadcast_to(away.world.color, (30, 40, 3)), rtol=1e-6)
    clear = render(variant(away, noise_threshold=0.01, film_transparent=True)).passes["Combined"]
    assert np.all(clear[..., 3] == 0.0) and np.all(clear[..., :3] == 0.0)   # nothing in front


def test_a_lower_threshold_takes_more_samples_and_no_worse_an_image():
    desc = base()
    # an independent reference: other seeds for the paths and the pixels
    ref = render(variant(desc, samples=256, noise_threshold=0.0, seed=5,
                         multiple_paths=320000)).passes["Combined"][..., :3]
    got = []
    for th in (0.2, 0.02, 0.0):
        out = render(variant(desc, noise_threshold=th))
        err = float(np.sqrt(np.mean((out.passes["Combined"][..., :3] - ref) ** 2)))
        got.append((out.stats["pixel_samples"], err))
    spp = [g[0] for g in got]
    assert 4 <= spp[0] < spp[1] < spp[2] == 16
    assert got[0][1] > got[2][1]                      # more samples, closer to the converged
    assert got[1][1] < 1.1 * got[2][1]                # the threshold holds the error


def test_the_noise_is_the_standard_error_over_the_root_of_the_mean():
    acc = Accumulator(2, {"Combined": None})
    # pixel 0: samples 1, 3 (mean 2, sample variance 2); pixel 1: constant 5
    vals = np.array([1.0, 3.0, 5.0, 5.0])
    r = {"single": np.repeat(vals[:, None], 3, 1), "multiple": np.zeros((4, 3)),
         "emission": np.zeros((4, 3)), "T": np.zeros((4, 3)), "depth": np.full(4, 1e10)}
    acc.add(np.arange(2), 2, r, np.zeros(4, bool), np.zeros((4, 3)), False)
    noise = acc.noise(np.arange(2))
    np.testing.assert_allclose(noise, [np.sqrt(2.0 / 2) / np.sqrt(2.0 + 1e-4), 0.0])
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
    rng = np.random.default_rng(3)
    order = sample_order(16)
    assert sorted(order.tolist()) == list(range(16))
    offs = pixel_offsets(16, 50, rng)
    bands = gather_bands(16, 50, rng, order)
    for n, cells in ((4, 2), (16, 4)):
        first = offs[:, order[:n]]                     # (pixels, n, 2)
        cell = np.floor(first * cells).astype(int)
        for p in range(50):                            # one sample in each of n cells
            assert len({(a, b) for a, b in cell[p]}) == n
            for dim in range(2):                       # and in each of n equal bands
                assert len(set((bands[dim, p, order[:n]] * n // 16).tolist())) == n
    # unbiased: the first 4 samples are spread uniformly over the pixel
    big = pixel_offsets(16, 20000, rng)[:, order[:4]]
    assert abs(big.mean() - 0.5) < 0.01
    assert np.histogram(big[..., 0], bins=8, range=(0, 1))[0].min() > 0.9 * 20000 * 4 / 8


@pytest.mark.parametrize("spp", [1, 4, 9, 16, 6])
def test_each_pixel_draws_its_own_offsets(spp):
    """No two pixels of a tile share their samples' places: a row of pixels straddling an
    edge would be all bright or all dark together (p_area_in_box's lamp, 50 %, 4 spp)."""
    offs = pixel_offsets(spp, 4000, np.random.default_rng(7))
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


def test_no_more_samples_than_the_first_round_renders_as_without_adaptive_sampling():
    desc = base()
    for spp in (1, 4):
        a = render(variant(desc, samples=spp, noise_threshold=0.01)).passes
        b = render(variant(desc, samples=spp, noise_threshold=0.0)).passes
        for k in a:
            np.testing.assert_array_equal(a[k], b[k], err_msg=f"{spp} {k}")
