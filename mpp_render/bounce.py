"""Light that flat diffuse surfaces reflect into the media (one bounce), as area lights.

A grey ground under a plume, lit by a point light, sends a good part of what it receives back
up into the smoke: in smoke_plume Cycles' indirect light in the volume holds that bounce, and
without it our Volume Multiple was 0.71 of Cycles' (docs/method.md, "Light from the ground").
Each flat surface near a medium is cut into ``tiles`` x ``tiles`` rectangles over the part
of it the media stand over; a rectangle becomes an AREA light (lights.py) facing the media,
of power

    P = R A <E>   (W, RGB),   radiance R <E> / pi   (W/(m^2 sr), Lambertian)

where R = base colour x (1 - metallic) is the surface's diffuse albedo, A the rectangle's
area (m^2) and <E> the irradiance the scene's lights bring onto it (W/m^2: cosine to the
normal, attenuated through the media, averaged over ``SUB`` x ``SUB`` points of the
rectangle, points off the mesh counting as dark).  The media then scatter the rectangle's
light like any area light's, once exactly in the march and multiply through its pyramid;
being light that has bounced, all of it lands in Volume Multiple (``Light.indirect``), as
Cycles counts it in Volume Indirect.

Left out: curved surfaces (no single plane to tile), the surfaces' shadows on each other,
specular reflection, light that reaches the surface only after scattering in the media, and
further bounces, and the world's volume (render.py makes no bounce lights under one: its grid
spans the whole view, and each rectangle would cost a light's precompute over all of it; a
ground under a lamp in fog, 64 x 48 pixels, took 10.3 s with them against 1.7 s without, for
3.6 % more light).  All lengths in metres, world space.
"""
from __future__ import annotations

from typing import List

import numpy as np

from . import kernels
from .lights import incident, is_dark
from .media import PreparedMedium
from .scene import Light, Surface
from .surfaces import intersect, prepare_surfaces

TILES = 2          # rectangles along each side of the region a surface lights
SUB = 6            # irradiance points along each side of a rectangle
FLAT_TOLERANCE = 1e-4  # largest distance of a vertex from the plane, over the mesh's size
DARK = 1e-6        # a rectangle below this fraction of the brightest one emits nothing
MAX_LIGHTS = 8     # the brightest rectangles of all surfaces kept (each costs a light's precompute)


EDGE_CANDIDATES = 64  # mesh edges tried as the direction of the rectangles' sides


def plane_of(surface: Surface):
    """(origin (3,), unit axes e1, e2 in the plane, unit normal n) of a flat mesh, or None
    when its vertices do not lie in one plane (within ``FLAT_TOLERANCE`` of its size).
    e1 runs along the mesh edge (of the first ``EDGE_CANDIDATES``) whose direction gives the
    vertices the smallest bounding rectangle, so that a square's rectangles follow its sides
    (the plane's principal axes are any pair when its spread is the same both ways)."""
    v = np.asarray(surface.vertices, np.float64).reshape(-1, 3)
    if len(v) < 3 or len(surface.triangles) == 0:
        return None
    o = v.mean(axis=0)
    _, sv, vt = np.linalg.svd(v - o, full_matrices=False)
    size = float(np.max(np.ptp(v, axis=0)))
    if not (size > 0.0) or sv[1] <= 0.0:
        return None
    n = vt[2]
    if np.max(np.abs((v - o) @ n)) > FLAT_TOLERANCE * size:
        return None
    tri = np.asarray(surface.triangles, np.int64).reshape(-1, 3)[:EDGE_CANDIDATES]
    edges = (v[np.roll(tri, -1, axis=1)] - v[tri]).reshape(-1, 3)
    edges = edges - np.outer(edges @ n, n)
    length = np.linalg.norm(edges, axis=1)
    e1 = vt[0]
    if np.any(length > 0.0):
        cand = np.vstack([e1[None], edges[length > 0.0] / length[length > 0.0, None]])
        rel = v - o
        areas = [np.ptp(rel @ a) * np.ptp(rel @ np.cross(n, a)) for a in cand]
        e1 = cand[int(np.argmin(np.round(areas, 12)))]
    return o, e1, np.cross(n, e1), n


def media_corners(media: List[PreparedMedium]) -> np.ndarray:
    """World corners (8M,3) of the media's grid boxes."""
    out = []
    for pm in media:
        n = np.array(pm.grid.shape, np.float64) - 1.0
        c = np.stack(np.meshgrid(*[[0.0, x] for x in n], indexing="ij"), -1).reshape(-1, 3)
        out.append(c @ pm.i2w[:3, :3].T + pm.i2w[:3, 3])
    return np.concatenate(out) if out else np.zeros((0, 3))


def surface_irradiance(media: List[PreparedMedium], lights: List[Light], pts, normal, step):
    """Irradiance (N,3, W/m^2) the ``lights`` bring onto the plane points ``pts`` (N,3) of
    unit ``normal``, through the media (optical depth marched with ``step`` m)."""
    from .precompute.lightdepth import light_optical_depth
    e = np.zeros((len(pts), 3))
    for light in lights:
        if is_dark(light):
            continue
        d, el = incident(light, pts, sample=kernels.light_sample)
        cos = np.clip(-(d @ normal), 0.0, None)
        lit = cos > 0.0
        if not np.any(lit) or not np.any(el[lit] > 0.0):
            continue
        tau = np.zeros((len(pts), 3))
        if media:
            tau[lit] = light_optical_depth(media, light, pts[lit], step)
        e += el * cos[:, None] * np.exp(-tau)
    return e


def bounce_lights(surfaces: List[Surface], lights: List[Light], media: List[PreparedMedium],
                  step: float, tiles: int = TILES) -> List[Light]:
    """AREA lights for the light the flat surfaces reflect into the media (module docstring):
    ``tiles`` x ``tiles`` per flat, non-black surface under or beside a medium, those that
    receive light, the ``MAX_LIGHTS`` brightest of them; [] without media or lights."""
    live = [l for l in lights if not is_dark(l)]
    corners = media_corners(media)
    if not live or not len(corners) or tiles < 1:
        return []
    centre = corners.mean(axis=0)
    out = []
    for surface in surfaces:
        albedo = np.clip(np.asarray(surface.base_color, np.float64).reshape(3), 0.0, 1.0) * \
            (1.0 - float(np.clip(surface.metallic, 0.0, 1.0)))
        plane = plane_of(surface)
        if plane is None or not np.any(albedo > 0.0) or np.any(np.asarray(surface.emission) > 0):
            continue
        o, e1, e2, n = plane
        if (centre - o) @ n < 0.0:  # the side the media stand on emits
            n, e2 = -n, -e2
        height = (corners - o) @ n
        if not np.any(height > 0.0):
            continue
        reach = float(np.max(height))
        mst = np.stack([(corners - o) @ e1, (corners - o) @ e2], 1)
        v = np.asarray(surface.vertices, np.float64).reshape(-1, 3)
        vst = np.stack([(v - o) @ e1, (v - o) @ e2], 1)
        lo = np.maximum(mst.min(0) - reach, vst.min(0))
        hi = np.minimum(mst.max(0) + reach, vst.max(0))
        if np.any(hi <= lo):
            continue
        size = (hi - lo) / tiles
        sub = ((np.arange(SUB) + 0.5) / SUB)
        grid = np.stack(np.meshgrid(sub, sub, indexing="ij"), -1).reshape(-1, 2)
        tiles_st = [(i, j) for i in range(tiles) for j in range(tiles)]
        st = np.concatenate([lo + (np.array(ij) + grid) * size for ij in tiles_st])
        lift = 1e-3 * max(reach, 1.0)  # off the surface, so that its own mesh does not shadow it
        pts = o + st[:, :1] * e1 + st[:, 1:] * e2 + lift * n
        # on the mesh where a ray straight down from the lifted point meets it
        _, hit = intersect(prepare_surfaces([surface]), pts, np.broadcast_to(-n, pts.shape),
                           np.full(len(pts), 2.0 * lift))
        on = hit >= 0
        e = np.zeros((len(st), 3))
        if np.any(on):
            e[on] = surface_irradiance(media, live, pts[on], n, step)
        power = albedo * e.reshape(len(tiles_st), SUB * SUB, 3).mean(axis=1) * float(np.prod(size))
        top = float(power.max()) if power.size else 0.0
        for (i, j), p in zip(tiles_st, power):
            if not (top > 0.0) or p.max() <= DARK * top:
                continue
            c = o + (lo[0] + (i + 0.5) * size[0]) * e1 + (lo[1] + (j + 0.5) * size[1]) * e2 + lift * n
            m = np.eye(4)
            m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = e1 * size[0], e2 * size[1], -n, c
            out.append(Light("AREA", f"{surface.name} (bounce {i},{j})", p, position=c.copy(),
                             direction=n.copy(), matrix=m, shape="RECTANGLE", size_x=1.0,
                             size_y=1.0, normalize=True, indirect=True))
    out.sort(key=lambda l: -float(np.sum(l.strength)))
    return out[:MAX_LIGHTS]
