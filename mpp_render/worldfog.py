"""Cycles' world volume: a homogeneous fog that fills all space, bounded for the march.

Cycles treats the world's Volume shader as an infinite homogeneous medium (checked with
Cycles renders, see docs/usage.md): a ray that hits nothing crosses infinitely much of it,
so in every colour channel where its extinction sigma_t > 0 the background is black, a sun
(infinitely far) lights nothing, and the fog is integrated to infinity whatever the
camera's clip end.  Here (``World.volume``, a Medium with source 'WORLD'):

* *Attenuation of lights* by the fog is analytic everywhere: sigma_t x the distance to the
  light (``optical_depth``), added to what the other media and surfaces contribute; suns and
  the background are zeroed in the fog's channels (``effective_world``, ``effective_lights``).
* *The march* needs the fog as a voxel grid (its field holds the per-light optical depth
  with the shadows of surfaces and other media: the volumetric shadows, "god rays").  The
  grid (``bounded_medium``) is a box aligned with the camera covering the view frustum from
  the near clip to a depth D = min(D_view, D_content): D_view is where the camera's
  transmittance through the fog alone falls to e^-TAU_VIEW (9e-4), D_content is
  CONTENT_MARGIN x the depth of the farthest content that lights the fog or sits in it (the
  lights in front of the camera, the boxes of the other media seen by a grid of probe rays;
  not surfaces, which can reach far from any light).  Its voxels are cubes,
  ``voxel_resolution`` of them along the longest side.  Only camera rays march the grid, so
  fog outside the frustum needs no voxels.
* *Beyond the box* (``tail``): a camera ray leaving the box continues through homogeneous fog
  to its surface hit or to infinity.  That stretch is integrated semi-analytically: the
  emission exactly, e (1 - e^(-sigma_t L)) / sigma_t, and the single scattering of every
  point, spot and area light by TAIL_NODES-point Gauss-Legendre quadrature in the fog's
  transmittance,
  with each light's irradiance, phase function and attenuation exp(-sigma_t r) through the
  fog alone: shadows of surfaces and other media beyond the box are not traced there.  The
  background behind it is attenuated by exp(-sigma_t L) (0 for L = infinity).  Measured on
  the god-ray scene of tests/blender/test_world_volume.py: docs/usage.md.

The box's padding (media.prepare) ramps the density from 1 to 0 over one voxel beyond the
data; the tail starts halfway through that ramp, which puts back the half voxel of fog the
ramp leaves out.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import List, Optional

import numpy as np

from .camera import primary_rays
from .lights import pack_light
from .phase import hg
from .scene import Light, Medium, SceneDescription, World

TAU_VIEW = 7.0          # camera optical depth through the fog where the grid may end
CONTENT_MARGIN = 1.25   # the grid reaches this factor beyond the farthest content seen
PROBES = 17             # probe rays per image side that find the content's depth
MARGIN_VOXELS = 2.0     # voxels of fog kept beyond the frustum on every side
TAIL_NODES = 16         # Gauss-Legendre points of the single-scattering tail per ray
FOG_TAU_MAX = 50.0      # optical depth standing for "infinitely far" (a sun): T = 2e-22


def active(world: World) -> Optional[Medium]:
    """The world's fog when it does anything (extinction or emission > 0), else None."""
    fog = world.volume
    if fog is None:
        return None
    st = np.asarray(fog.sigma_s, np.float64) + np.asarray(fog.sigma_a, np.float64)
    if np.any(st > 0) or np.any(np.asarray(fog.emission, np.float64) > 0):
        return fog
    return None


def clear_channels(fog: Medium) -> np.ndarray:
    """1.0 in the colour channels where the fog has no extinction, 0.0 where it has."""
    st = np.asarray(fog.sigma_s, np.float64) + np.asarray(fog.sigma_a, np.float64)
    return (st <= 0).astype(np.float64)


def effective_world(world: World, fog: Medium) -> World:
    """The background seen through infinite fog: zero in the fog's channels."""
    return World(color=np.asarray(world.color, np.float64) * clear_channels(fog), volume=world.volume)


def effective_lights(lights: List[Light], fog: Medium) -> List[Light]:
    """``lights`` with every sun's strength zeroed in the fog's channels (a sun is infinitely
    far behind the fog); the other lights unchanged (same objects)."""
    keep = clear_channels(fog)
    out = []
    for light in lights:
        if light.kind == "SUN":
            light = dataclasses.replace(light, strength=np.asarray(light.strength, np.float64) * keep)
        out.append(light)
    return out


def optical_depth(sigma_t, distance) -> np.ndarray:
    """RGB optical depth (N,3) of the fog over ``distance`` (N,) metres (inf allowed):
    sigma_t x distance, capped at FOG_TAU_MAX; 0 in channels without extinction."""
    st = np.asarray(sigma_t, np.float64).reshape(1, 3)
    dist = np.asarray(distance, np.float64).reshape(-1, 1)
    with np.errstate(invalid="ignore"):
        tau = np.where(st > 0, np.minimum(st * np.minimum(dist, 1e300), FOG_TAU_MAX), 0.0)
    return tau


# -- the box ------------------------------------------------------------------------------

def view_depth(desc: SceneDescription, fog: Medium) -> float:
    """Axial depth (m) where the camera's transmittance through the fog alone reaches
    e^-TAU_VIEW: TAU_VIEW / the smallest positive sigma_t (inf when it has no extinction)."""
    st = np.asarray(fog.sigma_s, np.float64) + np.asarray(fog.sigma_a, np.float64)
    pos = st[st > 0]
    return float(TAU_VIEW / pos.min()) if pos.size else np.inf


def content_depth(desc: SceneDescription, media) -> float:
    """Axial depth (m) of the farthest content that lights the fog or sits in it: the lights
    in front of the camera and the boxes of the other ``media`` (prepared) crossed by a
    PROBES x PROBES grid of rays over the image.  Surfaces do not count: where no light is
    near, the fog beyond them is lit smoothly and the tail serves it.  0 when there is none."""
    from .media import ray_box
    cam = desc.camera
    g = np.linspace(0.0, 1.0, PROBES)
    px, py = np.meshgrid(g * cam.width, g * cam.height, indexing="ij")
    o, d, tmin, tmax, axial = primary_rays(cam, px.ravel(), py.ravel())
    far = np.zeros(len(o))
    for pm in media:
        a, b = ray_box(pm, o, d)
        far = np.where(b > np.maximum(a, tmin), np.maximum(far, b), far)
    depth = float(np.max(far * axial, initial=0.0))
    c2w = np.asarray(cam.cam_to_world, np.float64)
    fwd = -c2w[:3, 2]
    for light in desc.lights:
        if light.kind == "SUN" or not np.any(np.asarray(light.strength, np.float64) > 0):
            continue
        pos = (np.asarray(light.matrix, np.float64)[:3, 3] if light.kind == "AREA"
               else np.asarray(light.position, np.float64))
        reach = float(np.linalg.norm(pos - c2w[:3, 3])) if str(cam.projection).upper() == "PANO" \
            else float(np.dot(pos - c2w[:3, 3], fwd))
        depth = max(depth, reach)
    return depth


@dataclass
class FogBox:
    """The fog's grid: ``medium`` (source 'WORLD', density 1 on ``shape`` index points, voxel
    ``voxel`` m) covering the view frustum to axial depth ``depth`` m."""

    medium: Medium
    depth: float
    voxel: float


def bounded_medium(desc: SceneDescription, fog: Medium, media=(),
                   resolution: int = 128) -> FogBox:
    """The fog as a grid on the camera-aligned box described in the module docstring, with
    ``resolution`` voxels along its longest side (at least 8).  ``media``: the other prepared
    media (they only locate the content).  A fog that glows and scatters is its own content
    everywhere (the glow it scatters falls beside the surfaces in view, however far from the
    lights: precompute.fogglow): its grid runs to D_view."""
    cam = desc.camera
    near = max(float(cam.clip_start), 0.0)
    d_view = view_depth(desc, fog)
    d_content = content_depth(desc, media) * CONTENT_MARGIN
    if glows(fog) and np.isfinite(d_view):
        d_content = d_view
    depth = min(d_view, d_content) if d_content > near else d_view
    if not np.isfinite(depth):   # emission only, nothing to bound it: the content, or 10 m
        depth = max(d_content, near + 10.0)
    depth = max(depth, near + 1e-3)
    shape, i2w, voxel = frustum_box(cam, near, depth, resolution)
    med = Medium(name=fog.name, density=np.ones(shape, np.float32), index_to_world=i2w,
                 sigma_s=np.asarray(fog.sigma_s, np.float64), sigma_a=np.asarray(fog.sigma_a, np.float64),
                 g=float(fog.g), emission=np.asarray(fog.emission, np.float64), source="WORLD")
    return FogBox(med, float(depth), voxel)


FIELD_STEPS = 256  # samples along each probe ray that sizes a varying fog's box (field_depth)


def field_depth(cam, extinction_at) -> float:
    """Axial depth (m) a world fog whose coefficients vary in space needs for its grid: along
    each of PROBES x PROBES camera rays, where the camera's optical depth through the fog
    reaches TAU_VIEW, or else just past the farthest point with extinction before the clip
    end; the largest over the rays (at least 1 mm past the near clip).  ``extinction_at``
    (N,3) world points -> (N,) the fog's largest extinction there, 1/m; read at FIELD_STEPS
    points a ray, so a layer thinner than the clip range over FIELD_STEPS may be missed."""
    g = np.linspace(0.0, 1.0, PROBES)
    px, py = np.meshgrid(g * cam.width, g * cam.height, indexing="ij")
    o, d, tmin, tmax, axial = primary_rays(cam, px.ravel(), py.ravel())
    near = max(float(cam.clip_start), 0.0)
    tmax = np.where(np.isfinite(tmax), tmax, float(cam.clip_end) / np.maximum(axial, 1e-9))
    frac = (np.arange(FIELD_STEPS) + 0.5) / FIELD_STEPS
    t = tmin[:, None] + (tmax - tmin)[:, None] * frac[None, :]
    pts = o[:, None, :] + d[:, None, :] * t[..., None]
    sig = np.maximum(np.nan_to_num(np.asarray(extinction_at(pts.reshape(-1, 3)), np.float64)),
                     0.0).reshape(t.shape)
    dt = ((tmax - tmin) / FIELD_STEPS)[:, None]
    tau = np.cumsum(sig * dt, axis=1)
    reach = np.zeros(len(o))
    for r in range(len(o)):
        hit = np.flatnonzero(tau[r] >= TAU_VIEW)
        some = np.flatnonzero(sig[r] > 0.0)
        if hit.size:
            reach[r] = t[r, hit[0]] + dt[r, 0]
        elif some.size:
            reach[r] = min(t[r, some[-1]] + dt[r, 0], tmax[r])
    return max(float(np.max(reach * axial)), near + 1e-3)


def frustum_box(cam, near: float, depth: float, resolution: int):
    """(shape, index_to_world (4,4), voxel m) of a grid of cubic voxels, ``resolution`` along
    its longest side (at least 8), on the camera-aligned box round the view frustum from
    axial depth ``near`` to ``depth`` (m), ``MARGIN_VOXELS`` wider on every side."""
    xmin, xmax, ymin, ymax = (float(v) for v in cam.plane)
    if str(cam.projection).upper() == "PANO":   # it sees all round: a cube round the camera
        lo = np.full(3, -depth)
        hi = np.full(3, depth)
    elif str(cam.projection).upper() == "ORTHO":
        lo = np.array([xmin, ymin, -depth])
        hi = np.array([xmax, ymax, -near])
    else:
        lo = np.array([min(xmin * near, xmin * depth), min(ymin * near, ymin * depth), -depth])
        hi = np.array([max(xmax * near, xmax * depth), max(ymax * near, ymax * depth), -near])
    n = max(int(resolution), 8)
    voxel = float(np.max(hi - lo)) / (n - 2.0 * MARGIN_VOXELS - 1.0)
    lo = lo - MARGIN_VOXELS * voxel
    hi = hi + MARGIN_VOXELS * voxel
    shape = tuple(int(np.ceil((b - a) / voxel - 1e-9)) + 1 for a, b in zip(lo, hi))
    local = np.eye(4)
    local[:3, :3] = np.eye(3) * voxel
    local[:3, 3] = lo
    return shape, np.asarray(cam.cam_to_world, np.float64) @ local, voxel


@dataclass
class FarField:
    """The fog's multiply scattered light far from the camera, for the tail: ``M`` float32
    (X,Y,Z,3) W/(m^2 sr) (paths.py's M, summed over the lights) on the voxels of a coarse
    frustum box (``frustum_box`` to the depth ``view_depth``), ``w2i`` (3,4) world ->
    its index."""

    w2i: np.ndarray
    M: np.ndarray

    def read(self, x, trilinear=None) -> np.ndarray:
        """M (N,3) at world points ``x`` (N,3), trilinear; 0 outside the box.  ``trilinear``:
        the read (media.trilinear's arguments and values; None: media.trilinear itself; the
        frame passes the compiled kernels.trilinear)."""
        if trilinear is None:
            from .media import trilinear
        idx = np.asarray(x, np.float64) @ self.w2i[:, :3].T + self.w2i[:, 3]
        return trilinear(self.M, idx)   # float32 values, float64 weights: a float64 sum


def tail_start(pm, origins, dirs) -> np.ndarray:
    """Ray parameter (N,) where the tail of prepared fog grid ``pm`` starts: halfway between
    the exits from its data box (density 1) and from its padded box (density 0)."""
    from .media import to_index
    o = to_index(pm, origins)
    d = dirs @ pm.w2i[:, :3].T
    exits = []
    for lo, hi in ((1.0, np.array(pm.grid.shape, np.float64) - 2.0),
                   (0.0, np.array(pm.grid.shape, np.float64) - 1.0)):
        with np.errstate(divide="ignore", invalid="ignore"):
            ta = (lo - o) / d
            tb = (hi - o) / d
        t = np.where(np.abs(d) > 1e-300, np.maximum(ta, tb), np.inf)
        exits.append(np.min(t, axis=1))
    return 0.5 * (exits[0] + exits[1])


# -- beyond the box -----------------------------------------------------------------------

def far_field(fields) -> Optional[FarField]:
    """The sum of the lights' FarFields in ``fields`` (the fog's MultipleFields, None where a
    light has none), or None when none has one."""
    fars = [f.far for f in fields if f is not None and getattr(f, "far", None) is not None]
    if not fars:
        return None
    return FarField(fars[0].w2i, np.sum([f.M for f in fars], axis=0).astype(np.float32))


def tail(fog: Medium, lights: List[Light], origins, dirs, s0, s1, nodes: int = TAIL_NODES,
         far: Optional[FarField] = None, glow=None, trilinear=None, light_sample=None):
    """What the homogeneous fog adds to rays o + s d over s in [s0, s1] (s1 may be inf;
    nothing where s1 <= s0), as seen from s0: ``(single (N,3), emission (N,3),
    transmittance (N,3), multiple (N,3))``, radiance in W/(m^2 sr).  Single scattering of the
    POINT, SPOT and AREA ``lights`` through the fog alone (no shadows), by ``nodes``-point
    Gauss-Legendre quadrature in u = 1 - exp(-sigma (s - s0)), sigma the smallest positive
    extinction; multiple scattering sigma_s M at the same nodes, M read from ``far`` (0
    without it).  ``glow``: None, or the fog's own glow ``glow_radiance`` (E1, Em), scattered
    towards the camera along the stretch as sigma_s E1 (into single) and sigma_s Em (into
    multiple), exactly as in the endless fog (the surfaces' shade on it is left out beyond
    the grid).  Emission in channels without extinction over an infinite stretch would be
    infinite; it is left out there (the caller warns).  ``trilinear``: how ``far`` is read
    (FarField.read).  ``light_sample``: how the lights are sampled at the nodes
    (lights.light_sample's arguments and values; None: lights.light_sample itself; the frame
    passes the compiled kernels.light_sample)."""
    o = np.asarray(origins, np.float64)
    d = np.asarray(dirs, np.float64)
    s0 = np.asarray(s0, np.float64)
    length = np.maximum(np.asarray(s1, np.float64) - s0, 0.0)
    n = len(o)
    st = np.asarray(fog.sigma_s, np.float64) + np.asarray(fog.sigma_a, np.float64)
    ss = np.asarray(fog.sigma_s, np.float64)
    em = np.maximum(np.asarray(fog.emission, np.float64), 0.0)
    L = length[:, None]
    finite = np.isfinite(L)
    with np.errstate(invalid="ignore", over="ignore"):
        trans = np.where(st > 0, np.exp(-st * np.where(finite, L, 1e300)), 1.0)
        emitted = np.where(st > 0, em * -np.expm1(-st * np.where(finite, L, 1e300)) / np.where(st > 0, st, 1.0),
                           np.where(finite, em * np.where(finite, L, 0.0), 0.0))
    single = np.zeros((n, 3))
    multiple = np.zeros((n, 3))
    if glow is not None:
        # sigma_s E int_0^L e^(-sigma_t s) ds = sigma_s E (1 - e^(-sigma_t L)) / sigma_t
        with np.errstate(invalid="ignore", over="ignore"):
            span = np.where(st > 0, -np.expm1(-st * np.where(finite, L, 1e300))
                            / np.where(st > 0, st, 1.0), 0.0)
        single += ss * glow[0] * span
        multiple += ss * glow[1] * span
    used = [li for li in lights if li.kind != "SUN" and np.any(np.asarray(li.strength) > 0)]
    pos = st[st > 0]
    live = np.flatnonzero(length > 0)
    if (used or far is not None) and pos.size and np.any(ss > 0) and live.size:
        if light_sample is None:
            from .lights import light_sample
        sig = float(pos.min())
        recs = [pack_light(li) for li in used]
        with np.errstate(over="ignore"):
            u_max = -np.expm1(-sig * length[live])            # (M,)
        k, kw = np.polynomial.legendre.leggauss(nodes)      # Gauss-Legendre on [-1, 1]
        u = u_max[:, None] * (0.5 * (k[None, :] + 1.0))      # (M, K)
        s = -np.log1p(-u) / sig                              # distance from s0
        w = (u_max[:, None] * 0.5 * kw[None, :]) / (sig * (1.0 - u))  # ds per node
        x = (o[live, None, :] + d[live, None, :] * (s0[live, None] + s)[..., None]).reshape(-1, 3)
        dd = np.repeat(d[live], nodes, axis=0)
        inc = np.zeros((len(x), 3))
        for rec in recs:
            wi, e, wc, dc = light_sample(rec, x, np.full(len(x), 0.5), np.full(len(x), 0.5))[:4]
            cos = -np.einsum("ij,ij->i", wi, dd)
            inc += hg(cos, float(fog.g))[:, None] * e * np.exp(-optical_depth(st, dc))
        att = np.exp(-st[None, None, :] * s[..., None])      # (M, K, 3) fog from s0 to the node
        single[live] = ss * np.sum(att * inc.reshape(len(live), nodes, 3) * w[..., None], axis=1)
        if far is not None:
            m = far.read(x, trilinear).reshape(len(live), nodes, 3)
            multiple[live] = ss * np.sum(att * m * w[..., None], axis=1)
    return single, emitted, trans, multiple


def glow_radiance(fog: Medium, multiple: bool):
    """``(E1, Em)`` (3,) each, W/(m^2 sr): the fog's own glow that a point of the endless,
    homogeneous fog receives from every direction, away from anything else (so the same
    after any phase function): E1 = e / sigma_t unscattered, and Em = e sigma_s / (sigma_a
    sigma_t) after scattering once or more (with ``multiple``; else 0), so that E1 + Em =
    e / sigma_a, the radiance of an endless medium that emits e and absorbs sigma_a.  0 in
    channels without extinction, and Em 0 where the fog absorbs nothing (it would be
    infinite; ``lossless_glow`` warns).  e the emission (W/(m^3 sr)), sigma in 1/m."""
    st = np.asarray(fog.sigma_s, np.float64) + np.asarray(fog.sigma_a, np.float64)
    ss = np.asarray(fog.sigma_s, np.float64)
    sa = np.asarray(fog.sigma_a, np.float64)
    em = np.maximum(np.asarray(fog.emission, np.float64), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        e1 = np.where(st > 0, em / np.where(st > 0, st, 1.0), 0.0)
        em_ = np.where((sa > 0) & (st > 0), e1 * ss / np.where(sa > 0, sa, 1.0), 0.0)
    return e1, (em_ if multiple else np.zeros(3))


def glows(fog: Medium) -> bool:
    """Whether the fog emits and scatters in some colour channel (its glow lights it)."""
    return bool(np.any((np.asarray(fog.emission, np.float64) > 0)
                       & (np.asarray(fog.sigma_s, np.float64) > 0)))


def lossless_glow(fog: Medium) -> bool:
    """Whether the fog glows and scatters, without absorbing, in some colour channel: its
    multiply scattered glow is infinite there (in Cycles as bright as its Volume Bounces
    allow)."""
    em = np.asarray(fog.emission, np.float64)
    return bool(np.any((em > 0) & (np.asarray(fog.sigma_s, np.float64) > 0)
                       & (np.asarray(fog.sigma_a, np.float64) <= 0)))


def infinite_emission(fog: Medium) -> bool:
    """Whether the fog emits in a channel without extinction (infinite radiance in Cycles)."""
    st = np.asarray(fog.sigma_s, np.float64) + np.asarray(fog.sigma_a, np.float64)
    return bool(np.any((np.asarray(fog.emission, np.float64) > 0) & (st <= 0)))
