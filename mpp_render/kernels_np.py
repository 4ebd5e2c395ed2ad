"""Numpy twins of the hot kernels: the readable specification and the test oracle.

Each function here has a compiled twin of the same name in ``mpp_render._kernels`` (C,
releases the GIL); ``mpp_render.kernels`` picks one.  Both must agree to 1e-4 relative.
"""
from __future__ import annotations

import numpy as np

from .media import density_from, trilinear


def optical_depth(points, dirs, t_max, grids, w2is, sigma_ts, thresholds, step, offset=0.5):
    """RGB optical depth (N,3) along rays p + s*dir, s in [0, t_max], through every medium.

    ``points`` (N,3), ``dirs`` (N,3) unit, ``t_max`` (N,) metres; ``grids`` padded float32
    density arrays, ``w2is`` their (3,4) world->index maps, ``sigma_ts`` their RGB extinction
    per unit density (1/m), ``thresholds`` their sharp-boundary thresholds (-1: smooth; see
    media.density_from).  Each ray is cut into n = ceil(t_max/step) equal segments and the
    density is read at the fraction ``offset`` of each segment (midpoint rule for 0.5)."""
    points = np.asarray(points, np.float64)
    dirs = np.asarray(dirs, np.float64)
    t_max = np.maximum(np.asarray(t_max, np.float64), 0.0)
    n = np.ceil(t_max / step).astype(np.int64)
    h = np.where(n > 0, t_max / np.maximum(n, 1), 0.0)
    tau = np.zeros((len(points), 3))
    for j in range(int(n.max()) if len(n) else 0):
        live = n > j
        if not live.any():
            break
        s = (j + offset) * h[live]
        x = points[live] + dirs[live] * s[:, None]
        acc = np.zeros((len(x), 3))
        for g, w2i, st, thr in zip(grids, w2is, sigma_ts, thresholds):
            idx = x @ w2i[:, :3].T + w2i[:, 3]
            acc += density_from(trilinear(g, idx), thr)[:, None] * st[None, :]
        tau[live] += acc * h[live][:, None]
    return tau
