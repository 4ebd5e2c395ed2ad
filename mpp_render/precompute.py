"""Per-light and world-light precompute on each medium's voxel grid.

For every medium we build one *field* array (X, Y, Z, C) float32 on the medium's padded grid,
read by the march with a single trilinear fetch per step:

* channel 0: density (dimensionless);
* for each lit light l, 3 channels: RGB optical depth tau_l from the voxel point to the light
  through *all* media (transmittance exp(-tau_l));
* 3 channels of world light: the RGB radiance the constant world background brings to the
  voxel *after* the phase function towards the camera and the attenuation through all media:
  A(x) = L_world * integral p(w_in . w_cam(x)) T(x, -w_in) dw_in, estimated with directions
  drawn from the phase lobe (so the estimate is the mean transmittance).  w_cam(x) points
  from x to the camera, which is exact for camera rays through x.
* with multiple scattering in a forward-scattering medium, for each lit light 3 channels of
  the light of its forward peak, W/m^2 (``FieldLayout.beam_channels``, ``peak_light``);
* last, for a medium with an emission grid (scene.Medium.emission_grid) only, 3 channels of
  its emitted radiance per metre (W/(m^3 sr)), copied from the grid
  (``FieldLayout.emission_channels``); the march adds them to the Emission pass.

The lights' optical depth is swept over the whole grid (``sweep_light``: the light's rays
followed slab by slab, a few passes over the grid instead of one march per voxel); the world
light is computed on a coarse lattice and interpolated to the voxels whose trilinear support
touches non-zero density (``needed_flat``; the rest stay 0).

The world's fog (a medium with source 'WORLD', worldfog.py) fills all space homogeneously, so
its optical depth to a light is sigma_t x distance, added analytically to what the other media
(integrated by the kernel) and the surfaces give; its grid is never marched here.  On the fog's
own grid the surfaces' shadows are prefiltered (``soft_visibility``): the optical depth holds
-ln of the visibility averaged over each voxel near a shadow's edge, so that the interpolated
field places the god rays' edges where they are instead of darkening a voxel of lit fog beside
every shadow (interpolating the 0 / SHADOW_TAU step of a binary shadow does that).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Callable, List, Optional

import numpy as np

from . import kernels, kernels_np
from .camera import towards_camera
from .firstflight import FirstFlight, fft_shape, first_flight, flight_weight
from .lights import is_dark, towards_light
from .media import PreparedMedium, density_from, union_interval
from .parallel import run_chunks
from .phase import sample_hg
from .scene import Camera, Light, World
from .surfaces import occluded
from .worldfog import optical_depth as fog_optical_depth


AMBIENT_RESOLUTION = 32  # lattice points along the longest side for the world light
MULTIPLE_RESOLUTION = 64  # lattice points along the longest side for the light pyramid
PEAK_PAD = 4  # lattice points beyond the grid where peak_light follows the light on


@dataclass
class FieldLayout:
    """Channel offsets in a medium's field array.  ``light_channels[i]`` is the offset of
    light i's optical depth, or None when the light is skipped (dark).  ``channels``: the
    channels every medium's field has; ``emission_channels[m]``: the offset of medium m's
    emission grid (its field then has ``channels + 3``), or None.  ``beam_channels[i]``
    (multiple scattering on, some medium with a forward peak): the offset of light i's
    forward peak's light (W/m^2, ``peak_light``: what has scattered into the peak and not
    out of it, spread sideways), first the optical depth through the delta-scaled media
    (media.delta_scaled) from which it is made; right after the lights' channels."""

    light_channels: List[Optional[int]]
    ambient_channel: Optional[int]
    channels: int
    ambient_multiple_channel: Optional[int] = None
    emission_channels: Optional[List[Optional[int]]] = None
    beam_channels: Optional[List[Optional[int]]] = None


@dataclass
class Precomputed:
    """``fields``: per medium (X,Y,Z,C) float32 (layout above); ``multiple``: per medium, per
    light, a MultipleField or None (multiple scattering off, dark light, or no scattering)."""

    fields: List[np.ndarray]
    layout: FieldLayout
    multiple: list = field(default_factory=list)
    seconds: float = 0.0
    stats: dict = field(default_factory=dict)


def needed_flat(pm: PreparedMedium):
    """Flat indices of the padded grid points whose trilinear neighbourhood holds non-zero
    density: every point of a cell with a non-zero corner (the 3x3x3 dilation of the
    occupied points, diagonal neighbours included)."""
    return np.flatnonzero(_dilate(pm.grid > 0.0))


def grid_points(pm: PreparedMedium, flat):
    """World positions (N,3) of the padded grid points with flat indices ``flat``."""
    ijk = np.stack(np.unravel_index(flat, pm.grid.shape), axis=1).astype(np.float64)
    return ijk @ pm.i2w[:3, :3].T + pm.i2w[:3, 3]


def needed_points(pm: PreparedMedium):
    """``needed_flat`` and the world positions of those points."""
    flat = needed_flat(pm)
    return flat, grid_points(pm, flat)


def _exit_distance(media, points, dirs, limit):
    t0, t1 = union_interval(media, points, dirs, np.zeros(len(points)), limit)
    return np.where(t1 > 0.0, np.minimum(t1, limit), 0.0)


SHADOW_TAU = 50.0  # optical depth standing for "blocked by an opaque surface" (T ~ 2e-22)


def kernel_arrays(media):
    return ([m.grid for m in media], [m.w2i for m in media], [m.sigma_t for m in media],
            [m.threshold for m in media])


def _media_arrays_for(media, coefficient):
    """Kernel arrays integrating ``coefficient``: 'sigma_t' or 'sigma_s' (RGB optical depth)
    or 'length' (metres inside non-zero density, in all three channels)."""
    if coefficient == "sigma_t":
        return kernel_arrays(media)
    if coefficient == "sigma_s":
        return ([m.grid for m in media], [m.w2i for m in media], [m.sigma_s for m in media],
                [m.threshold for m in media])
    if coefficient == "length":
        return ([(m.grid > 0).astype(np.float32) for m in media], [m.w2i for m in media],
                [np.ones(3) for _ in media], [-1.0 for _ in media])
    raise ValueError(coefficient)


SKIP_MIN_VOXELS = 1 << 20  # grids from which optical_depth walks the bricks (measured:
# below it a grid sits in the cache, a step is as cheap as a brick crossing and walking the
# bricks costs more than it saves; above it 1.7-2.9x faster on the public scenes' grids)


def media_bricks(media):
    """The media's brick bounds (media.brick_bounds) for optical_depth to add empty and
    constant stretches in one go, or None for small grids (SKIP_MIN_VOXELS); the result is
    the same either way."""
    if not media or max(m.grid.size for m in media) < SKIP_MIN_VOXELS:
        return None
    return [m.bricks for m in media]


def density_lengths(media: List[PreparedMedium], points, dirs, t_max, step):
    """(N, M) metres of density along rays p + s dir, s in [0, t_max] cut where they leave
    the media's boxes, per medium: the integral of density_from(grid) (kernels.optical_depth
    with each medium's coefficient a unit vector, three media per call).  Any RGB optical
    depth through the media is then a product with their coefficients (M, 3), so one march
    gives both the extinction and the scattering optical depth."""
    od = kernels.get("optical_depth")
    n, M = len(points), len(media)
    out = np.zeros((n, M))
    # the rays end where they leave the last medium, of all of them (not only of the group)
    t_max = _exit_distance(media, points, dirs, t_max) if M > 3 else t_max
    for g0 in range(0, M, 3):
        grp = media[g0:g0 + 3]
        units = [np.eye(3)[k] for k in range(len(grp))]
        v = od(points, dirs, t_max, [m.grid for m in grp], [m.w2i for m in grp], units,
               [m.threshold for m in grp], float(step), 0.5, bricks=media_bricks(grp),
               clip=M <= 3)
        out[:, g0:g0 + len(grp)] = v[:, :len(grp)]
    return out


def split_fog(media: List[PreparedMedium]):
    """(the media other than the world's fog, the fog's PreparedMedium or None)."""
    fog = next((pm for pm in media if pm.medium.source == "WORLD"), None)
    return [pm for pm in media if pm is not fog], fog


def light_optical_depth(media: List[PreparedMedium], light: Light, points, step,
                        chunk=1 << 14, should_cancel=None, surfaces=None, threads=0,
                        coefficient="sigma_t", fog_sigma_t=None):
    """RGB optical depth (N,3) from world ``points`` to ``light`` (its centre) through media;
    ``SHADOW_TAU`` is added where an opaque surface (``surfaces``, a SurfaceSet) blocks the
    way, so surfaces cast volumetric shadows, and with ``fog_sigma_t`` (RGB 1/m) the world
    fog's sigma_t x distance (worldfog.optical_depth).  ``media`` must not hold the fog.
    ``coefficient`` (see _media_arrays_for) picks what is integrated; shadows and fog are
    added to 'sigma_t' only.  None when cancelled."""
    od = kernels.get("optical_depth")
    arrays = _media_arrays_for(media, coefficient) if media else None
    # the bricks bound density_from(grid), which 'length' does not integrate
    bricks = None if coefficient == "length" else media_bricks(media)
    if coefficient != "sigma_t":
        surfaces = None
        fog_sigma_t = None
    out = np.zeros((len(points), 3))

    def work(a, b):
        p = points[a:b]
        d, limit = towards_light(light, p)
        if arrays is not None:
            tau = od(p, d, limit, *arrays, float(step), 0.5, bricks=bricks, clip=True)
        else:
            tau = np.zeros((len(p), 3))
        if fog_sigma_t is not None:
            tau = tau + fog_optical_depth(fog_sigma_t, limit)
        if surfaces is not None and not surfaces.empty:
            tau += SHADOW_TAU * occluded(surfaces, p, d, limit)[:, None]
        out[a:b] = tau

    if not run_chunks(len(points), chunk, work, threads, should_cancel):
        return None
    return out


SELF_VOXELS = 1.5  # surfaces this close to a fog voxel (in voxels) do not shadow it
SOFT_OFFSETS = (np.stack(np.meshgrid(*[[-0.25, 0.25]] * 3, indexing="ij"), -1).reshape(-1, 3))


def soft_visibility(surfaces, light: Light, pm: PreparedMedium, flat, points, chunk=1 << 14,
                    threads=0, should_cancel=None):
    """Visibility of ``light`` (0..1, (N,)) from the needed points ``points`` (at flat indices
    ``flat`` of ``pm``'s grid) past the opaque ``surfaces``: 1 or 0 at the voxel point, and
    near a shadow's edge (a 6-neighbour sees otherwise) the mean over the 2 x 2 x 2 points a
    quarter voxel off, a box filter one voxel wide.  Surfaces within ``SELF_VOXELS`` voxels
    of a point do not shadow it: the voxels just behind a lit floor or wall (which camera
    rays never reach) then do not darken the lit fog in front of it through the
    interpolation; a shadow starts that far behind its caster instead.  None when cancelled."""
    vis = np.ones(len(points))
    if surfaces is None or surfaces.empty or not len(points):
        return vis
    skip = SELF_VOXELS * pm.voxel_size

    def binary(p):
        d, limit = towards_light(light, p)
        return ~occluded(surfaces, p + d * skip, d, np.maximum(limit - skip, 0.0))

    def work(a, b):
        vis[a:b] = binary(points[a:b])

    if not run_chunks(len(points), chunk, work, threads, should_cancel):
        return None
    grid = np.ones(pm.grid.shape, bool)
    grid.reshape(-1)[flat] = vis > 0.5
    edge = np.zeros_like(grid)
    for ax in range(3):
        for sft in (1, -1):
            edge |= grid != np.roll(grid, sft, axis=ax)
    todo = np.flatnonzero(edge.reshape(-1)[flat])
    if todo.size:
        off = SOFT_OFFSETS @ pm.i2w[:3, :3].T  # quarter-voxel offsets in metres
        acc = np.zeros(todo.size)
        for o in off:
            part = np.zeros(todo.size)

            def work_o(a, b):
                part[a:b] = binary(points[todo[a:b]] + o)

            if not run_chunks(todo.size, chunk, work_o, threads, should_cancel):
                return None
            acc += part
        vis[todo] = acc / len(off)
    return vis


WORLD_RNG_BLOCK = 1 << 11  # points sharing one random stream in world_light
WORLD_CHUNK_RAYS = 1 << 14  # rays (points x directions) per world-light chunk, for a quick Esc


def world_chunk(n_dirs: int) -> int:
    """Points per world-light chunk: at most ``WORLD_CHUNK_RAYS`` rays, a power of two that
    divides ``WORLD_RNG_BLOCK`` (at least 16 points)."""
    chunk = WORLD_RNG_BLOCK
    while chunk > 16 and chunk * max(1, int(n_dirs)) > WORLD_CHUNK_RAYS:
        chunk //= 2
    return chunk


def _block_uniforms(seed, a, b):
    """(b - a, 2) uniforms for points a..b-1: point i takes row i mod WORLD_RNG_BLOCK of the
    stream seeded by (seed, 7919, start of its block), so the numbers do not depend on how
    the points are cut into chunks."""
    parts = []
    s = a
    while s < b:
        block = s - s % WORLD_RNG_BLOCK
        e = min(b, block + WORLD_RNG_BLOCK)
        rows = np.random.default_rng([seed, 7919, block]).random((e - block, 2))
        parts.append(rows[s - block:])
        s = e
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def world_light(media: List[PreparedMedium], pm: PreparedMedium, world: World, camera: Camera,
                points, n_dirs, step, seed=0, chunk=None, should_cancel=None, surfaces=None,
                threads=0, multiple=False):
    """A(x) (N,3): world radiance scattered towards the camera per unit sigma_s, attenuated;
    with ``multiple`` also A_ms(x) (N,3), the same for the sky light that has scattered on
    its way in (the collided part exp(-tau_a) (1 - exp(-tau_s)), see docs/method.md), and the
    pair is returned.  Points draw their jitter from streams seeded by (seed, block of
    ``WORLD_RNG_BLOCK`` points), so the result depends on neither the thread count nor the
    chunk size (by default ``world_chunk(n_dirs)``, short enough to serve Esc quickly).
    None when cancelled."""
    colour = np.asarray(world.color, np.float64)
    n = len(points)
    if n == 0 or not np.any(colour > 0):
        return (np.zeros((n, 3)), np.zeros((n, 3))) if multiple else np.zeros((n, 3))
    # (M, 3); with no media but the fog (which has no extinction where the sky still shows)
    # every optical depth is 0
    sig_t = np.stack([m.sigma_t for m in media]) if media else np.zeros((0, 3))
    sig_s = np.stack([m.sigma_s for m in media]) if media else np.zeros((0, 3))
    out = np.zeros((n, 3))
    out_ms = np.zeros((n, 3))
    golden = 0.6180339887498949
    j = np.arange(n_dirs)
    chunk = world_chunk(n_dirs) if chunk is None else int(chunk)

    def work(a, b):
        p = points[a:b]
        m = len(p)
        to_cam = towards_camera(camera, p)
        r = _block_uniforms(seed, a, b)
        u1 = np.mod((j[None, :] + 0.5) / n_dirs + r[:, :1], 1.0).ravel()
        u2 = np.mod(j[None, :] * golden + r[:, 1:], 1.0).ravel()
        axis = np.repeat(to_cam, n_dirs, axis=0)
        w_in = sample_hg(u1, u2, pm.g, axis)  # propagation directions of the arriving light
        d = -w_in  # march towards where the light comes from
        pp = np.repeat(p, n_dirs, axis=0)
        lengths = density_lengths(media, pp, d, np.full(len(pp), np.inf), step) if media \
            else np.zeros((len(pp), 0))
        tau = lengths @ sig_t
        if surfaces is not None and not surfaces.empty:
            tau += SHADOW_TAU * occluded(surfaces, pp, d, np.full(len(pp), np.inf))[:, None]
        out[a:b] = np.exp(-tau).reshape(m, n_dirs, 3).mean(axis=1) * colour
        if multiple:
            tau_s = np.minimum(lengths @ sig_s, tau)
            collided = np.exp(-(tau - tau_s)) * -np.expm1(-tau_s)
            out_ms[a:b] = collided.reshape(m, n_dirs, 3).mean(axis=1) * colour

    if not run_chunks(n, chunk, work, threads, should_cancel):
        return None
    return (out, out_ms) if multiple else out


@dataclass
class MultipleField:
    """Multiple-scattering data of one light on one medium: the light pyramid (pyramid.py) of
    the first-scattering source and the medium's occupancy, on a lattice ``stride`` voxels
    apart (spacing ``h`` metres).  Level channels: the RGB power per volume (W/m^3) that the
    light's unscattered beam scatters, Q = sigma_s E exp(-tau) (the start of every multiply
    scattered path), each level moved by its paths' drift (``drift_levels``).  ``first``:
    None, or for a mesh volume whose first flights mostly leave it the exact first two
    flights (firstflight.FirstFlight on the finest lattice) that replace the walk's, by their
    weight (march.flatten_levels)."""

    stride: int
    h: float
    levels: list
    first: Optional[FirstFlight] = None


NEAR_LIGHT_CELLS = 3  # lattice cells around a point or spot light whose source is averaged


def near_light_cells(pm: PreparedMedium, light: Light, stride: int, shape) -> np.ndarray:
    """Flat indices of the pyramid lattice cells within ``NEAR_LIGHT_CELLS`` cells of a point
    or spot light inside (or next to) the medium's grid."""
    c = (np.asarray(light.position, np.float64) @ pm.w2i[:, :3].T + pm.w2i[:, 3]) / stride
    lo = np.maximum(np.floor(c - NEAR_LIGHT_CELLS).astype(int), 0)
    hi = np.minimum(np.ceil(c + NEAR_LIGHT_CELLS).astype(int), np.array(shape) - 1)
    if np.any(hi < lo):
        return np.zeros(0, np.int64)
    g = np.stack(np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(lo, hi)], indexing="ij"), -1)
    return np.ravel_multi_index(tuple(g.reshape(-1, 3).T), shape)


def first_scattering(pm: PreparedMedium, rho, e, tau, peak=None) -> np.ndarray:
    """The power per volume (W/m^3, (N,3)) the light's unscattered beam scatters at points of
    density ``rho`` (N,), irradiance ``e`` (N,3, W/m^2) and optical depth ``tau`` (N,3) from
    the light: Q = rho sigma_s E exp(-tau), where every multiply scattered path starts; with
    the forward peak's light ``peak`` (N,3, W/m^2, ``peak_light``) beside the unscattered
    light, Q = rho sigma_s (E exp(-tau) + peak) (``pm`` then the delta-scaled medium)."""
    light = e * np.exp(-np.asarray(tau, np.float64))
    if peak is not None:
        light = light + np.asarray(peak, np.float64)
    return (np.asarray(rho)[:, None] * pm.sigma_s[None, :]) * light


def lattice_shape(shape, stride: int) -> tuple:
    """Points along each axis of a lattice ``stride`` voxels apart that covers a grid of
    ``shape`` (its last point at or beyond the grid's last voxel)."""
    return tuple((s - 1 + stride - 1) // stride + 1 for s in shape)


def pyramid_lattice(pm: PreparedMedium, resolution: int = MULTIPLE_RESOLUTION):
    """(stride, shape, h) of the light pyramid's lattice on ``pm``: about ``resolution``
    points along the grid's longest side, never finer than the voxels; h its spacing, m."""
    stride = max(1, int(np.ceil(max(pm.grid.shape) / max(int(resolution), 2))))
    h = stride * float(np.cbrt(abs(np.linalg.det(pm.i2w[:3, :3]))))
    return stride, lattice_shape(pm.grid.shape, stride), h


SPOT_CULL = True   # cell_mean_irradiance skips the cells a spot's cone misses (a switch for
# benchmarks/performance.py)


def cell_mean_irradiance(light: Light, pts, cell: np.ndarray, n: int = 2) -> np.ndarray:
    """The light's irradiance (W/m^2, (N,3)) averaged over the lattice cells centred on
    ``pts`` (N,3, m) with edges the columns of ``cell`` (3,3, m): n^3 points each (midpoint
    rule).  A spot's cone narrower than the lattice (fog_beam's is 0.2 m wide where it
    enters, two lattice spacings) read at the points alone is over- or under-counted as the
    lattice falls; a sun's irradiance is the same everywhere and read once, and an area
    light's is already its emitter's integral (lights.area_incident), read once.  Cells
    wholly outside a spot's cone (``lights.outside_spot``) are 0 without a read."""
    from .lights import irradiance, outside_spot
    if light.kind in ("SUN", "AREA"):
        return irradiance(light, pts)
    pts = np.asarray(pts, np.float64).reshape(-1, 3)
    cell = np.asarray(cell, np.float64)
    corner = 0.5 * float(np.linalg.norm(np.abs(cell).sum(axis=1)))   # m, a bound
    lit = np.flatnonzero(~outside_spot(light, pts, corner)) if SPOT_CULL else \
        np.arange(len(pts))
    if lit.size < len(pts):
        out = np.zeros((len(pts), 3))
        if lit.size:
            out[lit] = cell_mean_irradiance(light, pts[lit], cell, n)
        return out
    t = (np.arange(n) + 0.5) / n - 0.5
    offs = np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3) @ cell.T
    acc = np.zeros((len(pts), 3))
    for o in offs:
        acc += irradiance(light, pts + o)
    return acc / len(offs)


def peak_light(pm: PreparedMedium, fld: np.ndarray, light: Light, channel: int, beam: int,
               mean_sigma_s: float, flat, step: float,
               resolution: int = MULTIPLE_RESOLUTION,
               should_cancel: Optional[Callable[[], bool]] = None, fog: bool = False):
    """The light of the forward peak, W/m^2: what has scattered into the peak
    (phase.delta_fraction) and not yet out of it, spread sideways as the peak's angles take
    it (docs/method.md, "The forward peak spreads").  Returns (lattice (X,Y,Z,3) float32,
    stride): on a lattice ``stride`` voxels apart, about ``resolution`` points along the
    grid's longest side (finer where ``fine_stride`` says so), for
    ``kernels.upsample_into``; None when ``should_cancel`` says so.

    Along a line from the light the beam's light beyond the unscattered light is
    B = E (exp(-tau*) - exp(-tau)) (``fld``'s ``beam`` and ``channel`` optical depths at the
    voxels ``flat`` where they were computed; elsewhere, also beyond the grid, through
    ``pm`` and its delta-scaled self alone, marched with ``step`` m, or for the world's
    ``fog`` sigma_t x distance, so that the light that has left the medium goes on).  Light that scattered into the peak at a distance s'
    from where the line entered the medium is off the line by about theta (s - s') at s,
    theta^2 the peak's mean squared angle (phase.peak_msa); with the scatterings spread
    evenly along the way, the spread per axis is w^2 = (theta^2 / 2) (s^2 / 3) [m^2],
    s = (tau - tau*) / (f sigma_s) (m; the medium's mean sigma_s ``mean_sigma_s``, 1/m).
    That is the first scattering's spread: later scatterings into the peak are the walk's
    (the delta-scaled walk carries the whole transport of the phase function).  B is
    blurred by that width, read from a pyramid of Gaussians: beside a narrow beam the peak's
    light lights the medium, and beside a medium's sides it has left through them."""
    from . import pyramid
    from .media import delta_scaled
    from .phase import delta_fraction, peak_msa
    stride, _, h = pyramid_lattice(pm, resolution)
    fine = fine_stride(pm, stride)
    stride, shape, h = fine, lattice_shape(pm.grid.shape, fine), h * fine / stride
    f = delta_fraction(pm.g)
    per_metre = np.sqrt(peak_msa(pm.g) / 6.0)   # w / s, the first turn's spread per axis
    pad = 0
    if f > 0.0 and mean_sigma_s > 0.0:   # room for the widest spread beyond the grid
        sub = fld[::stride, ::stride, ::stride]   # the lattice's points, a view
        deepest = np.nan_to_num(float(np.max(sub[..., channel:channel + 3]
                                             - sub[..., beam:beam + 3])), nan=0.0, posinf=1e30)
        reach = 3.0 * per_metre * max(deepest, 0.0) / (f * mean_sigma_s)
        pad = int(min(np.ceil(reach / h), PEAK_PAD))
    ext = tuple(n + 2 * pad for n in shape)
    idx = lattice_index(ext) - pad
    pts = (idx * float(stride)) @ pm.i2w[:3, :3].T + pm.i2w[:3, 3]
    ijk = idx.astype(np.int64) * stride
    inside = np.all((ijk >= 0) & (ijk < np.array(pm.grid.shape)), axis=1)
    gflat = np.ravel_multi_index(tuple(np.where(inside[:, None], ijk, 0).T), pm.grid.shape)
    known = np.zeros(pm.grid.size, bool)
    known[flat] = True
    known = inside & known[gflat]
    tau = np.zeros((len(idx), 3))
    tau_b = np.zeros((len(idx), 3))
    v = fld.reshape(-1, fld.shape[-1])[gflat[known]]
    tau[known] = v[:, channel:channel + 3]
    tau_b[known] = v[:, beam:beam + 3]
    # the light is needed where a blur reaches the medium: within ``pad`` points of it
    near = known.reshape(ext)
    for _ in range(pad):
        near = _dilate(near)
    near = np.flatnonzero(near)
    e = np.zeros((len(idx), 3))
    e[near] = cell_mean_irradiance(light, pts[near], stride * pm.i2w[:3, :3])
    rest = np.flatnonzero(~known & np.any(e > 0.0, axis=1))  # no light, no peak: no depth
    if rest.size and f > 0.0:
        for out, through in ((tau, pm), (tau_b, delta_scaled(pm))):
            got = fog_optical_depth(through.sigma_t, towards_light(light, pts[rest])[1]) if fog \
                else light_optical_depth([through], light, pts[rest], step,
                                         should_cancel=should_cancel)
            if got is None:
                return None
            out[rest] = got
    if should_cancel and should_cancel():
        return None
    b = e * np.maximum(np.exp(-tau_b) - np.exp(-tau), 0.0)
    if f > 0.0 and mean_sigma_s > 0.0:
        with np.errstate(invalid="ignore"):
            n = np.mean(tau - tau_b, axis=1)
        s = np.nan_to_num(np.maximum(n, 0.0), nan=0.0, posinf=1e30) / (f * mean_sigma_s)
        width = per_metre * s
        levels = pyramid.build(b.astype(np.float32).reshape(ext + (3,)), 10)
        if should_cancel and should_cancel():
            return None
        core = np.all((idx >= 0) & (idx < np.array(shape)), axis=1)
        b = pyramid.lookup(levels, idx[core] + pad, width[core], h)
    return np.ascontiguousarray(b.reshape(shape + (3,)), np.float32), stride


def cell_mean_source(pm: PreparedMedium, fld: np.ndarray, light: Light, channel: int,
                     stride: int, shape, cells: np.ndarray,
                     beam: Optional[int] = None) -> np.ndarray:
    """The first-scattering source Q = sigma_s E exp(-tau) (W/m^3, (len(cells), 3)) averaged
    over the voxels of each lattice cell in ``cells`` (the voxels nearest to the cell's
    point), with a point light's E ~ 1/r^2 read as 1/max(r^2, R^2/3): the exact mean of
    1/r^2 over the ball of one voxel's volume (radius R) centred on the light.  Next to a
    point light the source varies too fast for one read at the lattice point: a light
    inside a medium then lost 25-55 % of its first-scattered power to the pyramid."""
    from .lights import incident
    from .media import density_from
    ci = np.stack(np.unravel_index(cells, shape), axis=1)
    offs = np.stack(np.meshgrid(*[np.arange(stride) - stride // 2] * 3, indexing="ij"), -1).reshape(-1, 3)
    ijk = (ci[:, None, :] * stride + offs[None]).reshape(-1, 3)
    ok = np.all((ijk >= 0) & (ijk < np.array(pm.grid.shape)), axis=1)
    flat = np.ravel_multi_index(tuple(np.where(ok[:, None], ijk, 0).T), pm.grid.shape)
    pts = ijk.astype(np.float64) @ pm.i2w[:3, :3].T + pm.i2w[:3, 3]
    v = fld.reshape(-1, fld.shape[-1])[flat]
    rho = np.where(ok, density_from(v[:, 0], pm.threshold), 0.0)
    _, e = incident(light, pts)
    vol = abs(np.linalg.det(pm.i2w[:3, :3]))
    r_min2 = (3.0 * vol / (4.0 * np.pi)) ** (2.0 / 3.0) / 3.0
    r2 = np.einsum("ij,ij->i", pts - light.position, pts - light.position)
    held = max(float(light.radius), 1e-4) ** 2  # lights.light_sample's own floor on r^2
    e = e * (np.maximum(r2, held) / np.maximum(r2, r_min2))[:, None]
    q = first_scattering(pm, rho, e, v[:, channel:channel + 3],
                         None if beam is None else v[:, beam:beam + 3])
    return q.reshape(len(cells), len(offs), 3).mean(axis=1)


def _tent_restrict(a: np.ndarray, axis: int, stride: int, n_out: int) -> np.ndarray:
    """``a`` restricted along ``axis`` to every ``stride``-th point with the tent weights
    (stride - |t|) / stride^2, t = -(stride-1)..stride-1 (zero beyond the ends): each point's
    value shared among the lattice points around it in proportion to their nearness, so that
    the sum times the lattice spacing keeps the sum times the voxel size."""
    n = a.shape[axis]
    pad = [(0, 0)] * a.ndim
    pad[axis] = (stride - 1, stride * n_out - n + stride)
    p = np.pad(a, pad)
    out = 0.0
    for i, t in enumerate(range(-(stride - 1), stride)):
        sl = [slice(None)] * a.ndim
        sl[axis] = slice(i, i + stride * n_out, stride)
        out = out + ((stride - abs(t)) / float(stride * stride)) * p[tuple(sl)]
    return out


def lattice_source(pm: PreparedMedium, fld: np.ndarray, light: Light, channel: int,
                   stride: int, shape, chunk: int = 16,
                   should_cancel: Optional[Callable[[], bool]] = None,
                   beam: Optional[int] = None) -> Optional[np.ndarray]:
    """The first-scattering source Q = sigma_s E exp(-tau) (W/m^3, (N,3) in the C order of
    the lattice ``shape`` ``stride`` voxels apart) from every voxel of the field ``fld``
    (optical depth at ``channel``), each voxel's power shared among the lattice points
    around it (``_tent_restrict`` along each axis): the lattice holds the voxels' power, where
    reading Q at the lattice points alone missed (or doubled) the thin layer a light lights
    inside a dense medium's face as the lattice fell against it (docs/ms_resolution.md).
    Stride 1 reads the voxels themselves.  Made ``chunk`` voxel planes at a time; None when
    ``should_cancel`` says so between them."""
    from .lights import irradiance
    from .media import density_from
    nx = pm.grid.shape[0]
    rows = np.zeros((nx, shape[1], shape[2], 3))
    flat_fld = fld.reshape(nx, -1, fld.shape[-1])
    for a in range(0, nx, chunk):
        if should_cancel and should_cancel():
            return None
        b = min(a + chunk, nx)
        ijk = np.stack(np.meshgrid(np.arange(a, b), np.arange(pm.grid.shape[1]),
                                   np.arange(pm.grid.shape[2]), indexing="ij"), -1).reshape(-1, 3)
        v = flat_fld[a:b].reshape(-1, fld.shape[-1])
        rho = density_from(v[:, 0], pm.threshold)
        live = rho > 0.0
        q = np.zeros((len(v), 3))
        if np.any(live):
            pts = ijk[live].astype(np.float64) @ pm.i2w[:3, :3].T + pm.i2w[:3, 3]
            e = irradiance(light, pts)
            q[live] = first_scattering(pm, rho[live], e, v[live, channel:channel + 3],
                                       None if beam is None else v[live, beam:beam + 3])
        q = q.reshape((b - a,) + tuple(pm.grid.shape[1:]) + (3,))
        if stride > 1:
            q = _tent_restrict(_tent_restrict(q, 1, stride, shape[1]), 2, stride, shape[2])
        rows[a:b] = q
    if stride > 1:
        rows = _tent_restrict(rows, 0, stride, shape[0])
    return rows.reshape(-1, 3)


def multiple_field(pm: PreparedMedium, fld: np.ndarray, light: Light, channel: int,
                   camera: Camera, max_levels=8, resolution: int = MULTIPLE_RESOLUTION,
                   should_cancel: Optional[Callable[[], bool]] = None,
                   g_last: Optional[float] = None,
                   beam: Optional[int] = None, threads: int = 0) -> Optional[MultipleField]:
    """The light pyramid of ``light`` on medium ``pm`` from its precomputed field ``fld``
    (optical depth at ``channel``), see MultipleField, on a lattice of about ``resolution``
    points along the grid's longest side (never finer than the voxels): the source
    (``lattice_source``) spread level by level, each level losing what leaves through the
    medium's surface (boundary.py) and then moved along the light by the mean displacement
    of its paths (``drift_levels``), for the light that ``camera`` sees.  None when
    ``should_cancel`` says so.  ``pm`` is the medium as the walk sees it: precompute hands
    the delta-scaled medium (media.delta_scaled) and the optical depth of its beam, and
    ``g_last`` the medium's own g, that of the last scattering towards the camera.
    ``threads``: for the exact first flights' convolutions (firstflight.py)."""
    from . import boundary
    from .mpp import level_paths, walk_displacement
    stride, shape, h = pyramid_lattice(pm, resolution)
    got = source_lattice(pm, fld, light, channel, stride, beam, should_cancel)
    if got is None:
        return None
    base, rho, pts = got
    inside = rho[rho > 0]
    mean_rho = float(np.mean(inside)) if inside.size else 0.0
    sigma_s = np.asarray(pm.sigma_s, np.float64) * mean_rho
    g = float(pm.g)
    # the walk's loss through the surface, for the medium's mean (grey) coefficients
    ss, sa = float(np.mean(sigma_s)), float(np.mean(pm.sigma_a)) * mean_rho
    z_b = boundary.extrapolation_length(ss, sa, g)
    keep = None
    if np.isfinite(z_b) and ss > 0.0:
        l_tr = 1.0 / (ss * max(1.0 - g, 1e-6))
        drifts = [float(walk_displacement(float(l_k) / l_tr, g)[0]) * l_tr
                  for _, _, l_k in level_paths(h, max_levels, l_tr, g)]
        keep = boundary.survival(pm, (rho > 0).reshape(shape), stride, h, z_b, drifts,
                                 lambda x: light_direction(light, x))
    if should_cancel and should_cancel():
        return None
    first = None
    if pm.threshold >= 0.0 and camera is not None and \
            str(camera.projection).upper() in ("PERSP", "ORTHO"):
        # a mesh volume, whose levels the march sums once (march.flatten_levels): the first
        # flight exact where the first flights mostly leave the medium (firstflight.py)
        fine = fine_stride(pm, stride)
        sigma_t = np.asarray(pm.sigma_t, np.float64) * mean_rho
        if fine != stride and flight_weight(
                base.reshape(tuple(shape) + (3,)), (rho > 0).reshape(shape),
                stride * pm.i2w[:3, :3], light_direction(light, pts),
                g if g_last is None else float(g_last), sigma_t) is None:
            fine = stride   # the walk serves: no finer source for flights never made
        got = (base, rho, pts) if fine == stride else \
            source_lattice(pm, fld, light, channel, fine, beam, should_cancel)
        if got is None:
            return None
        fshape = lattice_shape(pm.grid.shape, fine)
        first = first_flight(got[0].reshape(tuple(fshape) + (3,)), (got[1] > 0).reshape(fshape),
                             fine * pm.i2w[:3, :3], light_direction(light, got[2]),
                             towards_camera(camera, got[2]),
                             g if g_last is None else float(g_last), sigma_t, sigma_s,
                             should_cancel, threads)
        if should_cancel and should_cancel():
            return None
        if first is not None:
            first.stride = fine
    levels, directions = source_pyramid(base, light, pts, shape, g, max_levels, keep)
    if should_cancel and should_cancel():
        return None
    drift_levels(levels, pm, light, camera, stride, h, sigma_s, directions, g_last)
    return MultipleField(stride, h, levels, first)


def source_lattice(pm: PreparedMedium, fld: np.ndarray, light: Light, channel: int,
                   stride: int, beam: Optional[int] = None,
                   should_cancel: Optional[Callable[[], bool]] = None):
    """(source (N,3) W/m^3, density (N,), points (N,3) m) on the lattice ``stride`` voxels
    apart (C order of ``lattice_shape``): the first-scattering source of ``lattice_source``,
    averaged over the cells round a point or spot light (``cell_mean_source``), and the
    medium's density at the lattice points.  None when ``should_cancel`` says so."""
    shape = lattice_shape(pm.grid.shape, stride)
    idx, pts = lattice_points(pm, shape, stride)
    rho = density_from(lattice_values(fld[..., 0], idx, stride), pm.threshold)
    base = lattice_source(pm, fld, light, channel, stride, shape, should_cancel=should_cancel,
                          beam=beam)
    if base is None:
        return None
    if light.kind in ("POINT", "SPOT"):
        near = near_light_cells(pm, light, stride, shape)
        if near.size:
            base[near] = cell_mean_source(pm, fld, light, channel, stride, shape, near, beam)
    return base, rho, pts


# What follows a narrow beam in a mesh volume -- the forward peak's light (peak_light) and
# the exact first flights (firstflight.py) -- is computed on a lattice finer than the walk's
# by this factor where the first flights' FFT on it stays within FINE_POINTS: round a beam a
# few lattice steps wide their light is as narrow (fog_beam on the walk's 64 points: the
# beam's axis 14 % too dark, its sides 60 % too bright; docs/method.md).  Larger grids, and
# the media of varying density (VDB grids, the world's fog), whose first flights are the
# walk's, keep the walk's lattice (the forward peak's light alone on the finer lattice took
# smoke_plume's precompute from 1.8 s to 5.2 s for the same error).
REFINE = 2
FINE_POINTS = 1 << 22


def fine_stride(pm: PreparedMedium, stride: int) -> int:
    """The stride (voxels) of the lattice for the forward peak's light and the exact first
    flights, for a walk on ``stride``: the largest divisor of ``stride`` at most
    stride / REFINE (the walk's lattice points are then among its points,
    march.flatten_levels), or ``stride`` itself where that is 1, the medium is not a mesh
    volume (``pm.sharp``) or the finer lattice's FFT would exceed FINE_POINTS."""
    if not pm.sharp:
        return stride
    fine = next((d for d in range(stride // REFINE, 0, -1) if stride % d == 0), stride)
    n = int(np.prod(fft_shape(lattice_shape(pm.grid.shape, fine))))
    return fine if n <= FINE_POINTS else stride


def source_pyramid(base, light: Light, pts, shape, g: float, max_levels: int, keep=None):
    """(levels, directions): the pyramid (pyramid.build) of the source ``base`` ((N,3) W/m^3
    at the lattice points ``pts`` (N,3, m) of ``shape``) and, for a point or spot light in a
    medium with g != 0, the pyramid of the light's direction at each first scattering
    weighted by its power, and that power ((X,Y,Z,4) per level, blurred with the source:
    level k then holds the sums from which drift_levels takes the mean direction of the
    sources each point gathers); None for the others, whose direction is the same
    everywhere or does not drift.  ``keep``: pyramid.build's loss on the way (boundary.py),
    applied to the directions as to the light they travel with."""
    from . import pyramid
    if light.kind not in ("POINT", "SPOT") or g == 0.0:
        return pyramid.build(base.astype(np.float32).reshape(tuple(shape) + (3,)), max_levels,
                             keep), None
    power = base.sum(axis=1, keepdims=True)
    full = np.concatenate([base, power * light_direction(light, pts), power], axis=1)
    built = pyramid.build(full.astype(np.float32).reshape(tuple(shape) + (7,)), max_levels, keep)
    return ([np.ascontiguousarray(lev[..., :3]) for lev in built],
            [np.ascontiguousarray(lev[..., 3:]) for lev in built])


def drift_levels(levels, pm: PreparedMedium, light: Light, camera: Camera, stride: int,
                 h: float, sigma_s, directions=None, g_last: Optional[float] = None):
    """Move each level of a light pyramid (in place) so that level k at x reads the first
    scatterings at x - E[x_k | v]: the paths the level stands for (``level_paths``, of
    representative length l_k) start from a first scattering of the light travelling along d
    and drift forward along it; of the light that leaves x towards the camera (v, unit,
    towards the camera's position; its axis for an orthographic camera), those that arrive
    heading towards v came further along v (``kernels_np.walk_displacement``).

    d belongs to the first scatterings read, not to x: ``directions`` (one (X,Y,Z,4) array
    per level, blurred with it) holds the power-weighted sum of the light's direction at the
    first scatterings and their power, so d at the point read is their mean (shorter than 1
    where sources of several directions mix, as round a point light); the point read is
    found by a few fixed-point steps y = x - shift(d(y)).  Without ``directions``, or where a
    level holds no power, d is the light's own direction there (``light_direction``).
    ``sigma_s``: the medium's mean scattering coefficient where it has density (1/m; one per
    colour channel, or one for all), giving the transport length l_tr = 1 / (sigma_s (1 - g))
    of the paths: each channel drifts by its own.  ``g_last``: the anisotropy of the last
    scattering, towards the camera (the medium's own g where ``pm`` is delta-scaled; pm.g
    when None).  Beyond the lattice the
    source is zero.  Nothing moves for g = 0 or a medium that does not scatter
    (docs/method.md, "Drift along the light")."""
    from .mpp import level_paths, walk_displacement
    g = float(pm.g)
    g_last = g if g_last is None else float(g_last)
    sigma_s = np.broadcast_to(np.asarray(sigma_s, np.float64), (3,))
    if g == 0.0 or not np.all(sigma_s > 0.0):
        return
    # channels scattering alike drift alike: one resample for a grey medium
    l_tr = 1.0 / (sigma_s * max(1.0 - g, 1e-6))
    groups = [(float(l_tr[0]), [0, 1, 2])] if np.all(sigma_s == sigma_s[0]) else \
        [(float(l_tr[c]), [c]) for c in range(3)]
    paths = [level_paths(h, len(levels), l_c, g) for l_c, _ in groups]
    if directions is not None:
        mean_directions = mean_source_directions(directions, light, pm, stride)
    read = kernels.get("trilinear")   # a float64 grid (the mean directions) reads on numpy
    for k in range(len(levels)):
        lev = levels[k]
        idx, x = lattice_points(pm, lev.shape[:3], stride * 2 ** k)
        view = towards_camera(camera, x)
        padded = np.pad(lev, ((1, 1), (1, 1), (1, 1), (0, 0)))
        moved = np.empty(lev.shape, np.float32)
        for (l_tr, chans), per_level in zip(groups, paths):
            u = float(per_level[k][2]) / l_tr
            drift, beta = walk_displacement(u, g, g_last)

            def source_index(d):
                shift = l_tr * (float(drift) * d + float(beta) * (view - g_last * g * np.exp(-u) * d))
                return idx - (shift @ pm.w2i[:3, :3].T) / (stride * 2.0 ** k)

            src = source_index(light_direction(light, x))
            if directions is not None:
                mean = mean_directions[k]
                top = np.array(mean.shape[:3], np.float64) - 1.0 - 1e-9
                for _ in range(3):  # beyond the lattice, the direction at its nearest edge
                    src = source_index(read(mean, np.clip(src, 0.0, top)))
            moved[..., chans] = read(padded[..., chans], src + 1.0).reshape(
                lev.shape[:3] + (len(chans),))
        levels[k] = moved


def mean_source_directions(directions, light: Light, pm: PreparedMedium, stride: int):
    """Per level, the mean direction (X,Y,Z,3) of the light at the first scatterings that
    level's points gather, from their power-weighted sums ``directions`` (see drift_levels).
    Where a level holds (next to) no power the next coarser level's mean stands in, and
    beyond the coarsest the light's own direction there: what a source would have if some
    of the light's power reached it."""
    out = [None] * len(directions)
    for k in range(len(directions) - 1, -1, -1):
        sums = directions[k].astype(np.float64)
        idx, x = lattice_points(pm, sums.shape[:3], stride * 2 ** k)
        if k + 1 < len(directions):
            coarser = np.pad(out[k + 1], ((1, 1), (1, 1), (1, 1), (0, 0)), mode="edge")
            mean = kernels.get("trilinear")(coarser, idx / 2.0 + 1.0)
        else:
            mean = light_direction(light, x)
        power = sums[..., 3].reshape(-1)
        held = power > 1e-6 * max(float(power.max()), 1e-300)
        mean[held] = sums[..., :3].reshape(-1, 3)[held] / power[held, None]
        out[k] = mean.reshape(sums.shape[:3] + (3,))
    return out


def light_direction(light: Light, points) -> np.ndarray:
    """The direction (N,3, unit) the light travels at ``points`` (N,3, m): radial from a point
    or spot light, the axis of a sun or area light."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if light.kind in ("SUN", "AREA"):
        axis = np.asarray(light.direction, np.float64)
        return np.tile(axis / np.linalg.norm(axis), (len(points), 1))
    return -towards_light(light, points)[0]


def lattice_points(pm: PreparedMedium, shape, spacing: int):
    """(index coordinates (N,3), world positions (N,3, m)) of a lattice of ``shape`` whose
    points lie ``spacing`` padded-grid voxels apart from the grid's origin (a pyramid level k:
    stride 2^k), in C order."""
    idx = lattice_index(shape)
    return idx, (idx * float(spacing)) @ pm.i2w[:3, :3].T + pm.i2w[:3, 3]


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


@dataclass
class SweepPyramid:
    """One pyramid of light columns for ``kernels.light_sweep``: slabs along ``axis`` from
    ``i_first`` to ``i_last`` (travelling ``sign`` = +1 or -1, away from the light), the
    column lattice ``n_p`` x ``n_q`` placed by ``coef`` (kernels_np.column_index), ``cone``
    for columns fanning out from a point (only the voxels of this pyramid are written)."""

    axis: int
    sign: int
    i_first: int
    i_last: int
    coef: np.ndarray
    n_p: int
    n_q: int
    cone: bool


def _lattice(lo, hi):
    """First column number and count of a lattice (spacing 1) covering [lo, hi]."""
    first = int(np.floor(lo))
    return first, max(2, int(np.ceil(hi)) - first + 1)


def light_position(light: Light):
    """World position of a local light's centre (the point optical depths are taken to)."""
    m = np.asarray(light.matrix, np.float64)
    return m[:3, 3] if light.kind == "AREA" else np.asarray(light.position, np.float64)


def sweep_pyramids(pm: PreparedMedium, light: Light):
    """(pyramids, light in index coordinates) for sweeping ``light`` over ``pm``'s padded
    grid, or None when the light cannot be swept (non-finite or astronomically far: the
    caller then marches every voxel exactly).

    A sun gives one pyramid of parallel columns along the grid axis closest to its
    direction; a local light up to six, one per axis and side, fanning out from its centre,
    each covering the voxels whose largest offset from the light is along its axis."""
    shape = pm.grid.shape
    if light.kind == "SUN":
        d = -np.asarray(light.direction, np.float64)
        u = pm.w2i[:, :3] @ d  # index-space direction towards the sun
        if not np.all(np.isfinite(u)):
            return None
        axis = int(np.argmax(np.abs(u)))
        if not abs(u[axis]) > 0.0:
            return None
        sign = -1 if u[axis] > 0 else 1
        i_first, i_last = (0, shape[axis] - 1) if sign > 0 else (shape[axis] - 1, 0)
        coef = np.zeros(6)
        coef[4] = 1.0
        counts = []
        for slot, e in enumerate(kernels_np._other_axes(axis)):
            slope = u[e] / u[axis]
            # column p sits at p + first + (i - i_first) slope on slab i: cover every voxel
            ends = [j - (i - i_first) * slope for j in (0, shape[e] - 1) for i in (i_first, i_last)]
            first, n = _lattice(min(ends), max(ends))
            coef[slot] = first - i_first * slope
            coef[2 + slot] = slope
            counts.append(n)
        return [SweepPyramid(axis, sign, i_first, i_last, coef, counts[0], counts[1], False)], \
            np.zeros(3)
    c = light_position(light)
    L = pm.w2i[:, :3] @ c + pm.w2i[:, 3]
    if not np.all(np.isfinite(L)) or np.max(np.abs(L)) > 1e9:
        return None
    out = []
    for axis in range(3):
        n_a = shape[axis]
        for sign in (1, -1):
            far = n_a - 1 if sign > 0 else 0
            d_far = sign * (far - L[axis])
            if not d_far > 0.0:
                continue
            i_first = max(0, int(np.floor(L[axis])) + 1) if sign > 0 else \
                min(n_a - 1, int(np.ceil(L[axis])) - 1)
            if not (0 <= i_first < n_a) or not sign * (i_first - L[axis]) > 0.0:
                continue
            coef = np.zeros(6)
            coef[4] = -L[axis] / (far - L[axis])
            coef[5] = 1.0 / (far - L[axis])
            counts = []
            for slot, e in enumerate(kernels_np._other_axes(axis)):
                if L[e] - d_far > shape[e] - 1 or L[e] + d_far < 0:
                    break  # the cone misses the grid
                # voxels project from the light onto the far slab; the extremes come from
                # the corners of the box between the first and the far slab
                proj = [L[e] + (j - L[e]) * (far - L[axis]) / (i - L[axis])
                        for j in (0, shape[e] - 1) for i in (i_first, far)]
                first, n = _lattice(max(min(proj), L[e] - d_far), min(max(proj), L[e] + d_far))
                coef[slot] = L[e] + coef[4] * (first - L[e])
                coef[2 + slot] = coef[5] * (first - L[e])
                counts.append(n)
            if len(counts) == 2:
                out.append(SweepPyramid(axis, sign, i_first, far, coef, counts[0], counts[1], True))
    return out, L


SWEEP_PIECE = 2.0  # longest piece of a column segment, in precompute steps (Simpson's rule)


def _sub_steps(pm: PreparedMedium, pyr: SweepPyramid, step: float) -> int:
    """Pieces per slab-to-slab segment so that none is longer than ``SWEEP_PIECE`` steps of
    ``step`` metres (the longest segment is at a corner column of the lattice)."""
    longest = 0.0
    for p in (0, pyr.n_p - 1):
        for q in (0, pyr.n_q - 1):
            a = kernels_np.column_index(pyr.axis, pyr.coef, float(pyr.i_first), p, q)
            b = kernels_np.column_index(pyr.axis, pyr.coef, float(pyr.i_first + pyr.sign), p, q)
            longest = max(longest, float(np.linalg.norm(pm.i2w[:3, :3] @ (b - a))))
    return max(1, int(np.ceil(longest / (SWEEP_PIECE * step) - 1e-9)))


def _dilate(mask):
    """3x3x3 dilation of a boolean grid (its outer layer is padding: np.roll's wrap is harmless)."""
    for ax in range(3):
        mask = mask | np.roll(mask, 1, axis=ax) | np.roll(mask, -1, axis=ax)
    return mask


def near_sharp_surfaces(pm: PreparedMedium, media: List[PreparedMedium]):
    """Flat indices of ``pm``'s voxels next to a sharp (mesh) surface: its own inside voxels
    with an outside voxel among their 26 neighbours, and its voxels within one voxel of the
    surface of any other sharp medium in ``media``."""
    out = np.zeros(pm.grid.shape, bool)
    if pm.sharp:
        inside = pm.grid >= pm.threshold
        out |= inside & _dilate(~inside)
    others = [m for m in media if m is not pm and m.sharp]
    if others:
        ijk = np.stack(np.meshgrid(*[np.arange(n, dtype=np.float64) for n in pm.grid.shape],
                                   indexing="ij"), -1).reshape(-1, 3)
        world = ijk @ pm.i2w[:3, :3].T + pm.i2w[:3, 3]
        for m in others:
            idx = world @ m.w2i[:, :3].T + m.w2i[:, 3]
            near = np.flatnonzero(np.all((idx > -1.0) & (idx < np.array(m.grid.shape)), axis=1))
            inside = np.zeros(len(world), bool)   # beyond m's grid m has no density
            inside[near] = kernels.get("trilinear")(m.grid, idx[near]) >= m.threshold
            inside = inside.reshape(pm.grid.shape)
            out |= _dilate(inside) & _dilate(~inside)
    return np.flatnonzero(out)


SWEEP = True  # lights by the sweep (False: one exact march per needed voxel, the old way;
# a switch for benchmarks/performance.py)
SWEEP_CELLS = 16  # column cells per sweep chunk (at least): chunks run in parallel, Esc between


def sweep_light(media: List[PreparedMedium], pm: PreparedMedium, light: Light, field: np.ndarray,
                channel: int, step: float, surfaces=None, threads=0, should_cancel=None,
                needed=None, fog_sigma_t=None, sharp=None):
    """Fill ``field[..., channel:channel+3]`` with the RGB optical depth from every voxel of
    ``pm``'s grid to ``light`` through all media, with ``kernels.light_sweep``: the light's
    rays are followed slab by slab across the grid, so the cost is that of a few passes over
    the grid instead of one march per voxel.  Each column starts from the exact optical depth
    of its first point (``light_optical_depth``: the media between the grid and the light)
    and every voxel interpolates the four columns around it on its slab.

    ``SHADOW_TAU`` is added where an opaque surface (``surfaces``) lies between a voxel and
    the light, tested per voxel at ``needed`` = (flat indices, world points) (all voxels by
    default), as before the sweep: shadow edges stay sharp; so is the world fog's optical
    depth with ``fog_sigma_t`` (RGB 1/m; ``media`` must not hold the fog).  ``sharp``: the
    flat indices ``near_sharp_surfaces(pm, media)`` gives, where the caller has them (they
    depend on the media's grids only, not on the light).  Returns True when done, False
    when cancelled, None when the light cannot be swept (the caller then marches every
    voxel)."""
    plan = sweep_pyramids(pm, light) if SWEEP else None
    if plan is None:
        return None
    pyramids, L = plan
    sweep = kernels.get("light_sweep")
    grids, w2is, sigmas, thrs = kernel_arrays(media)
    a2w = pm.i2w[:3, :]
    n_threads = threads if threads > 0 else (os.cpu_count() or 1)
    jobs = []
    for pyr in pyramids:
        pq = np.stack(np.meshgrid(np.arange(pyr.n_p), np.arange(pyr.n_q), indexing="ij"), -1)
        idx = kernels_np.column_index(pyr.axis, pyr.coef, float(pyr.i_first), pq[..., 0], pq[..., 1])
        start = idx.reshape(-1, 3) @ a2w[:, :3].T + a2w[:, 3]
        init = light_optical_depth(media, light, start, step, should_cancel=should_cancel,
                                   threads=threads)
        if init is None:
            return False
        n_sub = _sub_steps(pm, pyr, step)
        cells = pyr.n_p - 1
        per = max(SWEEP_CELLS, -(-cells // (4 * n_threads)))
        for a in range(0, cells, per):
            jobs.append((pyr, init.reshape(pyr.n_p, pyr.n_q, 3), a, min(cells, a + per), n_sub))

    def work(a, b):
        for pyr, init, p_lo, p_hi, n_sub in jobs[a:b]:
            sweep(field, channel, a2w, pyr.axis, pyr.sign, pyr.i_first, pyr.i_last, pyr.coef, L,
                  pyr.cone, init, p_lo, p_hi, n_sub, grids, w2is, sigmas, thrs)

    if not run_chunks(len(jobs), 1, work, threads, should_cancel):
        return False
    if pm.sharp or any(m.sharp for m in media):
        # The optical depth bends sharply at a mesh volume's surface, which the columns'
        # interpolation would smear over a voxel; the voxels there (for the medium's own
        # surface its inside layer, what the march reads once its refinement, march.py, has
        # stepped off the surface) march exactly.
        flat = near_sharp_surfaces(pm, media) if sharp is None else sharp
        tau = light_optical_depth(media, light, grid_points(pm, flat), step,
                                  should_cancel=should_cancel, threads=threads)
        if tau is None:
            return False
        field.reshape(-1, field.shape[-1])[flat, channel:channel + 3] = tau
    shadowed = surfaces is not None and not surfaces.empty
    if shadowed or fog_sigma_t is not None:
        if needed is None:
            flat = np.arange(int(np.prod(pm.grid.shape)))
            needed = flat, grid_points(pm, flat)
        flat, pts = needed
        view = field.reshape(-1, field.shape[-1])

        def per_voxel(a, b):
            d, limit = towards_light(light, pts[a:b])
            add = np.zeros((b - a, 3))
            if fog_sigma_t is not None:
                add += fog_optical_depth(fog_sigma_t, limit)
            if shadowed:
                add += SHADOW_TAU * occluded(surfaces, pts[a:b], d, limit)[:, None]
            view[flat[a:b], channel:channel + 3] += add.astype(np.float32)

        return run_chunks(len(flat), 1 << 14, per_voxel, threads, should_cancel)
    return True


upsample = kernels_np.upsample  # (re-exported: the world light's lattice to the voxels)


def coarse_lattice(pm: PreparedMedium, stride: int):
    """Index points of ``pm``'s padded grid taken every ``stride`` voxels (covering the whole
    grid) whose neighbourhood of radius ``stride`` holds density.  Returns (shape, flat
    indices into that coarse shape, world positions (K,3))."""
    shape = lattice_shape(pm.grid.shape, stride)
    occ = pm.grid > 0.0
    dil = occ.copy()
    for ax in range(3):
        acc = dil.copy()
        for s in range(1, stride + 1):
            acc |= np.roll(dil, s, axis=ax) | np.roll(dil, -s, axis=ax)
        dil = acc
    sub = np.zeros(shape, bool)
    picked = dil[::stride, ::stride, ::stride]
    sub[:picked.shape[0], :picked.shape[1], :picked.shape[2]] = picked
    flat = np.flatnonzero(sub)
    ijk = np.stack(np.unravel_index(flat, shape), axis=1).astype(np.float64) * stride
    return shape, flat, ijk @ pm.i2w[:3, :3].T + pm.i2w[:3, 3]


def precompute(media: List[PreparedMedium], lights: List[Light], world: World, camera: Camera,
               n_dirs: int = 64, step_factor: float = 1.0, seed: int = 0,
               should_cancel: Optional[Callable[[], bool]] = None,
               progress: Optional[Callable[[float, str], None]] = None,
               surfaces=None, threads: int = 0, multiple: bool = False,
               multiple_resolution: int = MULTIPLE_RESOLUTION) -> Optional[Precomputed]:
    """Field arrays for every medium, and with ``multiple`` the light pyramids; None when
    cancelled.  ``surfaces`` (a SurfaceSet or None) shadow the lights and the sky.  Media
    that cannot scatter (sigma_s = 0) get no multiple-scattering data."""
    import time
    t_start = time.perf_counter()
    from .media import delta_scaled
    chans = [None] * len(lights)
    c = 1
    for i, light in enumerate(lights):
        if not is_dark(light):
            chans[i] = c
            c += 3
    beams = [None] * len(lights)
    delta = [delta_scaled(pm) for pm in media]
    if multiple and any(d is not pm for d, pm in zip(delta, media)):
        for i in range(len(lights)):
            if chans[i] is not None:
                beams[i] = c
                c += 3
    amb = c if np.any(np.asarray(world.color) > 0) else None
    amb_ms = None
    if amb is not None:
        c += 3
        if multiple:
            amb_ms = c
            c += 3
    layout = FieldLayout(chans, amb, c, amb_ms,
                         [c if pm.emission_grid is not None else None for pm in media],
                         beams if any(b is not None for b in beams) else None)
    ms_all = []
    step = step_factor * min(pm.voxel_size for pm in media) if media else 1.0
    solid, fog = split_fog(media)
    fog_st = None if fog is None else fog.sigma_t
    delta_of = {id(pm): d for pm, d in zip(media, delta)}
    solid_delta = [delta_of[id(pm)] for pm in solid]
    fog_delta = None if fog is None else delta_of[id(fog)].sigma_t
    shadowed = surfaces is not None and not surfaces.empty
    fields = []
    n_pts = 0
    n_ambient = 0
    for mi, pm in enumerate(media):
        cm = c if pm.emission_grid is None else c + 3
        f = np.zeros(pm.grid.shape + (cm,), np.float32)
        f[..., 0] = pm.grid
        if pm.emission_grid is not None:
            f[..., c:c + 3] = pm.emission_grid
        flat = needed_flat(pm)
        n_pts += len(flat)
        pts = grid_points(pm, flat) if shadowed or fog is not None else None
        view = f.reshape(-1, cm)
        sharp = None
        if any(b is not None for b in beams):   # the medium's mean sigma_s, for peak_light
            rho = density_from(pm.grid.reshape(-1)[flat], pm.threshold)
            occ = rho[rho > 0]
            mean_ss = float(np.mean(pm.sigma_s)) * (float(occ.mean()) if occ.size else 0.0)
        for li, light in enumerate(lights):
            if chans[li] is None:
                continue
            if progress:
                progress(0.0, f"Light attenuation: {light.name} on {pm.medium.name}")
            # the unscattered beam through the media, then (multiple scattering with a forward
            # peak) the beam of unscattered and forward-scattered light: the same optical depth
            # through the delta-scaled media, the surfaces as opaque
            for ch, through, own, through_fog in ((chans[li], solid, pm, fog_st),
                                                  (beams[li], solid_delta, delta[mi], fog_delta)):
                if ch is None:
                    continue
                swept = None
                if pm is not fog:
                    if sharp is None and (own.sharp or any(m.sharp for m in through)):
                        # the same voxels for every light and for the delta-scaled media
                        sharp = near_sharp_surfaces(own, through)
                    swept = sweep_light(through, own, light, f, ch, step, surfaces=surfaces,
                                        threads=threads, should_cancel=should_cancel,
                                        needed=None if pts is None else (flat, pts),
                                        fog_sigma_t=through_fog, sharp=sharp)
                if swept is False:
                    return None
                if swept is None:  # the fog, or not sweepable: march from every needed voxel
                    pts = grid_points(pm, flat) if pts is None else pts
                    tau = light_optical_depth(through, light, pts, step,
                                              should_cancel=should_cancel,
                                              surfaces=None if pm is fog else surfaces,
                                              threads=threads, fog_sigma_t=through_fog)
                    if tau is None:
                        return None
                    if pm is fog and shadowed:
                        vis = soft_visibility(surfaces, light, pm, flat, pts, threads=threads,
                                              should_cancel=should_cancel)
                        if vis is None:
                            return None
                        tau = tau - np.log(np.maximum(vis, np.exp(-SHADOW_TAU)))[:, None]
                    view[flat, ch:ch + 3] = tau
            if beams[li] is not None:
                # the beam channels: from the beam's optical depth to the forward peak's own
                # light, spread sideways (W/m^2)
                peak = peak_light(pm, f, light, chans[li], beams[li], mean_ss, flat, step,
                                  multiple_resolution, should_cancel, fog=pm is fog)
                if peak is None:
                    return None
                kernels.get("upsample_into")(f, beams[li], peak[0], peak[1], flat)
        if amb is not None:
            if progress:
                progress(0.0, f"World light on {pm.medium.name}")
            # the world light is smooth: compute it on a lattice ``stride`` voxels apart and
            # interpolate trilinearly to the needed points
            stride = max(1, int(round(max(pm.grid.shape) / AMBIENT_RESOLUTION)))
            cshape, cflat, cpts = coarse_lattice(pm, stride)
            a = world_light(solid, pm, world, camera, cpts, n_dirs, 2.0 * step, seed=seed + mi,
                            should_cancel=should_cancel, surfaces=surfaces, threads=threads,
                            multiple=amb_ms is not None)
            if a is None:
                return None
            up = kernels.get("upsample_into")
            for ch, vals in zip((amb, amb_ms), a if amb_ms is not None else (a,)):
                coarse = np.zeros((int(np.prod(cshape)), 3), np.float32)
                coarse[cflat] = vals
                up(f, ch, coarse.reshape(cshape + (3,)), stride, flat)
            n_ambient += len(cpts)
        ms = [None] * len(lights)
        if multiple and np.any(pm.sigma_s > 0):
            for li, light in enumerate(lights):
                if chans[li] is None:
                    continue
                if progress:
                    progress(0.0, f"Light pyramid: {light.name} on {pm.medium.name}")
                # the walk starts where the beam of unscattered and forward-scattered light
                # first scatters out of the forward peak (docs/method.md, "The forward peak")
                ms[li] = multiple_field(delta[mi], f, light, chans[li], camera, beam=beams[li],
                                        resolution=multiple_resolution,
                                        should_cancel=should_cancel, g_last=float(pm.g),
                                        threads=threads)
                if should_cancel and should_cancel():
                    return None
        ms_all.append(ms)
        fields.append(f)
    return Precomputed(fields, layout, ms_all, time.perf_counter() - t_start,
                       {"points": n_pts, "ambient_points": n_ambient,
                        "backend": kernels.backend()})
