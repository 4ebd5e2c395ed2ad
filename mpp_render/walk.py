"""The walk: the model of the renderer's multiple scattering, the light pyramid's levels
(no bpy, no kernel).

Multiple scattering is looked up in a pyramid of blurred light, level k blurred to a width
W_k = h 2^k (h the lattice spacing, m).  The walk says which light paths each level stands
for and how they spread and drift: ``walk_width_sq`` and ``walk_displacement`` (a persistent
random walk of transport length l_tr = 1 / (sigma_s (1 - g)), in units of l_tr),
``path_length_for_width`` (the path length, m, whose spread is a given width),
``level_paths`` (each level's range of path lengths), and ``level_table`` (per level,
density on the axis ``RHO_TABLE`` and colour channel, the path-length weight in m and the
last scattering's anisotropy) read through ``table_lookup`` by the march kernels and the
first flights.  The precompute uses level_paths and walk_displacement (the pyramid's drift,
precompute.lightpyramid and boundary), the march and firstflight the level table.

Its terms are derived from the most-probable-path closed forms of ``mpp.py`` (tests/test_mpp.py
holds the walk to them) in docs/method.md §9.  Units: lengths in metres, coefficients in 1/m.
"""
from __future__ import annotations

import numpy as np


def _phi1_small(z):
    """(1 - e^-z) / z, 1 - z / 2 for z <= 1e-12 (the level table's form of _phi1)."""
    z = np.asarray(z, np.float64)
    safe = np.where(z > 1e-12, z, 1.0)
    return np.where(z > 1e-12, -np.expm1(-safe) / safe, 1.0 - 0.5 * z)


def walk_width_sq(u, g):
    """Per-axis variance, in units of the transport length l_tr = 1/(sigma_s (1 - g)) squared,
    of the position of a photon after path length u l_tr since its first scattering, about
    its mean drift g l_tr (1 - e^-u) along the beam: a persistent random walk whose direction
    correlation decays as e^-u, started with mean cosine g.  (2 (u - 1 + e^-u) - g^2
    (1 - e^-u)^2) / 3: ballistic u^2 (1 - g^2) / 3 for u << 1, diffusive 2u/3 for u >> 1."""
    u = np.asarray(u, np.float64)
    e = -np.expm1(-u)
    return np.maximum((2.0 * (u - e) - g * g * e * e) / 3.0, 0.0)


def walk_displacement(u, g, g_last=None):
    """Mean displacement of the walk of ``walk_width_sq`` after path length u l_tr, in units
    of the transport length l_tr, for the light that leaves its last scattering towards a
    given direction v: (drift, beta) with

        E[x | v] = drift d + beta (v - g_last g e^-u d)      (d: the light's direction, unit)

    drift = g (1 - e^-u) is the walk's mean progress along d (g: the walk's mean cosine after
    its first scattering).  beta is the regression of the position on the direction
    scattered into at the end by HG of anisotropy ``g_last`` (the medium's own g, where the
    walk is the delta-scaled medium's, phase.delta_g; g when None): Cov(x, v) / Var(v) =
    g_last (1 - e^-u) (1 - g^2 e^-u) / (1 - g_last^2 g^2 e^-2u), traces over the three axes,
    with Cov(x, u) from E[u(t) . u(t')] = e^-(t' - t) / l_tr and E[v | u] = g_last u.
    beta -> g_last u / (1 + g^2) for u << 1 when g_last = g (a straight flight: the light
    that heads towards v came from behind it, along v), 0 for g_last = 0 (an isotropic last
    scattering forgets the path)."""
    u = np.asarray(u, np.float64)
    g_last = g if g_last is None else g_last
    e = np.exp(-u)
    em = -np.expm1(-u)
    beta = g_last * em * (1.0 - g * g * e) / np.maximum(1.0 - (g_last * g * e) ** 2, 1e-300)
    return g * em, beta


_U_TABLE = np.logspace(-6, 7, 521)


def path_length_for_width(width_sq, l_tr, g):
    """Path length (m) at which walk_width_sq reaches ``width_sq`` (m^2), for transport
    length ``l_tr`` (m, arrays; inf for a medium that does not scatter: ballistic flight)."""
    table = walk_width_sq(_U_TABLE, g)
    ratio = width_sq / np.where(np.isfinite(l_tr), l_tr * l_tr, 1.0)
    ballistic = np.sqrt(width_sq * 3.0 / max(1.0 - g * g, 1e-6))
    u = np.exp(np.interp(np.log(np.maximum(ratio, 1e-300)), np.log(np.maximum(table, 1e-300)),
                         np.log(_U_TABLE)))
    small = ~np.isfinite(l_tr) | (ratio < table[0])
    return np.where(small, ballistic, u * np.where(np.isfinite(l_tr), l_tr, 0.0))


# Density axis of the per-medium level tables: log-spaced relative densities.
RHO_TABLE = np.logspace(-4, 4, 257)
LOG_RHO0 = float(np.log(RHO_TABLE[0]))
DLOG_RHO = float(np.log(RHO_TABLE[1]) - np.log(RHO_TABLE[0]))


def level_paths(h, levels, l_tr, g):
    """Per pyramid level k (width W_k = h 2^k, m; level 0 unblurred) the range [lo, hi] of the
    path lengths (m) it stands for -- spreads w(l) within a factor sqrt(2) of W_k -- and
    their representative length l_k (geometric mean; hi / 2 on level 0): a list of
    (lo, hi, l_k), arrays shaped like ``l_tr`` (m)."""
    out = []
    lo = np.zeros(np.shape(l_tr))
    for k in range(levels):
        hi = path_length_for_width((h * 2.0 ** (k + 0.5)) ** 2, l_tr, g)
        out.append((lo, hi, np.sqrt(lo * hi) if k else 0.5 * hi))
        lo = hi
    return out


def level_table(g, sigma_s, sigma_a, h, levels, exact_flights=0):
    """Per pyramid level k, density rho (RHO_TABLE) and colour channel, the path-length
    weight int e^(-sigma_a rho l) dl (m) over the paths the level stands for, and the
    anisotropy g g* e^(-l_k / l_tr) of the last scattering: (levels, len(RHO_TABLE), 6)
    float64, the weights of R, G, B then their anisotropies.

    ``g``, ``sigma_s``, ``sigma_a``: the medium's HG anisotropy and coefficients per unit
    density (1/m), one per channel (3) or one for all: a chromatic medium absorbs along its
    paths, and spreads them, by channel; ``h`` the pyramid's lattice spacing (m).  The walk
    is the delta-scaled medium's (phase.delta_fraction: g* = g / (1 + g), sigma_s* = sigma_s
    (1 - g^2) for g > 0; the same transport length l_tr = 1 / (sigma_s (1 - g))), started
    with mean cosine g* where the beam first scatters out of the forward peak; the last
    scattering, towards the camera, is the medium's own HG(g) of light whose mean cosine is
    g* e^(-u).  Level k (width W_k = h 2^k, level 0 unblurred) stands for the paths whose
    spread w(l) lies within a factor sqrt(2) of W_k.

    ``exact_flights`` (0, 1 or 2): only the paths that have scattered at least that many
    times since their first scattering (their first flights are then firstflight.py's): a
    path of length l has scattered n times with the Poisson probability P_n =
    (sigma_s* l)^n e^(-sigma_s* l) / n!, so the weight is int e^(-sigma_a l) (1 - sum_{n <
    exact_flights} P_n) dl, and the mean cosine of those paths is
    g* (e^(-u) - sum P_n g*^n) / (1 - sum P_n) (each scattering multiplies it by g*: the
    straight paths keep g*, so the paths that turned hold less than the average)."""
    from .phase import delta_fraction, delta_g
    rho = RHO_TABLE
    b1 = max(1.0 - g, 1e-6)
    g_walk = delta_g(g)
    keep = 1.0 - delta_fraction(g)
    n_exact = int(exact_flights)
    if n_exact not in (0, 1, 2):
        raise ValueError("exact_flights must be 0, 1 or 2")
    out = np.zeros((levels, len(rho), 6))
    for c, (s_c, a_c) in enumerate(zip(np.broadcast_to(np.asarray(sigma_s, np.float64), (3,)),
                                       np.broadcast_to(np.asarray(sigma_a, np.float64), (3,)))):
        ss, sa = rho * s_c, rho * a_c
        with np.errstate(divide="ignore"):
            l_tr = np.where(ss > 0, 1.0 / (ss * b1), np.inf)
        walk_ss = ss * keep
        st = sa + walk_ss
        for k, (lo, hi, l_k) in enumerate(level_paths(h, levels, l_tr, g_walk)):
            span = hi - lo
            weight = np.exp(-sa * lo) * span * _phi1_small(sa * span)
            mean_cos = np.exp(-l_k / l_tr)
            if n_exact:
                # int e^(-sigma_a l) P_0 dl = int e^(-sigma_t* l) dl over [lo, hi]
                weight = weight - np.exp(-st * lo) * span * _phi1_small(st * span)
                p0 = np.exp(-walk_ss * l_k)
                done, turned = p0, p0
                if n_exact == 2:
                    # int e^(-sigma_a l) P_1 dl = sigma_s* [(sigma_t* l + 1) e^(-sigma_t* l)
                    # / sigma_t*^2] from hi to lo
                    st2 = np.maximum(st * st, 1e-300)
                    weight = weight - walk_ss * ((st * lo + 1.0) * np.exp(-st * lo)
                                                 - (st * hi + 1.0) * np.exp(-st * hi)) / st2
                    p1 = walk_ss * l_k * p0
                    done, turned = p0 + p1, p0 + p1 * g_walk
                weight = np.maximum(weight, 0.0)
                mean_cos = np.where(done < 1.0 - 1e-9,
                                    (mean_cos - turned) / np.maximum(1.0 - done, 1e-12), mean_cos)
            out[k, :, c] = weight
            out[k, :, 3 + c] = g * g_walk * mean_cos
    return out


def table_lookup(table, rho):
    """Linear interpolation of ``table`` (levels, R, C) in log density; (levels, N, C)."""
    f = (np.log(np.maximum(rho, 1e-300)) - LOG_RHO0) / DLOG_RHO
    f = np.clip(f, 0.0, table.shape[1] - 1.0)
    i = np.minimum(np.floor(f).astype(np.int64), table.shape[1] - 2)
    t = (f - i)[None, :, None]
    return table[:, i] * (1.0 - t) + table[:, i + 1] * t
