"""Where light paths start besides the lattice's first scatterings (precompute.lightpaths):

* **The world fog beyond its grid** (``fog_starts``).  The fog fills all space, but its grid
  only covers what the camera sees; light that first scatters beside or behind it still
  reaches the fog in view.  Points are drawn round the light: a direction uniform over the
  light's sphere (a spot's cone, an area light's hemisphere), a distance r with density
  sigma e^(-sigma r) (sigma the smallest extinction), so a point's probability density is
  p(x) = sigma e^(-sigma r) / (Omega r^2) (Omega the solid angle sampled).  Those inside the
  grid's data (where the lattice's own source is) are dropped.  Each kept point carries the
  power Q(x) / (p(x) M) (W, M the points drawn) with Q = sigma_s E e^(-tau) the
  first-scattering source (W/m^3): E the light's irradiance, tau its optical depth through
  the fog, the other media and the surfaces' shadows (lightdepth.light_optical_depth).
* **Lit surfaces** (``surface_starts``).  A surface sends back R E cos(theta) of the light it
  receives (W/m^2; R its directional albedo towards the light, every layer of its Principled
  BSDF, surfaces.sky_albedo: the specular's Fresnel too), taken as a cosine lobe about its
  normal on the lit side (the paths then bounce off surfaces with their diffuse albedo).
  Points are drawn over the triangles within ``SURFACE_REACH`` bounding radii of a bounded
  medium, denser near it as the light it gets from them falls (``surface_points``), and
  uniformly within a world fog's reach; each carries power R E cos(theta) e^(-tau) w (W),
  w the area it stands for (m^2).

Both return (points (N,3) m, power (N,3) W, directions (N,3) unit): the light's propagation
for fog points, the lit side's normal for surface points.  All lengths in metres.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional

import numpy as np

from ..lights import disc_transmittance, extent_radius, incident
from ..scene import Light
from .. import kernels
from ..media import disc_reaches
from ..surfaces import mean_sky_albedo, sky_albedo
from ..phase import orthonormal_basis
from .lightdepth import kernel_arrays, light_optical_depth, light_position
from .source import light_direction

FOG_POINTS = 16384       # first scatterings drawn round a light in the fog, per light
SURFACE_POINTS = 16384   # points drawn on the surfaces within reach, per light
# How far from a bounded medium (in its bounding sphere's radii) the surfaces' light that
# reaches it is drawn (surface_points' 1/d^3 density about it): from a surface of uniform
# irradiance the light arriving from beyond distance R falls as r0 / R, so 64 leaves out at
# most about 1.6 % of it (docs/method.md §8)
SURFACE_REACH = 64.0
# The same for a surface's share of the sky's deficit (sky_ground_starts), whose paths are
# aimed at the medium (paths.py, lobe 3): its light from beyond R falls as r0 / R too, and
# with the points' 1/d^3 density the reach costs few of them (beyond 64 radii about 1.5 %)
GROUND_REACH = 1024.0
REACH_MFP = 10.0         # a path in the fog this many mean free paths beyond the grid ends
LIFT = 1e-6              # surface points are lifted this fraction of the scene's size


@dataclass
class Surroundings:
    """What lies round the medium whose paths are traced: ``solid`` the media other than the
    world fog (prepared; they attenuate the light), ``fog_sigma_t`` the fog's RGB extinction
    (1/m, None without one), ``surfaces`` a surfaces.SurfaceSet or None (an empty set becomes
    None), ``step`` the march
    step (m) of the light's optical depth, ``bounce`` whether the surfaces reflect light
    (Settings.surface_bounce; else they only absorb it), ``disc_exact`` the lamp radii (an
    area light's half-diagonals) within which a lamp's disc points or an area light's emitter
    points get their own optical depth (Tuning.disc_exact,
    lights.disc_transmittance; 0: off), at least ``disc_voxels`` of the finest voxel
    (Tuning.disc_voxels; media.disc_reaches)."""

    solid: List
    fog_sigma_t: Optional[np.ndarray]
    surfaces: object
    step: float
    bounce: bool = True
    disc_exact: float = 0.0
    disc_voxels: float = 0.0

    def __post_init__(self):
        if self.surfaces is not None and self.surfaces.empty:
            self.surfaces = None
        self._enclosed = {}
        self._disc_depth = {}
        self._camera_depth = {}

    def enclosed(self, pm) -> Optional[np.ndarray]:
        """bool (X,Y,Z) the voxels of prepared medium ``pm`` behind the surfaces
        (enclosed.enclosed_voxels), made once per medium; None without surfaces."""
        if self.surfaces is None:
            return None
        if id(pm) not in self._enclosed:
            from .enclosed import enclosed_voxels
            self._enclosed[id(pm)] = enclosed_voxels(pm, self.surfaces)
        return self._enclosed[id(pm)]

    def skip_disc(self, light: Light) -> None:
        """``light``'s disc (emitter) points take the stretched centre's depth alone in
        ``disc``: its fold found no medium uneven across it (discdepth.disc_changes)."""
        self._disc_depth[id(light)] = (None, 0.0)

    def disc(self, light: Light, x, tau, change=None) -> np.ndarray:
        """lights.disc_transmittance of ``light`` at points ``x`` (N,3, m) from the optical
        depth ``tau`` (N,3) to its centre, the disc (emitter) points within
        media.disc_reaches of the lamp marched through the solid media (the world fog,
        homogeneous, needs no correction); beyond, ``change`` (N,3, the field's disc
        channels) or None."""
        if id(light) not in self._disc_depth:   # asked once per chunk of voxels: decide once
            reach = disc_reaches(self.solid, [light], self.disc_exact, self.disc_voxels)[0]
            radius = extent_radius(light)
            self._disc_depth[id(light)] = (self.solid_depth(), reach / radius) \
                if reach and radius > 0.0 else (None, 0.0)
        depth, radii = self._disc_depth[id(light)]
        return disc_transmittance(light, x, tau, self.step, depth=depth, reach=radii,
                                  change=change, transmit=kernels.emitter_transmittance)

    def camera_depth(self, key, make):
        """The optical depth to the camera of a path lattice's points (lightpaths.lattice_depth)
        under ``key`` (the medium, the lattice's shape and stride, the eye), made once by
        ``make()``: the lights' lobe fits and roulettes and the sky deficit's on the same
        lattice share it.
        Callers must not modify it."""
        if key not in self._camera_depth:
            self._camera_depth[key] = make()
        return self._camera_depth[key]

    def optical_depth(self, light: Light, x) -> np.ndarray:
        """(N,3) optical depth from points ``x`` (N,3, m) to ``light``'s centre as the
        light's sweep gives a voxel's: through the solid media, the world fog and the
        surfaces' shadows (lightdepth.light_optical_depth at ``step``)."""
        return light_optical_depth(self.solid, light, x, self.step, surfaces=self.surfaces,
                                   fog_sigma_t=self.fog_sigma_t)

    def solid_depth(self):
        """Callable (points, unit dirs, lengths m) -> (N,3) optical depth through the solid
        media (kernels.optical_depth at ``step``); there must be some."""
        arrays = kernel_arrays(self.solid)

        def od(p, d, t):
            return kernels.optical_depth(p, d, t, *arrays, float(self.step), 0.5, clip=True)
        return od


def reach(pm, grid=None) -> tuple:
    """(centre (3,) m, radius m) of the sphere within which paths of medium ``pm`` may return
    to its grid (or ``grid``: (w2i (3,4), shape) of another grid the paths deposit on): for
    the world fog the grid's half-diagonal plus ``REACH_MFP`` mean free paths, for another
    medium twice its grid's half-diagonal (surfaces within it send light in)."""
    w2i, shape = (pm.w2i, pm.grid.shape) if grid is None else grid
    m = np.linalg.inv(np.vstack([np.asarray(w2i, np.float64), [0.0, 0.0, 0.0, 1.0]]))
    n = np.array(shape, np.float64) - 1.0
    corners = np.stack(np.meshgrid(*[[0.0, x] for x in n], indexing="ij"), -1).reshape(-1, 3)
    world = corners @ m[:3, :3].T + m[:3, 3]
    centre = world.mean(axis=0)
    half = float(np.max(np.linalg.norm(world - centre, axis=1)))
    if pm.endless:
        st = np.asarray(pm.sigma_t, np.float64)
        return centre, half + REACH_MFP / float(st[st > 0].min())
    return centre, 2.0 * half


def surface_reach(pm, radii: float = SURFACE_REACH) -> tuple:
    """(centre (3,) m, radius m, scale r0 m or None) of the sphere within which the surfaces'
    light that reaches medium ``pm`` is drawn (surface_points): a bounded medium's
    ``radii`` bounding radii, its points denser near it (r0 its bounding radius); a
    world fog's ``reach``, its points uniform (its paths end beyond it)."""
    centre, radius = reach(pm)
    if pm.endless:
        return centre, radius, None
    scale = 0.5 * radius
    return centre, float(radii) * scale, scale


def _cone(light: Light):
    """(axis (3,), cos of the half-angle) of the directions a light sends light into."""
    if light.kind == "SPOT":
        axis = np.asarray(light.direction, np.float64)
        half = min(0.5 * float(light.spot_size) * 1.05 + 1e-3, np.pi)
        return axis / np.linalg.norm(axis), float(np.cos(half))
    if light.kind == "AREA":
        axis = np.asarray(light.direction, np.float64)
        return axis / np.linalg.norm(axis), 0.0
    return np.array([0.0, 0.0, 1.0]), -1.0


def fog_starts(pm, light: Light, around: Surroundings, seed: int):
    """First scatterings of ``light`` in the world fog ``pm`` beyond its grid (module
    docstring), or None when none carries light (a sun: the fog has put it out)."""
    if light.kind == "SUN":
        return None
    st = np.asarray(pm.sigma_t, np.float64)
    sig = float(st[st > 0].min())
    rng = np.random.default_rng(seed)
    u = rng.random((FOG_POINTS, 3))
    axis, cmin = _cone(light)
    c = 1.0 - u[:, 0] * (1.0 - cmin)
    s = np.sqrt(np.maximum(0.0, 1.0 - c * c))
    phi = 2.0 * np.pi * u[:, 1]
    t1, t2 = orthonormal_basis(axis[None, :])
    d = t1 * (s * np.cos(phi))[:, None] + t2 * (s * np.sin(phi))[:, None] + axis * c[:, None]
    r = -np.log1p(-u[:, 2]) / sig
    x = light_position(light) + d * r[:, None]
    idx = pm.to_index(x)
    inside = np.all((idx >= 0.5) & (idx <= np.array(pm.grid.shape) - 1.5), axis=1)
    keep = ~inside & (r > 0.0)
    if not np.any(keep):
        return None
    x, r = x[keep], r[keep]
    _, e = incident(light, x, sample=kernels.light_sample)
    tau = light_optical_depth(around.solid, light, x, around.step, surfaces=around.surfaces,
                              fog_sigma_t=st)
    q = np.asarray(pm.sigma_s, np.float64) * e * around.disc(light, x, tau)
    omega = 2.0 * np.pi * (1.0 - cmin)
    pdf = sig * np.exp(-sig * r) / (omega * r * r)
    power = q / (pdf * FOG_POINTS)[:, None]
    live = np.all(np.isfinite(power), axis=1) & (power.sum(axis=1) > 0.0)
    if not np.any(live):
        return None
    return x[live], power[live], light_direction(light, x[live])


def surface_albedo(ss) -> np.ndarray:
    """(T,3) diffuse albedo of every triangle of SurfaceSet ``ss``: base colour clipped to
    [0, 1] x (1 - metallic)."""
    p = ss.params
    base = np.clip(p["base_color"], 0.0, 1.0) * (1.0 - np.clip(p["metallic"], 0.0, 1.0))[:, None]
    return np.ascontiguousarray(base[ss.surface], np.float64)


def surface_points(ss, centre, radius: float, m: int, rng, albedo_min: float = -1.0,
                   scale: Optional[float] = None):
    """(points (N,3) m, triangles (N,) int, weights (N,) m^2): about ``m`` points on the parts
    of the SurfaceSet ``ss``'s triangles inside the sphere (``centre``, ``radius``), each
    standing for ``weight`` of their area (the estimate of the integral of f over those
    parts is the sum of weight x f over the points).  Triangles whose largest diffuse albedo
    is not above ``albedo_min`` (surface_albedo) are left out; None where nothing remains.

    ``scale`` None (or not above 0): the points spread uniformly, all of the same weight.  A
    triangle smaller than the disc the sphere cuts from its plane is drawn over whole, else
    that disc is, and the draws outside the triangle or the sphere are dropped: a ground far
    wider than the sphere gets its points where the sphere is, not over all of it.

    ``scale`` r0 (m): the points' density per area follows g(d) = (r0^2 / (r0^2 + d^2))^(3/2),
    d their distance from ``centre``: the light a diffuse surface sends into a medium of
    radius about r0 from distance d falls as 1/d^3 per area (its solid angle 1/d^2 times the
    grazing cosine, about the height over d), so each point's share of that light stays
    about the same however far the sphere reaches.  The triangles are cut in four (at their
    sides' midpoints) until each piece's longest side is under ``PIECE_SIDE`` sqrt(r0^2 +
    d^2), d at its centroid (so g changes little across it), or ``PIECES_MOST`` pieces;
    a piece is picked by its area times g at its centroid and drawn over uniformly, and a
    point's weight is one over m times its density there: the estimate stays unbiased."""
    centre = np.asarray(centre, np.float64)
    corners = np.stack([ss.v0, ss.v0 + ss.e1, ss.v0 + ss.e2], axis=1)
    lo, hi = corners.min(axis=1), corners.max(axis=1)
    gap = np.linalg.norm(np.maximum(np.maximum(lo - centre, centre - hi), 0.0), axis=1)
    dist = np.einsum("ij,ij->i", centre[None, :] - ss.v0, ss.normal)   # to the plane
    cand = np.flatnonzero((gap <= radius) & (np.abs(dist) < radius) &
                          (surface_albedo(ss).max(axis=1) > albedo_min))
    if not cand.size:
        return None
    if scale is not None and float(scale) > 0.0:
        return _points_about(corners[cand], cand, centre, radius, m, rng, float(scale))
    area = 0.5 * np.linalg.norm(np.cross(ss.e1[cand], ss.e2[cand]), axis=1)
    disc_r = np.sqrt(np.maximum(radius * radius - dist[cand] ** 2, 0.0))
    disc = np.pi * disc_r ** 2
    whole = area <= disc
    domain = np.where(whole, area, disc)
    total = float(domain.sum())
    if not (total > 0.0):
        return None
    pick = np.minimum(np.searchsorted(np.cumsum(domain) / total, rng.random(m), side="right"),
                      len(cand) - 1)
    tri = cand[pick]
    a, b = rng.random(m), rng.random(m)
    flip = a + b > 1.0
    a, b = np.where(flip, 1.0 - a, a), np.where(flip, 1.0 - b, b)
    p = ss.v0[tri] + a[:, None] * ss.e1[tri] + b[:, None] * ss.e2[tri]
    big = ~whole[pick]
    if np.any(big):      # uniform in the plane's disc, kept where inside the triangle
        nb = ss.normal[tri[big]]
        t1, t2 = orthonormal_basis(nb)
        r = disc_r[pick[big]] * np.sqrt(rng.random(int(big.sum())))
        phi = 2.0 * np.pi * rng.random(int(big.sum()))
        q = (centre - dist[tri[big]][:, None] * nb) + \
            t1 * (r * np.cos(phi))[:, None] + t2 * (r * np.sin(phi))[:, None]
        p[big] = q
    rel = p - ss.v0[tri]
    e1, e2 = ss.e1[tri], ss.e2[tri]
    d11, d12, d22 = (np.einsum("ij,ij->i", x, y) for x, y in ((e1, e1), (e1, e2), (e2, e2)))
    r1, r2 = np.einsum("ij,ij->i", rel, e1), np.einsum("ij,ij->i", rel, e2)
    det = d11 * d22 - d12 * d12
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (d22 * r1 - d12 * r2) / det
        v = (d11 * r2 - d12 * r1) / det
    inside = (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0)
    keep = (inside | ~big) & (np.linalg.norm(p - centre, axis=1) <= radius)
    if not np.any(keep):
        return None
    # each draw stands for total / m of the domains (their expected share; a triangle's
    # realised count would lose the small triangles that no draw falls on)
    return p[keep], tri[keep], np.full(int(keep.sum()), total / m)


PIECE_SIDE = 0.5         # surface_points: a piece's longest side over sqrt(r0^2 + d^2)
PIECES_MOST = 1 << 17    # ... and the pieces cut at most


def _points_about(corners, tri, centre, radius: float, m: int, rng, r0: float):
    """surface_points with ``scale`` r0: ``corners`` (T,3,3) of the triangles ``tri``."""
    while True:   # cut the pieces across which g changes too much, in four
        mid = corners.mean(axis=1)
        d_mid = np.linalg.norm(mid - centre, axis=1)
        side = np.max(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2), axis=1)
        near = np.linalg.norm(np.maximum(np.maximum(corners.min(axis=1) - centre,
                                                    centre - corners.max(axis=1)), 0.0),
                              axis=1) <= radius
        corners, tri, mid, d_mid, side = (x[near] for x in (corners, tri, mid, d_mid, side))
        cut = side > PIECE_SIDE * np.sqrt(r0 * r0 + d_mid ** 2)
        if not np.any(cut) or len(tri) + 3 * int(cut.sum()) > PIECES_MOST:
            break
        c = corners[cut]
        m01, m12, m20 = (0.5 * (c[:, i] + c[:, (i + 1) % 3]) for i in range(3))
        kids = np.concatenate([np.stack(x, axis=1) for x in
                               ((c[:, 0], m01, m20), (m01, c[:, 1], m12),
                                (m20, m12, c[:, 2]), (m01, m12, m20))])
        corners = np.concatenate([corners[~cut], kids])
        tri = np.concatenate([tri[~cut], np.tile(tri[cut], 4)])
    if not len(tri):
        return None
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    g = _falloff(d_mid, r0)
    mass = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1) * g
    total = float(mass.sum())
    if not (total > 0.0):
        return None
    pick = np.minimum(np.searchsorted(np.cumsum(mass) / total, rng.random(m), side="right"),
                      len(tri) - 1)
    a, b = rng.random(m), rng.random(m)
    flip = a + b > 1.0
    a, b = np.where(flip, 1.0 - a, a), np.where(flip, 1.0 - b, b)
    p = corners[pick, 0] + a[:, None] * e1[pick] + b[:, None] * e2[pick]
    keep = np.linalg.norm(p - centre, axis=1) <= radius
    if not np.any(keep):
        return None
    # a point's density per area is g(piece) / total over m draws
    return p[keep], tri[pick[keep]], total / (m * g[pick[keep]])


def _falloff(d, r0: float) -> np.ndarray:
    """g(d) = (r0^2 / (r0^2 + d^2))^(3/2) (surface_points), 1 at d = 0."""
    d = np.asarray(d, np.float64)
    return (r0 * r0 / (r0 * r0 + d * d)) ** 1.5


def ground_albedo(around: Surroundings) -> Optional[np.ndarray]:
    """(T,3) the share R of a uniform sky's light each triangle of ``around``'s surfaces
    reflects (surfaces.mean_sky_albedo: every layer of its BSDF, cosine-weighted over the
    directions; 0 where the surfaces do not bounce light), or None without surfaces."""
    ss = around.surfaces
    if ss is None:
        return None
    if not around.bounce:
        return np.zeros((len(ss.v0), 3))
    return mean_sky_albedo(ss)


def sky_ground_starts(pm, around: Surroundings, seed: int, sky):
    """(points, power, normals, jitter m) of the surfaces as the sky's deficit sees them
    (precompute/skydeficit.py, docs/method.md §9.8): in the furnace every surface round the
    medium sends the sky's radiance L_w back, as the sky would have from behind it; a surface
    that reflects the share R of a uniform sky (``ground_albedo``) sends R L_w, so it falls
    short by (1 - R) L_w, a fictitious emission of pi (1 - R) L_w w (W) a point (w its area,
    m^2), in a cosine lobe from the side that faces the medium (every triangle whatever its
    albedo; R is taken as the same in every direction here), drawn as ``surface_points``
    draws them within ``GROUND_REACH`` bounding radii.  Its first
    flight is the surface's light along the directions it hides, taken in closed form
    (worldlight.world_light); its later flights are traced and taken off the sky's multiply
    scattered light.  ``sky``: the sky's RGB radiance L_w (W/(m^2 sr)).
    None without a sky or surfaces, or where every surface is white."""
    ss = around.surfaces
    if ss is None or sky is None or pm.endless:
        return None
    sky = np.asarray(sky, np.float64).reshape(3)
    if not np.any(sky > 0.0):
        return None
    centre, radius, scale = surface_reach(pm, GROUND_REACH)
    rng = np.random.default_rng([seed, 6151])
    got = surface_points(ss, centre, radius, SURFACE_POINTS, rng, scale=scale)
    if got is None:
        return None
    p, pick, share = got
    n = ss.normal[pick]     # the side that faces the medium's centre
    n = np.where((np.einsum("ij,ij->i", centre[None, :] - p, n) < 0.0)[:, None], -n, n)
    p = p + n * (LIFT * ss.scale)
    power = np.pi * (1.0 - ground_albedo(around)[pick]) * sky[None, :] * share[:, None]
    live = np.all(np.isfinite(power), axis=1) & (power.sum(axis=1) > 0.0)
    if not np.any(live):
        return None
    return p[live], power[live], n[live], float(np.sqrt(share.min()))


def surface_starts(pm, light: Light, around: Surroundings, seed: int):
    """(points, power, normals, jitter m) of the light ``light`` reflects off the surfaces
    within ``SURFACE_REACH`` bounding radii of a bounded medium, denser near it, or within a
    world fog's ``reach(pm)`` (module docstring; the points: ``surface_points``), or None when
    they reflect none."""
    ss = around.surfaces
    if ss is None or not around.bounce:
        return None
    centre, radius, scale = surface_reach(pm)
    rng = np.random.default_rng(seed)
    got = surface_points(ss, centre, radius, SURFACE_POINTS, rng, scale=scale)
    if got is None:
        return None
    p, pick, share = got
    d, e = incident(light, p, sample=kernels.light_sample)
    n = ss.normal[pick]
    cos = -np.einsum("ij,ij->i", d, n)
    n = np.where((cos < 0.0)[:, None], -n, n)          # the lit side
    lit = (np.abs(cos) > 0.0) & (e.max(axis=1) > 0.0)
    if not np.any(lit):
        return None
    p = p[lit] + n[lit] * (LIFT * ss.scale)
    tau = light_optical_depth(around.solid, light, p, around.step, surfaces=ss,
                              fog_sigma_t=around.fog_sigma_t)
    # the share of the light from d that the surface reflects: every layer of its BSDF
    # (the directional albedo towards the light, surfaces.sky_albedo; by reciprocity)
    power = sky_albedo(ss, pick[lit], d[lit]) * e[lit] * np.abs(cos[lit])[:, None] * \
        around.disc(light, p, tau) * share[lit, None]
    live = np.all(np.isfinite(power), axis=1) & (power.sum(axis=1) > 0.0)
    if not np.any(live):
        return None
    # the starts' tent: the points' spacing where they lie closest (by the medium)
    return p[live], power[live], n[lit][live], float(np.sqrt(share.min()))
