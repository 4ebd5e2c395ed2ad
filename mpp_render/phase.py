"""Henyey-Greenstein phase function.

Convention: ``cos_theta`` is the cosine between the *propagation* direction of the incident
light and the propagation direction of the scattered light, so g > 0 scatters forward.
The phase function is normalised over the sphere: its integral over solid angle (sr) is 1,
its unit is 1/sr.
"""
from __future__ import annotations

import functools

import numpy as np

G_LIMIT = 0.999  # |g| is clamped here: beyond it the lobe is narrower than any grid resolves


def clamp_g(g: float) -> float:
    return float(np.clip(g, -G_LIMIT, G_LIMIT))


def hg(cos_theta, g):
    """Henyey-Greenstein p(cos) = (1 - g^2) / (4 pi (1 + g^2 - 2 g cos)^1.5), in 1/sr.
    ``g``: a scalar or an array broadcasting with ``cos_theta``, clamped to +-G_LIMIT."""
    g = np.clip(np.asarray(g, np.float64), -G_LIMIT, G_LIMIT)
    c = np.asarray(cos_theta, dtype=np.float64)
    denom = np.maximum(1.0 + g * g - 2.0 * g * c, 1e-12)
    return (1.0 - g * g) / (4.0 * np.pi * denom * np.sqrt(denom))


def sample_hg(u1, u2, g: float, axis):
    """Directions distributed by HG around the unit propagation direction ``axis`` (N,3).

    ``u1``, ``u2`` in [0, 1) (N,); returns unit vectors (N,3) whose cosine with ``axis``
    follows the HG distribution (inverse CDF, exact for any g in (-1, 1))."""
    g = clamp_g(g)
    u1 = np.asarray(u1, np.float64)
    u2 = np.asarray(u2, np.float64)
    if abs(g) < 1e-4:
        cos_t = 1.0 - 2.0 * u1
    else:
        s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u1)
        cos_t = (1.0 + g * g - s * s) / (2.0 * g)
    cos_t = np.clip(cos_t, -1.0, 1.0)
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * np.pi * u2
    axis = np.asarray(axis, np.float64)
    t1, t2 = orthonormal_basis(axis)
    return (t1 * (sin_t * np.cos(phi))[:, None] + t2 * (sin_t * np.sin(phi))[:, None]
            + axis * cos_t[:, None])


def orthonormal_basis(n):
    """Two unit vectors (N,3) orthogonal to the unit vectors ``n`` (N,3) and to each other
    (Duff et al. 2017, branchless)."""
    n = np.atleast_2d(np.asarray(n, np.float64))
    sign = np.where(n[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t1 = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=1)
    t2 = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    return t1, t2


def delta_fraction(g: float) -> float:
    """The forward peak f = g^2 of the delta-Eddington split of HG (Joseph, Wiscombe and
    Weinman, J. Atmos. Sci. 33, 1976): HG(g) ~ f delta(forward) + (1 - f) HG(g*) with
    g* = (g - f) / (1 - f) = g / (1 + g), which keeps the transport coefficient:
    sigma_s (1 - f) (1 - g*) = sigma_s (1 - g).  0 for g <= 0 (no forward peak to split)."""
    g = clamp_g(g)
    return g * g if g > 0.0 else 0.0


def delta_g(g: float) -> float:
    """g* of the delta-Eddington split (``delta_fraction``): g / (1 + g) for g > 0, else g."""
    g = clamp_g(g)
    return g / (1.0 + g) if g > 0.0 else g


@functools.lru_cache(maxsize=64)
def _peak_msa(g: float) -> float:
    if g <= 0.0:
        return 0.0
    f = delta_fraction(g)
    theta = np.linspace(0.0, np.pi, 200001)
    dens = hg(np.cos(theta), g) * 2.0 * np.pi * np.sin(theta)  # per radian of polar angle
    mass = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(theta))])
    cut = float(np.interp(f, mass, theta))
    inner = theta <= cut
    t, d = theta[inner], dens[inner]
    dt = np.diff(t)
    m2 = float(np.sum(0.5 * (d[1:] * t[1:] ** 2 + d[:-1] * t[:-1] ** 2) * dt))
    m0 = float(np.sum(0.5 * (d[1:] + d[:-1]) * dt))
    return m2 / max(m0, 1e-300)


def peak_cone_cos(g: float) -> float:
    """The cosine of the forward cone that holds the fraction f = delta_fraction(g) of HG(g)'s
    scattering (its forward peak): from HG's closed-form distribution of cos,
    P(cos > c) = (1 - g^2) / (2 g) (1 / (1 - g) - 1 / sqrt(1 + g^2 - 2 g c)).  About
    cos(26 deg) for g = 0.85; 1 (no cone) for g <= 0."""
    g = clamp_g(g)
    f = delta_fraction(g)
    if f <= 0.0:
        return 1.0
    a = 1.0 / (1.0 - g) - 2.0 * g * f / (1.0 - g * g)
    return float(np.clip((1.0 + g * g - 1.0 / (a * a)) / (2.0 * g), -1.0, 1.0))


def outside_peak(cos_theta, g: float):
    """HG(g) without its forward peak, renormalised (1/sr): HG(cos; g) / (1 - f) outside the
    cone of ``peak_cone_cos(g)``, 0 inside -- the directions of a scattering out of the peak
    (delta_fraction), where the delta-Eddington split puts HG(g*) instead.  HG(g) itself for
    g <= 0."""
    f = delta_fraction(g)
    p = hg(cos_theta, g)
    if f <= 0.0:
        return p
    return np.where(np.asarray(cos_theta) < peak_cone_cos(g), p / (1.0 - f), 0.0)


def peak_msa(g: float) -> float:
    """The mean squared polar angle (rad^2) of the forward peak that delta_fraction splits
    off HG(g): of the directions within the forward cone that holds the fraction f of HG's
    scattering (the peak is not a delta: this is how far its light strays from the beam;
    about (13 deg)^2 for g = 0.85).  0 for g <= 0."""
    return _peak_msa(round(clamp_g(g), 6))
