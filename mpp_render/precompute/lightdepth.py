"""Optical depth from points to a light through all media (``light_optical_depth``: one
march per point) and over a whole grid at once (``sweep_light``: the light's rays followed slab
by slab, a few passes over the grid instead of one march per voxel).

The world's fog (a medium with source 'WORLD', worldfog.py) fills all space homogeneously, so
its optical depth to a light is sigma_t x distance, added analytically to what the other media
(integrated by the kernel) and the surfaces give; its grid is never marched here.  On the fog's
own grid the surfaces' shadows are prefiltered (``soft_visibility``): the optical depth holds
-ln of the visibility averaged over each voxel near a shadow's edge, so that the interpolated
field places the god rays' edges where they are instead of darkening a voxel of lit fog beside
every shadow (interpolating the 0 / SHADOW_TAU step of a binary shadow does that).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List

import numpy as np

from .. import kernels, kernels_np
from ..lights import towards_light
from ..media import PreparedMedium
from ..parallel import run_chunks, worker_count
from ..scene import Light, Tuning
from ..surfaces import occluded
from ..worldfog import optical_depth as fog_optical_depth
from .lattice import dilate, grid_points


def _exit_distance(media, points, dirs, limit):
    t0, t1 = kernels.union_interval(media, points, dirs, np.zeros(len(points)), limit)
    return np.where(t1 > 0.0, np.minimum(t1, limit), 0.0)


SHADOW_TAU = 50.0  # optical depth standing for "blocked by an opaque surface" (T ~ 2e-22)
# optical depth past which a ray's transmittance, e^-37 = 8.5e-17 < 2^-53, adds less than half
# an ulp to a sum of order 1 (a mean over directions of transmittances at most 1): where
# density_lengths is told the extinction, its rays end there
OPAQUE_DEPTH = 37.0


def extinction_media(media):
    """The media as the transmittance kernels read them: each one's
    ``PreparedMedium.extinction_parts`` (itself, or three of one channel each where its
    extinction's colour varies per voxel)."""
    return [p for m in media for p in m.extinction_parts()]


def kernel_arrays(media):
    """(grids, w2is, sigma_ts, thresholds) for the optical-depth kernels through ``media``
    (``extinction_media``; ``media_bricks`` of the same media matches them)."""
    parts = extinction_media(media)
    return ([m.grid for m in parts], [m.w2i for m in parts], [m.sigma_t for m in parts],
            [m.threshold for m in parts])


def media_bricks(media, tuning: Tuning = Tuning()):
    """The media's brick bounds (media.brick_bounds) for optical_depth to add empty and
    constant stretches in one go, or None for small grids (below ``tuning.skip_min_voxels``
    voxels: such a grid sits in the cache, a step is as cheap as a brick crossing and walking
    the bricks costs more than it saves; above it 1.7-2.9x faster on the public scenes'
    grids); the result is the same either way."""
    if not media or max(m.grid.size for m in media) < tuning.skip_min_voxels:
        return None
    return [m.bricks for m in extinction_media(media)]


def density_lengths(media: List[PreparedMedium], points, dirs, t_max, step,
                    tuning: Tuning = Tuning(), sig_t=None):
    """(N, M) metres of density along rays p + s dir, s in [0, t_max] cut where they leave
    the media's boxes, per medium: the integral of density_from(grid) (kernels.optical_depth
    with each medium's coefficient a unit vector, three media per call).  Any RGB optical
    depth through the media is then a product with their coefficients (M, 3), so one march
    gives both the extinction and the scattering optical depth.  ``sig_t``: None, or the
    media's extinction per unit density (M, 3, 1/m): a ray then ends where that optical
    depth reaches ``OPAQUE_DEPTH`` in every channel (each call's three media tested on their
    own depth, which is at most the whole), so its lengths are exact up to there and hold
    the ray's first OPAQUE_DEPTH or more."""
    od = kernels.optical_depth
    n, M = len(points), len(media)
    out = np.zeros((n, M))
    # the rays end where they leave the last medium, of all of them (not only of the group)
    t_max = _exit_distance(media, points, dirs, t_max) if M > 3 else t_max
    for g0 in range(0, M, 3):
        grp = media[g0:g0 + 3]
        units = [np.eye(3)[k] for k in range(len(grp))]
        stop = None
        if sig_t is not None:
            stop = np.zeros((3, 3))
            stop[:len(grp)] = np.asarray(sig_t, np.float64).reshape(M, 3)[g0:g0 + len(grp)]
        v = od(points, dirs, t_max, [m.grid for m in grp], [m.w2i for m in grp], units,
               [m.threshold for m in grp], float(step), 0.5, bricks=media_bricks(grp, tuning),
               clip=M <= 3, stop=stop, stop_depth=OPAQUE_DEPTH)
        out[:, g0:g0 + len(grp)] = v[:, :len(grp)]
    return out


def depth_rows(media: List[PreparedMedium]):
    """(tracks, sig_t (K,3), sig_s (K,3)): ``density_lengths`` through ``tracks`` times
    ``sig_t`` is the extinction's optical depth through ``media``, times ``sig_s`` the
    scattering's (each medium's mean sigma_s on its density).  A medium whose extinction's
    colour varies per voxel gives four tracks: its density (scattering only) and its
    ``extinction_parts`` (extinction only)."""
    tracks, st, ss = [], [], []
    for m in media:
        if m.extinction_density is not None:   # its scattering track (the parts scatter none)
            tracks.append(m)
            st.append(np.zeros(3))
            ss.append(m.sigma_s)
        for p in m.extinction_parts():
            tracks.append(p)
            st.append(p.sigma_t)
            ss.append(p.sigma_s)
    if not tracks:
        return [], np.zeros((0, 3)), np.zeros((0, 3))
    return tracks, np.stack(st), np.stack(ss)


def split_fog(media: List[PreparedMedium]):
    """(the media other than the world's fog, the fog's PreparedMedium or None)."""
    fog = next((pm for pm in media if pm.endless), None)
    return [pm for pm in media if pm is not fog], fog


def light_optical_depth(media: List[PreparedMedium], light: Light, points, step,
                        chunk=1 << 14, should_cancel=None, surfaces=None, threads=0,
                        fog_sigma_t=None, tuning: Tuning = Tuning()):
    """RGB optical depth (N,3) from world ``points`` to ``light`` (its centre) through media;
    ``SHADOW_TAU`` is added where an opaque surface (``surfaces``, a SurfaceSet) blocks the
    way, so surfaces cast volumetric shadows, and with ``fog_sigma_t`` (RGB 1/m) the world
    fog's sigma_t x distance (worldfog.optical_depth).  ``media`` must not hold the fog.
    Raises cancel.Cancelled on Esc."""
    od = kernels.optical_depth
    arrays = kernel_arrays(media) if media else None
    bricks = media_bricks(media, tuning)
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

    run_chunks(len(points), chunk, work, threads, should_cancel)
    return out


SELF_VOXELS = 1.5  # surfaces this close to a fog voxel (in voxels) do not shadow it
SOFT_OFFSETS = (np.stack(np.meshgrid(*[[-0.25, 0.25]] * 3, indexing="ij"), -1).reshape(-1, 3))


def eye_depth(pm: PreparedMedium, eye, points, threads: int = 0,
              should_cancel=None) -> np.ndarray:
    """(N,) the optical depth (largest channel) from world ``points`` (N,3, m) to the point
    ``eye`` (3,, m: the camera's) through the medium ``pm`` alone, marched at half its voxel
    (``light_optical_depth`` of a point light there)."""
    light = Light("POINT", "camera", np.ones(3), position=np.asarray(eye, np.float64))
    return light_optical_depth([pm], light, np.asarray(points, np.float64).reshape(-1, 3),
                               0.5 * float(pm.voxel_size), threads=threads,
                               should_cancel=should_cancel).max(axis=1)


def soft_visibility(surfaces, light: Light, pm: PreparedMedium, flat, points, chunk=1 << 14,
                    threads=0, should_cancel=None):
    """Visibility of ``light`` (0..1, (N,)) from the needed points ``points`` (at flat indices
    ``flat`` of ``pm``'s grid) past the opaque ``surfaces``: 1 or 0 at the voxel point, and
    near a shadow's edge (a 6-neighbour sees otherwise) the mean over the 2 x 2 x 2 points a
    quarter voxel off, a box filter one voxel wide.  Surfaces within ``SELF_VOXELS`` voxels
    of a point do not shadow it: the voxels just behind a lit floor or wall (which camera
    rays never reach) then do not darken the lit fog in front of it through the
    interpolation; a shadow starts that far behind its caster instead.  Raises
    cancel.Cancelled on Esc."""
    vis = np.ones(len(points))
    if surfaces is None or surfaces.empty or not len(points):
        return vis
    skip = SELF_VOXELS * pm.voxel_size

    def binary(p):
        d, limit = towards_light(light, p)
        return ~occluded(surfaces, p + d * skip, d, np.maximum(limit - skip, 0.0))

    def work(a, b):
        vis[a:b] = binary(points[a:b])

    run_chunks(len(points), chunk, work, threads, should_cancel)
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

            run_chunks(todo.size, chunk, work_o, threads, should_cancel)
            acc += part
        vis[todo] = acc / len(off)
    return vis


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


def _column_span(lo, hi):
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
            first, n = _column_span(min(ends), max(ends))
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
                first, n = _column_span(max(min(proj), L[e] - d_far), min(max(proj), L[e] + d_far))
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


def near_sharp_surfaces(pm: PreparedMedium, media: List[PreparedMedium]):
    """Flat indices of ``pm``'s voxels next to a sharp (mesh) surface: its own inside voxels
    with an outside voxel among their 26 neighbours, and its voxels within one voxel of the
    surface of any other sharp medium in ``media``."""
    out = np.zeros(pm.grid.shape, bool)
    if pm.sharp:
        inside = pm.grid >= pm.threshold
        out |= inside & dilate(~inside)
    others = [m for m in media if m is not pm and m.sharp]
    if others:
        ijk = np.stack(np.meshgrid(*[np.arange(n, dtype=np.float64) for n in pm.grid.shape],
                                   indexing="ij"), -1).reshape(-1, 3)
        world = pm.to_world(ijk)
        for m in others:
            idx = m.to_index(world)
            near = np.flatnonzero(np.all((idx > -1.0) & (idx < np.array(m.grid.shape)), axis=1))
            inside = np.zeros(len(world), bool)   # beyond m's grid m has no density
            inside[near] = kernels.trilinear(m.grid, idx[near]) >= m.threshold
            inside = inside.reshape(pm.grid.shape)
            out |= dilate(inside) & dilate(~inside)
    return np.flatnonzero(out)


SWEEP_CELLS = 16  # column cells per sweep chunk (at least): chunks run in parallel, Esc between
# A lit voxel (swept depth below THICK_LIT) of a density grid whose 3 x 3 x 3 neighbourhood
# holds an optically thick voxel (Tuning.cell_tau) marches its depth exactly
THICK_LIT = 8.0
# their march's step at most, in voxels: one read per step at its midpoint misses the kinks of
# the trilinear density where a dense voxel meets an empty one (at a voxel a step the lit
# voxels of a dragon at 2.5 a voxel came out up to 0.07 deep)
THICK_STEP = 0.125


def near_thick_cells(pm: PreparedMedium, depth: np.ndarray, cell_tau: float) -> np.ndarray:
    """Flat indices of the voxels of ``pm``'s density grid (not a mesh volume's sharp surface,
    not the world's fog) that are lit (``depth``, (X,Y,Z) their swept optical depth, below
    THICK_LIT) and lie next to an optically thick voxel: one of their 27 neighbours'
    extinction (its density times the largest coefficient, or its extinction density's
    channels times theirs) times the voxel size at least ``cell_tau`` (> 0).
    There the sweep's columns, interpolated bilinearly slab after slab, smooth the shadows
    that sharp dense features cast a voxel apart (a third-party dragon of 1.2-2.5 optical
    depth a voxel: its lit voxels' depth 0.03-0.05 too deep on average, their light 3-4 %
    dark)."""
    if pm.sharp or pm.endless or not cell_tau > 0.0:
        return np.zeros(0, np.int64)
    if pm.extinction_density is not None:   # each channel's own density
        ext = (pm.extinction_density * np.asarray(pm.sigma_t, np.float32)).max(axis=-1)
    else:
        ext = pm.grid * float(np.max(pm.sigma_t))
    thick = ext * float(pm.voxel_size) >= cell_tau
    if not thick.any():
        return np.zeros(0, np.int64)
    return np.flatnonzero(dilate(thick) & (depth < THICK_LIT))


def sweep_light(media: List[PreparedMedium], pm: PreparedMedium, light: Light, field: np.ndarray,
                channel: int, step: float, surfaces=None, threads=0, should_cancel=None,
                needed=None, fog_sigma_t=None, sharp=None, tuning: Tuning = Tuning()):
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
    when the light cannot be swept (the caller then marches every voxel); raises
    cancel.Cancelled on Esc."""
    plan = sweep_pyramids(pm, light)
    if plan is None:
        return False
    pyramids, L = plan
    sweep = kernels.light_sweep
    grids, w2is, sigmas, thrs = kernel_arrays(media)
    a2w = pm.i2w[:3, :]
    n_threads = worker_count(threads)
    jobs = []
    for pyr in pyramids:
        pq = np.stack(np.meshgrid(np.arange(pyr.n_p), np.arange(pyr.n_q), indexing="ij"), -1)
        idx = kernels_np.column_index(pyr.axis, pyr.coef, float(pyr.i_first), pq[..., 0], pq[..., 1])
        start = pm.to_world(idx.reshape(-1, 3))
        init = light_optical_depth(media, light, start, step, should_cancel=should_cancel,
                                   threads=threads, tuning=tuning)
        n_sub = _sub_steps(pm, pyr, step)
        cells = pyr.n_p - 1
        per = max(SWEEP_CELLS, -(-cells // (4 * n_threads)))
        for a in range(0, cells, per):
            jobs.append((pyr, init.reshape(pyr.n_p, pyr.n_q, 3), a, min(cells, a + per), n_sub))

    def work(a, b):
        for pyr, init, p_lo, p_hi, n_sub in jobs[a:b]:
            sweep(field, channel, kernels.SweepJob(a2w, pyr.axis, pyr.sign, pyr.i_first,
                                                   pyr.i_last, pyr.coef, L, pyr.cone, init,
                                                   p_lo, p_hi, n_sub, grids, w2is, sigmas,
                                                   thrs))

    run_chunks(len(jobs), 1, work, threads, should_cancel)
    if pm.sharp or any(m.sharp for m in media):
        # The optical depth bends sharply at a mesh volume's surface, which the columns'
        # interpolation would smear over a voxel; the voxels there (for the medium's own
        # surface its inside layer, what the march reads once its refinement, march.py, has
        # stepped off the surface) march exactly.
        flat = near_sharp_surfaces(pm, media) if sharp is None else sharp
        tau = light_optical_depth(media, light, grid_points(pm, flat), step,
                                  should_cancel=should_cancel, threads=threads, tuning=tuning)
        field.reshape(-1, field.shape[-1])[flat, channel:channel + 3] = tau
    flat = near_thick_cells(pm, field[..., channel:channel + 3].min(axis=-1), tuning.cell_tau)
    if flat.size:
        tau = light_optical_depth(media, light, grid_points(pm, flat),
                                  min(step, THICK_STEP * float(pm.voxel_size)),
                                  should_cancel=should_cancel, threads=threads, tuning=tuning)
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

        run_chunks(len(flat), 1 << 14, per_voxel, threads, should_cancel)
    return True
