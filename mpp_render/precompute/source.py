"""The first-scattering source Q = sigma_s E exp(-tau) (W/m^3) on a lattice: where every
multiply scattered path starts (``restricted_source``: the voxels' power shared among the
lattice points; ``source_and_density``: with the cells round a point light averaged and the
density at the lattice points), and the light of the forward peak beside the unscattered beam
(``peak_light``, W/m^2), both on the walk's lattice or one finer (``fine_stride``).
"""
from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from .. import kernels, pyramid
from ..firstflight import fft_shape
from ..lights import (area_geometry, disc_transmittance, emitter_normal, emitter_polygon,
                      incident, irradiance, outside_spot, towards_light)
from ..media import PreparedMedium, delta_scaled, density_from
from ..parallel import check, run_chunks
from ..phase import delta_fraction, peak_msa
from ..scene import Light, Tuning
from ..worldfog import optical_depth as fog_optical_depth
from .lattice import (MULTIPLE_RESOLUTION, dilate, lattice_index, lattice_points, lattice_shape,
                      lattice_values, walk_lattice)
from .lightdepth import light_optical_depth


PEAK_PAD = 4  # lattice points beyond the grid where peak_light follows the light on
NEAR_LIGHT_CELLS = 3  # lattice cells around a point or spot light whose source is averaged


def near_light_cells(pm: PreparedMedium, light: Light, stride: int, shape) -> np.ndarray:
    """Flat indices of the pyramid lattice cells within ``NEAR_LIGHT_CELLS`` cells of a point
    or spot light inside (or next to) the medium's grid."""
    c = pm.to_index(np.asarray(light.position, np.float64)) / stride
    lo = np.maximum(np.floor(c - NEAR_LIGHT_CELLS).astype(int), 0)
    hi = np.minimum(np.ceil(c + NEAR_LIGHT_CELLS).astype(int), np.array(shape) - 1)
    if np.any(hi < lo):
        return np.zeros(0, np.int64)
    g = np.stack(np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(lo, hi)], indexing="ij"), -1)
    return np.ravel_multi_index(tuple(g.reshape(-1, 3).T), shape)


def first_scattering(pm: PreparedMedium, rho, e, tau, peak=None, trans=None,
                     colour=None) -> np.ndarray:
    """The power per volume (W/m^3, (N,3)) the light's unscattered beam scatters at points of
    density ``rho`` (N,), irradiance ``e`` (N,3, W/m^2) and optical depth ``tau`` (N,3) from
    the light: Q = rho sigma_s E exp(-tau), where every multiply scattered path starts; with
    the forward peak's light ``peak`` (N,3, W/m^2, ``peak_light``) beside the unscattered
    light, Q = rho sigma_s (E exp(-tau) + peak) (``pm`` then the delta-scaled medium).
    ``trans`` (N,3): the transmittance to use instead of exp(-tau) (a lamp's disc mean,
    lights.disc_transmittance).  ``colour`` (N,3): the factor on sigma_s at the points
    (PreparedMedium.scatter_at), or None for the medium's one colour."""
    light = e * (np.exp(-np.asarray(tau, np.float64)) if trans is None else trans)
    if peak is not None:
        light = light + np.asarray(peak, np.float64)
    if colour is not None:
        light = light * np.maximum(np.asarray(colour, np.float64), 0.0)
    return (np.asarray(rho)[:, None] * pm.sigma_s[None, :]) * light


def cell_mean_irradiance(light: Light, pts, cell: np.ndarray, n: int = 2,
                         cull: bool = True) -> np.ndarray:
    """The light's irradiance (W/m^2, (N,3)) averaged over the lattice cells centred on
    ``pts`` (N,3, m) with edges the columns of ``cell`` (3,3, m): n^3 points each (midpoint
    rule).  A spot's cone narrower than the lattice (fog_beam's is 0.2 m wide where it
    enters, two lattice spacings) read at the points alone is over- or under-counted as the
    lattice falls; a sun's irradiance is the same everywhere and read once, and an area
    light's is already its emitter's integral (lights.area_incident), read once.  Cells
    wholly outside a spot's cone (``lights.outside_spot``) are 0 without a read (``cull``;
    the same result, faster: Tuning.spot_cull).  Every point is read through the compiled
    light sample (kernels.light_sample; its numpy twin to 1e-8)."""
    if light.kind in ("SUN", "AREA"):
        return irradiance(light, pts, kernels.light_sample)
    pts = np.asarray(pts, np.float64).reshape(-1, 3)
    cell = np.asarray(cell, np.float64)
    corner = 0.5 * float(np.linalg.norm(np.abs(cell).sum(axis=1)))   # m, a bound
    lit = np.flatnonzero(~outside_spot(light, pts, corner)) if cull else \
        np.arange(len(pts))
    if lit.size < len(pts):
        out = np.zeros((len(pts), 3))
        if lit.size:
            out[lit] = cell_mean_irradiance(light, pts[lit], cell, n, cull)
        return out
    t = (np.arange(n) + 0.5) / n - 0.5
    offs = np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3) @ cell.T
    acc = np.zeros((len(pts), 3))
    for o in offs:
        acc += irradiance(light, pts + o, kernels.light_sample)
    return acc / len(offs)


VOXEL_POINTS = 3   # per axis: a spot's irradiance is a voxel's mean over VOXEL_POINTS^3 points


def voxel_irradiance(light: Light, pts, i2w, n: int = VOXEL_POINTS) -> np.ndarray:
    """The light's irradiance (W/m^2, (N,3)) at voxel centres ``pts`` (N,3, m): a spot's the
    mean over each voxel (``cell_mean_irradiance`` on the voxel's cell ``i2w``, ``n``^3
    points), a point light's read at the centre with its falloff at least the mean of a
    voxel's ball round it (``near_falloff``), any other light's read at the centre.  A spot's
    cone a few voxels wide read at the centres alone is over- or under-counted as the voxels
    fall (the single scattering reads it exactly at every march sample, the paths' source did
    not): on fog_beam the paths' second order went from 1.186 to 1.155 of Cycles' (split by
    volume_bounces), the same at 6 points per axis as at 3."""
    if light.kind == "SPOT":
        return cell_mean_irradiance(light, pts, np.asarray(i2w, np.float64), n)
    e = irradiance(light, pts, kernels.light_sample)
    if light.kind == "POINT":
        e = e * near_falloff(light, pts, i2w)[:, None]
    return e


def near_falloff(light: Light, pts, i2w) -> np.ndarray:
    """(N,) the factor that takes a point light's falloff (``point_falloff``) read at ``pts``
    (N,3, m) to its read at max(r^2, R^2 / 3): for a light without radius the exact mean of
    1 / r^2 over the ball of one voxel's volume (radius R; voxel edges the columns of ``i2w``)
    centred on the light, where the centre's read grows without bound; 1 beyond R, and for a
    lamp whose disc is wider than R."""
    vol = abs(np.linalg.det(np.asarray(i2w, np.float64)[:3, :3]))
    r_min2 = (3.0 * vol / (4.0 * np.pi)) ** (2.0 / 3.0) / 3.0
    rel = np.asarray(pts, np.float64).reshape(-1, 3) - np.asarray(light.position, np.float64)
    r2 = np.einsum("ij,ij->i", rel, rel)
    return point_falloff(np.maximum(r2, r_min2), light.radius) / point_falloff(r2, light.radius)


def peak_light(pm: PreparedMedium, fld: np.ndarray, light: Light, channel: int, beam: int,
               mean_sigma_s: float, flat, step: float,
               resolution: int = MULTIPLE_RESOLUTION,
               should_cancel: Optional[Callable[[], bool]] = None, fog: bool = False,
               tuning: Tuning = Tuning()):
    """The light of the forward peak, W/m^2: what has scattered into the peak
    (phase.delta_fraction) and not yet out of it, spread sideways as the peak's angles take
    it (docs/method.md, "The forward peak spreads").  Returns (lattice (X,Y,Z,3) float32,
    stride): on a lattice ``stride`` voxels apart, about ``resolution`` points along the
    grid's longest side (finer where ``fine_stride`` says so), for
    ``kernels.upsample_into``; raises cancel.Cancelled when ``should_cancel`` says so.

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
    stride, _, h = walk_lattice(pm, resolution)
    fine = fine_stride(pm, stride, tuning)
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
    pts = pm.to_world(idx * float(stride))
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
        near = dilate(near)
    near = np.flatnonzero(near)
    e = np.zeros((len(idx), 3))
    e[near] = cell_mean_irradiance(light, pts[near], stride * pm.i2w[:3, :3],
                                   cull=tuning.spot_cull)
    rest = np.flatnonzero(~known & np.any(e > 0.0, axis=1))  # no light, no peak: no depth
    if rest.size and f > 0.0:
        for out, through in ((tau, pm), (tau_b, delta_scaled(pm))):
            got = fog_optical_depth(through.sigma_t, towards_light(light, pts[rest])[1]) if fog \
                else light_optical_depth([through], light, pts[rest], step,
                                         should_cancel=should_cancel, tuning=tuning)
            out[rest] = got
    check(should_cancel)
    b = e * np.maximum(np.exp(-tau_b) - np.exp(-tau), 0.0)
    if f > 0.0 and mean_sigma_s > 0.0:
        with np.errstate(invalid="ignore"):
            n = np.mean(tau - tau_b, axis=1)
        s = np.nan_to_num(np.maximum(n, 0.0), nan=0.0, posinf=1e30) / (f * mean_sigma_s)
        width = per_metre * s
        levels = pyramid.build(b.astype(np.float32).reshape(ext + (3,)), 10)
        check(should_cancel)
        core = np.all((idx >= 0) & (idx < np.array(shape)), axis=1)
        b = pyramid.lookup(levels, idx[core] + pad, width[core], h)
    return np.ascontiguousarray(b.reshape(shape + (3,)), np.float32), stride


def point_falloff(r2, radius: float) -> np.ndarray:
    """A point light's irradiance per unit intensity (1/m^2) at squared distances ``r2``
    (m^2): Cycles' soft-falloff disc of ``radius``, 2 (1 - r / sqrt(r^2 + R^2)) / R^2
    (lights.light_sample), 1 / r^2 without a radius (floored at light_sample's 1e-8 m^2)."""
    r2 = np.asarray(r2, np.float64)
    if radius <= 0.0:
        return 1.0 / np.maximum(r2, 1e-8)
    big = float(radius) ** 2
    return 2.0 * (1.0 - np.sqrt(r2 / (r2 + big))) / big


def cell_mean_source(pm: PreparedMedium, fld: np.ndarray, light: Light, channel: int,
                     stride: int, shape, cells: np.ndarray,
                     beam: Optional[int] = None, disc=None,
                     disc_channel: Optional[int] = None) -> np.ndarray:
    """The first-scattering source Q = sigma_s E exp(-tau) (W/m^3, (len(cells), 3)) averaged
    over the voxels of each lattice cell in ``cells`` (the voxels nearest to the cell's
    point), with a point light's falloff (``point_falloff``) read at max(r^2, R^2/3): for a
    light without radius the exact mean of 1/r^2 over the ball of one voxel's volume
    (radius R) centred on the light; a lamp's disc is finite at its centre and changes
    nothing beyond R.  Next to a
    point light the source varies too fast for one read at the lattice point: a light
    inside a medium then lost 25-55 % of its first-scattered power to the pyramid."""
    ci = np.stack(np.unravel_index(cells, shape), axis=1)
    # the tent's weights, as restricted_source shares every other voxel's power (1 in all)
    tw = tent_weights(stride)
    t, w = np.array(list(tw)), np.array(list(tw.values()))
    offs = np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3)
    weight = np.einsum("i,j,k->ijk", w, w, w).reshape(-1)
    ijk = (ci[:, None, :] * stride + offs[None]).reshape(-1, 3)
    ok = np.all((ijk >= 0) & (ijk < np.array(pm.grid.shape)), axis=1)
    flat = np.ravel_multi_index(tuple(np.where(ok[:, None], ijk, 0).T), pm.grid.shape)
    pts = pm.to_world(ijk.astype(np.float64))
    v = fld.reshape(-1, fld.shape[-1])[flat]
    rho = np.where(ok, density_from(v[:, 0], pm.threshold), 0.0)
    _, e = incident(light, pts, sample=kernels.light_sample)
    e = e * near_falloff(light, pts, pm.i2w[:3, :3])[:, None]
    tau = v[:, channel:channel + 3]
    q = first_scattering(pm, rho, e, tau, None if beam is None else v[:, beam:beam + 3],
                         _disc(disc, light, pts, tau, pm, _change(v, disc_channel)),
                         pm.scatter_at(flat=flat))
    return np.einsum("nkc,k->nc", q.reshape(len(cells), len(offs), 3), weight)


# A mesh volume whose optical depth across one voxel exceeds SURFACE_TAU: the voxels by its
# surface take their first-scattering source from 2 x 2 x 2 points of their cell, each with
# its own optical depth to the light and inside the sharp surface or not.  The centre's read
# missed the lit layer's steep exp(-tau) (the field's depth, trilinear between an outside and
# an inside voxel, is too deep there by up to a third of a voxel's) and the parts of cells
# whose centre lies outside the surface: p_sphere_thick (density 40, 0.64 per voxel) had its
# sun's first scatterings at 12.69 W against 13.49 W from a Monte Carlo over the mesh's
# surface; at 0.125 per voxel (slab_forward) the centres are within 0.1 %.
SURFACE_TAU = 0.2
SURFACE_DEEP = 8.0   # surface voxels whose inside neighbours lie deeper are left as they are
# a voxel's cell read at 2 x 2 x 2 points a quarter voxel from its centre (index offsets)
CELL_POINTS = np.array([(a, b, c) for a in (-0.25, 0.25) for b in (-0.25, 0.25)
                        for c in (-0.25, 0.25)])


def surface_band_source(pm: PreparedMedium, fld: np.ndarray, light: Light, channel: int,
                        depth: Callable, disc=None) -> Optional[tuple]:
    """(flat voxel indices (N,), Q (N,3) W/m^3, flat indices (M,), factors (M,3)): the
    first-scattering source of the voxels by a dense mesh volume's surface (see
    SURFACE_TAU), each the mean over 2 x 2 x 2 points a quarter voxel from its centre of
    sigma_s rho E exp(-tau) (rho 1 inside the sharp surface, as the march reads it, else 0;
    tau from ``depth(light, points)``, the optical depth as the light's sweep gives a
    voxel's, pathstarts.Surroundings.optical_depth; the lamp's disc through ``disc`` as in
    restricted_source); and for the voxels inside, off the surface and within SURFACE_DEEP,
    the factor by which exp(-tau) over the cell exceeds its centre's, tau linear across it
    (``cell_depth_factor``).  None where the medium is not such a mesh volume or no surface
    voxel lies within SURFACE_DEEP of the light."""
    if not pm.sharp or pm.endless:
        return None
    if not float(np.max(pm.sigma_t)) * float(pm.voxel_size) > SURFACE_TAU:
        return None
    inside = density_from(pm.grid, pm.threshold) > 0.0
    shallow = np.where(inside, fld[..., channel:channel + 3].min(axis=-1), np.inf)
    for ax in range(3):    # the shallowest inside voxel of each 3 x 3 x 3 neighbourhood
        shallow = np.minimum(shallow, np.minimum(np.roll(shallow, 1, axis=ax),
                                                 np.roll(shallow, -1, axis=ax)))
    surface = dilate(inside) & dilate(~inside)
    band = surface & (shallow < SURFACE_DEEP)
    flat = np.flatnonzero(band)
    if not flat.size:
        return None
    deep = np.flatnonzero(inside & ~surface & (shallow < SURFACE_DEEP))
    from ..media import trilinear
    q = cell_points_source(pm, flat, light,
                           lambda idx: density_from(trilinear(pm.grid, idx), pm.threshold),
                           lambda idx, pts: depth(light, pts), disc)
    return flat, q, deep, cell_depth_factor(fld[..., channel:channel + 3], deep)


def cell_points_source(pm: PreparedMedium, flat: np.ndarray, light: Light, density: Callable,
                       depth: Callable, disc=None) -> np.ndarray:
    """(N,3) W/m^3: the first-scattering source of the voxels ``flat`` (N,) of ``pm``, each the
    mean over its cell's CELL_POINTS (index coordinates kept within [0, n-1] per axis: the
    padding, density 0, beyond) of sigma_s rho E exp(-tau), rho from ``density(idx)`` and tau
    from ``depth(idx, world points)`` at the points with density (the lamp's disc through
    ``disc`` as in restricted_source)."""
    ijk = np.stack(np.unravel_index(flat, pm.grid.shape), axis=1).astype(np.float64)
    idx = (ijk[:, None, :] + CELL_POINTS[None]).reshape(-1, 3)
    idx = np.clip(idx, 0.0, np.array(pm.grid.shape, np.float64) - 1.0 - 1e-9)
    rho = np.reshape(np.asarray(density(idx), np.float64), -1)
    live = rho > 0.0
    q = np.zeros((len(idx), 3))
    if np.any(live):
        pts = pm.to_world(idx[live])
        _, e = incident(light, pts, sample=kernels.light_sample)
        tau = depth(idx[live], pts)
        q[live] = first_scattering(pm, rho[live], e, tau, None, _disc(disc, light, pts, tau, pm),
                                   pm.scatter_at(idx=idx[live]))
    return q.reshape(len(flat), len(CELL_POINTS), 3).mean(axis=1)


def thick_band_source(pm: PreparedMedium, fld: np.ndarray, light: Light, channel: int,
                      cell_tau: float, disc=None, walk: int = Tuning.cell_walk) -> Optional[tuple]:
    """surface_band_source's for a density grid (a VDB, a shader's density): the voxels that
    lightdepth.near_thick_cells gives (lit, next to a voxel of at least ``cell_tau`` optical
    depth across), each the mean over its cell's CELL_POINTS of sigma_s rho E exp(-tau) with
    rho read trilinearly and tau as the march reads it in such a cell (kernels.walk_tau on
    the field, the medium's own extinction on the way): the light entering a dense voxel
    falls off within it, which its centre's read alone takes as the whole cell's (a
    third-party dragon of 1.2-2.5 optical depth a voxel: its multiple scattering 0.85x
    Cycles', docs/method.md, "Light in an optically thick voxel").  No deeper voxels' factors
    (empty arrays).  None where no voxel qualifies."""
    from ..kernels import trilinear, walk_tau
    from .lightdepth import near_thick_cells
    flat = near_thick_cells(pm, fld[..., channel:channel + 3].min(axis=-1), cell_tau)
    if not flat.size:
        return None
    # the density, the light's depth and any extinction density alone, read by the compiled
    # trilinear kernel
    parts = [fld[..., [0, channel, channel + 1, channel + 2]]]
    if pm.extinction_density is not None:
        parts.append(pm.extinction_density)
    own = np.ascontiguousarray(np.concatenate(parts, axis=-1), np.float32)

    def depth(idx, pts):
        w, dist = towards_light(light, pts)
        return walk_tau(own, pm.w2i, pm.sigma_t, 4 if pm.extinction_density is not None else -1,
                        1, pts, w, dist, trilinear(own, idx)[:, 1:4],
                        float(np.max(pm.sigma_t)) or 1.0, pm.voxel_size, cell_tau, walk)

    q = cell_points_source(pm, flat, light, lambda idx: trilinear(own, idx)[:, 0], depth, disc)
    return flat, q, np.zeros(0, np.int64), np.ones((0, 3))


def emitter_band_source(pm: PreparedMedium, fld: np.ndarray, light: Light, channel: int,
                        disc=None) -> Optional[tuple]:
    """surface_band_source's for an area light's emitter in the medium: the voxels whose cells
    the emitter's plane cuts (centre within half the cell's extent along the normal), over
    the emitter and a voxel round it, each the mean over its cell's CELL_POINTS of
    sigma_s rho E exp(-tau), rho and tau read trilinearly.  The emitter lights one side:
    a voxel centred just behind its plane reads nothing at its centre though its cell's
    front part, where the trilinear density reaches, is lit at the emitter's full
    irradiance; the centres alone missed that layer (half a voxel under a 0.4 m emitter in
    VDB smoke: 15 % of the light's first-scattered power, against rays traced from the
    emitter; docs/method.md, *An area light's source*).  None for any other light, or where
    the plane cuts no cell of the grid."""
    if light.kind != "AREA":
        return None
    c, ax, ay, _ = area_geometry(light)
    n = emitter_normal(light)
    i2w = np.asarray(pm.i2w, np.float64)[:3, :3]
    half_n = 0.5 * float(np.abs(i2w.T @ n).sum())          # the cell's half extent along n, m
    idx = pm.to_index(emitter_polygon(light))
    shape = np.array(pm.grid.shape[:3])
    lo = np.clip(np.floor(idx.min(axis=0)) - 2, 0, shape - 1).astype(int)
    hi = np.clip(np.ceil(idx.max(axis=0)) + 2, 0, shape - 1).astype(int)
    if np.any(hi < lo):
        return None
    # the plane in index coordinates, m . idx + s0 = 0: along the axis it crosses most
    # steeply a column meets the band (|distance| < half_n) at no more than 4 voxels
    m = i2w.T @ n
    s0 = float(n @ (np.asarray(pm.i2w, np.float64)[:3, 3] - c))
    k = int(np.argmax(np.abs(m)))
    a_, b_ = [ax_ for ax_ in range(3) if ax_ != k]
    pa, pb = np.meshgrid(np.arange(lo[a_], hi[a_] + 1), np.arange(lo[b_], hi[b_] + 1),
                         indexing="ij")
    kstar = -(m[a_] * pa + m[b_] * pb + s0) / m[k]
    ijk = np.zeros(pa.shape + (4, 3), np.int64)
    ijk[..., a_] = pa[..., None]
    ijk[..., b_] = pb[..., None]
    ijk[..., k] = np.floor(kstar)[..., None].astype(np.int64) + np.arange(-1, 3)
    ijk = ijk.reshape(-1, 3)
    ijk = ijk[np.all((ijk >= 0) & (ijk < shape), axis=1)]
    rel = pm.to_world(ijk.astype(np.float64)) - c
    voxel = float(np.max(np.linalg.norm(i2w, axis=0)))
    on = np.abs(rel @ n) < half_n
    for a in (ax, ay):   # within the emitter's half axis and a voxel beyond it
        la = float(np.linalg.norm(a))
        on &= np.abs(rel @ a) / max(la, 1e-300) <= la + voxel
    flat = np.ravel_multi_index(tuple(ijk[on].T), pm.grid.shape[:3])
    if not flat.size:
        return None
    from ..media import trilinear
    tau = np.ascontiguousarray(fld[..., channel:channel + 3])
    q = cell_points_source(pm, flat, light,
                           lambda i: density_from(trilinear(pm.grid, i), pm.threshold),
                           lambda i, pts: trilinear(tau, i), disc)
    return flat, q, np.zeros(0, np.int64), np.ones((0, 3))


def merged_bands(first: Optional[tuple], then: Optional[tuple]) -> Optional[tuple]:
    """Two bands of ``restricted_source`` as one: ``then``'s voxels take its source, the
    rest of ``first``'s keep theirs (and its factors)."""
    if first is None or then is None:
        return then if first is None else first
    keep = ~np.isin(first[0], then[0])
    return (np.concatenate([first[0][keep], then[0]]), np.concatenate([first[1][keep], then[1]]),
            first[2], first[3])


def cell_depth_factor(tau: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """(N,3): the mean over each voxel ``flat``'s cell of exp(-(tau - tau_centre)) for an
    optical depth ``tau`` (X,Y,Z,3) linear across it, prod over the axes of sinh(d/2) / (d/2)
    with d the central difference of tau along the axis (the voxels must not lie on the
    grid's edge).  At 0.64 per voxel (density 40) the centre's read is 1.6 % low."""
    ijk = np.unravel_index(flat, tau.shape[:3])
    out = np.ones((len(flat), 3))
    for ax in range(3):
        up = list(ijk)
        dn = list(ijk)
        up[ax] = np.minimum(ijk[ax] + 1, tau.shape[ax] - 1)
        dn[ax] = np.maximum(ijk[ax] - 1, 0)
        half = 0.25 * np.abs(tau[tuple(up)].astype(np.float64) - tau[tuple(dn)])
        out *= np.where(half > 1e-8, np.sinh(half) / np.maximum(half, 1e-8), 1.0)
    return out


def _change(rows: np.ndarray, disc_channel: Optional[int]) -> Optional[np.ndarray]:
    """The disc channels (discdepth.py) of field ``rows`` (N,C), or None without them."""
    return None if disc_channel is None else rows[:, disc_channel:disc_channel + 3]


def _disc(disc, light: Light, pts, tau, pm: PreparedMedium, change=None) -> np.ndarray:
    """The lamp's disc transmittance at ``pts`` through ``disc`` (see source_and_density) or
    lights.disc_transmittance at the voxel size; ``change``: the field's disc channels
    there (discdepth.py) or None."""
    if disc is not None:
        return disc(light, pts, tau, change) if change is not None else disc(light, pts, tau)
    return disc_transmittance(light, pts, tau, pm.voxel_size, change=change,
                              transmit=kernels.emitter_transmittance)


def tent_restrict(a: np.ndarray, axis: int, stride: int, n_out: int,
                  boxed: bool = False, weights: Optional[dict] = None) -> np.ndarray:
    """``a`` restricted along ``axis`` to every ``stride``-th point with the tent weights
    (stride - |t|) / stride^2, t = -(stride-1)..stride-1 (zero beyond the ends): each point's
    value shared among the lattice points around it in proportion to their nearness, so that
    the sum times the lattice spacing keeps the sum times the voxel size.  ``boxed``: the
    weights are the tent's integral over each voxel's width instead (``box_tent_weights``,
    t = -stride..stride), for a value that holds over the whole voxel (the paths' nearest-
    voxel density).  ``weights``: {t: w} given instead of either (nodal.py's moments)."""
    if weights is None:
        weights = box_tent_weights(stride) if boxed else tent_weights(stride)
    reach = max(weights)
    n = a.shape[axis]
    pad = [(0, 0)] * a.ndim
    pad[axis] = (reach, stride * n_out - n + reach + 1)
    p = np.pad(a, pad)
    out = 0.0
    for t, w in weights.items():
        sl = [slice(None)] * a.ndim
        sl[axis] = slice(t + reach, t + reach + stride * n_out, stride)
        out = out + w * p[tuple(sl)]
    return out


def tent_weights(stride: int) -> dict:
    """{t: (stride - |t|) / stride^2} for t = -(stride-1)..stride-1: the share of a voxel t
    voxels from a lattice point that the point's tent takes (the shares of one voxel over
    the points round it sum to 1/stride per axis, the weights of one point to 1)."""
    return {t: (stride - abs(t)) / float(stride * stride) for t in range(-(stride - 1), stride)}


def box_tent_weights(stride: int) -> dict:
    """{t: w}: the tent of half-width ``stride`` (voxels; height 1 / stride, so its integral
    is 1) integrated over the voxel [t - 1/2, t + 1/2], t = -stride..stride: a voxel beside
    the tent's end still holds a sliver of it."""
    s = float(stride)

    def g(u):  # the tent's integral from -s to u
        u = min(max(u, -s), s)
        return (u + s) ** 2 / (2.0 * s) if u <= 0.0 else s - (s - u) ** 2 / (2.0 * s)

    return {t: (g(t + 0.5) - g(t - 0.5)) / s for t in range(-stride, stride + 1)}


def restricted_source(pm: PreparedMedium, fld: np.ndarray, light: Light, channel: int,
                   stride: int, shape, chunk: int = 16,
                   should_cancel: Optional[Callable[[], bool]] = None,
                   beam: Optional[int] = None,
                   voxels: Optional[np.ndarray] = None, disc=None, band=None,
                   disc_channel: Optional[int] = None, threads: int = 1) -> np.ndarray:
    """The first-scattering source Q = sigma_s E exp(-tau) (W/m^3, (N,3) in the C order of
    the lattice ``shape`` ``stride`` voxels apart) from every voxel of the field ``fld``
    (optical depth at ``channel``), each voxel's power shared among the lattice points
    around it (``tent_restrict`` along each axis): the lattice holds the voxels' power, where
    reading Q at the lattice points alone missed (or doubled) the thin layer a light lights
    inside a dense medium's face as the lattice fell against it (docs/ms_resolution.md).
    Stride 1 reads the voxels themselves.  Made ``chunk`` voxel planes at a time, on
    ``threads`` workers (parallel.run_chunks: the light's compiled sample and emitter
    transmittance release the GIL; each chunk writes its own planes, so the result does not
    depend on the count); raises cancel.Cancelled when ``should_cancel`` says so between
    them.  ``voxels`` (float32, the
    grid's shape): filled with each voxel's Q summed over its channels (the paths' starts,
    precompute.lightpaths).  ``band``: None, or surface_band_source's (flat voxel indices,
    Q (N,3)) that replace those voxels' source and (flat indices, factors (M,3)) that scale
    theirs.  ``disc_channel``: the light's disc channels in ``fld`` (discdepth.py) or None."""
    nx = pm.grid.shape[0]
    plane = int(np.prod(pm.grid.shape[1:]))
    rows = np.zeros((nx, shape[1], shape[2], 3))
    flat_fld = fld.reshape(nx, -1, fld.shape[-1])

    def planes(a, b):
        ijk = np.stack(np.meshgrid(np.arange(a, b), np.arange(pm.grid.shape[1]),
                                   np.arange(pm.grid.shape[2]), indexing="ij"), -1).reshape(-1, 3)
        v = flat_fld[a:b].reshape(-1, fld.shape[-1])
        rho = density_from(v[:, 0], pm.threshold)
        live = rho > 0.0
        q = np.zeros((len(v), 3))
        if np.any(live):
            pts = pm.to_world(ijk[live].astype(np.float64))
            e = voxel_irradiance(light, pts, pm.i2w[:3, :3])
            tau = v[live, channel:channel + 3]
            q[live] = first_scattering(pm, rho[live], e, tau,
                                       None if beam is None else v[live, beam:beam + 3],
                                       _disc(disc, light, pts, tau, pm, _change(v[live],
                                                                                disc_channel)),
                                       pm.scatter_at(flat=a * plane + np.flatnonzero(live)))
        if band is not None:
            here = (band[2] >= a * plane) & (band[2] < b * plane)
            q[band[2][here] - a * plane] *= band[3][here]
            here = (band[0] >= a * plane) & (band[0] < b * plane)
            q[band[0][here] - a * plane] = band[1][here]
        q = q.reshape((b - a,) + tuple(pm.grid.shape[1:]) + (3,))
        if voxels is not None:
            voxels[a:b] = q.sum(axis=-1)
        if stride > 1:
            q = tent_restrict(tent_restrict(q, 1, stride, shape[1]), 2, stride, shape[2])
        rows[a:b] = q
    run_chunks(nx, chunk, planes, threads, should_cancel)
    if stride > 1:
        rows = tent_restrict(rows, 0, stride, shape[0])
    return rows.reshape(-1, 3)


def source_and_density(pm: PreparedMedium, fld: np.ndarray, light: Light, channel: int,
                   stride: int, beam: Optional[int] = None,
                   should_cancel: Optional[Callable[[], bool]] = None,
                   voxels: Optional[np.ndarray] = None, disc=None, depth=None,
                   cell_tau: float = 0.0, cell_walk: int = Tuning.cell_walk,
                   disc_channel: Optional[int] = None, threads: int = 1):
    """(source (N,3) W/m^3, density (N,), points (N,3) m) on the lattice ``stride`` voxels
    apart (C order of ``lattice_shape``): the first-scattering source of ``restricted_source``,
    averaged over the cells round a point or spot light (``cell_mean_source``), and the
    medium's density at the lattice points.  Raises cancel.Cancelled on Esc.  ``voxels``:
    filled with the voxels' own source (``restricted_source``).  ``disc``: callable (light,
    points, tau) -> transmittance (pathstarts.Surroundings.disc), or None for
    lights.disc_transmittance at the voxel size.  ``depth``: callable (light, points) ->
    optical depth as the light's sweep gives a voxel's (pathstarts.Surroundings.optical_depth):
    a dense mesh volume's surface voxels then take their source from points of their cells
    (surface_band_source; not for the walk's forward peak, ``beam``).  ``cell_tau`` > 0: a
    density grid's lit voxels by optically thick ones take theirs from points of their cells
    (thick_band_source; Tuning.cell_tau, ``cell_walk`` Tuning.cell_walk).  An area light's
    emitter in the medium: the voxels whose cells its plane cuts take theirs from points of
    their cells too (emitter_band_source; not for ``beam``).  ``disc_channel``:
    the light's disc channels in ``fld`` (discdepth.py; the voxels' and the cells' round the
    lamp, not the bands'), or None.  ``threads``: restricted_source's."""
    shape = lattice_shape(pm.grid.shape, stride)
    idx, pts = lattice_points(pm, shape, stride)
    rho = density_from(lattice_values(fld[..., 0], idx, stride), pm.threshold)
    band = None if depth is None or beam is not None else \
        surface_band_source(pm, fld, light, channel, depth, disc)
    if band is None and beam is None and cell_tau > 0.0:
        band = thick_band_source(pm, fld, light, channel, cell_tau, disc, cell_walk)
    if beam is None:   # an area light's emitter in the medium: the cells its plane cuts
        band = merged_bands(band, emitter_band_source(pm, fld, light, channel, disc))
    base = restricted_source(pm, fld, light, channel, stride, shape, should_cancel=should_cancel,
                          beam=beam, voxels=voxels, disc=disc, band=band,
                          disc_channel=disc_channel, threads=threads)
    if light.kind in ("POINT", "SPOT"):
        near = near_light_cells(pm, light, stride, shape)
        if near.size:
            base[near] = cell_mean_source(pm, fld, light, channel, stride, shape, near, beam, disc,
                                          disc_channel)
    return base, rho, pts


# What follows a narrow beam in a mesh volume -- the forward peak's light (peak_light) and
# the exact first flights (firstflight.py) -- is computed on a lattice finer than the walk's
# by Tuning.refine where the first flights' FFT on it stays within FINE_POINTS: round a beam a
# few lattice steps wide their light is as narrow (fog_beam on the walk's 64 points: the
# beam's axis 14 % too dark, its sides 60 % too bright; docs/method.md).  Larger grids, and
# the media of varying density (VDB grids, the world's fog), whose first flights are the
# walk's, keep the walk's lattice (the forward peak's light alone on the finer lattice took
# smoke_plume's precompute from 1.8 s to 5.2 s for the same error).
FINE_POINTS = 1 << 22


def fine_stride(pm: PreparedMedium, stride: int, tuning: Tuning = Tuning()) -> int:
    """The stride (voxels) of the lattice for the forward peak's light and the exact first
    flights, for a walk on ``stride``: the largest divisor of ``stride`` at most
    stride / ``tuning.refine`` (the walk's lattice points are then among its points,
    precompute.flatten.flatten_levels), or ``stride`` itself where that is 1, the medium is not a mesh
    volume (``pm.sharp``) or the finer lattice's FFT would exceed FINE_POINTS."""
    if not pm.sharp:
        return stride
    fine = next((d for d in range(stride // tuning.refine, 0, -1) if stride % d == 0), stride)
    n = int(np.prod(fft_shape(lattice_shape(pm.grid.shape, fine))))
    return fine if n <= FINE_POINTS else stride


def light_direction(light: Light, points) -> np.ndarray:
    """The direction (N,3, unit) the light travels at ``points`` (N,3, m): radial from a point
    or spot light, the axis of a sun or area light."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if light.kind in ("SUN", "AREA"):
        axis = np.asarray(light.direction, np.float64)
        return np.tile(axis / np.linalg.norm(axis), (len(points), 1))
    return -towards_light(light, points)[0]
