"""Where a tile's pixel samples fall, drawn on demand (tiles.FrameMarch.tile).

Sample s of pixel p has its offset in the pixel square [0, 1)^2, its lens point and its
surface-gather bands from counter-based random numbers of (tile, p, s): the same numbers
whichever adaptive round takes the sample, and nothing drawn for the samples no round takes
(with adaptive sampling most pixels take one or two of their ``spp``).

* Offsets: on a k x k grid of strata when ``spp`` = k^2, jittered in each; with k a power of
  two, sample s in stratum (i, j) = divmod(s, k) XOR a random mask per pixel, so that
  tiles.sample_order's first 4^m samples are one in each cell of a 2^m x 2^m grid, each
  uniform in its cell; otherwise uniform.  Each pixel draws its own (offsets shared by a
  tile's pixels made their errors alike: a row straddling a lamp's bright edge all bright or
  all dark together).
* Gather bands (surfaces.shade's strata of r^2 and phi): with ``order`` (adaptive rounds) and
  ``spp`` a power of two, the sample taken t-th gets the band bitreverse(t) XOR a random mask
  per pixel and dimension, so the first 2^m samples taken hold one sample in each of 2^m
  equal bands; otherwise a random Latin hypercube per pixel (a permutation of the bands).
* Step strata (march.march_rays' ``jitter``): the same, in a dimension of their own: the
  sample's stratum of the march's steps, the part of a step its jittered point lies on
  (shuffled per step by the pixel's key, ``pixel_keys``: kernels_np.step_stratum), so that
  a pixel's samples read each step at points spread over it (the jitter's noise, the most
  of a dense medium's, falls faster than 1 / n in the samples taken).
"""
from __future__ import annotations

import functools
import math
from typing import Optional

import numpy as np

from .rng import hash32

_M32 = 0xFFFFFFFF
D_OFFSET, D_LENS, D_BAND, D_CELL_MASK, D_BAND_MASK = 0, 2, 4, 6, 8   # dimensions of the draws
D_STEP_BAND, D_STEP_MASK, D_STEP_KEY = 10, 11, 12


def power_of_two_side(spp: int) -> int:
    """k when ``spp`` = k^2 with k a power of two (the strata adaptive rounds spread), else 0."""
    k = int(round(math.sqrt(spp)))
    return k if k * k == spp and not k & (k - 1) else 0


def reverse_bits(values: np.ndarray, bits: int) -> np.ndarray:
    """``values`` (integers below 2^bits) with their ``bits`` low bits in reverse order."""
    out = np.zeros(len(values), np.int64)
    for b in range(bits):
        out |= ((values >> b) & 1) << (bits - 1 - b)
    return out


@functools.lru_cache(maxsize=64)
def _salt(dim: int) -> np.uint32:
    """The hash that salts dimension ``dim``'s draws (PixelSamples._bits)."""
    return np.uint32(hash32(np.uint32((dim * 0x9E3779B1 + 0x68E31DA4) & _M32)))


class PixelSamples:
    """The samples of ``npx`` pixels, ``spp`` each, of the tile whose draws ``key`` (uint32)
    seeds (module docstring); ``order``: the order adaptive rounds take a pixel's samples in
    (tiles.sample_order), or None."""

    def __init__(self, spp: int, npx: int, key: int, order: Optional[np.ndarray] = None):
        self.spp, self.npx = int(spp), int(npx)
        self.key = np.uint32(int(key) & _M32)
        k = int(round(math.sqrt(self.spp)))
        self.k = k if k * k == self.spp else 0
        pix = np.arange(self.npx, dtype=np.int64)
        self.cell_mask = None
        if power_of_two_side(self.spp):
            self.cell_mask = np.stack([self._bits(pix, 0, D_CELL_MASK + a) % k for a in (0, 1)],
                                      -1)                                    # (npx, 2)
        self.rank = None   # with adaptive rounds over a power of two: each sample's turn
        if order is not None and not self.spp & (self.spp - 1):
            self.rank = np.empty(self.spp, np.int64)
            self.rank[np.asarray(order)] = np.arange(self.spp)
            self.rev = reverse_bits(np.arange(self.spp), self.spp.bit_length() - 1)
            self.band_mask = np.stack([self._bits(pix, 0, D_BAND_MASK + a) % self.spp
                                       for a in (0, 1)])                     # (2, npx)
            self.step_mask = self._bits(pix, 0, D_STEP_MASK) % self.spp      # (npx,)

    def _bits(self, pixels, samples, dim: int) -> np.ndarray:
        """uint32 hashes of (pixel, sample, dim), as int64."""
        ids = (np.asarray(pixels, np.int64) * self.spp + np.asarray(samples, np.int64)) & _M32
        return hash32(hash32(ids.astype(np.uint32) ^ self.key) ^ _salt(dim)).astype(np.int64)

    def _uniform(self, pixels, samples, dim: int) -> np.ndarray:
        """[0, 1) numbers (24 bits) of (pixel, sample, dim)."""
        return (self._bits(pixels, samples, dim) >> 8).astype(np.float64) * (1.0 / 16777216.0)

    def _grid(self, pixels, samples):
        p = np.asarray(pixels, np.int64)[:, None]
        s = np.asarray(samples, np.int64)[None, :]
        return np.broadcast_arrays(p, s)

    def offsets(self, pixels, samples) -> np.ndarray:
        """(len(pixels), len(samples), 2) offsets in [0, 1)^2 of those pixels' samples."""
        p, s = self._grid(pixels, samples)
        u = np.stack([self._uniform(p, s, D_OFFSET + a) for a in (0, 1)], -1)
        if not self.k:
            return u
        cells = np.stack(np.divmod(s, self.k), -1)
        if self.cell_mask is not None:
            cells = cells ^ self.cell_mask[np.asarray(pixels, np.int64)][:, None, :]
        return (cells + u) / self.k

    def lens(self, pixels, samples) -> np.ndarray:
        """(len(pixels), len(samples), 2) points in [0, 1)^2 of the lens (depth of field)."""
        p, s = self._grid(pixels, samples)
        return np.stack([self._uniform(p, s, D_LENS + a) for a in (0, 1)], -1)

    def bands(self, pixels, samples) -> np.ndarray:
        """(2, len(pixels), len(samples)) the gather bands (0 .. spp - 1) of those samples."""
        return np.stack([self._strata(pixels, samples, None if self.rank is None else
                                      self.band_mask[a], D_BAND + a) for a in (0, 1)])

    def step_bands(self, pixels, samples) -> np.ndarray:
        """(len(pixels), len(samples)) the march steps' strata (0 .. spp - 1) of those
        samples (module docstring)."""
        return self._strata(pixels, samples, None if self.rank is None else self.step_mask,
                            D_STEP_BAND)

    def pixel_keys(self, pixels) -> np.ndarray:
        """(len(pixels),) uint32 keys of those pixels, the same for all their samples (the
        march shuffles each step's strata by them: kernels_np.step_stratum)."""
        return self._bits(pixels, 0, D_STEP_KEY).astype(np.uint32)

    def _strata(self, pixels, samples, mask, dim: int) -> np.ndarray:
        """(len(pixels), len(samples)) strata (0 .. spp - 1): with adaptive rounds the
        sample's turn bit-reversed XOR the pixel's ``mask``, else a permutation per pixel
        drawn in dimension ``dim``."""
        pixels = np.asarray(pixels, np.int64)
        samples = np.asarray(samples, np.int64)
        if self.rank is not None:
            return self.rev[self.rank[samples]][None, :] ^ mask[pixels][:, None]
        p, s = self._grid(pixels, np.arange(self.spp))
        return np.argsort(self._uniform(p, s, dim), axis=1)[:, samples]
