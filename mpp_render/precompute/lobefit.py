"""The camera's multiply scattered light from the traced paths' lobe, fitted to their deposits.

The paths' deposits M_d(y) (paths.py) estimate, at each lattice point y, the light that the
medium scatters towards the camera: each deposit weighs the phase function at the path's own
direction w, p(w . v(y)).  In a strongly forward-scattering medium that weight is mostly
small and now and then very large (g 0.95: HG peaks at 62 /sr against its mean 1 / 4 pi =
0.08), so the few paths that happen to point at the camera carry the estimate and M_d is noisy
(p_sphere_g95: two seeds' images differ by 0.083 of the image's mean, the whole of its error
against Cycles).  The same paths' moments (paths.py, "Moments": M0 and M1 per channel) hold
the light's amount and mean direction with little noise, and the Henyey-Greenstein lobe they
close to (the march's reading of the moments, kernels_np.read_level),

    M_c(y) = 4 pi M0(y) HG(v(y) . G / |G|; |G|),      G = M1 / M0,

is smooth in v but biased: the multiply scattered light is a mixture of lobes (the sharp one
of the light scattered twice, the broad ones of later orders) that no single HG lobe matches
(p_sphere_g95's image 15 % dark with M_c alone).  So, per channel:

1. **The lobe, scaled by the deposits.**  M_r(y) = M_c(y) a(y), where a(x) = a0 + b . (x - y)
   is the local-linear fit of M_d / M_c over the window of (2 r + 1)^3 lattice points round
   y: a0, b minimise sum_y' u(y') (M_d(y') - M_c(y') a(y'))^2 / M_c(y').  The lobe brings
   the shape between lattice points and along the camera's direction; the deposits set its
   level, and the slope b follows how the lobe's bias changes across the window (depth below
   a lit face: a box-filtered ratio there left p_backlit_vdb's image 3 % dark where the
   sharp lobe gives way to the broad ones).  u(y') is the lattice point's medium (its tent
   mass) times its transmittance to the camera, so the fit keeps what the camera sees.
   Where y lies beyond ``kernels_np.LOBE_REACH`` standard deviations of the window's
   weighted spread from its weighted centre (the weight in a plane y is off: a thick lit
   face seen edge on), the line is an extrapolation and a is the window's weighted mean
   ratio instead.
2. **As far as the noise warrants.**  The paths come in two halves (kernels.trace_paths_media,
   ``halves``), each an estimate M_A, M_B of M_d; the window's mean of u (M_A - M_B)^2 / 4 over
   that of u is
   V, the variance of M_d, and the window's mean of D^2, D = M_d - M_r, is V plus the fit's
   squared bias.  M = M_r + k D with k = max(0, 1 - V / mean D^2): the Wiener weight, which
   keeps M_r where the deposits' difference from it is their noise and moves to M_d where
   it is more than their noise.

As paths are added V falls and k goes to 1, so M converges to M_d, the unbiased estimate;
the fit only takes noise off while there is more noise than the lobe's error.  Nothing here
is fitted to a scene: r (``Tuning.lobe_window``) is the one choice, measured on the public
suite (docs/method.md §9.9, *The camera's light from the paths' lobe*).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from .. import kernels
from ..kernels_np import box_sum
from ..phase import G_LIMIT, hg

__all__ = ["lobe", "box_sum", "lobe_ratio", "fitted", "camera_weight"]


def lobe(moments: np.ndarray, towards: np.ndarray) -> np.ndarray:
    """float64 (LX,LY,LZ,3): M_c, the HG lobe of the paths' ``moments`` (LX,LY,LZ,12: M0 RGB,
    then M1 along x, y, z, RGB each; paths.py) seen along ``towards`` (LX,LY,LZ,3, unit, to
    the camera), 4 pi M0 HG(towards . G / |G|; min(|G|, G_LIMIT)) with G = M1 / M0, and 0
    where M0 <= 0 (kernels_np.read_level's closure)."""
    m = np.asarray(moments, np.float64)
    tw = np.asarray(towards, np.float64)
    out = np.zeros(m.shape[:3] + (3,))
    for c in range(3):
        m0 = m[..., c]
        pos = m0 > 0.0
        G = np.stack([m[..., 3 + 3 * j + c] for j in range(3)], -1) / \
            np.where(pos, m0, 1.0)[..., None]
        gl = np.sqrt(np.einsum("...j,...j->...", G, G))
        cs = np.where(gl > 0.0, np.einsum("...j,...j->...", G, tw) / np.where(gl > 0.0, gl, 1.0),
                      0.0)
        out[..., c] = np.where(pos, 4.0 * np.pi * m0 * hg(np.clip(cs, -1.0, 1.0),
                                                           np.minimum(gl, G_LIMIT)), 0.0)
    return out


def lobe_ratio(md: np.ndarray, mc: np.ndarray, u: np.ndarray, r: int) -> np.ndarray:
    """float64 (LX,LY,LZ,3): M_r = M_c a, a the local-linear fit of M_d / M_c over each
    window of radius ``r`` with weights ``u`` (LX,LY,LZ) (module docstring, step 1); M_d
    where the window holds no weight, M_c is 0 throughout it, or M_c is 0 at the point
    (kernels.lobe_ratio: one fit for a grey medium's three equal channels)."""
    return kernels.lobe_ratio(md, mc, u, r, 1 if _grey(md) and _grey(mc) else 3)


def _grey(x: np.ndarray) -> bool:
    """Whether the three channels of ``x`` (...,3) are the same values (a grey medium)."""
    return bool(np.array_equal(x[..., 0], x[..., 1]) and np.array_equal(x[..., 0], x[..., 2]))


def fitted(md: np.ndarray, moments: np.ndarray, towards: np.ndarray, u: np.ndarray,
           halves: np.ndarray, r: int) -> np.ndarray:
    """float32 (LX,LY,LZ,3): the camera's M (module docstring) from the deposits ``md``
    (LX,LY,LZ,3, M of all the paths), their ``moments`` (LX,LY,LZ,12), the directions
    ``towards`` the camera, the weights ``u`` (LX,LY,LZ; ``camera_weight``) and ``halves``
    (LX,LY,LZ,3), M_A - M_B, the difference of the two halves' own estimates, over windows of
    radius ``r`` lattice points; ``md`` itself for r < 1."""
    md = np.asarray(md, np.float64)
    if r < 1:
        return np.ascontiguousarray(md, np.float32)
    u = np.asarray(u, np.float64)
    mr = lobe_ratio(md, lobe(moments, towards), u, r)
    uw = box_sum(u, r)[..., None]
    has = uw > 0.0
    den = np.where(has, uw, 1.0)
    var = box_sum(u[..., None] * np.asarray(halves, np.float64) ** 2, r) / den / 4.0
    diff = md - mr
    spread = box_sum(u[..., None] * diff ** 2, r) / den
    k = np.where(has & (spread > 0.0),
                 np.clip(1.0 - var / np.where(spread > 0.0, spread, 1.0), 0.0, 1.0), 1.0)
    return np.ascontiguousarray(mr + k * diff, np.float32)


def camera_weight(tent_mass: np.ndarray, tau: Optional[np.ndarray]) -> np.ndarray:
    """float64 (LX,LY,LZ): each lattice point's weight in the fit, its tent mass (m^3) times
    e^-tau, ``tau`` its optical depth to the camera (LX,LY,LZ; None: 1)."""
    u = np.asarray(tent_mass, np.float64).reshape(np.shape(tent_mass)[:3])
    if tau is None:
        return u
    return u * np.exp(-np.asarray(tau, np.float64))
