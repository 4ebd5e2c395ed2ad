"""Voxelising the interior of a closed triangle mesh (numpy only, no bpy).

The lattice is laid in the mesh's *object* space, so a rotated or scaled box stays a box of
voxels, and mapped to the world by the object's matrix.  Voxel centres sit at integer index
points; the lattice covers the object-space bounding box exactly, with voxel edges as close to
cubic in *world* metres as the box allows: ``resolution`` voxels along the longest world side.

Inside/outside is the even-odd rule along index axis k: for every voxel column (i, j) the
triangles' crossings of the column's line are found (vectorised over triangle/column pairs),
and a voxel centre is inside when an odd number of crossings lie below it.
"""
from __future__ import annotations

import math
from typing import Optional, Tuple

import numpy as np

# Sub-voxel offsets (index units) that move columns off shared triangle edges and vertices,
# where a crossing could otherwise be counted twice or not at all.
_JITTER = np.array([3.1415926e-7, 2.7182818e-7, 1.4142135e-7])
_PAIRS_PER_CHUNK = 1 << 22


def lattice(vertices: np.ndarray, matrix: np.ndarray, resolution: int):
    """``(shape, index_to_object 4x4)`` of the voxel lattice over the object-space bounding
    box of ``vertices`` (N,3); None when the box is flat along some axis.

    ``matrix``: the object's 4x4 world matrix, used only to measure the world lengths of the
    box's sides.  Each axis gets ``ceil(world side / h)`` voxels (at least 1) with
    ``h = longest world side / resolution``; the voxel size along an axis is then
    object side / count, so the lattice ends exactly on the box."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    side = hi - lo
    if np.any(side <= 0.0) or not np.all(np.isfinite(side)):
        return None
    world_side = side * np.linalg.norm(np.asarray(matrix, dtype=np.float64)[:3, :3], axis=0)
    h = float(world_side.max()) / max(int(resolution), 1)
    if h <= 0.0:
        return None
    shape = tuple(max(1, int(math.ceil(w / h - 1e-9))) for w in world_side)
    step = side / np.array(shape, dtype=np.float64)
    index_to_object = np.eye(4)
    index_to_object[:3, :3] = np.diag(step)
    index_to_object[:3, 3] = lo + 0.5 * step
    return shape, index_to_object


def inside(vertices: np.ndarray, triangles: np.ndarray, index_to_object: np.ndarray,
           shape: Tuple[int, int, int]) -> np.ndarray:
    """Boolean (nx, ny, nz): whether each voxel centre lies inside the mesh (even-odd rule)."""
    nx, ny, nz = shape
    step = np.diag(index_to_object)[:3]
    origin = index_to_object[:3, 3]
    p = (np.asarray(vertices, np.float64) - origin) / step - _JITTER
    tri = p[np.asarray(triangles, np.int64)]                  # (M, 3 corners, 3 xyz)
    x, y = tri[..., 0], tri[..., 1]
    area = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    i0 = np.clip(np.ceil(x.min(axis=1)), 0, nx).astype(np.int64)
    i1 = np.clip(np.floor(x.max(axis=1)), -1, nx - 1).astype(np.int64)
    j0 = np.clip(np.ceil(y.min(axis=1)), 0, ny).astype(np.int64)
    j1 = np.clip(np.floor(y.max(axis=1)), -1, ny - 1).astype(np.int64)
    w = np.maximum(i1 - i0 + 1, 0)
    count = w * np.maximum(j1 - j0 + 1, 0)
    keep = (count > 0) & (np.abs(area) > 1e-300)
    toggles = np.zeros((nx, ny, nz + 1), np.uint8)  # crossings per column, mod 256
    idx = np.flatnonzero(keep)
    start = 0
    while start < idx.size:
        # a chunk of triangles whose column pairs fit in memory
        csum = np.cumsum(count[idx[start:]])
        stop = start + max(1, int(np.searchsorted(csum, _PAIRS_PER_CHUNK, side="right")))
        _crossings(tri[idx[start:stop]], area[idx[start:stop]], i0[idx[start:stop]],
                   j0[idx[start:stop]], w[idx[start:stop]], count[idx[start:stop]], toggles, nz)
        start = stop
    parity = np.cumsum(toggles, axis=2, dtype=np.uint8)[..., :nz] & 1
    return parity.astype(bool)


def _crossings(tri, area, i0, j0, w, count, toggles, nz):
    """Add, for every (triangle, column) pair whose column passes through the triangle's xy
    projection, one toggle at the first voxel centre above the crossing."""
    t = np.repeat(np.arange(len(tri)), count)
    offset = np.arange(t.size) - np.repeat(np.cumsum(count) - count, count)
    i = i0[t] + offset % w[t]
    j = j0[t] + offset // w[t]
    x, y, z = tri[t, :, 0], tri[t, :, 1], tri[t, :, 2]
    # signed areas of the sub-triangles opposite each corner (barycentric numerators)
    b0 = (x[:, 1] - i) * (y[:, 2] - j) - (x[:, 2] - i) * (y[:, 1] - j)
    b1 = (x[:, 2] - i) * (y[:, 0] - j) - (x[:, 0] - i) * (y[:, 2] - j)
    b2 = (x[:, 0] - i) * (y[:, 1] - j) - (x[:, 1] - i) * (y[:, 0] - j)
    a = area[t]
    hit = np.where(a > 0, (b0 > 0) & (b1 > 0) & (b2 > 0), (b0 < 0) & (b1 < 0) & (b2 < 0))
    if not np.any(hit):
        return
    zc = (b0 * z[:, 0] + b1 * z[:, 1] + b2 * z[:, 2])[hit] / a[hit]
    k = np.clip(np.floor(zc).astype(np.int64) + 1, 0, nz)
    np.add.at(toggles, (i[hit], j[hit], k), 1)


def voxelise(vertices: np.ndarray, triangles: np.ndarray, matrix: np.ndarray,
             resolution: int) -> Optional[Tuple[np.ndarray, np.ndarray]]:
    """``(density float32 (nx, ny, nz), index_to_world 4x4)`` of the mesh interior: 1 at voxel
    centres inside, 0 outside.  ``vertices`` (N,3) are in object space, ``matrix`` is the
    object's world matrix.  None when the mesh is flat (no interior)."""
    lat = lattice(vertices, matrix, resolution)
    if lat is None:
        return None
    shape, i2o = lat
    density = inside(vertices, triangles, i2o, shape).astype(np.float32)
    return density, np.asarray(matrix, dtype=np.float64) @ i2o


def is_closed(triangles: np.ndarray) -> bool:
    """Whether every edge of the triangle mesh is shared by an even number of triangles (a
    watertight surface, so the even-odd rule is meaningful)."""
    tris = np.asarray(triangles, np.int64)
    if tris.size == 0:
        return False
    edges = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(np.all(counts % 2 == 0))
