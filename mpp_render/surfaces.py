"""Opaque surfaces: ray intersection, shadow rays and Principled BSDF shading (no bpy).

Surfaces stop camera rays and light: the march ends where a camera ray hits one, and a point
whose path to a light crosses one is in shadow.  A surface point seen along ``w_v`` (towards
the viewer) leaves the radiance (W/(m^2 sr))

    L_o = emission + sum_lights f(w_v, w_l) cos(theta_l) E_l T_media,l V_l
          + albedo(w_v) L_world T_media,sky V_sky

with E_l the light's irradiance (W/m^2) on a plane facing it, theta_l the angle between the
normal (turned towards the viewer) and the direction w_l to the light, T_media the
transmittance through the media, V the surface visibility, and for the sky one
cosine-distributed direction per point whose visibility and transmittance stand for the
whole sky; along that direction a surface it hits adds its own light, reflected the same way
(``shade``'s ``bounces``; a render follows ``Tuning.surface_bounces``, 2).  There is no glass or transmission.

f is Cycles' Principled BSDF (principled.py).

Intersection is a Moller-Trumbore test against every triangle after a bounding-box cull per
64 triangles (kernels.intersect: compiled, or its numpy twin); it is
meant for the ground planes and props of smoke scenes (thousands of triangles), not for
million-triangle meshes.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, List

import numpy as np

from . import kernels
from .gathers import directions as gather_directions
from .principled import Principled
from .scene import Surface

EPS = 1e-6          # relative offset (m per m of scene extent) for shadow-ray origins

# per-surface parameters (scene.Surface fields) and their shapes
_SCALARS = ("specular", "roughness", "metallic", "coat_weight", "coat_roughness", "coat_ior",
            "diffuse_roughness", "multiscatter", "weight")
_COLOURS = ("base_color", "emission", "specular_tint", "coat_tint")


@dataclass
class SurfaceSet:
    """All surfaces' triangles flattened.  ``v0``, ``e1``, ``e2``: (M,3) float64 corner and
    edges; ``normal``: (M,3) unit geometric normals; ``surface``: (M,) index of each
    triangle's surface into ``params``, which holds one row per surface of every
    ``scene.Surface`` shading field (colours (S,3), the rest (S,)), sanitised as Cycles
    clamps them; ``scale``: the scene's extent (m)."""

    v0: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    normal: np.ndarray
    surface: np.ndarray
    params: Dict[str, np.ndarray]
    scale: float

    @property
    def empty(self) -> bool:
        return len(self.v0) == 0

    @property
    def triangles(self) -> np.ndarray:
        """float64 (M,9) each triangle's corner and two edges, as the kernels take them."""
        if getattr(self, "_triangles", None) is None:
            self._triangles = np.ascontiguousarray(
                np.concatenate([self.v0, self.e1, self.e2], axis=1), np.float64)
        return self._triangles


def _colour(v) -> np.ndarray:
    return np.broadcast_to(np.nan_to_num(np.asarray(v, np.float64), nan=0.0), (3,))


def _finite(v, default=0.0) -> float:
    v = float(v)
    return v if np.isfinite(v) else default


def surface_params(s: Surface) -> Dict[str, np.ndarray]:
    """One surface's shading inputs, clamped to the ranges Cycles' Principled node uses."""
    p = {
        "base_color": np.maximum(_colour(s.base_color), 0.0),
        "emission": np.maximum(_colour(s.emission), 0.0),
        "specular_tint": np.maximum(_colour(s.specular_tint), 0.0),
        "coat_tint": np.maximum(_colour(s.coat_tint), 0.0),
        "specular": np.clip(_finite(s.specular), 0.0, 1.0),
        "roughness": np.clip(_finite(s.roughness), 0.0, 1.0),
        "metallic": np.clip(_finite(s.metallic), 0.0, 1.0),
        "coat_weight": max(_finite(s.coat_weight), 0.0),
        "coat_roughness": np.clip(_finite(s.coat_roughness), 0.0, 1.0),
        "coat_ior": max(_finite(s.coat_ior, 1.5), 1.0),
        "diffuse_roughness": np.clip(_finite(s.diffuse_roughness), 0.0, 1.0),
        "multiscatter": 1.0 if s.multiscatter else 0.0,
        "weight": max(_finite(s.weight, 1.0), 0.0),
    }
    return {k: np.asarray(v, np.float64) for k, v in p.items()}


def prepare_surfaces(surfaces: List[Surface]) -> SurfaceSet:
    """Flatten surfaces into triangle arrays; degenerate (zero-area) triangles are dropped."""
    v0s, e1s, e2s, owner, rows = [], [], [], [], []
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
        v0s.append(a)
        e1s.append(e1)
        e2s.append(e2)
        owner.append(np.full(len(a), len(rows), np.int64))
        rows.append(surface_params(s))
    if not v0s:
        z = np.zeros((0, 3))
        params = {k: np.zeros((0, 3)) for k in _COLOURS}
        params.update({k: np.zeros(0) for k in _SCALARS})
        return SurfaceSet(z, z, z, z, np.zeros(0, np.int64), params, 1.0)
    v0 = np.concatenate(v0s)
    e1 = np.concatenate(e1s)
    e2 = np.concatenate(e2s)
    n = np.cross(e1, e2)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    pts = np.concatenate([v0, v0 + e1, v0 + e2])
    params = {k: np.stack([r[k] for r in rows]) for k in rows[0]}
    return SurfaceSet(v0, e1, e2, n, np.concatenate(owner), params,
                      float(max(np.max(pts.max(axis=0) - pts.min(axis=0)), 1e-3)))


def intersect(ss: SurfaceSet, o, d, tmax):
    """Closest hit of rays o + t d, t in (0, tmax).  Returns (t (N,), triangle (N,) int,
    -1 where nothing is hit; t = tmax there): kernels.intersect (compiled, without the GIL,
    or its numpy twin kernels_np.intersect_triangles)."""
    o = np.asarray(o, np.float64)
    n = len(o)
    t_max = np.array(np.broadcast_to(np.asarray(tmax, np.float64), (n,)))
    if ss.empty or n == 0:
        return t_max, np.full(n, -1, np.int64)
    return kernels.intersect(o, d, t_max, ss.triangles)


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


def sky_albedo(ss: SurfaceSet, tri, d) -> np.ndarray:
    """(N,3) the directional albedo of triangles ``tri`` hit by rays ``d`` (unit): the share
    of a uniform sky's radiance each reflects back along -d, every layer of its Principled
    BSDF (principled.Principled.albedo)."""
    tri = np.asarray(tri, np.int64)
    if len(tri) == 0:
        return np.zeros((0, 3))
    d = np.asarray(d, np.float64)
    bsdf = Principled({k: v[ss.surface[tri]] for k, v in ss.params.items()},
                      facing_normals(ss, tri, d), -d)
    # a degenerate triangle's normal reads nothing back (no NaN into the media's light)
    return np.clip(np.nan_to_num(bsdf.albedo(), nan=0.0, posinf=0.0, neginf=0.0), 0.0, 1.0)


SKY_ALBEDO_NODES = 16   # Gauss-Legendre nodes in the cosine of mean_sky_albedo's directions


def mean_sky_albedo(ss: SurfaceSet) -> np.ndarray:
    """(T,3) each triangle's ``sky_albedo`` averaged over the directions it reflects into,
    cosine-weighted (what a uniform sky's light off it is, as a share of that light's
    power): ``SKY_ALBEDO_NODES`` Gauss-Legendre nodes in the cosine, per surface."""
    n_surf = len(ss.params["weight"])
    x, w = np.polynomial.legendre.leggauss(SKY_ALBEDO_NODES)
    mu = 0.5 * (x + 1.0)
    weight = w * mu                      # 2 mu d mu over [0, 1], the nodes' half-width 1/2
    k = len(mu)
    prm = {key: np.repeat(v, k, axis=0) for key, v in ss.params.items()}
    normal = np.tile([0.0, 0.0, 1.0], (n_surf * k, 1))
    view = np.tile(np.stack([np.sqrt(1.0 - mu * mu), np.zeros(k), mu], axis=1), (n_surf, 1))
    a = np.clip(Principled(prm, normal, view).albedo(), 0.0, 1.0).reshape(n_surf, k, 3)
    per_surface = np.einsum("skc,k->sc", a, weight)
    return np.ascontiguousarray(per_surface[ss.surface], np.float64)


def shade(ss: SurfaceSet, tri, p, d, lights, world_color, media_optical_depth, rng,
          media_radiance=None, bounces: int = 1, gathers: int = 1, strata=None,
          guides=None, guided: float = 0.5, cached=None):
    """Outgoing radiance (N,3) W/(m^2 sr) of surface points ``p`` hit by rays ``d``.

    ``media_optical_depth(points, dirs, t_max)`` -> (N,3) optical depth through the media
    (the caller binds the prepared media); ``rng`` jitters area/sphere light points and the
    one cosine-weighted direction per point that gathers the sky and the volumes' light.
    ``media_radiance(points, dirs, t_max)`` -> ((N,3), (N,3)), when given, is the radiance the
    volumes scatter and emit towards ``points`` along ``dirs`` up to ``t_max`` (m; a march,
    bound by the caller) and the transmittance along the same segment: the light the smoke and
    fog around a surface throw onto it (single and multiple scattering and emission), and what
    the sky and the other surfaces seen along that direction are seen through (the march's
    own transmittance, an unbiased estimate of exp(-tau), instead of a second pass of
    ``media_optical_depth`` along the same ray).  With the cosine-weighted direction the
    estimate of its reflection is the layers' directional albedo x that radiance, unbiased
    over samples per pixel.

    ``bounces``: surface-to-surface bounces gathered along that same direction.  Where it
    hits a surface, that point's own light (``shade`` of it with ``bounces - 1`` and one
    gather, which reads ``media_radiance`` along its own direction as well) seen through the
    media is reflected the same way: a lit ground brightens the pillars that stand on it, and
    the fog's glow on that ground brightens them too, as Cycles' diffuse bounces do (they
    count no volume bounce, and the light a volume scatters once towards the last surface is
    direct light there, so both are in its single-scattering images).

    ``gathers``: cosine-weighted directions per point (their mean), stratified in the radial
    coordinate (``gathers`` equal bands of cos^2); the bounces' own points gather one.
    ``strata``: (band_r (N,) int, band_phi (N,) int, count) -- bands of r^2 and phi, each
    one of ``count``, given by the caller as two random permutations per pixel over its
    samples: a pixel's gathers are then a Latin hypercube over (r^2, phi) that shares out
    the hemisphere instead of drawing it independently, and each sample's band is uniform,
    so the estimate stays unbiased where only some of a pixel's samples hit the surface.
    The lights' emitter points (a lamp's disc, an area light) are drawn on the same bands,
    crossed (band_phi for the first number, band_r for the second): the direct light and the
    gathered light are separate terms of the sum, each drawn uniformly, so sharing the bands
    costs no bias, and a pixel's samples share out the emitter (its soft shadow's noise).
    ``guides`` (gathers.Guides): lamps inside the media, about which a share ``guided`` of
    the gathers that read ``media_radiance`` are drawn (gathers.directions, weighed by the
    balance heuristic); None: all cosine-weighted.

    ``cached``: ``(po, nrm, tri) -> (incident (N,3), ok (N,) bool)``, the frame's cache of
    the gathered light (surfacecache.SurfaceCache.lookup bound to the points' pixels): where
    ``ok`` its ``incident`` stands for the gathers (``gathered``), which only the others
    trace."""
    from .lights import is_dark, pack_light

    n_pts = len(p)
    nrm = facing_normals(ss, tri, d)
    po = offset_points(ss, p, nrm)
    bsdf = Principled({k: v[ss.surface[tri]] for k, v in ss.params.items()}, nrm, -d)
    out = bsdf.emission.copy()
    for light in lights:
        if is_dark(light):
            continue
        u = rng.random((n_pts, 2))
        if strata is not None:   # the pixel's samples share out the emitter, as the gathers
            u = on_bands(u, strata, crossed=True)
        # the emitter point drawn (a lamp's disc, an area light's solid angle) and its
        # distance: the shadow ray and its optical depth run to that point, not as far as
        # the centre along the drawn direction (in smoke round a lamp, or fog under a large
        # area light, the centre's distance leaves out or adds medium)
        wi, e, _, _, reach = kernels.light_sample(pack_light(light), po, u[:, 0], u[:, 1],
                                                     normal=nrm)
        to_l = -wi
        cos = np.einsum("ij,ij->i", nrm, to_l)
        lit = np.flatnonzero(cos > 0)
        if not lit.size:
            continue
        dist = reach[lit]
        vis = ~occluded(ss, po[lit], to_l[lit], dist)
        lit, dist = lit[vis], dist[vis]
        if not lit.size:
            continue
        tau = media_optical_depth(po[lit], to_l[lit], dist)
        out[lit] += bsdf.eval(to_l[lit], lit) * e[lit] * np.exp(-tau)
    wc = np.asarray(world_color, np.float64)
    if np.any(wc > 0) or media_radiance is not None or bounces > 0:
        albedo = bsdf.albedo()
        todo = np.arange(n_pts)
        if cached is not None:   # the frame's cache of the gathered light (surfacecache.py)
            incident, ok = cached(po, nrm, tri)
            out[ok] += albedo[ok] * incident[ok]
            todo = np.flatnonzero(~ok)
            if strata is not None:
                strata = (np.asarray(strata[0])[todo], np.asarray(strata[1])[todo], strata[2])
        if todo.size:
            out[todo] += albedo[todo] * gathered(
                ss, po[todo], nrm[todo], lights, wc, media_optical_depth, rng, media_radiance,
                bounces, gathers, strata, guides, guided)
    return out


def on_bands(u: np.ndarray, strata, crossed: bool = False) -> np.ndarray:
    """``u`` (N, ..., 2) numbers in [0, 1) moved onto each point's bands of ``strata``
    ((band_r (N,), band_phi (N,), count), ``shade``): number a on [b_a / count,
    (b_a + 1) / count); ``crossed``: band_phi for the first number, band_r for the second."""
    count = max(int(strata[2]), 1)
    bands = (strata[1], strata[0]) if crossed else (strata[0], strata[1])
    lead = (slice(None),) + (None,) * (u.ndim - 2)    # a point's bands over its other axes
    out = np.empty_like(u)
    for a in (0, 1):
        out[..., a] = (np.asarray(bands[a])[lead] + u[..., a]) / count
    return out


def gathered(ss: SurfaceSet, po, nrm, lights, world_color, media_optical_depth, rng,
             media_radiance=None, bounces: int = 1, gathers: int = 1, strata=None,
             guides=None, guided: float = 0.5):
    """The light that reaches points ``po`` (offset off their surfaces, (N,3) m) with
    normals ``nrm`` through ``gathers`` directions each (their balance-heuristic weights
    applied, gathers.directions): sum_k weight_k L_k (N,3) W/(m^2 sr), which times a
    layer's directional albedo is what it reflects (``shade``, whose other arguments these
    are).  It does not depend on the direction the point is seen from, so a cache may hold
    it (surfacecache.py)."""
    wc = np.asarray(world_color, np.float64)
    n_pts = len(po)
    k = max(int(gathers), 1)
    u = rng.random((n_pts, k, 2))
    if strata is not None:   # the pixel's samples share out (r^2, phi)
        u = on_bands(u, strata)
    if media_radiance is None or k * guided < 1.0:
        guides = None
    choose = rng.random((n_pts, k)) if guides is not None else None
    w, weight = gather_directions(nrm, po, u, k, guides, choose, guided)
    w, weight = w.reshape(-1, 3), weight.reshape(-1)
    pk = np.repeat(po, k, axis=0)
    # a guided direction below the surface gathers nothing: not traced
    live = np.flatnonzero(weight > 0.0)
    pk, w = pk[live], w[live]
    t_hit, tri_hit = intersect(ss, pk, w, np.full(len(pk), np.inf))
    acc = np.zeros((len(pk), 3))
    trans = None   # the transmittance along each gather, where the media's march gives it
    if media_radiance is not None:
        radiance, trans = media_radiance(pk, w, t_hit)
        acc += radiance

    def seen_through(idx, t_max):
        if trans is not None:
            return trans[idx]
        return np.exp(-media_optical_depth(pk[idx], w[idx], t_max))
    if bounces > 0:
        hit = np.flatnonzero(tri_hit >= 0)
        if hit.size:
            ph = pk[hit] + w[hit] * t_hit[hit, None]
            seen = shade(ss, tri_hit[hit], ph, w[hit], lights, wc,
                         media_optical_depth, rng, media_radiance, bounces - 1)
            acc[hit] += seen * seen_through(hit, t_hit[hit])
    if np.any(wc > 0):
        # the uniform sky seen through cosine-distributed directions (where no surface
        # hides it)
        sky = np.flatnonzero(~np.isfinite(t_hit))
        if sky.size:
            acc[sky] += wc * seen_through(sky, np.full(sky.size, np.inf))
    full = np.zeros((n_pts * k, 3))
    full[live] = acc * weight[live, None]
    return full.reshape(n_pts, k, 3).sum(axis=1)
