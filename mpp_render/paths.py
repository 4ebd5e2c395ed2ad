"""Multiple scattering by light paths traced through the medium (the converging estimate).

The walk of the light pyramid (mpp.py, precompute/lightpyramid.py) is a model: smooth and
cheap, but with errors no setting removes.  This module estimates the same quantity by Monte
Carlo, so that it converges as paths are added and the lattice is refined:

    M(y) = integral of rho(x) t_y(x) [integral over directions of L_1+(x, w) p(w . v(y); g) dw]
           d^3x / integral of rho(x) t_y(x) d^3x                                  [W/(m^2 sr)]

(t_y the trilinear tent of lattice point y, rho the density) where L_1+ is the radiance of
the light that has scattered at least once, v(y) the unit direction from the lattice point y
to the camera and p the medium's Henyey-Greenstein phase function (phase.py: cosine between
propagation directions).  The march reads it as one flattened level (march.MarchContext):
J_ms(x) = rho(x) sigma_s M(x), the radiance that the medium at x scatters towards the camera
from the light that has scattered before, i.e. every order from the second on.  Single
scattering stays the march's exact one.

**Paths.**  Each path starts where the light's unscattered beam first scatters: a lattice
point drawn in proportion to its first-scattering power Q V (precompute.source:
Q = sigma_s E exp(-tau), W/m^3, tent-shared from the voxels, so a tent-distributed offset of
one lattice step per axis undoes the sharing), with the direction drawn from p about the
light's propagation there.  It then flies through the voxels' density (nearest voxel), with
tentative collisions at a rate mu = max(majorant, 1 / h) per metre (h the lattice spacing;
null-collision tracking, Woodcock et al. 1965): at each tentative point the path deposits
its weight / mu times the density there, times the trilinear share of each of the 8 lattice
points around it and p(w . v) at that point (the track-length estimate of the integral of
rho L p against each point's tent, unbiased for any mu >= the majorant; divided by the
tent's integral of rho, precompute.lightpaths makes M the medium's mean under the tent, so
a lattice point beside the medium's surface is not diluted by the empty side); a tentative
point is a real collision with probability rho sigma_t,max / mu.  Chromatic media use
spectral tracking weights: a real collision multiplies channel c by
sigma_s,c / sigma_t,max, a null one by (1 - rho sigma_t,c / mu) / (1 - rho sigma_t,max / mu).
After ``MAX_COLLISIONS`` real collisions, or once it leaves the grid, a path ends; below a
tenth of its start weight it survives a Russian roulette; after ``MAX_EVENTS`` tentative
collisions it ends too.  A rate that would put more than ``MAX_RATE_SPAN`` tentative points
along the grid's diagonal is refused (``rate_span``), and beyond ``PATHS_MAX_SPAN`` the
precompute keeps the walk.  Surfaces do not stop paths.

Random numbers are the march's counter hash (kernels_np.uniform) of (path key, event,
dimension), so the C kernel (csrc/paths.c) and this numpy twin draw the same numbers and
trace the same paths.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .kernels_np import hash32, uniform
from .phase import clamp_g, hg, sample_hg

__all__ = ["PathInputs", "trace_paths_np", "MAX_COLLISIONS", "ROULETTE", "PATHS_MAX_SPAN"]

MAX_COLLISIONS = 4096    # real collisions after which a path ends (albedo 1, optical depth 1e4)
ROULETTE = 0.1           # below this fraction of its start weight a path plays roulette
MAX_EVENTS = 1_000_000   # tentative collisions after which a path ends (csrc/paths.c)
MAX_RATE_SPAN = 1e6      # the most tentative collisions along the grid's diagonal (csrc/paths.c)
# Beyond this many tentative collisions along the grid's diagonal (an optical size of about
# 2000) the precompute keeps the walk: an albedo-1 medium of optical depth 1e3 took 370 us a
# path (4096 collisions each), 6 minutes for a default render's paths.
PATHS_MAX_SPAN = 2000.0

# random dimensions
_D_PICK, _D_JIT, _D_DIR, _D_FLY, _D_HIT, _D_TURN, _D_RR = 0, 1, 7, 10, 11, 12, 14


@dataclass
class PathInputs:
    """What the tracer reads.  ``density``: float32 (X,Y,Z) the medium's density per voxel
    (media.density_from applied); ``w2i``: (3,4) world -> voxel index; ``i2w``: (3,3) voxel
    index steps in world metres; ``sigma_s``, ``sigma_t``: (3,) 1/m per unit density; ``g``;
    ``stride``: voxels per lattice step (lattice point k at voxel index k stride);
    ``towards``: float64 (LX,LY,LZ,3) unit directions from each lattice point to the camera;
    ``starts``: (N,3) world positions of the lattice points that scatter; ``weights``: (N,3)
    W, the weight of a path from each (its first-scattering power over the probability of
    drawing it, ``from_power``); ``dirs``: (N,3) unit propagation of the light there;
    ``cdf``: (N,) the cumulative probabilities of the starts; ``rate``: mu, tentative
    collisions per metre; ``n_paths``; ``seed``; ``max_collisions``: real collisions after
    which a path ends (1: the first flights alone, the second order)."""

    density: np.ndarray
    w2i: np.ndarray
    i2w: np.ndarray
    sigma_s: np.ndarray
    sigma_t: np.ndarray
    g: float
    stride: int
    towards: np.ndarray
    starts: np.ndarray
    weights: np.ndarray
    dirs: np.ndarray
    cdf: np.ndarray
    rate: float
    n_paths: int
    seed: int = 0
    max_collisions: int = MAX_COLLISIONS


def from_power(power: np.ndarray):
    """(weights (N,3), cdf (N,)) for starts of first-scattering power ``power`` (N,3) W > 0:
    each drawn with probability proportional to its power summed over channels."""
    lum = power.sum(axis=1)
    total = float(lum.sum())
    return power * (total / lum)[:, None], np.cumsum(lum) / total


def rate_span(rate: float, i2w: np.ndarray, shape) -> float:
    """Tentative collisions at ``rate`` (1/m) along the diagonal of a grid of ``shape`` voxels
    whose index steps are the columns of ``i2w`` (3,3, m)."""
    diagonal = np.asarray(i2w, np.float64) @ np.asarray(shape, np.float64)
    return float(rate) * float(np.linalg.norm(diagonal))


def path_keys(seed: int, n: int) -> np.ndarray:
    """uint32 keys of paths 0..n-1 for ``seed``."""
    base = hash32(np.uint32((seed * 0x27D4EB2F + 0x165667B1) & 0xFFFFFFFF))
    return hash32(np.arange(n, dtype=np.uint32) ^ base)


def _turn(u1, u2, g, axis):
    """HG-distributed unit directions about ``axis`` (phase.sample_hg, renormalised as the C
    twin does)."""
    d = sample_hg(u1, u2, g, axis)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def trace_paths_np(inp: PathInputs) -> np.ndarray:
    """The numpy twin of csrc/paths.c: float64 (LX,LY,LZ,3) sums of weight / mu x density x
    trilinear share x p(w . v) over every tentative point of ``inp.n_paths`` paths (W m / sr;
    divide by the cell volume times the mean density under the point's tent for M)."""
    lshape = inp.towards.shape[:3]
    out = np.zeros((int(np.prod(lshape)), 3))
    n = int(inp.n_paths)
    if n <= 0 or len(inp.cdf) == 0:
        return out.reshape(lshape + (3,))
    g = clamp_g(inp.g)
    keys = path_keys(inp.seed, n)
    k = np.minimum(np.searchsorted(inp.cdf, uniform(keys, 0, _D_PICK), side="right"),
                   len(inp.cdf) - 1)
    off = np.stack([uniform(keys, 0, _D_JIT + 2 * a) + uniform(keys, 0, _D_JIT + 2 * a + 1) - 1.0
                    for a in range(3)], axis=1) * inp.stride
    pos = inp.starts[k] + off @ inp.i2w.T
    d = _turn(uniform(keys, 0, _D_DIR), uniform(keys, 0, _D_DIR + 1), g, inp.dirs[k])
    w = inp.weights[k] / n
    w0 = w.max(axis=1)
    event = np.zeros(n, np.int64)
    hits = np.zeros(n, np.int64)
    alive = np.arange(n)
    shape = np.array(inp.density.shape)
    lsh = np.array(lshape)
    st_max = float(np.max(inp.sigma_t))
    mu = float(inp.rate)
    tw = inp.towards.reshape(-1, 3)
    while alive.size:
        kk = keys[alive]
        ev = event[alive] + 1
        event[alive] = ev
        t = -np.log(1.0 - uniform(kk, ev, _D_FLY)) / mu
        p = pos[alive] + t[:, None] * d[alive]
        pos[alive] = p
        idx = p @ inp.w2i[:, :3].T + inp.w2i[:, 3]
        vox = np.floor(idx + 0.5).astype(np.int64)
        inside = np.all((vox >= 0) & (vox < shape), axis=1)
        alive, idx, vox, kk, ev = alive[inside], idx[inside], vox[inside], kk[inside], ev[inside]
        if not alive.size:
            break
        rho = inp.density[tuple(vox.T)].astype(np.float64)
        rho = np.where(rho >= 0.0, rho, 0.0)
        # deposit, weighted by the density: the 8 lattice points round the point, each with
        # its own phase
        lat = idx / inp.stride
        base = np.floor(lat).astype(np.int64)
        fr = lat - base
        wd = w[alive] * (rho / mu)[:, None]
        da = d[alive]
        for corner in range(8):
            o = np.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1])
            c = base + o
            ok = np.all((c >= 0) & (c < lsh), axis=1)
            share = np.prod(np.where(o == 1, fr, 1.0 - fr), axis=1) * ok
            flat = np.ravel_multi_index(tuple(np.where(ok[:, None], c, 0).T), lshape)
            ph = hg(np.einsum("ij,ij->i", da, tw[flat]), g)
            for ch in range(3):
                out[:, ch] += np.bincount(flat, wd[:, ch] * share * ph, minlength=len(out))
        p_hit = np.minimum(rho * st_max / mu, 1.0)
        hit = uniform(kk, ev, _D_HIT) < p_hit
        wa = w[alive]
        # null collisions: spectral tracking weights
        null = ~hit
        if np.any(null):
            num = 1.0 - rho[null, None] * inp.sigma_t[None, :] / mu
            wa[null] *= num / np.maximum(1.0 - p_hit[null], 1e-12)[:, None]
        if np.any(hit):
            wa[hit] *= (np.asarray(inp.sigma_s, np.float64) / st_max)[None, :]
            hi = alive[hit]
            d[hi] = _turn(uniform(kk[hit], ev[hit], _D_TURN),
                          uniform(kk[hit], ev[hit], _D_TURN + 1), g, d[hi])
            hits[hi] += 1
        w[alive] = wa
        # roulette after a real collision; the collision cap
        m = w[alive].max(axis=1) / np.maximum(w0[alive], 1e-300)
        q = np.where(hit & (m < ROULETTE), m / ROULETTE, 1.0)
        survive = uniform(kk, ev, _D_RR) < q
        w[alive] = w[alive] / np.maximum(q, 1e-300)[:, None]
        keep = survive & (hits[alive] < inp.max_collisions) & (w[alive].max(axis=1) > 0.0) \
            & (ev < MAX_EVENTS)
        alive = alive[keep]
    return out.reshape(lshape + (3,))

