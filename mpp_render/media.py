"""Media prepared for sampling: padded density grids, world <-> index maps, ray bounds.

A ``Medium`` (scene.py) holds density values at integer index points.  Here each medium is
padded by one voxel of zeros on every side, so trilinear interpolation fades the density to
zero over the voxel beyond the data, as OpenVDB's background does; ``PreparedMedium`` stores
the padded array and the affine map from world metres to *padded* index coordinates.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import List, Optional

import numpy as np

from .lights import extent_radius, has_extent
from .phase import clamp_g, delta_fraction, delta_g
from .scene import Medium

PAD = 1  # voxels of zeros round every side of a prepared grid (the trilinear fade)


@dataclass
class PreparedMedium:
    """A medium ready for the march and the precompute.

    ``grid``: float32 (X, Y, Z) padded density.  ``w2i``: (3, 4) world -> padded index map.
    ``i2w``: (4, 4) padded index -> world.  ``sigma_s``, ``sigma_a``, ``sigma_t``: RGB 1/m
    per unit density.  ``voxel_size``: the shortest world length of a voxel edge (m).
    ``emission_grid``: None or float32 (X, Y, Z, 3) padded emission grid (W/(m^3 sr)).
    ``scatter_grid``: None or float32 (X, Y, Z, 3) padded factor on ``sigma_s`` per voxel
    (Medium.scatter_grid; the padding repeats the edge voxels, where the density fades).
    ``extinction_density``: None or float32 (X, Y, Z, 3) padded, per channel the density the
    extinction reads where its colour varies in space (Medium.extinction_grid times the
    density): sigma_t,c(x) = sigma_t[c] * extinction_density[..., c](x), interpolated
    trilinearly; each channel is at most ``grid`` (``prepare`` folds a larger factor into
    the density), so the density's bounds bound the extinction too.  The transmittance
    kernels read it through ``extinction_parts``.
    """

    medium: Medium
    grid: np.ndarray
    w2i: np.ndarray
    i2w: np.ndarray
    sigma_s: np.ndarray
    sigma_a: np.ndarray
    sigma_t: np.ndarray
    g: float
    voxel_size: float
    threshold: float = -1.0
    emission_grid: Optional[np.ndarray] = None
    scatter_grid: Optional[np.ndarray] = None
    extinction_density: Optional[np.ndarray] = None

    @property
    def kind(self) -> str:
        """'fog': the world's volume, homogeneous and endless (worldfog.py; its grid a box
        round what the camera sees); 'mesh': a mesh volume, of one density wherever it has
        any, with a sharp surface (``threshold`` >= 0, density_from); 'grid': a density grid
        (VDB, fluid), interpolated."""
        if self.medium.source == "WORLD":
            return "fog"
        return "mesh" if self.threshold >= 0.0 else "grid"

    @property
    def sharp(self) -> bool:
        """Whether the medium has a sharp surface (a mesh volume's threshold)."""
        return self.threshold >= 0.0

    @property
    def endless(self) -> bool:
        """Whether the medium fills all space (the world's fog): its grid is only a window
        onto it, and beyond the grid it goes on with density ``outside_density``."""
        return self.medium.source == "WORLD"

    @property
    def uniform(self) -> bool:
        """Whether the medium has one density wherever it has any (a mesh volume)."""
        return self.sharp and not self.endless

    def scatter_at(self, flat=None, idx=None) -> Optional[np.ndarray]:
        """float64 (N,3) the factor on ``sigma_s`` (``scatter_grid``) at the voxels ``flat``
        (flat indices into ``grid``) or, trilinear, at index coordinates ``idx`` (N,3); None
        where the medium has one colour."""
        return _rgb_at(self.scatter_grid, flat, idx)

    def extinction_parts(self) -> List["PreparedMedium"]:
        """The medium as the transmittance kernels read it (optical depth, sweeps, density
        lengths): itself, or with an ``extinction_density`` three media of one channel each
        (channel c's density and sigma_t[c] in channel c alone, nothing scattered), whose
        optical depths add to the medium's."""
        if self.extinction_density is None:
            return [self]
        if getattr(self, "_parts", None) is None:
            parts = []
            for c in range(3):
                unit = np.zeros(3)
                unit[c] = 1.0
                parts.append(dataclasses.replace(
                    self, grid=np.ascontiguousarray(self.extinction_density[..., c]),
                    sigma_s=np.zeros(3), sigma_a=self.sigma_t * unit,
                    sigma_t=self.sigma_t * unit, emission_grid=None, scatter_grid=None,
                    extinction_density=None))
            self._parts = parts
        return self._parts

    @property
    def outside_density(self) -> float:
        """The density beyond the grid: 1 for the endless fog, 0 for any other medium."""
        return 1.0 if self.endless else 0.0

    def path_density(self) -> np.ndarray:
        """float32 (X,Y,Z) density the light paths fly through (paths.py): the endless fog's
        is 1 everywhere (its grid's padding ramp is the march's, not the fog's), any other
        medium's is density_from(grid)."""
        if self.endless:
            return np.ones(self.grid.shape, np.float32)
        return np.ascontiguousarray(density_from(self.grid, self.threshold), np.float32)

    @property
    def emits(self) -> bool:
        """Whether the medium gives off light somewhere (its constant emission where it has
        density, or its emission grid), whether or not it scatters: its light reaches the
        other media (precompute.emissionlight) and the surfaces."""
        if np.any(np.asarray(self.medium.emission) > 0.0):
            return True
        return self.emission_grid is not None and bool(np.any(self.emission_grid > 0.0))

    @property
    def scatters(self) -> bool:
        """Whether the medium scatters light in some colour (sigma_s > 0)."""
        return bool(np.any(np.asarray(self.sigma_s) > 0.0))

    @property
    def glows(self) -> bool:
        """Whether the medium gives off light that it scatters itself: ``emits`` and
        ``scatters`` (the endless world fog's glow: precompute.fogglow)."""
        return self.scatters and self.emits

    def emitted(self) -> Optional[np.ndarray]:
        """float64 (X,Y,Z,3) emitted radiance per metre of every voxel of the padded grid,
        W/(m^3 sr): the constant ``emission`` where the density is > 0 plus the emission
        grid (negative values as 0); None where the medium ``emits`` nothing or is the
        endless fog (whose glow has no voxels of its own: precompute.fogglow)."""
        if not self.emits or self.endless:
            return None
        const = np.maximum(np.asarray(self.medium.emission, np.float64).reshape(3), 0.0)
        e = np.zeros(self.grid.shape + (3,))
        if np.any(const > 0.0):
            e += (density_from(self.grid, self.threshold) > 0.0)[..., None] * const
        if self.emission_grid is not None:
            e += np.maximum(self.emission_grid.astype(np.float64), 0.0)
        return e

    def to_world(self, ijk) -> np.ndarray:
        """World positions (N,3, m) of padded index coordinates ``ijk`` (N,3)."""
        return ijk @ self.i2w[:3, :3].T + self.i2w[:3, 3]

    def to_index(self, points) -> np.ndarray:
        """Padded index coordinates (N,3) of world points (N,3, m)."""
        return points @ self.w2i[:, :3].T + self.w2i[:, 3]

    @property
    def bricks(self) -> np.ndarray:
        """The density bounds per brick of ``BRICK``^3 cells (``brick_bounds``), computed on
        first use."""
        if getattr(self, "_bricks", None) is None:
            self._bricks = brick_bounds(self.grid, self.threshold)
        return self._bricks

    @property
    def march_bricks(self) -> np.ndarray:
        """``bricks`` for the camera march: where the emission grid glows the largest bound is
        raised to ``GLOW_BOUND``, so that the march neither skips those super-steps nor
        lengthens their steps (the grid shines whatever the density)."""
        if self.emission_grid is None:
            return self.bricks
        if getattr(self, "_march_bricks", None) is None:
            glow = brick_bounds(np.abs(self.emission_grid).max(axis=-1))[..., 1] > 0.0
            b = self.bricks.copy()
            b[..., 1] = np.where(glow, np.maximum(b[..., 1], GLOW_BOUND), b[..., 1])
            self._march_bricks = b
        return self._march_bricks

    @property
    def shape(self):
        return self.grid.shape


def _rgb_at(grid, flat=None, idx=None) -> Optional[np.ndarray]:
    """float64 (N,3) of a padded 3-channel ``grid`` (or None) at the voxels ``flat`` or,
    trilinear, at index coordinates ``idx`` (N,3); None without a grid."""
    if grid is None:
        return None
    if flat is not None:
        return grid.reshape(-1, 3)[np.asarray(flat)].astype(np.float64)
    return np.asarray(trilinear(grid, np.asarray(idx, np.float64)), np.float64)


def delta_scaled(pm: PreparedMedium) -> PreparedMedium:
    """``pm`` with its phase split by delta-Eddington (phase.delta_fraction): the forward peak
    f sigma_s taken as no scattering at all, sigma_s* = sigma_s (1 - f), sigma_t* = sigma_s* +
    sigma_a, g* = g / (1 + g).  Light scattered into the peak goes on along the beam: the
    beam that the delta-scaled medium attenuates (optical depth with sigma_t*) holds the
    unscattered light and the forward-scattered light together (docs/method.md, "The
    forward peak").  ``pm`` itself where g <= 0."""
    f = delta_fraction(pm.g)
    if f <= 0.0:
        return pm
    ss = pm.sigma_s * (1.0 - f)
    st = ss + pm.sigma_a
    ext = pm.extinction_density
    if ext is not None:   # per channel sigma_t ext - f sigma_s c d, over sigma_t*
        sc = 1.0 if pm.scatter_grid is None else pm.scatter_grid
        removed = f * pm.sigma_s * sc * pm.grid[..., None]
        ext = np.maximum(pm.sigma_t * ext - removed, 0.0) / np.where(st > 0.0, st, 1.0)
        ext = np.ascontiguousarray(ext, np.float32)
    out = dataclasses.replace(pm, sigma_s=ss, sigma_t=st, g=delta_g(pm.g),
                              extinction_density=ext)
    out._bricks = getattr(pm, "_bricks", None)  # the same density: the same bounds
    out._parts = None
    return out


def sanitise(density) -> tuple:
    """(float32 copy of ``density`` with NaN, inf and negative values set to 0, how many)."""
    d = np.asarray(density, dtype=np.float32)
    bad = ~np.isfinite(d) | (d < 0)
    count = int(np.count_nonzero(bad))
    if count:
        d = np.where(bad, np.float32(0.0), d)
    return d, count


def prepare(medium: Medium, warnings=None) -> PreparedMedium:
    """Pad and map ``medium`` for sampling.  Raises ValueError (with a message for the user)
    when it cannot be rendered: not a 3-D grid, non-finite or degenerate (zero-scale)
    transform.  NaN, inf and negative voxels are set to 0 and counted in ``warnings``."""
    d, bad = sanitise(medium.density)
    if d.ndim != 3 or min(d.shape) < 1:
        raise ValueError(f"medium '{medium.name}': density must be a non-empty 3-D array")
    if bad and warnings is not None:
        warnings.append(f"medium '{medium.name}': {bad} voxels were NaN, infinite or negative "
                        "and were set to 0")
    m = np.asarray(medium.index_to_world, np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise ValueError(f"medium '{medium.name}': non-finite transform; skipped")
    if abs(np.linalg.det(m[:3, :3])) < 1e-30 or np.linalg.cond(m[:3, :3]) > 1e12:
        raise ValueError(f"medium '{medium.name}': degenerate transform (zero scale); skipped")
    grid = np.zeros(tuple(s + 2 * PAD for s in d.shape), np.float32)
    grid[PAD:-PAD, PAD:-PAD, PAD:-PAD] = d
    shift = np.eye(4)
    shift[:3, 3] = -float(PAD)
    i2w = m @ shift
    w2i = np.linalg.inv(i2w)[:3, :]
    voxel = float(np.min(np.linalg.norm(i2w[:3, :3], axis=0)))
    ss = np.asarray(medium.sigma_s, np.float64).reshape(3)
    sa = np.asarray(medium.sigma_a, np.float64).reshape(3)
    scatter = _colour_grid(medium, medium.scatter_grid, "scatter colour", d.shape, warnings,
                           edge=True)
    ext = _colour_grid(medium, medium.extinction_grid, "extinction colour", d.shape, warnings,
                       edge=True)
    thr = SHARP_THRESHOLD if medium.source == "MESH" and ext is None else -1.0
    if ext is not None:
        grid, scatter, ext = _fold_extinction(grid, scatter, ext)
    return PreparedMedium(medium, np.ascontiguousarray(grid), np.ascontiguousarray(w2i), i2w,
                          ss, sa, ss + sa, clamp_g(float(medium.g)), voxel, thr,
                          _colour_grid(medium, medium.emission_grid, "emission", d.shape,
                                       warnings), scatter, ext)


def _fold_extinction(grid, scatter, factor):
    """(density, scatter factor, extinction density) of a padded density ``grid`` whose
    extinction is ``factor`` (X,Y,Z,3) times it per channel: where a channel's factor is over
    1 the density is times the largest (the scattering's factor divided by it), so that
    every channel of the extinction density grid x factor is at most the density and the
    density's bounds (bricks, majorants) bound the extinction.  The coefficients per point
    are unchanged."""
    top = np.max(factor, axis=-1)
    over = top > 1.0
    if np.any(over):
        s = np.where(over, top, 1.0).astype(np.float32)
        grid = (grid * s).astype(np.float32)
        factor = factor / s[..., None]
        scatter = (np.ones(grid.shape + (3,), np.float32) if scatter is None else scatter) \
            / s[..., None]
        scatter = np.ascontiguousarray(scatter, np.float32)
    ext = np.minimum(grid[..., None] * factor, grid[..., None])
    return grid, scatter, np.ascontiguousarray(ext, np.float32)


def _colour_grid(medium: Medium, e, what: str, shape, warnings, edge: bool = False):
    """The padded float32 (X, Y, Z, 3) copy of the medium's grid ``e`` (its ``what`` in
    messages; NaN, inf and negative values set to 0 with a warning), or None when it has none,
    does not match the density's shape (warned; the medium then renders without it), or is
    all zero (an emission; ``edge`` False) or all one (a scatter colour's factor; ``edge``
    True).  The padding is zero, or with ``edge`` the edge voxels repeated."""
    if e is None:
        return None
    e = np.asarray(e)
    if e.shape != tuple(shape) + (3,):
        if warnings is not None:
            warnings.append(f"medium '{medium.name}': {what} grid of shape {e.shape} does not "
                            f"match the density {tuple(shape)} (+ 3 colours); ignored")
        return None
    e, bad = sanitise(e)
    if bad and warnings is not None:
        warnings.append(f"medium '{medium.name}': {bad} {what} values were NaN, infinite or "
                        "negative and were set to 0")
    if not np.any(e != (1.0 if edge else 0.0)):
        return None
    pad = ((PAD, PAD),) * 3 + ((0, 0),)
    return np.ascontiguousarray(np.pad(e, pad, mode="edge" if edge else "constant"),
                                np.float32)


# A mesh volume's surface is where its interpolated occupancy crosses one half.  The test is
# v >= 0.5 - 1e-9 rather than v >= 0.5: grid-aligned faces put many sample points exactly on
# 0.5, and there the two kernel twins' different rounding would otherwise decide differently.
SHARP_THRESHOLD = 0.5 - 1e-9


BRICK = 4  # cells per edge of the bricks of the empty-space grid
GLOW_BOUND = 1e30  # a brick's largest density bound where an emission grid glows (march_bricks)


def _block_reduce(a: np.ndarray, brick: int, fn) -> np.ndarray:
    """``fn`` (np.maximum or np.minimum) over the voxels b brick .. (b + 1) brick (inclusive)
    of each brick b along every axis of ``a``; b = ceil((n - 1) / brick) bricks per axis
    (voxels past the grid repeat its last one)."""
    out = a
    for ax in range(3):
        n = out.shape[ax]
        nb = max(1, -(-(n - 1) // brick))
        extra = nb * brick + 1 - n
        b = np.moveaxis(out, ax, 0)
        if extra > 0:
            b = np.concatenate([b, np.repeat(b[-1:], extra, axis=0)])
        body = fn.reduce(b[:nb * brick].reshape((nb, brick) + b.shape[1:]), axis=1)
        out = np.moveaxis(fn(body, b[brick:nb * brick + 1:brick]), 0, ax)
    return out


def brick_bounds(grid: np.ndarray, threshold: float = -1.0, brick: int = BRICK) -> np.ndarray:
    """Coarse bounds of a padded density ``grid`` (X,Y,Z): float32 (bx, by, bz, 2) with
    b = ceil((n - 1) / brick) bricks per axis, brick b covering the index cells
    [b brick, (b + 1) brick]; [..., 0] is the least and [..., 1] the largest density
    (``density_from``) any point of the brick can have: the extremes of the voxels its
    cells' trilinear interpolation reads (index b brick .. (b + 1) brick), widened by one
    voxel on each side so that a point a rounding error across a face is covered too.
    Largest 0: surely empty (the kernels skip it); least = largest: constant (the optical
    depth kernel integrates it in one go)."""
    g = np.asarray(grid, np.float32)
    hi, lo = g, g
    for ax in range(3):  # one-voxel max / min filters (np.roll wraps: the padding is 0 anyway)
        hi = np.maximum(hi, np.maximum(np.roll(hi, 1, axis=ax), np.roll(hi, -1, axis=ax)))
        lo = np.minimum(lo, np.minimum(np.roll(lo, 1, axis=ax), np.roll(lo, -1, axis=ax)))
    hi = _block_reduce(hi, brick, np.maximum)
    lo = _block_reduce(lo, brick, np.minimum)
    if threshold >= 0.0:
        hi = (hi >= threshold).astype(np.float32)
        lo = (lo >= threshold).astype(np.float32)
    return np.ascontiguousarray(np.stack([lo, hi], axis=-1), np.float32)


def density_from(value, threshold: float):
    """Density from an interpolated grid value: thresholded for sharp (mesh) media."""
    if threshold >= 0.0:
        return (value >= threshold).astype(value.dtype)
    return value


def to_index(pm: PreparedMedium, points):
    """World points (N,3) -> padded index coordinates (N,3)."""
    return pm.to_index(points)


def trilinear(grid, idx):
    """Trilinear interpolation of ``grid`` (X,Y,Z) or (X,Y,Z,C) at index coords (N,3).

    Points outside [0, X-1] x [0, Y-1] x [0, Z-1] return 0 (the padding makes the field fade
    to zero inside that range)."""
    X, Y, Z = grid.shape[:3]
    f = np.floor(idx)
    i0 = f.astype(np.int64)
    fr = idx - f
    inside = ((i0[:, 0] >= 0) & (i0[:, 0] < X - 1) & (i0[:, 1] >= 0) & (i0[:, 1] < Y - 1)
              & (i0[:, 2] >= 0) & (i0[:, 2] < Z - 1))
    i = np.where(inside[:, None], i0, 0)
    fx, fy, fz = fr[:, 0], fr[:, 1], fr[:, 2]
    flat = grid.reshape(X * Y * Z, -1)
    base = (i[:, 0] * Y + i[:, 1]) * Z + i[:, 2]
    sx, sy = Y * Z, Z
    out = 0.0
    for dx, wx in ((0, 1 - fx), (sx, fx)):
        for dy, wy in ((0, 1 - fy), (sy, fy)):
            w_xy = wx * wy
            c0 = flat[base + dx + dy]
            c1 = flat[base + dx + dy + 1]
            out = out + (w_xy * (1 - fz))[:, None] * c0 + (w_xy * fz)[:, None] * c1
    out = np.where(inside[:, None], out, 0.0)
    return out if grid.ndim == 4 else out[:, 0]


def ray_box(pm: PreparedMedium, origins, dirs):
    """Parametric interval (t0, t1) where rays o + t d (world, any |d|) lie inside the padded
    grid's sampling box; t0 > t1 where they miss.  Works in index space, where the map is
    affine, so t is the same parameter as in world space.  (Column-wise minima and maxima:
    numpy's reductions over a length-3 axis cost several times more.)"""
    o = to_index(pm, origins)
    d = dirs @ pm.w2i[:, :3].T
    hi = np.array(pm.grid.shape, np.float64) - 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        ta = -o * inv
        tb = (hi - o) * inv
    tmin = np.fmin(ta, tb)
    tmax = np.fmax(ta, tb)
    par = np.abs(d) < 1e-300
    if par.any():
        inside_par = (o >= 0.0) & (o <= hi)
        tmin = np.where(par, np.where(inside_par, -np.inf, np.inf), tmin)
        tmax = np.where(par, np.where(inside_par, np.inf, -np.inf), tmax)
    return (np.maximum(np.maximum(tmin[:, 0], tmin[:, 1]), tmin[:, 2]),
            np.minimum(np.minimum(tmax[:, 0], tmax[:, 1]), tmax[:, 2]))


def union_interval(media: List[PreparedMedium], origins, dirs, t_lo, t_hi):
    """Smallest interval covering every medium the rays cross, clipped to [t_lo, t_hi]."""
    n = len(origins)
    t0 = np.full(n, np.inf)
    t1 = np.full(n, -np.inf)
    for pm in media:
        a, b = ray_box(pm, origins, dirs)
        hit = b > a
        t0 = np.where(hit, np.minimum(t0, a), t0)
        t1 = np.where(hit, np.maximum(t1, b), t1)
    return np.maximum(t0, t_lo), np.minimum(t1, t_hi)


def surrounds(media: List[PreparedMedium], point) -> bool:
    """Whether ``point`` (3,) m lies inside one of the prepared ``media``: within a grid's
    sampling box, or anywhere for an endless one (the world's fog)."""
    p = np.asarray(point, np.float64).reshape(1, 3)
    for pm in media:
        if pm.endless:
            return True
        idx = to_index(pm, p)[0]
        if np.all(idx >= 0.0) and np.all(idx <= np.array(pm.grid.shape, np.float64) - 1.0):
            return True
    return False


def glow_lights(media: List[PreparedMedium]) -> bool:
    """Whether some medium's emission lights a medium that scatters (precompute.emissionlight):
    one ``emits`` and one ``scatters``, the same one or another."""
    return any(pm.emits for pm in media) and any(pm.scatters for pm in media)


def box_distance(pm: PreparedMedium, point) -> float:
    """A lower bound (m) of the distance from ``point`` (3,) to the medium's grid box: the
    distance in index space to the box of voxel centres times the map's smallest stretch
    (0 inside it)."""
    idx = to_index(pm, np.asarray(point, np.float64).reshape(1, 3))[0]
    hi = np.array(pm.grid.shape, np.float64) - 1.0
    gap = np.linalg.norm(idx - np.clip(idx, 0.0, hi))
    stretch = np.linalg.svd(np.asarray(pm.i2w, np.float64)[:3, :3], compute_uv=False).min()
    return float(gap * stretch)


def smooth_light(media: List[PreparedMedium], lights, reach: float) -> bool:
    """Whether the light in every one of ``media`` changes no faster than its voxels, so that
    the march may step a voxel at a time: every medium a density grid (no mesh volume's sharp
    surface, no world fog, whose lamps are in it) that does not emit (its emission changes
    at its own grid's scale, and the march's longer steps in thin smoke follow the density
    alone: a fire's glow moved by a voxel), no spot light (its cone's edge crosses
    the media wherever it goes), and every point and area light farther than ``reach`` (m)
    from every medium's box (its 1 / r^2 then changes by under 2 h / reach over a voxel h;
    the sun's and the sky's light is read from voxel grids)."""
    if any(pm.kind != "grid" or pm.emits for pm in media):
        return False
    for light in lights:
        if light.kind == "SUN":
            continue
        if light.kind == "SPOT":
            return False
        centre = np.asarray(light.matrix, np.float64)[:3, 3] if light.kind == "AREA" \
            else np.asarray(light.position, np.float64)
        if any(box_distance(pm, centre) <= reach for pm in media):
            return False
    return True


def uneven_within(media, centre, radius: float) -> bool:
    """Whether any of the prepared ``media`` may change its density within ``radius`` (m) of
    ``centre`` (3,): a brick of its brick_bounds overlapping the ball's box holds density
    and is not constant.  (A lamp's disc points see the stretched centre's optical depth,
    lights.path_stretch, exactly where none does.)"""
    c = np.asarray(centre, np.float64).reshape(3)
    corners = c + radius * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)],
                                    np.float64)
    for pm in media:
        idx = corners @ np.asarray(pm.w2i, np.float64)[:, :3].T + np.asarray(pm.w2i, np.float64)[:, 3]
        b = pm.bricks
        lo = np.clip(np.floor(idx.min(axis=0) / BRICK).astype(int), 0, np.array(b.shape[:3]) - 1)
        hi = np.clip(np.floor(idx.max(axis=0) / BRICK).astype(int), 0, np.array(b.shape[:3]) - 1)
        if np.any(idx.max(axis=0) < 0) or np.any(idx.min(axis=0) > np.array(pm.grid.shape) - 1):
            continue   # the ball misses the grid
        sub = b[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1]
        if np.any((sub[..., 1] > 0.0) & (sub[..., 0] != sub[..., 1])):
            return True
    return False


def disc_reaches(media, lights, disc_exact: float, disc_voxels: float = 0.0) -> list:
    """Per light, the distance (m) within which the march corrects the optical depth to a
    lamp's disc points or an area light's emitter points (kernels_np.disc_correction): for
    a light that shines from points off its centre (lights.has_extent) whose surroundings
    within it are uneven (``uneven_within``), ``disc_exact`` (Tuning) times its
    lights.extent_radius or ``disc_voxels`` (Tuning) times the finest voxel of ``media``,
    whichever is longer; else 0."""
    out = []
    finest = min((float(pm.voxel_size) for pm in media), default=0.0)
    for light in lights:
        reach = max(disc_exact * extent_radius(light), disc_voxels * finest) \
            if has_extent(light) else 0.0
        out.append(reach if reach > 0.0 and uneven_within(media, light.position, reach) else 0.0)
    return out
