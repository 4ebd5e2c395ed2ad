"""The light pyramid of multiple scattering (pyramid.py's levels on a lattice of the medium's
grid): the first-scattering source (source.py) spread level by level as the walk of the
scattered light spreads it, each level losing what leaves through the medium's surface
(boundary.py) and moved along the light by its paths' mean displacement towards what the
camera sees (``drift_levels``); for a mesh volume also the exact first flights
(firstflight.py).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from .. import kernels, pyramid
from ..camera import towards_camera
from ..firstflight import FirstFlight, first_flight, flight_weight
from ..walk import level_paths, walk_displacement
from ..media import PreparedMedium
from ..parallel import check
from ..scene import Camera, Light, Tuning
from . import boundary
from .lattice import MULTIPLE_RESOLUTION, lattice_points, lattice_shape, walk_lattice
from .source import fine_stride, light_direction, source_and_density


@dataclass
class MultipleField:
    """Multiple-scattering data of one light on one medium: the light pyramid (pyramid.py) of
    the first-scattering source and the medium's occupancy, on a lattice ``stride`` voxels
    apart (spacing ``h`` metres).  Level channels: the RGB power per volume (W/m^3) that the
    light's unscattered beam scatters, Q = sigma_s E exp(-tau) (the start of every multiply
    scattered path), each level moved by its paths' drift (``drift_levels``).  ``first``:
    None, or for a mesh volume whose first flights mostly leave it the exact first two
    flights (firstflight.FirstFlight on the finest lattice) that replace the walk's, by their
    weight (precompute.flatten.flatten_levels).  ``flat``: the levels are summed once towards the camera (``flattens``; precompute.flatten).
    ``traced``: ``levels`` is one level, the traced paths' M (paths.py), read as it is.
    ``far``: for the world fog's traced paths, their M beyond its grid (worldfog.FarField,
    read by worldfog.tail), else None.  ``moments``: for traced paths in a scene with
    surfaces, None or float32 (LX,LY,LZ,12) M's moments of order 0 and 1
    (paths.py, "Moments"), which the surfaces' gathers read (march.MarchContext.gathers)."""

    stride: int
    h: float
    levels: list
    first: Optional[FirstFlight] = None
    flat: bool = False
    traced: bool = False
    far: Optional[object] = None
    moments: Optional[np.ndarray] = None


def flattens(pm: PreparedMedium, camera: Optional[Camera], tuning: Tuning = Tuning()) -> bool:
    """Whether the march sums ``pm``'s light pyramids over levels and lights once
    (precompute.flatten.flatten_levels, with ``tuning.flatten``): a mesh volume (one density wherever it
    has any) seen by a perspective or orthographic camera, the direction from a sample to
    the camera then that of the camera ray through it.  Only such a medium gets the exact
    first flights, which join the flattened level."""
    return bool(tuning.flatten) and pm.uniform and camera is not None and \
        str(camera.projection).upper() in ("PERSP", "ORTHO")


def multiple_field(pm: PreparedMedium, fld: np.ndarray, light: Light, channel: int,
                   camera: Camera, max_levels=8, resolution: int = MULTIPLE_RESOLUTION,
                   should_cancel: Optional[Callable[[], bool]] = None,
                   g_last: Optional[float] = None,
                   beam: Optional[int] = None, threads: int = 0,
                   tuning: Tuning = Tuning()) -> MultipleField:
    """The light pyramid of ``light`` on medium ``pm`` from its precomputed field ``fld``
    (optical depth at ``channel``), see MultipleField, on a lattice of about ``resolution``
    points along the grid's longest side (never finer than the voxels): the source
    (``restricted_source``) spread level by level, each level losing what leaves through the
    medium's surface (boundary.py) and then moved along the light by the mean displacement
    of its paths (``drift_levels``), for the light that ``camera`` sees.  Raises
    cancel.Cancelled when ``should_cancel`` says so.  ``pm`` is the medium as the walk
    sees it: precompute hands the delta-scaled medium (media.delta_scaled) and the optical
    depth of its beam, and ``g_last`` the medium's own g, that of the last scattering
    towards the camera.
    ``threads``: for the first-scattering source (source.restricted_source) and the exact
    first flights' convolutions (firstflight.py).  ``tuning``:
    whether the levels are flattened (``flattens``) and the exact first flights made, and
    on what lattice (scene.Tuning)."""
    stride, shape, h = walk_lattice(pm, resolution)
    got = source_and_density(pm, fld, light, channel, stride, beam, should_cancel,
                             threads=threads)
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
    check(should_cancel)
    first = None
    flat = flattens(pm, camera, tuning)
    if flat and tuning.first_flights:
        # a mesh volume, whose levels the march sums once (precompute.flatten.flatten_levels): the first
        # flight exact where the first flights mostly leave the medium (firstflight.py)
        fine = fine_stride(pm, stride, tuning)
        sigma_t = np.asarray(pm.sigma_t, np.float64) * mean_rho
        if fine != stride and flight_weight(
                base.reshape(tuple(shape) + (3,)), (rho > 0).reshape(shape),
                stride * pm.i2w[:3, :3], light_direction(light, pts),
                g if g_last is None else float(g_last), sigma_t) is None:
            fine = stride   # the walk serves: no finer source for flights never made
        got = (base, rho, pts) if fine == stride else \
            source_and_density(pm, fld, light, channel, fine, beam, should_cancel,
                               threads=threads)
        fshape = lattice_shape(pm.grid.shape, fine)
        first = first_flight(got[0].reshape(tuple(fshape) + (3,)), (got[1] > 0).reshape(fshape),
                             fine * pm.i2w[:3, :3], light_direction(light, got[2]),
                             towards_camera(camera, got[2]),
                             g if g_last is None else float(g_last), sigma_t, sigma_s,
                             should_cancel, threads, tuning.exact_flights)
        check(should_cancel)
        if first is not None:
            first.stride = fine
    levels, directions = source_pyramid(base, light, pts, shape, g, max_levels, keep)
    check(should_cancel)
    drift_levels(levels, pm, light, camera, stride, h, sigma_s, directions, g_last)
    return MultipleField(stride, h, levels, first, flat)


def source_pyramid(base, light: Light, pts, shape, g: float, max_levels: int, keep=None):
    """(levels, directions): the pyramid (pyramid.build) of the source ``base`` ((N,3) W/m^3
    at the lattice points ``pts`` (N,3, m) of ``shape``) and, for a point or spot light in a
    medium with g != 0, the pyramid of the light's direction at each first scattering
    weighted by its power, and that power ((X,Y,Z,4) per level, blurred with the source:
    level k then holds the sums from which drift_levels takes the mean direction of the
    sources each point gathers); None for the others, whose direction is the same
    everywhere or does not drift.  ``keep``: pyramid.build's loss on the way (boundary.py),
    applied to the directions as to the light they travel with."""
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
    heading towards v came further along v (``walk.walk_displacement``).

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
    read = kernels.trilinear   # a float64 grid (the mean directions) reads on numpy
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
            mean = kernels.trilinear(coarser, idx / 2.0 + 1.0)
        else:
            mean = light_direction(light, x)
        power = sums[..., 3].reshape(-1)
        held = power > 1e-6 * max(float(power.max()), 1e-300)
        mean[held] = sums[..., :3].reshape(-1, 3)[held] / power[held, None]
        out[k] = mean.reshape(sums.shape[:3] + (3,))
    return out
