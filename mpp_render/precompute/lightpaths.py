"""Multiple scattering by traced light paths (paths.py) on the light pyramid's lattice: the
paths start where each light's unscattered beam first scatters (source.py) and their
deposits, seen from the camera, become the one level the march reads (march.MarchContext).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .. import kernels
from ..camera import towards_camera
from ..lights import distance_spread, has_extent, pack_light
from ..media import box_distance, density_from, trilinear
from ..parallel import worker_count
from ..paths import (MAX_COLLISIONS, MOMENT_CHANNELS, PATH_MEDIA, PATHS_MAX_SPAN,
                     SIGNED_CHANNELS, PathInputs, PathMedium, from_power, rate_span)
from ..scene import MULTIPLE_PATHS, Tuning
from .camerareach import roulette_odds
from .lattice import (MULTIPLE_RESOLUTION, dilate, lattice_points, lattice_values,
                      paths_lattice)
from .lightdepth import eye_depth
from .lobefit import camera_weight, fitted
from .nodal import nodal_values, tent_mass
from .pathstarts import (Surroundings, fog_starts, reach,
                         surface_albedo, surface_starts)
from .source import CELL_POINTS, light_direction, near_light_cells, source_and_density


# paths per lattice point the medium fills, at most, at the default Paths (the Paths setting
# caps the total; path_budget): a 65-point lattice of a mesh cube holds 270 000 such points,
# past the default 3 000 000 paths
PATHS_PER_POINT = 32
FAR_PATHS = 0.25     # the far box's paths, a fraction of the grid's
FAR_EYE = 1e4        # m: an orthographic camera's eye, this far back along its axis
# the share of the paths whose moments the camera's lobe (lobefit.py) is drawn from where no
# surface's gathers need them all: the moments' one random lattice point per deposit took
# p_sphere_g95's trace from 9.5 to 16.2 s with every path's
LOBE_MOMENTS = 0.25


def path_budget(n_paths: int, cells: int, setting: Optional[int] = None) -> int:
    """The paths traced for ``n_paths`` asked on media whose lattices hold ``cells`` points
    the media fill: at most ``PATHS_PER_POINT`` a point, and where the Paths ``setting``
    (``n_paths`` when None) is above the default (scene.MULTIPLE_PATHS), that many times
    more: a small grid (a VDB of under 128 voxels holds 20 000-60 000 such points) reaches
    the cap at the default, and without the factor more Paths would add nothing to it."""
    setting = int(n_paths) if setting is None else int(setting)
    scale = max(1.0, setting / float(MULTIPLE_PATHS))
    return min(int(n_paths), int(PATHS_PER_POINT * int(cells) * scale))


def traced_multiple(pm, fld: np.ndarray, light, channel: int, camera, n_paths: int,
                    resolution: int, seed: int = 0, threads: int = 0, should_cancel=None,
                    around: Optional[Surroundings] = None, moments: bool = True,
                    partners=(), deposits: float = Tuning.path_deposits,
                    nodal: bool = Tuning.path_nodal,
                    far_resolution: int = MULTIPLE_RESOLUTION,
                    cell_tau: float = Tuning.cell_tau, cell_walk: int = Tuning.cell_walk,
                    lobe_window: int = Tuning.lobe_window,
                    disc_channel: Optional[int] = None,
                    roulette_floor: float = Tuning.camera_roulette):
    """(stride, h, M, far, moments, cross, started) for ``light`` on medium ``pm`` (its field
    ``fld``, the light's optical depth at ``channel``): M float32 (LX,LY,LZ,3) W/(m^2 sr) on
    the light pyramid's lattice (lattice.walk_lattice at ``resolution``), from ``n_paths``
    paths (paths.py; at most ``PATHS_PER_POINT`` per lattice point the medium fills) seen
    from ``camera``; ``threads``
    share them; raises cancel.Cancelled when ``should_cancel`` says so.  The paths start
    where the light's unscattered beam first scatters in the medium (source.source_and_density:
    a lattice point by its power, then a point of its tent by the voxels' own source,
    paths.start_positions), and with ``around`` (pathstarts.Surroundings) also where it first scatters in the world
    fog beyond the fog's grid and where the lit surfaces reflect it (pathstarts.py); they
    reflect off the surfaces, and in the world fog they fly on beyond its grid.  Each kind
    of start gets paths in proportion to its power.  ``pm`` is the medium itself, not
    delta-scaled: the paths carry the forward peak (the split was measured worse,
    docs/history.md).  ``far``: for the world fog, its M beyond the grid (``_far_multiple``),
    else None.  Returned ``moments``: where ``moments`` is asked for and surfaces are round the
    medium (``around``), whose gathers look through it along other directions than the
    camera's, float32 (LX,LY,LZ,12) M's moments of order 0 and 1 (paths.py, "Moments"), else
    None.  ``partners``: (PreparedMedium, PathLattice) of the other media whose boxes
    overlap ``pm``'s (``overlapping``, ``partner_lattice``): the paths fly through them too,
    scatter in them by their own albedo and phase function and deposit on their lattices; a
    sixth item, per partner, is what they deposited there as M (float32 (LX,LY,LZ,3), with the
    moments where these are made (LX,LY,LZ,15)), to be added to that medium's M for this
    light; a seventh, (W, n): the power of the paths' starts (channels summed) and their
    number.  None where the medium is too dense for paths (paths.PATHS_MAX_SPAN): the caller
    keeps the walk.  ``deposits``, ``nodal``: Tuning.path_deposits, Tuning.path_nodal
    (PathLattice.of).  ``far_resolution``: the far box's voxels along its longest side (the
    *Multiple Scattering Resolution* as set, not raised round a lamp).  ``cell_tau``,
    ``cell_walk``: Tuning's (source.thick_band_source).  (The constant sky's light off the
    surfaces is the sky's, precompute/skydeficit.py.)  ``lobe_window``: with a ``camera``
    and a medium of g != 0, M towards the camera is the paths' lobe fitted to their deposits
    over windows of this many lattice points round each (lobefit.py, Tuning.lobe_window; 0:
    the deposits alone).  ``disc_channel``: the light's
    disc channels in ``fld`` (precompute/discdepth.py), or None.  ``roulette_floor``:
    Tuning.camera_roulette, the floor of the camera's roulette odds (camerareach.py), played
    where the paths' light is for the camera alone (no surface gathers their moments)."""
    stride, shape, h, sets = path_sets(pm, fld, light, channel, resolution, around, cell_tau,
                                       cell_walk, seed, disc_channel, threads)
    fog = pm.endless
    if not sets:
        return stride, h, np.zeros(tuple(shape) + (3,), np.float32), None, None, [], (0.0, 0)
    lat = PathLattice.of(pm, camera, resolution,
                         None if around is None else around.enclosed(pm), deposits=deposits,
                         nodal=nodal)
    if lat is None:
        return None
    n_paths = lat.paths(n_paths)
    started = (sum(float(np.asarray(item[1]).sum()) for item in sets), int(n_paths))
    gathered = moments and around is not None and around.surfaces is not None
    rec = start_light(light)
    fit = fits_lobe(pm, camera, lobe_window)
    odds = None
    if camera is not None and not gathered:
        odds = roulette_odds(pm, lambda: lattice_depth(pm, lat, camera, threads, should_cancel,
                                                       around), roulette_floor)
    accs = _trace_all(sets, n_paths, seed, threads, should_cancel, pm, lat, around,
                      moments=gathered or fit, partners=partners, light=rec, halves=fit,
                      moment_share=1.0 if gathered else LOBE_MOMENTS, odds=odds)
    if fit:
        accs, split = accs
    m = lat.mean(accs[0])
    if fit:
        light3 = lobe_light(pm, lat, camera, m, split, lobe_window, threads, should_cancel,
                            around=around)
        m = np.concatenate([light3, m[..., 3:]], axis=-1) if gathered else light3
    cross = [plat.mean(a) for (_, plat), a in zip(partners, accs[1:])]
    far = None
    if fog and camera is not None:
        far = _far_multiple(pm, sets, camera, n_paths, seed, threads, should_cancel, around,
                            light=rec, nodal=nodal, resolution=far_resolution)
    if not gathered:
        return stride, h, m, far, None, cross, started
    return (stride, h, np.ascontiguousarray(m[..., :3]), far,
            np.ascontiguousarray(m[..., 3:]), cross, started)


def path_sets(pm, fld, light, channel: int, resolution: int, around, cell_tau: float,
              cell_walk: int, seed: int, disc_channel: Optional[int] = None,
              threads: int = 1):
    """(stride, shape, h, sets): the paths' lattice at ``resolution`` and the starts of
    ``light``'s paths in ``pm`` (``traced_multiple``'s): its first scatterings, and with
    ``around`` where it first scatters in the world fog beyond the grid and where the
    surfaces reflect it; each set (points, power (N,3) W, directions, jitter, lobe[, start
    source and peaks]).  ``disc_channel``: the light's disc
    channels in ``fld`` (discdepth.py) or None; ``threads``: the source's
    (source.restricted_source)."""
    stride, shape, h = paths_lattice(pm, resolution)
    voxels = np.zeros(pm.grid.shape[:3], np.float32)
    base, _, pts = source_and_density(pm, fld, light, channel, stride, voxels=voxels,
                                      disc=None if around is None else around.disc,
                                      depth=None if around is None else around.optical_depth,
                                      cell_tau=cell_tau, cell_walk=cell_walk,
                                      disc_channel=disc_channel, threads=threads)
    power = base * cell_volume(pm, stride)
    live = power.sum(axis=1) > 0.0
    fog = pm.endless
    sets = []   # (points, power W, directions, jitter, lobe, start source and peaks or None)
    if np.any(live):
        peak = tent_peak(voxels, stride, shape).reshape(-1)
        if light.kind in ("POINT", "SPOT"):
            # round a lamp the voxels' source is a point sample of ~1/r^2 (their lattice power
            # is the cells' mean, source.cell_mean_source): there the starts only keep to the
            # medium (a peak of 0 accepts any draw with source)
            peak[near_light_cells(pm, light, stride, shape)] = 0.0
        rate = start_rates(pm, fld, light, channel, stride, shape, pts)
        sets.append((pts[live], power[live], light_direction(light, pts[live]), 1.0, 0,
                     (voxels, peak[live]), None, None if rate is None else rate[live]))
    if around is not None:
        if fog:
            got = fog_starts(pm, light, around, seed + 1)
            if got is not None:
                sets.append(got + (0.0, 0))
        if around.surfaces is not None:
            got = surface_starts(pm, light, around, seed + 2)
            if got is not None:
                sets.append(got[:3] + (got[3], 1))
    return stride, shape, h, sets


def start_power(pm, fld, light, channel: int, resolution: int,
                around: Optional[Surroundings] = None, cell_tau: float = Tuning.cell_tau,
                cell_walk: int = Tuning.cell_walk, seed: int = 0,
                disc_channel: Optional[int] = None) -> float:
    """W: the power of ``light``'s paths' starts in ``pm`` (``path_sets``, every set, the
    channels summed), what ``traced_multiple`` reports as its ``started`` power for the same
    arguments (``across_media``)."""
    return float(sum(float(np.asarray(item[1]).sum()) for item in
                     path_sets(pm, fld, light, channel, resolution, around, cell_tau,
                               cell_walk, seed, disc_channel)[3]))


def across_media(powers) -> list:
    """Per medium of a group that overlap, the share of the Paths setting its paths for one
    light take: the power of the light's paths' starts in it (``start_power``) over the most
    in the group (``powers``, W, one a medium), so that the light's paths weigh the same in
    each, the brightest taking the whole setting (1 where none scatters the light).  The
    paths of each fly through the others (partners) and deposit there too, so a medium the
    light reaches little (p_overlap's cube inside its sphere: 1.5 W against 39.9 W) is lit
    mostly by the others' paths."""
    top = max([float(p) for p in powers] + [0.0])
    return [float(p) / top if top > 0.0 else 1.0 for p in powers]


def start_rates(pm, fld, light, channel: int, stride: int, shape, pts) -> Optional[np.ndarray]:
    """(N,) per point of the paths' lattice (``shape``, ``stride`` voxels apart, world
    positions ``pts``) the mean extinction (1/m) along ``light``'s path to its centre: the
    field's optical depth there (channel ``channel`` on, the mean of its three) over the
    distance, at least half a voxel (lights.path_stretch's); None for a light that shines
    from its centre alone (lights.has_extent).  Its first scatterings draw their emitter
    point by the transmittance this stretches to each (paths.PathInputs.start_rate): below
    a wide emitter in a dense cloud the light arrives mostly from straight above, where the
    solid angle alone sends half of it in from the side.  0 (the solid angle alone) where
    the emitter's points' distances spread so little (lights.distance_spread) that their
    transmittances differ by under RATE_SPREAD: a small lamp seen from afar."""
    if not has_extent(light):
        return None
    idx, _ = lattice_points(pm, shape, stride)
    tau = sum(lattice_values(fld[..., channel + c], idx, stride) for c in range(3)) / 3.0
    dc = np.linalg.norm(pts - np.asarray(light.position, np.float64), axis=1)
    rate = tau / np.maximum(dc, 0.5 * float(pm.voxel_size))
    rate = np.where(np.isfinite(rate) & (rate > 0.0), rate, 0.0)
    return np.where(rate * distance_spread(light, pts) >= RATE_SPREAD, rate, 0.0)


RATE_SPREAD = 0.01   # start_rates: optical depths that differ by less draw by the solid angle


def start_light(light):
    """The packed record (lights.pack_light) the paths' first scatterings draw their incoming
    direction from at their starts (paths.PathInputs.light): every light but the sun, whose
    direction is the same everywhere.  A lamp's disc and an area light's emitter seen from
    near by send light from many directions; the lattice point's one direction (from the
    centre, or an area light's axis) turned the forward-scattered light of the first
    scattering all one way (an area light inside a box of albedo 0.7 and g 0.5: the multiple
    scattering 0.7x Cycles' above the light, 1.25x below)."""
    return None if light.kind == "SUN" else pack_light(light)


def overlapping(media) -> list:
    """Per medium of ``media`` (PreparedMedium), the indices of the others whose boxes in the
    world overlap its own (at most paths.PATH_MEDIA - 1, the first ones): the media its light
    paths fly through besides itself.  The world's fog (endless) has none and is none."""
    boxes = []
    for pm in media:
        n = np.asarray(pm.grid.shape[:3], np.float64)
        corners = np.array([[a, b, c] for a in (-0.5, n[0] - 0.5) for b in (-0.5, n[1] - 0.5)
                            for c in (-0.5, n[2] - 0.5)])
        w = pm.to_world(corners)
        boxes.append((w.min(axis=0), w.max(axis=0)))
    out = []
    for i, pm in enumerate(media):
        got = []
        for j, other in enumerate(media):
            if j == i or pm.endless or other.endless:
                continue
            (lo1, hi1), (lo2, hi2) = boxes[i], boxes[j]
            if np.all(lo1 < hi2) and np.all(lo2 < hi1):
                got.append(j)
        out.append(got[:PATH_MEDIA - 1])
    return out


def lit_by_glow(media, i: int) -> list:
    """The indices of the media that medium ``i``'s emission lights besides itself (its glow's
    paths fly through them, precompute.emissionlight): every other medium that scatters,
    overlapping it or apart from it across empty space, the world's fog among them (as the
    box of its grid), the nearest boxes first and at most paths.PATH_MEDIA - 1."""
    centre = media[i].to_world(0.5 * (np.asarray(media[i].grid.shape[:3], np.float64) - 1.0)[None])[0]
    near = [(box_distance(pm, centre), j) for j, pm in enumerate(media)
            if j != i and pm.scatters]
    return [j for _, j in sorted(near)[:PATH_MEDIA - 1]]


def tentative_rate(majorant: float, h: float, deposits: float) -> float:
    """The paths' tentative collisions per metre (paths.PathInputs.rate): the medium's
    ``majorant`` (1/m), or ``deposits`` per lattice spacing ``h`` (m) where that is more
    (Tuning.path_deposits; paths.py).  Raises ValueError for ``deposits`` not above 0."""
    if not deposits > 0.0:
        raise ValueError(f"path deposits per lattice step must be above 0, not {deposits}")
    return max(float(majorant), float(deposits) / float(h))


def _path_rate(pm, resolution: int, deposits: float):
    """(stride, shape, h, density, rate, dense) of medium ``pm``'s paths at ``resolution``:
    its lattice (paths_lattice), the density they fly through, their tentative collisions
    per metre (tentative_rate) and whether that many across the grid pass
    paths.PATHS_MAX_SPAN (too dense for paths)."""
    stride, shape, h = paths_lattice(pm, resolution)
    density = pm.path_density()
    rate = tentative_rate(float(density.max()) * float(np.max(pm.sigma_t)), h, deposits)
    dense = not rate_span(rate, np.asarray(pm.i2w[:3, :3], np.float64),
                          density.shape) <= PATHS_MAX_SPAN
    return stride, shape, h, density, rate, dense


def too_dense(pm, resolution: int, deposits: float = Tuning.path_deposits) -> bool:
    """Whether medium ``pm`` is too dense for paths at ``resolution`` (paths.PATHS_MAX_SPAN:
    its tentative collisions across the grid; PathLattice.of is None then)."""
    return _path_rate(pm, resolution, deposits)[-1]


def partner_lattice(pm, camera, resolution: int, around: Optional[Surroundings] = None,
                    deposits: float = Tuning.path_deposits, nodal: bool = Tuning.path_nodal):
    """The PathLattice other media's paths deposit on in ``pm`` (traced_multiple's
    ``partners``); None where it is too dense for paths."""
    return PathLattice.of(pm, camera, resolution,
                          None if around is None else around.enclosed(pm), deposits=deposits,
                          nodal=nodal)


def tent_peak(voxels: np.ndarray, stride: int, shape) -> np.ndarray:
    """(LX,LY,LZ): the largest of ``voxels`` (X,Y,Z) within each lattice point's tent, the
    voxels -stride..stride from it along each axis (0 beyond the grid): the peak that a
    first scattering's start is rejection-sampled against (paths.start_positions)."""
    m = voxels.astype(np.float32)
    for axis in range(m.ndim):
        n = m.shape[axis]
        pad = [(0, 0)] * m.ndim
        pad[axis] = (stride, stride)
        p = np.pad(m, pad)
        out = p.take(range(0, n), axis=axis)
        for t in range(1, 2 * stride + 1):
            np.maximum(out, p.take(range(t, t + n), axis=axis), out=out)
        m = out
    idx = [np.minimum(np.arange(s) * stride, voxels.shape[a] - 1) for a, s in enumerate(shape)]
    # a point past the grid's last voxel (lattice_shape may reach beyond it) takes the last
    # voxel's window, which holds its whole tent within the grid (a peak too high only
    # makes the sampling slower, never wrong)
    return m[np.ix_(*idx)].astype(np.float64)


def sharp_fraction(grid: np.ndarray, threshold: float) -> np.ndarray:
    """float64 (X,Y,Z): the part of each voxel's cell inside the sharp surface where the
    trilinear value of ``grid`` is >= ``threshold`` (media.density_from of media.trilinear,
    as the march and paths.density_at read it), from the cell's source.CELL_POINTS, computed
    only where a voxel or one of its 26 neighbours lies on the other side (elsewhere 1
    inside, 0 outside): the density the paths fly through, over each cell."""
    inside = np.asarray(grid) >= threshold
    frac = inside.astype(np.float64)
    mixed = dilate(inside) & dilate(~inside)
    idx = np.argwhere(mixed).astype(np.float64)
    if not len(idx):
        return frac
    acc = np.zeros(len(idx))
    for off in CELL_POINTS:
        acc += density_from(trilinear(grid, idx + off), threshold)
    frac[mixed] = acc / len(CELL_POINTS)
    return frac


def cell_volume(pm, stride: int) -> float:
    """m^3 of a cell of the lattice ``stride`` voxels apart on medium ``pm``."""
    return float(abs(np.linalg.det(np.asarray(pm.i2w[:3, :3], np.float64)))) * stride ** 3


@dataclass
class PathLattice:
    """Where a medium's paths deposit: the light pyramid's lattice (``stride`` voxels apart,
    ``shape``, spacing ``h`` m) on the medium's path density ``density`` (maps ``w2i`` /
    ``i2w``), the unit directions ``towards`` the camera from its points, the tentative
    collision ``rate`` (1/m), the density under each point's tent times the cell volume
    ``tent_mass`` (m^3, (LX,LY,LZ,1)) that turns deposits into M, and ``cells``, the
    lattice points the medium fills.  ``threshold``: >= 0 for a mesh volume, whose paths fly
    through its sharp surface as the march reads it (``density`` is then the grid's values,
    density 1 where their trilinear interpolation is >= it; paths.density_at), else -1
    (``density`` the voxels' own, read at the nearest voxel)."""

    stride: int
    shape: tuple
    h: float
    density: np.ndarray
    w2i: np.ndarray
    i2w: np.ndarray
    towards: np.ndarray
    rate: float
    tent_mass: np.ndarray
    cells: int
    threshold: float = -1.0
    offsets: Optional[np.ndarray] = None

    @classmethod
    def of(cls, pm, camera, resolution: int, enclosed: Optional[np.ndarray] = None,
           deposits: float = Tuning.path_deposits, nodal: bool = Tuning.path_nodal):
        """The lattice of medium ``pm`` at ``resolution`` seen from ``camera``; None where the
        medium is too dense for paths (paths.PATHS_MAX_SPAN).  ``enclosed``: None, or bool
        (X,Y,Z) the voxels behind the scene's surfaces (Surroundings.enclosed), left out of
        the tent mass: no light reaches them, and a lattice point by a ground is the mean of
        the medium above it.  ``deposits``: tentative collisions per lattice spacing h at
        least (Tuning.path_deposits): the rate is max(majorant, deposits / h).  ``nodal``:
        ``mean`` moves each point's value from its tent's centroid to the point
        (Tuning.path_nodal, nodal.py)."""
        stride, shape, h, density, rate, dense = _path_rate(pm, resolution, deposits)
        if dense:
            return None
        i2w = np.asarray(pm.i2w[:3, :3], np.float64)
        _, lpts = lattice_points(pm, shape, stride)
        towards = np.ascontiguousarray(towards_camera(camera, lpts).reshape(tuple(shape) + (3,)))
        # the paths read the nearest voxel's density (paths.py): each voxel's density holds
        # over its whole cell, so the tent is integrated over the cell (a voxel just beyond
        # a point's tent still holds a sliver of it; weighing voxel centres alone gave such
        # a point no mass and its deposits from that sliver a spike in M).  A mesh volume's
        # paths fly through its sharp surface: each cell holds the part of it inside.
        sharp = pm.sharp and not pm.endless
        threshold = float(pm.threshold) if sharp else -1.0
        mean_rho = sharp_fraction(pm.grid, threshold) if sharp else density.astype(np.float64)
        if enclosed is not None and enclosed.shape == mean_rho.shape:
            mean_rho[enclosed] = 0.0
        mass, offsets = tent_mass(mean_rho, stride, shape, nodal)
        grid = np.ascontiguousarray(pm.grid, np.float32) if sharp else density
        return cls(stride, tuple(shape), h, grid, np.asarray(pm.w2i, np.float64), i2w,
                   towards, rate, mass[..., None] * cell_volume(pm, stride),
                   int(np.count_nonzero(mass > 0.0)), threshold, offsets)

    def paths(self, n_paths: int, setting: Optional[int] = None) -> int:
        """``n_paths``, at most ``PATHS_PER_POINT`` per lattice point the medium fills
        (times the Paths ``setting`` over the default, where above it: path_budget)."""
        return path_budget(n_paths, self.cells, setting)

    def mean(self, acc: np.ndarray, signed: bool = False) -> np.ndarray:
        """M (float32, W/(m^2 sr)) from the deposits ``acc``: divided by the density under each
        point's tent (the cell's mean), so that M is the medium's own average there and a point
        beside the medium's surface is not diluted by the empty side; with ``offsets`` (the
        tents' centroids, nodal.py) moved from each centroid to its point.  ``acc``'s last
        axis: 3 channels of light, or those and the 12 moments (paths.py), whose last 9, the
        first order, are signed.  ``signed``: the light channels too are left as moved, not
        stopped at 0 (unbiased where the light is taken off another estimate: skydeficit.py)."""
        m = np.divide(acc, self.tent_mass, out=np.zeros_like(acc), where=self.tent_mass > 0.0)
        if self.offsets is not None:
            return nodal_values(m, self.offsets, self.tent_mass[..., 0],
                                signed=m.shape[-1] if signed else
                                SIGNED_CHANNELS if m.shape[-1] == MOMENT_CHANNELS else 0)
        return np.ascontiguousarray(m, np.float32)


def _trace(sets, n_paths, seed, threads, should_cancel, pm, lat, around,
           max_collisions: int = MAX_COLLISIONS, moments: bool = False,
           light=None) -> np.ndarray:
    """The deposits (LX,LY,LZ,3) of ``n_paths`` paths shared among the start ``sets`` in
    proportion to their power, on the PathLattice ``lat``; each path ends after
    ``max_collisions`` real collisions and bounces (1: its first flight alone); with
    ``moments`` (LX,LY,LZ,15), their moments too (paths.py, "Moments"); raises
    cancel.Cancelled on Esc."""
    return _trace_all(sets, n_paths, seed, threads, should_cancel, pm, lat, around,
                      max_collisions, moments, light=light)[0]


def _trace_all(sets, n_paths, seed, threads, should_cancel, pm, lat, around,
               max_collisions: int = MAX_COLLISIONS, moments: bool = False,
               partners=(), light=None, min_collisions: int = 0, halves: bool = False,
               moment_share: float = 1.0, odds: Optional[np.ndarray] = None):
    """``_trace``'s deposits on ``lat``, then on each of the ``partners``' lattices
    ((PreparedMedium, PathLattice), traced_multiple), which the paths fly through too.  Each
    set of ``sets``: (points, power W, directions, jitter, lobe[, (start source, peaks) or
    None[, bias[, rates]]]), bias (N,) the relative odds of drawing each start
    (paths.from_power) or None, rates (N,) or None a lobe-0 set's ``start_rates``.
    ``light``: None, or the packed light record the first scatterings (the tracer reads it
    for lobe 0 sets only) draw their incoming direction from (``start_light``).
    ``min_collisions``: the real collisions and bounces a path makes before its deposits
    count (1: the light that has scattered at least once; paths.PathInputs).  ``halves``:
    returns (that list, (first, second)), each (LX,LY,LZ,3) the own lattice's light deposits
    as estimated by one half of every set's paths alone (kernels.trace_paths_media's halves,
    scaled to the whole: the two are independent estimates of the list's first).
    ``moment_share``: the share of the paths whose moments are kept (paths.PathInputs).
    ``odds``: None, or float32 (LX,LY,LZ) the camera's roulette odds on ``lat``
    (camerareach.roulette_odds, paths.PathInputs.odds)."""
    density, w2i, i2w = lat.density, lat.w2i, lat.i2w
    surf = around.surfaces if around is not None else None
    centre, radius = reach(pm, (w2i, density.shape))
    extra = dict(outside=pm.outside_density, reach_centre=centre, reach_radius=radius)
    if surf is not None:
        albedo = surface_albedo(surf) if around.bounce else np.zeros((len(surf.v0), 3))
        extra.update(triangles=np.stack([surf.v0, surf.e1, surf.e2], axis=1), albedo=albedo)
    st = np.asarray(pm.sigma_t, np.float64)
    others = tuple(PathMedium(plat.density, np.asarray(plat.w2i, np.float64),
                              np.asarray(opm.sigma_s, np.float64),
                              np.asarray(opm.sigma_t, np.float64), float(opm.g), plat.stride,
                              plat.towards, plat.rate, plat.threshold,
                              _own_grid(opm.scatter_grid, plat),
                              _own_grid(opm.extinction_density, plat))
                   for opm, plat in partners)
    scatter = _own_grid(pm.scatter_grid, lat)
    extinction = _own_grid(pm.extinction_density, lat)
    totals = np.array([float(item[1].sum()) for item in sets])
    acc, split = None, None
    for k, item in enumerate(sets):
        starts, pw, dirs, jitter, lobe = item[:5]
        source, peak = item[5] if len(item) > 5 and item[5] is not None else (None, None)
        if source is not None and source.shape != density.shape:
            source, peak = None, None
        n_k = max(1, int(round(n_paths * totals[k] / totals.sum())))
        weights, cdf = from_power(pw, item[6] if len(item) > 6 else None)
        inp = PathInputs(density, w2i, i2w, np.asarray(pm.sigma_s, np.float64), st, float(pm.g),
                         lat.stride, lat.towards, np.ascontiguousarray(starts), weights,
                         np.ascontiguousarray(dirs), cdf, lat.rate, n_k, int(seed) + 104729 * k,
                         max_collisions=max_collisions, jitter=jitter, lobe=lobe,
                         start_source=source, start_peak=peak, moments=moments,
                         others=others, threshold=lat.threshold, light=light,
                         scatter=scatter, extinction=extinction,
                         min_collisions=min_collisions, moment_share=moment_share, odds=odds,
                         start_rate=item[7] if len(item) > 7 and lobe == 0 else None, **extra)
        got = kernels.trace_paths_media(inp, threads=worker_count(threads),
                                        should_cancel=should_cancel, halves=halves)
        if halves:
            got, half = got
            light3 = got[0][..., :3]
            if half is None or not 0 < half[1] < n_k:   # too few paths to halve: no spread
                pair = (light3, light3)
            else:
                pair = (half[0] * (n_k / half[1]), (light3 - half[0]) * (n_k / (n_k - half[1])))
            split = pair if split is None else (split[0] + pair[0], split[1] + pair[1])
        acc = got if acc is None else [a + b for a, b in zip(acc, got)]
    return (acc, split) if halves else acc


def fits_lobe(pm, camera, lobe_window: int) -> bool:
    """Whether the camera's M of paths in ``pm`` is fitted to their lobe (lobefit.py,
    ``lobe_light``): with a ``camera``, a ``lobe_window`` > 0 and a phase function that is not
    flat (an isotropic medium's deposits weigh every direction alike)."""
    return lobe_window > 0 and camera is not None and float(pm.g) != 0.0


def lobe_light(pm, lat, camera, m: np.ndarray, split, lobe_window: int, threads: int = 0,
               should_cancel=None, signed: bool = False,
               around: Optional[Surroundings] = None) -> np.ndarray:
    """float32 (LX,LY,LZ,3) W/(m^2 sr): the camera's M on the PathLattice ``lat`` of ``pm``,
    the paths' lobe fitted to their deposits (lobefit.fitted) from ``m`` (``lat.mean`` of the
    deposits with their moments, (LX,LY,LZ,15)) and ``split`` (first, second: the light
    deposits of the paths' two halves, _trace_all's ``halves``), over windows of
    ``lobe_window`` lattice points.  At least 0 unless ``signed`` (an estimate taken off
    another, skydeficit.py: its noise is not to be stopped at 0 on its own).  ``around``: the
    precompute's Surroundings, which keeps the lattice's depth to the camera for the other
    lights and the sky's deficit on the same lattice (Surroundings.camera_depth)."""
    u = camera_weight(lat.tent_mass, lattice_depth(pm, lat, camera, threads, should_cancel,
                                                   around))
    first, second = split
    # the nodal move is linear where not stopped at 0: one for the halves' difference
    light3 = fitted(m[..., :3], m[..., 3:], lat.towards, u,
                    np.asarray(lat.mean(first - second, signed=True), np.float64), lobe_window)
    return light3 if signed else np.maximum(light3, np.float32(0.0))


def lattice_depth(pm, lat, camera, threads: int = 0, should_cancel=None,
                  around: Optional[Surroundings] = None) -> Optional[np.ndarray]:
    """``_camera_depth`` of the PathLattice ``lat``, kept by ``around`` (the precompute's
    Surroundings, Surroundings.camera_depth) for every light's lobe fit and roulette and the
    sky deficit's on the same lattice; made afresh without one.  Callers must not modify it."""
    depth = (lambda: _camera_depth(pm, lat, camera, threads, should_cancel))
    if around is None:
        return depth()
    return around.camera_depth(
        (id(pm), tuple(lat.shape), int(lat.stride), _eye(camera).tobytes()), depth)


def _camera_depth(pm, lat, camera, threads, should_cancel) -> Optional[np.ndarray]:
    """(LX,LY,LZ) the optical depth (largest channel) from each point of ``lat`` to the
    camera through the medium ``pm`` alone (an orthographic camera's from far along its
    axis); None for the world's fog, which fills the way (its lattice points are weighed
    by their medium alone)."""
    if pm.endless:
        return None
    _, lpts = lattice_points(pm, lat.shape, lat.stride)
    return eye_depth(pm, _eye(camera), lpts, threads, should_cancel).reshape(lat.shape)


def _eye(camera) -> np.ndarray:
    """(3,) m: the camera's eye (an orthographic camera's ``FAR_EYE`` back along its axis)."""
    c2w = np.asarray(camera.cam_to_world, np.float64)
    return c2w[:3, 3] + (FAR_EYE * c2w[:3, 2] if str(camera.projection).upper() == "ORTHO"
                         else 0.0)


def _own_grid(grid, lat) -> Optional[np.ndarray]:
    """A medium's 3-channel grid ``grid`` (PreparedMedium.scatter_grid or
    extinction_density, or None) as its paths read it on its path lattice ``lat``, whose
    density is the medium's own voxels; None without one."""
    if grid is None or grid.shape[:3] != lat.density.shape:
        return None
    return grid


def _far_multiple(pm, sets, camera, n_paths, seed, threads, should_cancel, around,
                  light=None, nodal: bool = Tuning.path_nodal,
                  resolution: int = MULTIPLE_RESOLUTION):
    """worldfog.FarField of the fog ``pm`` for one light: ``FAR_PATHS`` of ``n_paths`` paths
    from the same ``sets`` of starts, their M on the voxels of the far box (``far_lattice``)
    for the tail beyond the fog's grid (worldfog.tail).  None where the fog has no
    extinction (no such depth)."""
    from ..worldfog import FarField
    lat = far_lattice(pm, camera, around, resolution, nodal)
    if lat is None:
        return None
    acc = _trace(sets, max(1, int(n_paths * FAR_PATHS)), int(seed) + 7, threads, should_cancel,
                 pm, lat, around, light=light)
    return FarField(lat.w2i, lat.mean(acc))


def far_lattice(pm, camera, around: Optional[Surroundings] = None,
                resolution: int = MULTIPLE_RESOLUTION,
                nodal: bool = Tuning.path_nodal) -> Optional["PathLattice"]:
    """The PathLattice of the world fog ``pm``'s far field: the voxels (stride 1) of a
    frustum box of ``camera``, ``resolution`` voxels along its longest side (the *Multiple
    Scattering Resolution*: a coarser box's tents, 2 m and more in the suite's fogs, had
    smoothed the light by a ground), out to the depth where the camera's transmittance
    through the fog is e^-TAU_VIEW; None where the fog has no extinction.  Its tent mass is
    the part of each voxel's tent inside the box and in front of ``around``'s surfaces (the
    box lies partly under a ground, as the fog's grid does, enclosed.py): nothing is
    deposited beyond its faces or below the ground, and a point there had been the mean of
    the light and the dark (p_fog_area's horizon 3-4 % dark).  ``nodal``: PathLattice.of."""
    from ..worldfog import frustum_box, view_depth
    depth = view_depth(None, pm.medium)
    if not np.isfinite(depth):
        return None
    near = max(float(camera.clip_start), 0.0)
    shape, i2w4, voxel = frustum_box(camera, near, max(depth, near + 1e-3),
                                     max(2, int(resolution)))
    w2i = np.linalg.inv(i2w4)[:3]
    density = np.ones(shape, np.float32)
    lidx = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), -1).reshape(-1, 3)
    pts = lidx @ i2w4[:3, :3].T + i2w4[:3, 3]
    towards = np.ascontiguousarray(towards_camera(camera, pts).reshape(tuple(shape) + (3,)))
    # one deposit per voxel of the far box: Tuning.path_deposits was measured on the
    # media's own lattices only
    rate = tentative_rate(float(np.max(pm.sigma_t)), voxel, 1.0)
    rho = density.astype(np.float64)
    if around is not None and around.surfaces is not None:
        from .enclosed import enclosed_fraction
        rho -= enclosed_fraction(shape, i2w4, around.surfaces)
    mass, offsets = tent_mass(rho, 1, shape, nodal)
    return PathLattice(1, tuple(shape), voxel, density, w2i, np.ascontiguousarray(i2w4[:3, :3]),
                       towards, rate, mass[..., None] * voxel ** 3,
                       int(np.count_nonzero(mass > 0.0)), offsets=offsets)
