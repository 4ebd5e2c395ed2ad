"""Opaque surfaces: ray intersection, shadow rays and diffuse shading (no bpy).

Surfaces stop camera rays and light: the march ends where a camera ray hits one, and a point
whose path to a light crosses one is in shadow.  They are shaded as Lambertian reflectors of
their base colour (albedo, dimensionless) plus their emission (W/(m^2 sr)):

    L_o = emission + albedo / pi * sum_lights E_l cos(theta_l) T_media,l V_l
          + albedo * L_world * (mean transmittance of the sky over the cosine lobe)

with E_l the light's irradiance (W/m^2) on a plane facing it, theta_l the angle between the
surface normal (turned towards the viewer) and the direction to the light, T_media the
transmittance through the media and V_l the surface visibility.  There is no glossy, glass or
surface-to-surface light.

Intersection is a vectorised Moller-Trumbore test against every triangle of every surface,
after a per-surface bounding-box cull; it is meant for the ground planes and props of smoke
scenes (thousands of triangles), not for million-triangle meshes.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List

import numpy as np

from .scene import Surface

EPS = 1e-6          # relative offset (m per m of scene extent) for shadow-ray origins
RAY_CHUNK = 4096    # rays per block in the ray x triangle tests


@dataclass
class SurfaceSet:
    """All surfaces' triangles flattened.  ``v0``, ``e1``, ``e2``: (M,3) float64 corner and
    edges; ``normal``: (M,3) unit geometric normals; ``albedo``, ``emission``: (M,3) per
    triangle; ``boxes``: per surface (lo, hi, first, last) triangle ranges for culling."""

    v0: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    emission: np.ndarray
    boxes: list
    scale: float
    specular: np.ndarray = None
    roughness: np.ndarray = None

    @property
    def empty(self) -> bool:
        return len(self.v0) == 0


def prepare_surfaces(surfaces: List[Surface]) -> SurfaceSet:
    """Flatten surfaces into triangle arrays; degenerate (zero-area) triangles are dropped."""
    v0s, e1s, e2s, alb, emi, boxes, spec, rough = [], [], [], [], [], [], [], []
    first = 0
    for s in surfaces:
        v = np.asarray(s.vertices, np.float64).reshape(-1, 3)
        tri = np.asarray(s.triangles, np.int64).reshape(-1, 3)
        if len(tri) == 0 or len(v) == 0:
            continue
        tri = tri[np.all((tri >= 0) & (tri < len(v)), axis=1)]
        a, b, c = v[tri[:, 0]], v[tri[:, 1]], v[tri[:, 2]]
        e1, e2 = b - a, c - a
        area2 = np.linalg.norm(np.cross(e1, e2), axis=1)
        ok = np.isfinite(area2) & (area2 > 1e-20)
        a, e1, e2 = a[ok], e1[ok], e2[ok]
        if len(a) == 0:
            continue
        pts = np.concatenate([a, a + e1, a + e2])
        boxes.append((pts.min(axis=0), pts.max(axis=0), first, first + len(a)))
        first += len(a)
        v0s.append(a)
        e1s.append(e1)
        e2s.append(e2)
        alb.append(np.broadcast_to(np.clip(np.asarray(s.base_color, np.float64), 0, 1), (len(a), 3)))
        emi.append(np.broadcast_to(np.maximum(np.asarray(s.emission, np.float64), 0), (len(a), 3)))
        spec.append(np.full(len(a), float(np.clip(s.specular, 0.0, 1.0))))
        rough.append(np.full(len(a), float(np.clip(s.roughness, 0.0, 1.0))))
    if not v0s:
        z = np.zeros((0, 3))
        return SurfaceSet(z, z, z, z, z, z, [], 1.0, np.zeros(0), np.zeros(0))
    v0 = np.concatenate(v0s)
    e1 = np.concatenate(e1s)
    e2 = np.concatenate(e2s)
    n = np.cross(e1, e2)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    return SurfaceSet(v0, e1, e2, n, np.concatenate(alb), np.concatenate(emi), boxes,
                      float(max(np.max(hi - lo), 1e-3)), np.concatenate(spec), np.concatenate(rough))


def _box_hit(lo, hi, o, d, tmax):
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        ta = (lo - o) * inv
        tb = (hi - o) * inv
    t0 = np.nanmax(np.minimum(ta, tb), axis=1)
    t1 = np.nanmin(np.maximum(ta, tb), axis=1)
    return (t1 >= np.maximum(t0, 0.0)) & (t0 <= tmax)


def intersect(ss: SurfaceSet, o, d, tmax):
    """Closest hit of rays o + t d, t in (0, tmax].  Returns (t (N,), triangle (N,) int,
    -1 where nothing is hit; t = tmax there)."""
    o = np.asarray(o, np.float64)
    d = np.asarray(d, np.float64)
    n = len(o)
    t_best = np.array(np.broadcast_to(np.asarray(tmax, np.float64), (n,)))
    tri = np.full(n, -1, np.int64)
    if ss.empty or n == 0:
        return t_best, tri
    for lo, hi, a, b in ss.boxes:
        cand = np.flatnonzero(_box_hit(lo - 1e-9, hi + 1e-9, o, d, t_best))
        for c0 in range(0, len(cand), RAY_CHUNK):
            rays = cand[c0:c0 + RAY_CHUNK]
            oo, dd = o[rays], d[rays]
            for t0 in range(a, b, 256):
                sl = slice(t0, min(b, t0 + 256))
                e1, e2, v0 = ss.e1[sl], ss.e2[sl], ss.v0[sl]
                p = np.cross(dd[:, None, :], e2[None, :, :])            # (R,T,3)
                det = np.einsum("rtk,tk->rt", p, e1)
                ok = np.abs(det) > 1e-300
                inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
                s = oo[:, None, :] - v0[None, :, :]
                u = np.einsum("rtk,rtk->rt", s, p) * inv
                q = np.cross(s, e1[None, :, :])
                v = np.einsum("rk,rtk->rt", dd, q) * inv
                t = np.einsum("tk,rtk->rt", e2, q) * inv
                hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
                t = np.where(hit, t, np.inf)
                j = np.argmin(t, axis=1)
                tj = t[np.arange(len(rays)), j]
                better = tj < t_best[rays]
                t_best[rays[better]] = tj[better]
                tri[rays[better]] = t0 + j[better]
    return t_best, tri


def occluded(ss: SurfaceSet, o, d, tmax):
    """True where the segment o + t d, t in (0, tmax), crosses a surface."""
    if ss.empty:
        return np.zeros(len(o), bool)
    _, tri = intersect(ss, o, d, np.asarray(tmax, np.float64) * (1.0 - 1e-7))
    return tri >= 0


def offset_points(ss: SurfaceSet, p, normal):
    """Points nudged off the surface along ``normal`` so shadow rays do not hit their origin."""
    return p + normal * (EPS * ss.scale)


def facing_normals(ss: SurfaceSet, tri, d):
    """Unit normals of triangles ``tri`` turned against the ray directions ``d``."""
    n = ss.normal[tri]
    flip = np.einsum("ij,ij->i", n, d) > 0
    return np.where(flip[:, None], -n, n)


def shade(ss: SurfaceSet, tri, p, d, lights, world_color, media_optical_depth, rng):
    """Outgoing radiance (N,3) W/(m^2 sr) of surface points ``p`` hit by rays ``d``.

    ``media_optical_depth(points, dirs, t_max)`` -> (N,3) optical depth through the media
    (the caller binds the prepared media); ``rng`` jitters area/sphere light points and the
    one cosine-weighted sky direction per point."""
    from .lights import incident, is_dark, towards_light
    from .phase import orthonormal_basis

    n_pts = len(p)
    nrm = facing_normals(ss, tri, d)
    po = offset_points(ss, p, nrm)
    albedo = ss.albedo[tri]
    out = ss.emission[tri].copy()
    for light in lights:
        if is_dark(light):
            continue
        wi, e = incident(light, po, rng.random((n_pts, 2)))
        to_l = -wi
        cos = np.einsum("ij,ij->i", nrm, to_l)
        lit = np.flatnonzero(cos > 0)
        if not lit.size:
            continue
        dist = towards_light(light, po[lit])[1]
        vis = ~occluded(ss, po[lit], to_l[lit], dist)
        lit, dist = lit[vis], dist[vis]
        if not lit.size:
            continue
        tau = media_optical_depth(po[lit], to_l[lit], dist)
        brdf = dielectric_brdf(albedo[lit], ss.specular[tri[lit]], ss.roughness[tri[lit]],
                               nrm[lit], to_l[lit], -d[lit])
        out[lit] += brdf * e[lit] * cos[lit, None] * np.exp(-tau)
    wc = np.asarray(world_color, np.float64)
    if np.any(wc > 0):
        u = rng.random((n_pts, 2))
        r = np.sqrt(u[:, 0])
        phi = 2 * np.pi * u[:, 1]
        t1, t2 = orthonormal_basis(nrm)
        w = (t1 * (r * np.cos(phi))[:, None] + t2 * (r * np.sin(phi))[:, None]
             + nrm * np.sqrt(np.maximum(0.0, 1 - r * r))[:, None])
        vis = ~occluded(ss, po, w, np.full(n_pts, np.inf))
        tau = media_optical_depth(po, w, np.full(n_pts, np.inf))
        # a uniform sky seen by the diffuse base and reflected by the coat (its directional
        # albedo taken as Schlick's F at the viewing angle)
        cos_o = np.clip(-np.einsum("ij,ij->i", nrm, d), 0.0, 1.0)
        coat = np.where(ss.specular[tri] > 0, schlick(ss.specular[tri], cos_o), 0.0)
        out += (albedo + coat[:, None]) * wc * (np.exp(-tau) * vis[:, None])
    return out


def schlick(f0, cos):
    """Schlick's Fresnel reflectance for normal-incidence reflectance ``f0``."""
    return f0 + (1.0 - f0) * (1.0 - np.clip(cos, 0.0, 1.0)) ** 5


def dielectric_brdf(albedo, f0, roughness, n, wi, wo):
    """BRDF (1/sr, RGB (N,3)) of a diffuse base under a rough dielectric coat, the direct-light
    part of Blender's Principled BSDF as we approximate it: GGX specular (alpha =
    roughness^2, Smith shadowing, Schlick Fresnel with ``f0``) plus Lambertian ``albedo``
    (not reduced by the coat: measured closer to Cycles on smoke_plume's ground than the
    (1 - F) weighting).  ``wi`` towards the light, ``wo`` towards the viewer, ``n`` the normal
    on their side."""
    cos_i = np.clip(np.einsum("ij,ij->i", n, wi), 1e-6, 1.0)
    cos_o = np.clip(np.einsum("ij,ij->i", n, wo), 1e-6, 1.0)
    h = wi + wo
    h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
    a2 = np.maximum(roughness ** 4, 1e-8)
    nh = np.clip(np.einsum("ij,ij->i", n, h), 0.0, 1.0)
    dd = a2 / (np.pi * (nh * nh * (a2 - 1.0) + 1.0) ** 2)

    def g1(c):
        return 2.0 * c / (c + np.sqrt(a2 + (1.0 - a2) * c * c))

    f = np.where(f0 > 0, schlick(f0, np.einsum("ij,ij->i", wi, h)), 0.0)  # no coat: no gloss
    spec = dd * g1(cos_i) * g1(cos_o) * f / (4.0 * cos_i * cos_o)
    return albedo / np.pi + spec[:, None]
