"""Light escaping through a medium's surface: the survival of the light pyramid's walk.

The pyramid (mpp_render/pyramid.py) spreads the first-scattering source with Gaussians as if the
medium filled space: a path that leaves the medium comes back.  In a real medium it leaves
for good.  Diffusion theory places the loss at the *extrapolated boundary*, a distance

    z_b = 0.7104 / sigma_tr',   sigma_tr' = sigma_s (1 - g) + sigma_a   (1/m)

outside the surface, where the diffuse fluence, extrapolated linearly from inside, falls to
zero (the Milne problem's extrapolation length for a medium without index mismatch; Case and
Zweifel, *Linear Transport Theory*, 1967; the dipole of Jensen et al., SIGGRAPH 2001, uses
2/3 of it).  As each level is made from the last (``pyramid.build``'s ``keep``), its points
keep the fraction

    keep_k(x) = clamp(1 - dist(x + D_k d) / z_b, 0, 1)

of their light: 1 inside the medium, falling linearly to 0 at z_b outside it, read where the
level's paths have drifted to.  dist (m) is the distance to the nearest point of the medium
on the lattice; D_k = g (1 - exp(-l_k / l_tr)) l_tr the mean progress along the light's
direction d of the paths of level k (``walk.walk_displacement``): forward-scattering
light that enters through a face heads inwards, and is lost less than its symmetric blur
around the face says.  Level 0 (the unblurred source) loses nothing.

How well it works, and how it depends on the lattice: docs/method.md, "Escape through the
surface".
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from .. import kernels
from ..media import PreparedMedium
from .lattice import lattice_points

MILNE_EXTRAPOLATION = 0.7104  # z_b sigma_tr' for a medium without index mismatch
MAX_REACH = 24  # lattice cells beyond the medium searched for its nearest point


def extrapolation_length(sigma_s: float, sigma_a: float, g: float) -> float:
    """z_b (m) for scattering and absorption coefficients ``sigma_s``, ``sigma_a`` (1/m)
    and HG anisotropy ``g``; inf where the medium neither scatters nor absorbs."""
    tr = sigma_s * (1.0 - g) + sigma_a
    return MILNE_EXTRAPOLATION / tr if tr > 0.0 else float("inf")


def outside_distance(occupied: np.ndarray, h: float, reach: int) -> np.ndarray:
    """Euclidean distance (m, float64, shaped like ``occupied``) from each lattice point
    (spacing ``h`` m) to the nearest occupied one: 0 on the medium, exact up to ``reach``
    cells along each axis; a point with no occupied one that near reads at least reach h.
    Separable squared-distance minimisation over a window of +-reach cells per axis."""
    big = float((reach + 1) ** 2 * 3)
    f = np.where(occupied, 0.0, big)
    for ax in range(3):
        n = f.shape[ax]
        out = f.copy()
        for j in range(1, min(reach, n - 1) + 1):
            sl_a = [slice(None)] * 3
            sl_b = [slice(None)] * 3
            sl_a[ax], sl_b[ax] = slice(j, None), slice(None, n - j)
            # a point reads the point j cells before and after it along the axis
            np.minimum(out[tuple(sl_a)], f[tuple(sl_b)] + j * j, out=out[tuple(sl_a)])
            np.minimum(out[tuple(sl_b)], f[tuple(sl_a)] + j * j, out=out[tuple(sl_b)])
        f = out
    return np.sqrt(np.minimum(f, big)) * h


def survival(pm: PreparedMedium, occupied: np.ndarray, stride: int, h: float, z_b: float,
             drifts, light_direction: Callable) -> Callable:
    """``keep(k, shape)`` for pyramid.build: the fraction (float32, ``shape``) each point of
    level k keeps (module docstring).  ``occupied``: the medium on the pyramid's lattice
    (bool (X,Y,Z), ``stride`` voxels apart, spacing ``h`` m); ``z_b`` the extrapolation
    length (m); ``drifts`` D_k per level (m); ``light_direction(points)`` the light's unit
    direction at world points.  The lattice is padded so that the ramp beyond its edge is
    read where it lies (up to MAX_REACH cells)."""
    pad = int(min(np.ceil(z_b / h), MAX_REACH)) if np.isfinite(z_b) else 0
    occ = np.pad(occupied, pad)
    dist = outside_distance(occ, h, pad + 1)
    ramp = np.clip(1.0 - dist / z_b, 0.0, 1.0).astype(np.float32)[..., None]
    top = np.array(ramp.shape[:3], np.float64) - 1.0
    w2i = pm.w2i[:3, :3]

    def keep(k: int, shape) -> np.ndarray:
        idx, x = lattice_points(pm, shape, stride * 2 ** k)
        q = idx * float(2 ** k) + pad
        if drifts[k] != 0.0:
            q = q + (float(drifts[k]) * light_direction(x)) @ w2i.T / float(stride)
        return kernels.trilinear(ramp, np.clip(q, 0.0, top))[:, 0].reshape(
            shape).astype(np.float32)

    return keep
