"""The pilot of adaptive sampling: a sparse, cheap look at a frame's noise before its tiles.

Adaptive sampling (tiles.FrameMarch.tile) stops a pixel once the standard error of its mean
luminance is below the Noise Threshold t in the frame's own unit of brightness:

    se <= t * sqrt((I + NOISE_FLOOR * S) * S)

with I the pixel's mean luminance (the mean of its RGB radiance, W/(m^2 sr)) and S the frame's
mean luminance.  Over a frame whose pixels all meet it, the root-mean-square noise is at
most t * S: t is the relative noise the image keeps, the same at any exposure and in a dim
fog as in a bright cloud (Cycles' own rule, se <= t sqrt(I), lets a dim frame keep ten times
the relative noise of one a hundred times brighter; docs/adaptive.md).

S and the noise have to be known before the tiles run, and a pixel's variance needs two
samples at least.  So the pilot marches ``Tuning.pilot_samples`` samples in one pixel of
every ``Tuning.pilot_stride`` x ``Tuning.pilot_stride`` cell of the frame (its own random
stream; its samples are not kept in the image).  From them: S, and each cell's need, the
variance of one sample over the threshold's allowance.  Every pixel of the frame then takes
one sample.  A pixel takes the adaptive first round (``Tuning.adaptive_first``) and goes on
by its own variance when its cell or a neighbouring cell (3 x 3) needs more than one sample,
or when it or a neighbour is an outlier: its one sample further from the mean of its
neighbours' (in its tile) than the threshold allows one sample's noise to be (``outliers``).
The pilot sees a few pixels' spread; the outliers catch what it misses between them: a rare
bright path (a firefly) and an edge the pixel straddles.

In the rounds a pixel's noise is its samples' spread read as independent samples' times the
stratification's gain of its tile (``stratified_gain``): the samples are stratified, and
their mean varies less than var / n (a ground's gathered and direct light: 0.37 times).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

NOISE_FLOOR = 1e-4   # the threshold's allowance at I = 0, in units of S (as Cycles' 1e-4)
PILOT_SEED = 0x27D4EB2F  # offsets the seed of the pilot's rays
PILOT_TILE = 1 << 24     # offsets the pilot's chunks from the tiles in their gathers' streams


@dataclass
class SamplePlan:
    """What the pilot found: ``scale`` S (W/(m^2 sr), the frame's mean luminance, > 0),
    ``more`` ((H, W) bool), the pixels that take the adaptive first round after their first
    sample, and ``expected``, the samples a pixel is expected to take (the mean over the
    cells of what each needs, in the rounds' steps: 1, the first round, its doublings)."""

    scale: float
    more: np.ndarray
    expected: float = 1.0


def relative_noise(lum, lum2, count, scale: float) -> np.ndarray:
    """The standard error of each pixel's mean luminance from the sums of its samples'
    luminance ``lum``, their squares ``lum2`` and their ``count`` (at least 2), over the
    threshold's unit sqrt((I + NOISE_FLOOR S) S) with S = ``scale``."""
    n = np.asarray(count, np.float64)
    return np.sqrt(mean_variance(lum, lum2, n)) / np.sqrt(
        (np.maximum(lum / n, 0.0) + NOISE_FLOOR * scale) * scale)


def mean_variance(lum, lum2, count) -> np.ndarray:
    """The variance of each pixel's mean luminance, its samples read as independent: their
    variance (ddof 1) over their ``count``, from the sums ``lum`` and ``lum2``."""
    n = np.asarray(count, np.float64)
    mean = lum / n
    return np.maximum(lum2 / n - mean * mean, 0.0) / np.maximum(n - 1, 1)


# pixels with noise the halves must see before their gain is read (else 1)
GAIN_PIXELS = 16


def stratified_gain(taken) -> float:
    """What a tile's pixels' noise is, over what their samples' spread reads it as when
    taken for independent: at most 1.

    A pixel's samples are stratified (their places in the pixel, the surfaces' gathering
    bands: pixelsamples.PixelSamples; the first 2^m taken one in each of 2^m
    strata), and the mean of stratified samples varies less than var / n.  Each half of a
    pixel's samples as taken (``taken`` (P, n): each sample's luminance in the order taken,
    the first n/2 and the rest, each itself stratified) estimates the mean apart, so
    (A - B)^2 h (n - h) / n^2 (h = n // 2) estimates the variance of the whole mean with the
    stratification's gain in it (for independent samples it is the usual estimate's, and
    the finer strata of the whole make it an upper bound).  One pixel's is a single degree of
    freedom, so the gain is read over the tile: the sum over its pixels of that estimate
    over the sum of the independent one (``mean_variance``), weighted so by the noisiest
    pixels; 1 where fewer than GAIN_PIXELS pixels are noisy at all.  On a ground under an area light in fog (p_fog_area, its surfaces'
    light) the mean of 8 stratified samples varies 0.37 times as much as var / 8."""
    taken = np.asarray(taken, np.float64)
    n = taken.shape[1]
    h = n // 2
    a, b = taken[:, :h].mean(axis=1), taken[:, h:].mean(axis=1)
    halves = (a - b) ** 2 * h * (n - h) / (n * n)
    iid = mean_variance(taken.sum(axis=1), (taken * taken).sum(axis=1), n)
    live = iid > 0.0
    if np.count_nonzero(live) < GAIN_PIXELS or not np.isfinite(halves[live].sum()):
        return 1.0
    return float(min(1.0, halves[live].sum() / iid[live].sum()))


def grid(width: int, height: int, stride: int):
    """The pilot's pixels: ((gh, gw) cells of ``stride`` x ``stride`` pixels, the frame
    clipped; x and y (pixels, the cell's middle pixel, within the frame) of each, row-major)."""
    gw, gh = math.ceil(width / stride), math.ceil(height / stride)
    cx = np.minimum(np.arange(gw) * stride + stride // 2, width - 1)
    cy = np.minimum(np.arange(gh) * stride + stride // 2, height - 1)
    yy, xx = np.meshgrid(cy, cx, indexing="ij")
    return (gh, gw), xx.ravel(), yy.ravel()


def offsets(samples: int, n: int, rng) -> np.ndarray:
    """(n, samples, 2) places of each pilot pixel's samples in the pixel: one in each of
    ``samples`` equal rows, jittered (the pilot sees a pixel's spread, not its middle)."""
    rows = (np.arange(samples) + rng.random((n, samples))) / samples
    return np.stack([rng.random((n, samples)), rows], -1)


def plan(lum, lum2, count, shape, threshold: float, stride: int, width: int,
         height: int, samples: int = 16, first: int = 4) -> SamplePlan:
    """The frame's SamplePlan from the pilot's per-cell sums (``lum``, ``lum2``, ``count``,
    row-major over ``shape`` = (gh, gw)) at Noise Threshold ``threshold``, for at most
    ``samples`` a pixel and a first round of ``first``."""
    mean = lum / count
    seen = np.isfinite(mean)          # a non-finite sample is the march's report, not noise
    scale = float(mean[seen].mean()) if seen.any() else 0.0
    scale = scale if scale > 1e-12 else 1e-12
    # one sample's variance over the threshold's allowance: the samples a cell needs
    need = (relative_noise(lum, lum2, count, scale) / threshold) ** 2 * count
    grown = grow((need > 1.0).reshape(shape))   # a cell beside a noisy one: noisy too
    more = np.repeat(np.repeat(grown, stride, axis=0), stride, axis=1)[:height, :width]
    rounds = np.maximum(first, 2.0 ** np.ceil(np.log2(np.maximum(need, 1.0))))
    takes = np.where(need > 1.0, np.minimum(rounds, samples), 1.0)
    return SamplePlan(scale, np.ascontiguousarray(more), float(takes.mean()))


def grow(mask: np.ndarray) -> np.ndarray:
    """``mask`` (2-D bool) or its 3 x 3 neighbours."""
    wide = mask.copy()
    wide[1:, :] |= mask[:-1, :]
    wide[:-1, :] |= mask[1:, :]
    out = wide.copy()
    out[:, 1:] |= wide[:, :-1]
    out[:, :-1] |= wide[:, 1:]
    return out


def outliers(values: np.ndarray, tw: int, th: int, scale: float, threshold: float) -> np.ndarray:
    """(th * tw,) bool, row-major: the pixels of a ``tw`` x ``th`` tile whose one sample's
    luminance ``values`` lies further from the mean m of its neighbours than one sample's
    noise may: (v - m)^2 / (1 + 1/k) > t^2 (m + NOISE_FLOOR S) S, S = ``scale``,
    t = ``threshold``.  The neighbours are the k = 2p pixels of the p opposite pairs
    (left-right, up-down, the two diagonals) that lie in the tile, so that a gradient cancels
    in m at the tile's border as inside it; for independent noise of variance s^2 the
    difference has variance s^2 (1 + 1/k).  A corner pixel (no pair) is judged by its
    neighbours' growth (``grow``)."""
    v = np.asarray(values, np.float64).reshape(th, tw)
    total = np.zeros_like(v)
    pairs = np.zeros_like(v)
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = np.full((th, tw), np.nan)    # the neighbour at (-dy, -dx) and at (+dy, +dx)
        b = np.full((th, tw), np.nan)
        a[max(dy, 0):th, max(dx, 0):tw + min(dx, 0)] = v[0:th - dy, max(-dx, 0):tw - max(dx, 0)]
        b[0:th - dy, max(-dx, 0):tw - max(dx, 0)] = v[max(dy, 0):th, max(dx, 0):tw + min(dx, 0)]
        both = np.isfinite(a) & np.isfinite(b)
        total += np.where(both, a + b, 0.0)
        pairs += both
    k = 2.0 * pairs
    m = total / np.maximum(k, 1.0)
    dev2 = (v - m) ** 2 / (1.0 + 1.0 / np.maximum(k, 1.0))
    allow = threshold ** 2 * (np.maximum(m, 0.0) + NOISE_FLOOR * scale) * scale
    return ((dev2 > allow) & (k > 0)).ravel()
