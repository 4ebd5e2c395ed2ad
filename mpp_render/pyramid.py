"""The light pyramid: a field blurred with Gaussians of doubling width, looked up at any width.

Level 0 is the field itself on its lattice (spacing ``h`` metres).  Level k >= 1 holds the
field blurred with an isotropic Gaussian of standard deviation ``h * 2**k`` and sampled every
``2**k`` lattice points: it is made from level k-1 by a separable Gaussian of
sqrt(4**k - 4**(k-1)) h = sqrt(3) (2**(k-1) h) -- sqrt(3) level-(k-1) spacings -- and
dropping every other point.  Level k lattice point j sits at level-0 index j * 2**k.

``lookup(levels, idx, width, h)`` reads the field blurred to standard deviation ``width``
(metres) at level-0 index coordinates ``idx``: trilinear in space in the two levels whose
widths bracket ``width``, linear in log2(width / h) between them; widths below ``h`` read
level 0 unblurred, widths beyond the coarsest level read the coarsest level.
"""
from __future__ import annotations

from typing import Callable, List, Optional

import numpy as np

from . import kernels

SQRT3 = float(np.sqrt(3.0))


def gaussian_blur(a: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur (standard deviation ``sigma`` lattice spacings) over the first
    three axes of ``a`` (X,Y,Z[,C]); zero beyond the edges (light leaving the grid is lost)."""
    r = max(1, int(np.ceil(3.0 * sigma)))
    x = np.arange(-r, r + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    w /= w.sum()
    out = a.astype(np.float32, copy=True)
    for ax in range(3):
        n = out.shape[ax]
        pad = [(0, 0)] * out.ndim
        pad[ax] = (r, r)
        p = np.pad(out, pad)
        acc = np.zeros_like(out)
        for k, wk in enumerate(w):
            sl = [slice(None)] * out.ndim
            sl[ax] = slice(k, k + n)
            acc += np.float32(wk) * p[tuple(sl)]
        out = acc
    return out


def build(base: np.ndarray, max_levels: int = 8,
          keep: Optional[Callable[[int, tuple], np.ndarray]] = None) -> List[np.ndarray]:
    """Levels [base, blur 2h, blur 4h, ...] until a level is 2 points wide or ``max_levels``.
    ``keep(k, shape)``, where given, is the fraction (shape (X,Y,Z)) of level k's content that
    each of its points keeps, applied as the level is made and so carried into the coarser
    ones: what a walk loses on the way (boundary.survival)."""
    levels = [np.ascontiguousarray(base, np.float32)]
    while len(levels) < max_levels and min(levels[-1].shape[:3]) > 2:
        k = len(levels)
        src = levels[-1]
        # an odd count keeps the last point on the coarser lattice (j * 2 covers n - 1);
        # the extra point beyond the field is zero before the blur, like the field outside
        pad = [(0, (n + 1) % 2) for n in src.shape[:3]] + [(0, 0)] * (src.ndim - 3)
        src = np.pad(src, pad)
        sigma = SQRT3 if k > 1 else 2.0  # level 1: from the unblurred base to 2h
        level = gaussian_blur(src, sigma)[::2, ::2, ::2]
        if keep is not None:
            kept = np.asarray(keep(k, level.shape[:3]), np.float32)
            level = level * kept.reshape(kept.shape + (1,) * (level.ndim - 3))
        levels.append(np.ascontiguousarray(level))
    return levels


def lookup(levels: List[np.ndarray], idx, width, h: float):
    """The field blurred to ``width`` (m, (N,)) at level-0 index coords ``idx`` (N,3)."""
    idx = np.asarray(idx, np.float64)
    lev = np.log2(np.maximum(np.asarray(width, np.float64), h) / h)
    lev = np.clip(lev, 0.0, len(levels) - 1.0)
    k0 = np.floor(lev).astype(np.int64)
    k0 = np.minimum(k0, len(levels) - 2) if len(levels) > 1 else k0
    fr = lev - k0
    out = np.zeros((len(idx),) + levels[0].shape[3:])
    trilinear = kernels.trilinear
    for k in np.unique(k0):
        sel = np.flatnonzero(k0 == k)
        a = trilinear(levels[k], idx[sel] / 2.0 ** k)
        if len(levels) > 1:
            b = trilinear(levels[k + 1], idx[sel] / 2.0 ** (k + 1))
            f = fr[sel].reshape((-1,) + (1,) * (a.ndim - 1))
            a = a * (1.0 - f) + b * f
        out[sel] = a
    return out
