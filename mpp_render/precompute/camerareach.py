"""How far a path's light reaches the camera: the walk's reach and the camera's roulette.

A path in an absorbing medium walks an optical distance of about

    r = sqrt(2 / ((1 - a)(1 - g)))                                         [optical depth]

before it is absorbed (``walk_reach``: 1 / (1 - a) flights of mean square optical length
2 / (1 - g), albedo a of the channel that scatters most, anisotropy g), so the light of a
path at x reaches the camera mostly where the camera's optical depth tau_c(x) is within r.
Two estimates use that:

- the sky deficit's paths start by odds exp(-max(tau_c - r, 0)) (skydeficit.camera_odds);
- the lights' paths play a roulette (``roulette_odds``; paths.py, "The camera's roulette"):
  past the reach, the light a path will still carry to the camera falls as diffused light
  does, by e every diffusion length l = 1 / sqrt(3 (1 - a)(1 - a g)) (``diffusion_length``),
  and the odds of going on follow it (survival in proportion to the expected contribution,
  as in adjoint-driven Russian roulette, Vorba and Krivanek 2016):
  q(x) = max(floor, exp(-max(tau_c - r, 0) / l)), the largest within ``ODDS_STEPS``
  lattice steps round x.  At a real collision where q is below the lowest odds the path has
  met, it survives with the ratio and its weight grows by its inverse.  The estimate stays unbiased whatever the odds
  (a roulette moves noise, not the mean); they only say where the paths' work is spent.
  ``floor`` (Tuning.camera_roulette) bounds a path's weight to 1 / floor its plain weight.
"""
from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from ..paths import rate_span

# lattice steps round a point whose largest odds it takes: the tracer reads the nearest point's
# odds (up to half a step from the path) and a deposit lands on the 8 points round the path
# (up to a step away), so a path plays only where every point its odds and its light could
# reach is deep
ODDS_STEPS = 2


def largest_albedo(pm) -> float:
    """The albedo sigma_s / sigma_t of ``pm``'s channel that scatters most (0 without
    extinction)."""
    st = np.asarray(pm.sigma_t, np.float64)
    ss = np.asarray(pm.sigma_s, np.float64)
    return float(np.max(np.where(st > 0.0, ss / np.where(st > 0.0, st, 1.0), 0.0)))


def walk_reach(albedo: float, g: float) -> float:
    """The root-mean-square optical distance a path walks before it is absorbed in a medium of
    ``albedo`` and anisotropy ``g``: sqrt(2 / ((1 - albedo)(1 - g))), 1 / (1 - albedo)
    flights of mean square optical length 2 / (1 - g) (transport mean free paths); infinite
    where nothing absorbs or g is 1."""
    lost = (1.0 - float(albedo)) * (1.0 - float(g))
    return float(np.sqrt(2.0 / lost)) if lost > 0.0 else np.inf


def diffusion_length(albedo: float, g: float) -> float:
    """The optical distance over which diffused light falls by e in a medium of ``albedo``
    and anisotropy ``g``: 1 / sqrt(3 (1 - albedo)(1 - albedo g)) (diffusion theory: the
    fluence falls as exp(-sqrt(3 sigma_a sigma_tr) x), sigma_tr = sigma_t (1 - albedo g),
    here in units of sigma_t); infinite where nothing absorbs."""
    lost = 3.0 * (1.0 - float(albedo)) * (1.0 - float(albedo) * float(g))
    return float(1.0 / np.sqrt(lost)) if lost > 0.0 else np.inf


def optical_size(pm) -> float:
    """An upper bound of the optical depth any straight line inside ``pm``'s grid crosses:
    its largest extinction (1/m, the densest voxel's as its paths read it) times its box's
    diagonal (m): paths.rate_span at that rate."""
    dens = pm.path_density()
    top = float(np.max(dens)) if dens.size else 0.0
    return rate_span(top * float(np.max(pm.sigma_t)), np.asarray(pm.i2w, np.float64)[:3, :3],
                     dens.shape[:3])


def needs_roulette(pm, floor: float) -> bool:
    """Whether ``pm``'s paths can meet odds below 1 (``roulette_odds``): a floor below 1, a
    medium that absorbs (a finite reach) and is optically larger than that reach, and not the
    world's fog (no camera depth through it is kept)."""
    if not (0.0 < float(floor) < 1.0) or pm.endless:
        return False
    reach = walk_reach(largest_albedo(pm), float(pm.g))
    return bool(np.isfinite(reach) and optical_size(pm) > reach)


def roulette_odds(pm, depth: Callable[[], Optional[np.ndarray]],
                  floor: float) -> Optional[np.ndarray]:
    """float32 (LX,LY,LZ) the camera's roulette odds on a path lattice of ``pm`` whose points'
    optical depth to the camera ``depth()`` gives (called only where ``needs_roulette``:
    the depth is a march per lattice point): max(floor, exp(-max(tau - r, 0) / l)) (module
    docstring; r = walk_reach, l = diffusion_length), each point then given the largest odds
    within ``ODDS_STEPS`` lattice steps (``neighbours_largest``), or None where every odds is
    1 (nothing to play) or there is no depth.  The tracer reads the nearest point's odds, up
    to half a step from the path, and a deposit lands on the 8 points round it, up to a step
    away; a heterogeneous medium's depth changes within a step (a thin wisp's lattice point
    behind it).  p_dragon's full render (seeds 0-4) without the roulette 0.0201 / 0.0219 /
    0.0189 / 0.0189 / 0.0185; with it, the largest odds within one step 0.0203 / 0.0220 /
    0.0192 / 0.0193 / 0.0191, within two 0.0202 / 0.0219 / 0.0189 / 0.0189 / 0.0186
    (docs/performance.md, 2026-12-07)."""
    if not needs_roulette(pm, floor):
        return None
    tau = depth()
    if tau is None:
        return None
    albedo, g = largest_albedo(pm), float(pm.g)
    reach, length = walk_reach(albedo, g), diffusion_length(albedo, g)
    t = np.nan_to_num(np.asarray(tau, np.float64), nan=0.0, posinf=np.inf, neginf=0.0)
    odds = neighbours_largest(np.maximum(float(floor),
                                         np.exp(-np.maximum(t - reach, 0.0) / length)),
                              ODDS_STEPS)
    odds = odds.astype(np.float32)
    return odds if np.any(odds < 1.0) else None


def neighbours_largest(a: np.ndarray, steps: int = 1) -> np.ndarray:
    """Each point of the 3-D array ``a`` replaced by the largest value within ``steps`` points
    of it along every axis (a cube of (2 steps + 1)^3, taken axis by axis; the faces' values
    repeated beyond them)."""
    out = np.asarray(a)
    if out.ndim != 3 or not out.size:
        return out
    for ax in range(3):
        n = out.shape[ax]

        def part(lo):
            return tuple(slice(lo, lo + n) if k == ax else slice(None) for k in range(3))
        for _ in range(max(0, int(steps))):
            pad = np.pad(out, [(1, 1) if k == ax else (0, 0) for k in range(3)], mode="edge")
            out = np.maximum(np.maximum(pad[part(0)], pad[part(1)]), pad[part(2)])
    return out
