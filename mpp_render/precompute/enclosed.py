"""Which voxels of a medium's grid lie behind the scene's opaque surfaces: inside a closed
mesh, or under a ground.  No light reaches them, so they hold no light and must not weigh in
the traced paths' lattice means (lightpaths.PathLattice.tent_mass): a lattice point on a
ground whose tent reaches below it averaged the fog above with the empty fog beneath, and the
world fog's grid, a box over the view frustum, often lies a third below the ground
(p_fog_point: 30 % of its voxels).

The test reads the surfaces' orientation (a face's normal points to the side it is seen
from, where the light is): along each of the grid's three index axes, both ways, the nearest
surface a voxel centre's ray crosses is a vote, "behind" when the ray leaves through the
face's back (its normal along the ray), "in front" otherwise; no surface that way, no vote.
A voxel is enclosed when "behind" wins.  One ray per grid column and axis finds every
crossing along it (surfaces.intersect, again past each hit), so the cost is the grid's
columns, not its voxels.  A mesh with its normals flipped reads the other way round; the
paths still fly through every voxel (only the lattice means change), so a wrong vote can
brighten the lattice point it falls on, never block light.
"""
from __future__ import annotations

import numpy as np

MAX_CROSSINGS = 32   # surface crossings followed along one grid column


def crossings(ss, o, d, t_max: float):
    """Every surface crossing of the rays o + t d (unit d, (N,3) world metres) for t in
    (0, t_max]: (t (N,K) m, inf past a ray's last one; side (N,K): +1 where the face's normal
    points along d, -1 against it, 0 past the last)."""
    from ..surfaces import intersect
    n = len(o)
    ts = np.full((n, MAX_CROSSINGS), np.inf)
    side = np.zeros((n, MAX_CROSSINGS), np.int8)
    base = np.zeros(n)
    live = np.arange(n)
    eps = 1e-7 * max(float(t_max), 1e-6)
    for k in range(MAX_CROSSINGS):
        if not live.size:
            break
        t, tri = intersect(ss, o[live] + d[live] * base[live, None], d[live],
                           np.maximum(t_max - base[live], 0.0))
        hit = tri >= 0
        live, t, tri = live[hit], t[hit], tri[hit]
        ts[live, k] = base[live] + t
        side[live, k] = np.where(np.einsum("ij,ij->i", ss.normal[tri], d[live]) > 0.0, 1, -1)
        base[live] = ts[live, k] + eps
    return ts, side


def enclosed_voxels(pm, ss) -> np.ndarray:
    """bool (X,Y,Z): the voxels of prepared medium ``pm`` behind the opaque surfaces of the
    SurfaceSet ``ss`` (module docstring); all False without surfaces."""
    return enclosed_cells(tuple(pm.grid.shape[:3]), pm.i2w, ss)


def enclosed_cells(shape, i2w, ss) -> np.ndarray:
    """bool ``shape``: the voxels of a grid of ``shape`` (index to world ``i2w``, 4x4 or
    3x4, metres) behind the opaque surfaces of the SurfaceSet ``ss``; all False without
    surfaces (``enclosed_voxels``: a medium's grid; the world fog's far box,
    lightpaths._far_multiple)."""
    shape = tuple(int(n) for n in shape)
    if ss is None or ss.empty:
        return np.zeros(shape, bool)
    i2w = np.asarray(i2w, np.float64)
    behind = np.zeros(shape, np.int16)
    front = np.zeros(shape, np.int16)
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        step = i2w[:3, axis]
        length = float(np.linalg.norm(step))
        if not length > 0.0:
            continue
        d = step / length
        grid = np.meshgrid(*[np.arange(shape[a]) for a in others], indexing="ij")
        idx = np.zeros((grid[0].size, 3))
        for a, g in zip(others, grid):
            idx[:, a] = g.reshape(-1)
        idx[:, axis] = -1.0                       # each column's ray starts a voxel before it
        o = idx @ i2w[:3, :3].T + i2w[:3, 3]
        ts, side = crossings(ss, o, np.broadcast_to(d, o.shape).copy(),
                             (shape[axis] + 1) * length)
        tv = (np.arange(shape[axis]) + 1.0) * length          # the voxels along the ray
        k = (ts[:, None, :] < tv[None, :, None]).sum(axis=2)      # the next crossing's index
        rows = np.arange(len(ts))[:, None]
        nxt = np.where(k < MAX_CROSSINGS, side[rows, np.minimum(k, MAX_CROSSINGS - 1)], 0)
        prv = np.where(k > 0, side[rows, np.maximum(k - 1, 0)], 0)
        # ahead: leaving through the back (+1) is behind; looking back, a face whose normal
        # points along d (+1) faces the voxel: in front
        votes_behind = (nxt > 0).astype(np.int16) + (prv < 0)
        votes_front = (nxt < 0).astype(np.int16) + (prv > 0)
        order = [others[0], others[1], axis]
        back = np.argsort(order)
        shape_cols = (shape[others[0]], shape[others[1]], shape[axis])
        behind += votes_behind.reshape(shape_cols).transpose(back)
        front += votes_front.reshape(shape_cols).transpose(back)
    return behind > front


def enclosed_fraction(shape, i2w, ss, sub: int = 2) -> np.ndarray:
    """float64 ``shape``: the part of each voxel of a grid of ``shape`` (index to world
    ``i2w``) behind the surfaces of ``ss``, from ``enclosed_cells`` at the centres of
    ``sub`` x ``sub`` x ``sub`` equal parts of it: a voxel the ground cuts holds the part
    of its cell above it, not all or nothing by its centre."""
    shape = tuple(int(n) for n in shape)
    if ss is None or ss.empty or sub <= 1:
        return enclosed_cells(shape, i2w, ss).astype(np.float64)
    i2w = np.asarray(i2w, np.float64)
    fine = np.eye(4)
    fine[:3, :3] = i2w[:3, :3] / sub
    # fine index f is coarse index (f + 1/2) / sub - 1/2
    fine[:3, 3] = i2w[:3, 3] + i2w[:3, :3] @ np.full(3, 0.5 / sub - 0.5)
    got = enclosed_cells(tuple(n * sub for n in shape), fine, ss)
    return got.reshape(shape[0], sub, shape[1], sub, shape[2], sub).mean(axis=(1, 3, 5))

