"""Lattices on a medium's padded grid: the voxels the precompute fills (``needed_flat``),
the lattices ``stride`` voxels apart of the light pyramid (``walk_lattice``) and of the world
light (``coarse_lattice``); index coordinates to world positions: PreparedMedium.to_world.

Index coordinates count padded-grid voxels from the grid's origin; a lattice ``stride``
voxels apart has its point ``idx`` at index ``idx * stride``; lattices are in C order (the
order of ``reshape(-1)``).
"""
from __future__ import annotations

import numpy as np

from ..lights import extent_radius, is_dark
from ..media import PAD, PreparedMedium, box_distance


MULTIPLE_RESOLUTION = 64  # lattice points along the longest side for the light pyramid
CORE_CUBE = 32  # voxels: the largest half-side of core_radius's cube


def needed_flat(pm: PreparedMedium):
    """Flat indices of the padded grid points whose trilinear neighbourhood holds non-zero
    density: every point of a cell with a non-zero corner (the 3x3x3 dilation of the
    occupied points, diagonal neighbours included)."""
    return np.flatnonzero(dilate(pm.grid > 0.0))


def grid_points(pm: PreparedMedium, flat):
    """World positions (N,3) of the padded grid points with flat indices ``flat``."""
    ijk = np.stack(np.unravel_index(flat, pm.grid.shape), axis=1).astype(np.float64)
    return pm.to_world(ijk)


def needed_points(pm: PreparedMedium):
    """``needed_flat`` and the world positions of those points."""
    flat = needed_flat(pm)
    return flat, grid_points(pm, flat)


def lattice_shape(shape, stride: int) -> tuple:
    """Points along each axis of a lattice ``stride`` voxels apart that covers a grid of
    ``shape`` (its last point at or beyond the grid's last voxel)."""
    return tuple((s - 1 + stride - 1) // stride + 1 for s in shape)


def walk_lattice(pm: PreparedMedium, resolution: int = MULTIPLE_RESOLUTION):
    """(stride, shape, h) of the light pyramid's lattice on ``pm``: about ``resolution``
    points along the grid's longest side, never finer than the voxels; h its spacing, m."""
    return _lattice_along(pm, max(pm.grid.shape), resolution)


def paths_lattice(pm: PreparedMedium, resolution: int = MULTIPLE_RESOLUTION):
    """(stride, shape, h) of the traced paths' lattice on ``pm`` (precompute.lightpaths): at
    most ``resolution`` points along the longest side of the medium's voxels, its padding
    left out, never finer than the voxels; h its spacing, m.  (Counting the padding, as
    ``walk_lattice`` does, put a mesh volume of 128 voxels, 130 with its padding, on 44
    points for a Resolution of 64, not 64.)"""
    return _lattice_along(pm, max(max(pm.grid.shape) - 2 * PAD, 1), resolution)


def voxel_length(pm: PreparedMedium) -> float:
    """The side (m) of a cube of one voxel's volume: the lattices' spacing per voxel."""
    return float(np.cbrt(abs(np.linalg.det(pm.i2w[:3, :3]))))


def core_radius(pm: PreparedMedium, light) -> float:
    """The radius (m) of the core of the first scatterings round ``light`` inside ``pm``:
    the light's extent (lights.extent_radius: a lamp's radius, half an area light's
    diagonal) or the mean free path where it sits, whichever is less.  Within its extent a
    light's first-scattering source is about even (~ 1 / max(d, r)^2 round a lamp, flat
    under an emitter), and it falls as e^{-d / l} over a mean free path l.  l is 1 over
    the extinction (1/m, its largest channel) averaged over the cube of half-side the
    extent round the light (at least a voxel's, at most ``CORE_CUBE`` voxels: a wide
    emitter in a large grid reads a bounded cube), weighted by the extinction itself: where
    the first scatterings are; infinite where the cube is empty."""
    extent = float(extent_radius(light))
    voxel = voxel_length(pm)
    centre = np.rint(pm.to_index(np.asarray(light.position, np.float64).reshape(1, 3))[0])
    centre = np.clip(centre.astype(np.int64), 0, np.array(pm.grid.shape) - 1)
    half = min(max(1, int(np.ceil(extent / voxel))), CORE_CUBE)
    cube = pm.grid[tuple(slice(max(0, c - half), c + half + 1) for c in centre)]
    sigma = float(np.max(pm.sigma_t)) * cube.astype(np.float64)
    mass = float(sigma.sum())
    free_path = mass / float(np.square(sigma).sum()) if mass > 0.0 else np.inf
    return min(extent, free_path)


def lamp_resolution(pm: PreparedMedium, lights, resolution: int = MULTIPLE_RESOLUTION,
                    most: int = 2) -> int:
    """The traced paths' Resolution on ``pm`` (``paths_lattice``): ``resolution``, raised
    where a point, spot or area light sits inside the medium's box until the lattice's
    spacing h is at most half the radius of the core of its first scatterings
    (``core_radius``: its extent or the mean free path there, the less), one voxel at the
    finest.  Round such a light the multiply scattered light has a core as wide as that of
    its source, over which the lattice's splat and read smooth M with a tent of half-width
    h on each side; with h <= R / 2 the smoothing's standard deviation (h / sqrt(3) per
    pass, about 0.8 h for both) stays under half the core's radius R.  A pure point light
    (r = 0) asks for the voxels themselves.  ``most`` (Tuning.core_refine): the lattice
    is at most that many times finer along the longest side than ``resolution``, which
    bounds what the refinement adds on a large grid (its points, 8x at 2, hold about 600
    bytes each while the paths are traced)."""
    voxels = max(max(pm.grid.shape) - 2 * PAD, 1)
    voxel = voxel_length(pm)
    res = int(resolution)
    for light in lights:
        if light.kind == "SUN" or is_dark(light):
            continue
        if box_distance(pm, light.position) > 0.0:
            continue
        finest = max(1, int(np.floor(0.5 * core_radius(pm, light) / voxel + 1e-9)))
        if int(np.ceil(voxels / max(res, 2))) > finest:
            res = max(res, int(np.ceil(voxels / finest)))
    return min(res, max(int(resolution), int(most) * int(resolution)))


def _lattice_along(pm: PreparedMedium, voxels: int, resolution: int):
    """(stride, shape, h): the fewest whole voxels a step that put at most ``resolution``
    points along ``voxels`` voxels of ``pm``'s grid; h the spacing, m."""
    stride = max(1, int(np.ceil(voxels / max(int(resolution), 2))))
    h = stride * voxel_length(pm)
    return stride, lattice_shape(pm.grid.shape, stride), h


def lattice_points(pm: PreparedMedium, shape, spacing: int):
    """(index coordinates (N,3), world positions (N,3, m)) of a lattice of ``shape`` whose
    points lie ``spacing`` padded-grid voxels apart from the grid's origin (a pyramid level k:
    stride 2^k), in C order."""
    idx = lattice_index(shape)
    return idx, pm.to_world(idx * float(spacing))


def lattice_values(grid: np.ndarray, idx: np.ndarray, stride: int) -> np.ndarray:
    """``grid`` (X,Y,Z) at the lattice points ``idx`` (N,3 index coordinates, ``stride``
    voxels apart): the voxel itself, as media.trilinear reads a whole-voxel point, and 0 on
    the grid's last plane and beyond (trilinear's outside), without reading every channel of
    a field eight times."""
    ijk = idx.astype(np.int64) * int(stride)
    ok = np.all(ijk < np.array(grid.shape[:3]) - 1, axis=1)
    flat = np.ravel_multi_index(tuple(np.where(ok[:, None], ijk, 0).T), grid.shape[:3])
    return np.where(ok, grid.reshape(-1)[flat], 0.0)


def lattice_index(shape) -> np.ndarray:
    """Index coordinates (N,3) float64 of every point of a lattice of ``shape`` (3 ints), in
    C order (the order of ``reshape(-1)``)."""
    return np.stack(np.unravel_index(np.arange(int(np.prod(shape))), tuple(shape)),
                    axis=1).astype(np.float64)


def dilate(mask):
    """3x3x3 dilation of a boolean grid (its outer layer is padding: np.roll's wrap is harmless)."""
    for ax in range(3):
        mask = mask | np.roll(mask, 1, axis=ax) | np.roll(mask, -1, axis=ax)
    return mask


def coarse_lattice(pm: PreparedMedium, stride: int):
    """Index points of ``pm``'s padded grid taken every ``stride`` voxels (covering the whole
    grid: the last may lie beyond its last voxel, by less than ``stride``) whose neighbourhood
    of radius ``stride`` holds density (for a point beyond the grid: its last voxel's).  Returns (shape, flat
    indices into that coarse shape, world positions (K,3))."""
    shape = lattice_shape(pm.grid.shape, stride)
    occ = pm.grid > 0.0
    dil = occ.copy()
    for ax in range(3):
        acc = dil.copy()
        for s in range(1, stride + 1):
            acc |= np.roll(dil, s, axis=ax) | np.roll(dil, -s, axis=ax)
        dil = acc
    # a last point beyond the grid's last voxel (where stride does not divide the grid) is
    # taken where that voxel is: the voxels before it interpolate towards it
    at = [np.minimum(np.arange(n) * stride, s - 1) for n, s in zip(shape, pm.grid.shape)]
    flat = np.flatnonzero(dil[np.ix_(*at)])
    ijk = np.stack(np.unravel_index(flat, shape), axis=1).astype(np.float64) * stride
    return shape, flat, pm.to_world(ijk)
