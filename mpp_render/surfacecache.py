"""The light gathered onto the surfaces in view, held on a grid over the image (no bpy).

A surface point reflects the sky, the other surfaces and the light the media scatter and emit
as its layers' directional albedo times the gathered light G(x) = sum_k w_k L_k
(surfaces.gathered: W/(m^2 sr), a cosine-weighted mean over the hemisphere, with the
gathers' balance-heuristic weights w_k).  G depends on the point and its normal, not on the
direction it is seen from, and over a surface it changes on the scale of what throws the
light (a slab above a ground, the fog round a lamp), not of the pixels.  Gathered per camera
sample (4 marches each, Tuning.surface_gathers) it is most of the march where a ground is in
view, and its noise keeps adaptive sampling taking samples there.

So the frame gathers G once, before its pilot and tiles, at the points where camera rays
through a grid over the image meet a surface: ``Tuning.surface_cache`` points across the
image's width, at most one a pixel (the points at pixel coordinates i s, j s, s = W /
(across - 1) pixels, ``py`` down from the top edge as camera.primary_rays takes them), each
with ``Tuning.surface_cache_gathers`` directions stratified over the hemisphere.  Down to
that one point a pixel the grid is the same fraction of the image at any resolution: the
cache costs the same at 1280x720 and at 1920x1080, and a picture's expected value does not
depend on its pixel count.  A smaller image (the suite's 160x120) has a coarser grid than a
large one, so its error is an upper bound of a large image's box-downsampled to its size.

A camera sample whose ray meets a surface reads G bilinearly from the 4 grid points round its
pixel position (``lookup``), where all 4 (those with a weight) met the same surface, with
normals within ``COS_NORMAL`` of its own, in its plane (their distance from its tangent
plane at most ``PLANE`` times their distance from it).  Elsewhere (an edge, a silhouette, a
point the grid's rays did not see) the sample gathers itself as without the cache.  The
cache's error is its interpolation over s pixels (a smooth G: second order in s) and the
noise of its gathers, both falling as ``across`` and the gathers grow; ``across`` below 2
turns it off (every sample gathers, unbiased per sample: the Reference quality).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

COS_NORMAL = 0.95   # a grid point's normal within this cosine of the sample's
PLANE = 0.05        # a grid point's height over the sample's tangent plane per metre away
CACHE_SEED = 0x68E31DA4   # offsets the seed of the cache's gathers
CACHE_TILE = 1 << 25      # offsets the cache's chunks from the tiles' and the pilot's streams
CHUNK_POINTS = 256        # grid points a chunk of the cache's work gathers at


def stands_for(q, nq, sq, p, n, s) -> np.ndarray:
    """Whether points ``q`` (m) with unit normals ``nq`` on surfaces ``sq`` may stand for
    points ``p`` with normals ``n`` on surfaces ``s`` (arrays broadcasting against each other,
    the vectors along the last axis): the same surface (``s`` >= 0), normals within
    COS_NORMAL, ``q`` within PLANE of ``p``'s tangent plane."""
    rel = q - p
    height = np.abs(np.einsum("...j,...j->...", rel, n))
    return ((s >= 0) & (sq == s) & (np.einsum("...j,...j->...", nq, n) >= COS_NORMAL)
            & (height <= PLANE * np.linalg.norm(rel, axis=-1)))


@dataclass
class Grid:
    """The cache's grid over an image: ``nx`` x ``ny`` points ``spacing`` pixels apart, the
    first at the image's top-left corner (0, 0)."""

    nx: int
    ny: int
    spacing: float

    @classmethod
    def over(cls, width: int, height: int, across: int) -> "Grid":
        """``across`` (>= 2) points along the width, as many rows as cover the height."""
        across = max(2, int(across))
        s = float(width) / (across - 1)
        return cls(across, int(math.ceil(height / s)) + 1, s)

    def pixels(self):
        """(px (P,), py (P,)) the grid's points in pixel coordinates, row-major."""
        y, x = np.mgrid[0:self.ny, 0:self.nx]
        return x.ravel() * self.spacing, y.ravel() * self.spacing

    def corners(self, px, py):
        """(index (N,4) int, weight (N,4)) the 4 grid points round pixel positions
        ``px``, ``py`` and their bilinear weights (summing to 1)."""
        fx = np.asarray(px, np.float64) / self.spacing
        fy = np.asarray(py, np.float64) / self.spacing
        i0 = np.clip(np.floor(fx), 0, self.nx - 2).astype(np.int64)
        j0 = np.clip(np.floor(fy), 0, self.ny - 2).astype(np.int64)
        tx = np.clip(fx - i0, 0.0, 1.0)
        ty = np.clip(fy - j0, 0.0, 1.0)
        base = j0 * self.nx + i0
        index = np.stack([base, base + 1, base + self.nx, base + self.nx + 1], axis=1)
        weight = np.stack([(1 - tx) * (1 - ty), tx * (1 - ty), (1 - tx) * ty, tx * ty], axis=1)
        return index, weight


@dataclass
class SurfaceCache:
    """G at the grid's points: ``point`` (P,3) m (offset off the surface as the shading's
    points are), ``normal`` (P,3) unit (towards the camera), ``surface`` (P,) the surface's
    index (surfaces.SurfaceSet.surface; -1 where the ray met none), ``incident`` (P,3)
    W/(m^2 sr)."""

    grid: Grid
    point: np.ndarray
    normal: np.ndarray
    surface: np.ndarray
    incident: np.ndarray

    @classmethod
    def empty(cls, grid: Grid) -> "SurfaceCache":
        """A cache of ``grid`` whose points have met no surface yet."""
        p = grid.nx * grid.ny
        return cls(grid, np.zeros((p, 3)), np.zeros((p, 3)), np.full(p, -1, np.int64),
                   np.zeros((p, 3)))

    def fill(self, index, point, normal, surface, incident) -> None:
        """Store the gathered light of the grid points ``index`` (their rays met a surface)."""
        self.point[index] = point
        self.normal[index] = normal
        self.surface[index] = surface
        self.incident[index] = incident

    def compatible(self, a, b) -> np.ndarray:
        """Whether grid points ``b`` may stand for grid points ``a`` (index arrays of the
        same shape; stands_for)."""
        return stands_for(self.point[b], self.normal[b], self.surface[b],
                          self.point[a], self.normal[a], self.surface[a])

    def smooth(self, passes: int = 1) -> None:
        """Filter ``incident`` ``passes`` times with the 3 x 3 binomial kernel (1 2 1)^2 / 16
        over the grid, each point over its compatible neighbours (renormalised): the
        gathers' noise falls to 0.375 of a point's in one pass, the interpolation's
        footprint widens from one spacing to about two."""
        g = self.grid
        own = np.arange(g.nx * g.ny).reshape(g.ny, g.nx)
        for _ in range(max(0, int(passes))):
            total = np.zeros((g.ny, g.nx, 3))
            weight = np.zeros((g.ny, g.nx))
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    ys = slice(max(0, -dy), g.ny - max(0, dy))
                    xs = slice(max(0, -dx), g.nx - max(0, dx))
                    yn = slice(max(0, dy), g.ny - max(0, -dy))
                    xn = slice(max(0, dx), g.nx - max(0, -dx))
                    a, b = own[ys, xs], own[yn, xn]
                    w = (2 - abs(dx)) * (2 - abs(dy)) * self.compatible(a, b)
                    total[ys, xs] += w[..., None] * self.incident[b]
                    weight[ys, xs] += w
            hit = weight > 0
            self.incident.reshape(g.ny, g.nx, 3)[hit] = total[hit] / weight[hit, None]

    def lookup(self, px, py, point, normal, surface):
        """(incident (N,3), ok (N,) bool): G at the samples of pixel positions ``px``,
        ``py`` whose rays met surface ``surface`` (N,) at ``point`` (N,3, offset as the
        cache's) with facing normals ``normal`` (N,3), interpolated where ``ok`` (module
        docstring); 0 elsewhere."""
        index, weight = self.grid.corners(px, py)                # (N,4) each
        good = stands_for(self.point[index], self.normal[index], self.surface[index],
                          np.asarray(point, np.float64)[:, None, :],
                          np.asarray(normal, np.float64)[:, None, :],
                          np.asarray(surface)[:, None])
        ok = np.all(good | (weight <= 0.0), axis=1)
        incident = np.einsum("nk,nkj->nj", np.where(good, weight, 0.0), self.incident[index])
        incident[~ok] = 0.0
        return incident, ok
