"""The memory budget: media whose precompute would not fit are box-downsampled first.

The precompute (precompute/) holds one float32 field per medium on its padded grid
(nx+2, ny+2, nz+2) with ``1 + 3 L + 6`` channels: density, the optical depth to each of the L
lights that emit, and the world light (single and multiply scattered); 3 L more with
multiple scattering in a forward-scattering medium (the light of each light's forward peak,
precompute/layout.py); with multiple scattering the march adds 3 channels of a flat level on
the field's voxels (march.on_field), counted here as the field's.  ``field_bytes`` is
that size; it dominates the render's memory.  When the sum over media exceeds the budget,
the grid with the largest field is made one integer factor coarser, again and again, until
the sum fits (so the largest grids shrink first and end up about equally coarse).

A grid of n voxels along an axis downsampled by F gets m = ceil(n / F) voxels, each the
average of the old voxels it covers (a box filter; old voxels straddling two new ones are
shared by overlap), and its ``index_to_world`` is rescaled by n / m per axis so the grid's
box in the world (voxel cells from index -0.5 to n - 0.5) is exactly the old one and the
integral of density over it (the optical depth through it) is kept.  n / m equals F when F
divides n.
"""
from __future__ import annotations

import dataclasses
import math
from typing import List, Sequence, Tuple

import numpy as np

from .lights import is_dark
from .media import sanitise
from .scene import Light, Medium, SceneDescription

MB = 1 << 20  # bytes in the MB of ``Settings.memory_budget_mb``
WORLD_CHANNELS = 6  # world light, single and multiply scattered (counted even when unused)
ON_FIELD_CHANNELS = 3  # with multiple scattering, the march's flat level on the voxels


def field_channels(lights: Sequence[Light], beams: bool = False) -> int:
    """Channels of a medium's precompute field: density, 3 per emitting light (6 with
    ``beams``: multiple scattering in a medium with a forward peak), 6 of world light."""
    per_light = 6 if beams else 3
    return 1 + per_light * sum(1 for light in lights if not is_dark(light)) + WORLD_CHANNELS


def field_bytes(shape: Tuple[int, ...], lights: Sequence[Light], beams: bool = False,
                multiple: bool = False) -> int:
    """Bytes of the float32 precompute field of a medium whose density has ``shape``, with
    ``multiple`` (multiple scattering on) the march's level on its voxels too."""
    channels = field_channels(lights, beams) + (ON_FIELD_CHANNELS if multiple else 0)
    return 4 * channels * int(np.prod([int(s) + 2 for s in shape]))


def has_beams(media: Sequence[Medium], multiple: bool) -> bool:
    """Whether the precompute gives each light a beam channel: multiple scattering on and a
    medium with a forward peak (phase.delta_fraction > 0)."""
    from .phase import delta_fraction
    return bool(multiple) and any(delta_fraction(float(m.g)) > 0.0 for m in media)


def reduced_shape(shape: Tuple[int, ...], factor: int) -> Tuple[int, ...]:
    """The shape of a grid of ``shape`` downsampled by the integer ``factor``."""
    return tuple(max(1, -(-int(s) // int(factor))) for s in shape)


def plan(shapes: Sequence[Tuple[int, ...]], lights: Sequence[Light], budget_mb: float,
         beams: bool = False, multiple: bool = False) -> List[int]:
    """Integer downsampling factor of each grid (1: kept) so the fields of all fit in
    ``budget_mb`` MB (<= 0: unlimited).  The grid with the largest field is coarsened one
    factor at a time; when even one voxel per medium would not fit, the factors stop there."""
    factors = [1] * len(shapes)
    if budget_mb <= 0 or not shapes:
        return factors
    budget = float(budget_mb) * MB
    sizes = [field_bytes(s, lights, beams, multiple) for s in shapes]
    while sum(sizes) > budget:
        order = sorted(range(len(shapes)), key=lambda i: -sizes[i])
        i = next((i for i in order if max(reduced_shape(shapes[i], factors[i])) > 1), None)
        if i is None:
            break
        f = factors[i] + 1
        now = reduced_shape(shapes[i], factors[i])
        # skip factors that leave the shape as it is (e.g. 7 -> ceil(7/6) = ceil(7/5) = 2)
        while f < max(shapes[i]) and reduced_shape(shapes[i], f) == now:
            f += 1
        factors[i] = f
        sizes[i] = field_bytes(reduced_shape(shapes[i], f), lights, beams, multiple)
    return factors


def _axis_weights(n: int, m: int):
    """Overlaps of m new cells with n old ones along one axis, for a box filter: (k, m)
    old indices and (k, m) weights (summing to 1 per new cell), k = old cells per new cell
    at most.  New cell j spans old cells [j n/m, (j+1) n/m) (edges at integer old cells'
    boundaries -0.5 + i)."""
    s = n / m
    lo = np.arange(m) * s
    hi = lo + s
    k = int(math.ceil(s)) + 1
    first = np.floor(lo).astype(np.int64)
    idx = first[None, :] + np.arange(k)[:, None]
    over = np.clip(np.minimum(idx + 1, hi[None, :]) - np.maximum(idx, lo[None, :]), 0.0, None)
    over[idx >= n] = 0.0
    return np.minimum(idx, n - 1), (over / s).astype(np.float32)


def box_downsample(density: np.ndarray, factor: int) -> np.ndarray:
    """``density`` (nx,ny,nz) averaged onto ``reduced_shape(shape, factor)`` voxels (float32),
    each new voxel the overlap-weighted mean of the old voxels its cell covers."""
    out = np.asarray(density, np.float32)
    for ax, m in enumerate(reduced_shape(out.shape, factor)):
        n = out.shape[ax]
        if m == n:
            continue
        idx, w = _axis_weights(n, m)
        sh = [1] * 3
        sh[ax] = m
        acc = None
        for row in range(idx.shape[0]):
            term = np.take(out, idx[row], axis=ax) * w[row].reshape(sh)
            acc = term if acc is None else acc + term
        out = acc
    return np.ascontiguousarray(out, np.float32)


def downsampled_transform(index_to_world: np.ndarray, old_shape, new_shape) -> np.ndarray:
    """``index_to_world`` of the downsampled grid: new index j maps to old index
    -0.5 + (j + 0.5) n / m per axis, so the cells cover the same world box."""
    s = np.array([o / n for o, n in zip(old_shape, new_shape)], np.float64)
    a = np.eye(4)
    a[:3, :3] = np.diag(s)
    a[:3, 3] = 0.5 * (s - 1.0)
    return np.asarray(index_to_world, np.float64) @ a


def _describe(shape) -> str:
    return f"{shape[0]}^3" if len(set(shape)) == 1 else "x".join(str(s) for s in shape)


def fit_media(media: Sequence[Medium], lights: Sequence[Light], budget_mb: float,
              warnings: List[str], multiple: bool = False) -> List[Medium]:
    """``media`` with the grids that do not fit ``budget_mb`` MB downsampled (new Medium
    objects; the others are returned as they are) and a warning for each.  Media sharing
    one density array share the downsampled array too."""
    shapes = [tuple(np.shape(m.density)) for m in media]
    if any(len(s) != 3 for s in shapes):  # prepare() reports those
        return list(media)
    factors = plan(shapes, lights, budget_mb, has_beams(media, multiple), bool(multiple))
    out, done = [], {}
    for m, shape, f in zip(media, shapes, factors):
        if f == 1:
            out.append(m)
            continue
        key = (id(m.density), f)
        if key not in done:
            d, bad = sanitise(m.density)  # NaN would spread over the whole block
            if bad:
                warnings.append(f"medium '{m.name}': {bad} voxels were NaN, infinite or negative "
                                "and were set to 0")
            done[key] = box_downsample(d, f)
        small = done[key]
        warnings.append(f"medium '{m.name}': grid {_describe(shape)} downsampled by {f} to fit "
                        f"the memory budget of {budget_mb:g} MB; now {_describe(small.shape)}")
        out.append(dataclasses.replace(m, density=small, index_to_world=downsampled_transform(
            m.index_to_world, shape, small.shape), emission_grid=_downsampled_rgb(
                m, m.emission_grid, f), scatter_grid=_downsampled_rgb(m, m.scatter_grid, f,
                                                                      weighted=True),
            extinction_grid=_downsampled_rgb(m, m.extinction_grid, f, weighted=True)))
    return out


def _downsampled_rgb(m: Medium, e, factor: int, weighted: bool = False):
    """``e``, one of ``m``'s RGB grids, box-downsampled like its density (NaN and negatives
    first set to 0, so they do not spread over a block; prepare() warns about them), or None.
    ``weighted``: each block's mean weighted by the density (a scatter colour's or an
    extinction colour's factor: the block then scatters and attenuates what its voxels did
    together; 1 where the block is empty)."""
    if e is None or np.shape(e) != tuple(np.shape(m.density)) + (3,):
        return e  # None, or a mismatch that prepare() reports
    e = sanitise(e)[0]
    if not weighted:
        return np.stack([box_downsample(e[..., c], factor) for c in range(3)], axis=-1)
    w = sanitise(m.density)[0]
    den = box_downsample(w, factor)
    safe = np.where(den > 0, den, 1.0)
    return np.stack([np.where(den > 0, box_downsample(e[..., c] * w, factor) / safe, 1.0)
                     for c in range(3)], axis=-1).astype(np.float32)


def apply_budget(desc: SceneDescription, warnings: List[str]) -> SceneDescription:
    """``desc`` itself when its media fit ``desc.settings.memory_budget_mb``, else a shallow
    copy whose media are downsampled (``desc`` is left untouched); warnings are appended."""
    budget = float(getattr(desc.settings, "memory_budget_mb", 0) or 0)
    if budget <= 0 or not desc.media:
        return desc
    media = fit_media(desc.media, desc.lights, budget, warnings,
                      bool(getattr(desc.settings, "multiple", False)))
    if all(a is b for a, b in zip(media, desc.media)):
        return desc
    return dataclasses.replace(desc, media=media)
