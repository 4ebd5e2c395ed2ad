"""Voxelising the interior of a closed triangle mesh (numpy only, no bpy).

The lattice is laid in the mesh's *object* space, so a rotated or scaled box stays a box of
voxels, and mapped to the world by the object's matrix.  Voxel centres sit at integer index
points; the lattice covers the object-space bounding box exactly, with voxel edges as close to
cubic in *world* metres as the box allows: ``resolution`` voxels along the longest world side.

Inside/outside is the even-odd rule along index axis k: for every voxel column (i, j) the
triangles' crossings of the column's line are found (vectorised over triangle/column pairs),
and a voxel centre is inside when an odd number of crossings lie below it (``inside``).  The
medium's occupancy (``occupancy``) is that 1 / 0, except within half a voxel of the surface,
where the centres hold their signed distance to it, so that the trilinear one-half level
follows the mesh within the voxel.
"""
from __future__ import annotations

import math
from typing import Tuple

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


def _index_points(vertices, index_to_object) -> np.ndarray:
    """The vertices (N,3) in the lattice's index coordinates, moved off shared edges."""
    step = np.diag(index_to_object)[:3]
    origin = index_to_object[:3, 3]
    return (np.asarray(vertices, np.float64) - origin) / step - _JITTER


def _column_hits(p: np.ndarray, triangles: np.ndarray, shape: Tuple[int, int, int]):
    """(i, j, z, t) int64, int64, float64, int64: every crossing of a triangle (corners ``p``
    in index coordinates) with a column line (i, j) along index axis 2, at height z, and the
    triangle it crosses (its row of ``triangles``)."""
    nx, ny, _ = shape
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
    idx = np.flatnonzero(keep)
    parts = []
    start = 0
    while start < idx.size:
        # a chunk of triangles whose column pairs fit in memory
        csum = np.cumsum(count[idx[start:]])
        stop = start + max(1, int(np.searchsorted(csum, _PAIRS_PER_CHUNK, side="right")))
        c = idx[start:stop]
        i, j, z, t = _crossings(tri[c], area[c], i0[c], j0[c], w[c], count[c])
        parts.append((i, j, z, c[t]))
        start = stop
    if not parts:
        e = np.zeros(0, np.int64)
        return e, e, np.zeros(0), e
    return tuple(np.concatenate(q) for q in zip(*parts))


def inside(vertices: np.ndarray, triangles: np.ndarray, index_to_object: np.ndarray,
           shape: Tuple[int, int, int]) -> np.ndarray:
    """Boolean (nx, ny, nz): whether each voxel centre lies inside the mesh (even-odd rule)."""
    hits = _column_hits(_index_points(vertices, index_to_object), triangles, shape)
    return _parity(hits[:3], shape)


def _parity(hits, shape: Tuple[int, int, int]) -> np.ndarray:
    """Boolean (nx, ny, nz) from the crossings (i, j, z) of the column lines along index axis
    2 (``_column_hits``): a centre is inside when an odd number of them lie below it."""
    nx, ny, nz = shape
    i, j, z = hits
    toggles = np.zeros((nx, ny, nz + 1), np.uint8)  # crossings per column, mod 256
    # one toggle at the first voxel centre above each crossing
    np.add.at(toggles, (i, j, np.clip(np.floor(z).astype(np.int64) + 1, 0, nz)), 1)
    parity = np.cumsum(toggles, axis=2, dtype=np.uint8)[..., :nz] & 1
    return parity.astype(bool)


def _crossings(tri, area, i0, j0, w, count):
    """(i, j, z, t) of every (triangle, column) pair whose column passes through the
    triangle's xy projection: the column, the height where it crosses the triangle and the
    triangle (its index in ``tri``)."""
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
    zc = (b0 * z[:, 0] + b1 * z[:, 1] + b2 * z[:, 2])[hit] / a[hit]
    return i[hit], j[hit], zc, t[hit]


# The occupancy's ramp: half its width (voxels) about the surface.  Just under half a voxel
# keeps a box whose faces lie on the lattice's cell faces (a box's own lattice, ``lattice``)
# at the binary values (every centre half a voxel from its nearest face, less the columns'
# sub-voxel offsets _JITTER) and needs no voxels beyond the box; a centre nearer the surface
# than that takes the part of the ramp that moves the trilinear one-half level towards the
# surface.  (A ramp of sqrt(3) voxels puts that level on a flat face exactly but needs two
# voxels beyond the box on every side, which moves the multiple scattering's lattice.)
RAMP_HALF_WIDTH = 0.5 * (1.0 - 1e-4)


def occupancy(vertices: np.ndarray, triangles: np.ndarray, index_to_object: np.ndarray,
              shape: Tuple[int, int, int]) -> np.ndarray:
    """float32 (nx, ny, nz) in [0, 1]: each voxel centre's signed distance d to the mesh's
    surface (positive inside, in voxels) mapped to 1/2 + d / (2 RAMP_HALF_WIDTH), clamped to
    [0, 1]: the centres within RAMP_HALF_WIDTH of the surface move the trilinear
    interpolation's one-half level (the march's sharp surface, media.SHARP_THRESHOLD) from
    the binary centres' staircase towards the surface.  d is the distance to the plane of
    the triangle that the nearest crossing of the centre's column line meets, the nearest of
    the three axes' (one voxel along an axis at most: the surface is nearer than half a
    voxel only where some axis crosses it within that): exact for a flat face and for a
    convex edge's inside, and to first order on a curved surface.  Inside / outside is
    ``inside``'s even-odd rule, so the set of centres at or above one half is the same."""
    p = _index_points(vertices, index_to_object)
    tri = p[np.asarray(triangles, np.int64).reshape(-1, 3)]
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])   # unit normals (0 if flat)
    ln = np.linalg.norm(nrm, axis=1)
    nrm = nrm / np.where(ln > 0.0, ln, 1.0)[:, None]
    flats, dps = [], []
    for ax in range(3):
        perm = [(ax + 1) % 3, (ax + 2) % 3, ax]      # the column axis last
        sh = tuple(shape[q] for q in perm)
        i, j, z, t = _column_hits(p[:, perm], triangles, sh)
        if ax == 2:   # the columns along axis 2 are inside's: its even-odd rule from them
            ins = _parity((i, j, z), shape)
        for k in (np.floor(z).astype(np.int64), np.floor(z).astype(np.int64) + 1):
            ok = (k >= 0) & (k < sh[2]) & (np.abs(k - z) <= 1.0)
            cell = np.zeros((int(ok.sum()), 3), np.int64)
            cell[:, perm[0]], cell[:, perm[1]], cell[:, perm[2]] = i[ok], j[ok], k[ok]
            tt = t[ok]   # voxel centres sit at integer index points
            dps.append(np.abs(np.einsum("ij,ij->i", cell - tri[tt, 0], nrm[tt])))
            flats.append(np.ravel_multi_index(tuple(cell.T), shape))
    # each centre's nearest plane: the pairs sorted by centre, then distance
    flat, dp = np.concatenate(flats), np.concatenate(dps)
    order = np.lexsort((dp, flat))
    flat, dp = flat[order], dp[order]
    first = np.ones(len(flat), bool)
    first[1:] = flat[1:] != flat[:-1]
    near, d = flat[first], dp[first]
    # the binary voxels, and the centres a plane passes within the ramp's half-width of
    occ = ins.astype(np.float32).reshape(-1)
    ramp = d < RAMP_HALF_WIDTH
    near, d = near[ramp], d[ramp] / (2.0 * RAMP_HALF_WIDTH)
    inn = occ[near] > 0.0
    # the even-odd rule decides the side: a centre inside stays at or above one half
    occ[near] = np.where(inn, 0.5 + d, np.minimum(0.5 - d, 0.5 - 1e-6))
    return occ.reshape(shape)


def is_closed(triangles: np.ndarray) -> bool:
    """Whether every edge of the triangle mesh is shared by an even number of triangles (a
    watertight surface, so the even-odd rule is meaningful)."""
    tris = np.asarray(triangles, np.int64)
    if tris.size == 0:
        return False
    edges = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(np.all(counts % 2 == 0))
