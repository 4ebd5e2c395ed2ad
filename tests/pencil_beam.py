"""A Monte Carlo pencil beam in an infinite homogeneous Henyey-Greenstein medium: the
reference the most-probable-path closed forms of mpp_render/mpp.py are checked against
(tests/test_mpp.py).  Units: metres, 1/m."""
from typing import Dict

import numpy as np

from mpp_render.phase import sample_hg


def pencil_beam_mc(g, sigma_s, sigma_a, s_values, n_photons, rng) -> Dict[str, np.ndarray]:
    """Pencil beam from the origin along +z in an infinite homogeneous HG medium.

    Photons fly exponential free paths (1/sigma_s, m) and scatter with ``sample_hg``; at each
    path length in ``s_values`` (m) every photon's state is recorded.  Absorption does not
    change paths at a fixed path length, so it enters as the weight e^{-sigma_a s}.
    Returns ``s`` (K,), ``position`` (K, N, 3) m, ``direction`` (K, N, 3) unit,
    ``order`` (K, N) number of scatterings so far, ``weight`` (K,) survival e^{-sigma_a s}.
    """
    s_values = np.sort(np.asarray(s_values, np.float64))
    K = len(s_values)
    n = int(n_photons)
    pos = np.zeros((n, 3))
    d = np.zeros((n, 3))
    d[:, 2] = 1.0
    arc = np.zeros(n)
    order = np.zeros(n, np.int64)
    P = np.zeros((K, n, 3))
    D = np.zeros((K, n, 3))
    O = np.zeros((K, n), np.int64)
    alive = np.arange(n)
    s_max = s_values[-1] if K else 0.0
    while alive.size and sigma_s > 0:
        step = rng.exponential(1.0 / sigma_s, alive.size)
        a0 = arc[alive]
        a1 = a0 + step
        for kk, sk in enumerate(s_values):
            m = (a0 <= sk) & (a1 > sk) if sk > 0 else (a0 == 0.0)
            if np.any(m):
                idx = alive[m]
                P[kk, idx] = pos[idx] + (sk - a0[m])[:, None] * d[idx]
                D[kk, idx] = d[idx]
                O[kk, idx] = order[idx]
        pos[alive] += step[:, None] * d[alive]
        arc[alive] = a1
        alive = alive[a1 <= s_max]
        if alive.size:
            d[alive] = sample_hg(rng.random(alive.size), rng.random(alive.size), g, d[alive])
            order[alive] += 1
    if sigma_s <= 0:                               # no scattering: straight line
        for kk, sk in enumerate(s_values):
            P[kk, :, 2] = sk
            D[kk, :, 2] = 1.0
    return {"s": s_values, "position": P, "direction": D, "order": O,
            "weight": np.exp(-float(sigma_a) * s_values)}


def mc_width_sq(position, direction, mask=None) -> float:
    """Monte-Carlo estimate of w^2 (m^2) from recorded photons: per-axis Var(x) - Cov(x, u_x)^2
    / Var(u_x), pooling the two transverse axes (x, y), about zero (the beam's axis)."""
    if mask is not None:
        position, direction = position[mask], direction[mask]
    x = np.concatenate([position[:, 0], position[:, 1]])
    u = np.concatenate([direction[:, 0], direction[:, 1]])
    vx, vu, c = np.mean(x * x), np.mean(u * u), np.mean(x * u)
    return float(vx - c * c / vu) if vu > 0 else 0.0


