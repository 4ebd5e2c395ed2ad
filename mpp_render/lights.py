"""Light emission as seen from points in the media, in Cycles' units.

``incident(light, points, u)`` returns, for world points (N,3), the propagation direction of
the arriving light (unit, from the light towards the point) and the RGB irradiance E (W/m^2)
it brings on a plane facing it, *before* attenuation by the media.  Single scattering at a
point is then sigma_s * p(cos) * E * T_light.

* POINT / SPOT: radiant intensity I = P / (4 pi) W/sr (Cycles' point and spot convention), so
  E = I / d^2.  A light with a radius r is Cycles' default "soft falloff" lamp
  (kernel/light/point.h, the branch ``is_sphere = !use_soft_falloff`` takes by default): a
  disc of radius r facing the shading point with radiance I / (pi r^2).  It subtends the cone
  of half-angle atan(r / d) about the centre, so E = I / (pi r^2) * 2 pi (1 - cos theta_max)
  = 2 I (1 - d / sqrt(d^2 + r^2)) / r^2 (I / d^2 far away, 2 I / r^2 at the centre) whatever
  point of the disc is sampled; the jitter picks the direction uniformly in that solid
  angle (the phase function and a spot's cone see it), and the distance to the disc along it,
  d / cos(theta), scales the optical depth to the centre (``path_stretch``): the disc's
  light crosses more medium than the centre's path.  A spot with a radius averages its
  cone over 8 such directions (a lattice shifted by the jitter: the same mean as one
  direction, far less noise in the penumbra) and reports the irradiance-weighted direction.
* SPOT cone: smoothstep((cos(theta) - cos(size/2)) / ((1 - cos(size/2)) * blend)), theta
  measured in the light's local frame (non-uniform scale included); no normalisation by the
  cone's solid angle.
* SUN: ``strength`` is already the irradiance; a directional light along ``direction``.
* AREA: one point per call is picked on the emitter from ``u``; the estimate is
  L_e cos(theta_l) A / d^2 with L_e = P / (pi A) (``normalize``) or P / pi; only the front
  (local -Z) side emits.  Averaging calls with stratified ``u`` converges to the integral.
  The optical depth to the centre is scaled to the sampled point's distance, as for a disc.
"""
from __future__ import annotations

import numpy as np

from .kernels_np import SPOT_GATE_MARGIN, light_sample
from .lightrecord import (KIND_AREA, KIND_POINT, KIND_SPOT, KIND_SUN, L_AREA, L_AX, L_AY, L_BEAM,
                          L_BLEND, L_CHANNEL, L_COND, L_COSHALF, L_DIR, L_INDIRECT, L_INV, L_KIND,
                          L_NORMAL, L_NORMALIZE, L_POS, L_RADIUS, L_ROUND, L_STRENGTH, LIGHT_FIELDS)
from .scene import Light


def area_geometry(light: Light):
    """World-space centre, local X and Y half-axes (scaled) and the emitter area (m^2)."""
    m = np.asarray(light.matrix, np.float64)
    sx = light.size_x
    sy = light.size_y if light.shape in ("RECTANGLE", "ELLIPSE") else light.size_x
    ax = m[:3, 0] * 0.5 * sx
    ay = m[:3, 1] * 0.5 * sy
    area = 4.0 * np.linalg.norm(ax) * np.linalg.norm(ay)
    if light.shape in ("DISK", "ELLIPSE"):
        area *= np.pi / 4.0
    return m[:3, 3], ax, ay, area


_KINDS = {"POINT": KIND_POINT, "SPOT": KIND_SPOT, "SUN": KIND_SUN, "AREA": KIND_AREA}


def pack_light(light: Light, channel: int = -1, beam: int = -1) -> np.ndarray:
    """The light as one float64 record of ``LIGHT_FIELDS`` (layout: lightrecord), the form
    the kernels read; ``channel`` is its optical-depth channel in the media fields or -1,
    ``beam`` that of its forward peak's light (precompute.FieldLayout.beam_channels) or -1."""
    if light.kind not in _KINDS:
        raise ValueError(f"unsupported light type {light.kind!r}")
    r = np.zeros(LIGHT_FIELDS)
    r[L_KIND] = _KINDS[light.kind]
    r[L_STRENGTH:L_STRENGTH + 3] = np.asarray(light.strength, np.float64).reshape(3)
    d = np.asarray(light.direction, np.float64)
    r[L_DIR:L_DIR + 3] = d / max(np.linalg.norm(d), 1e-30)
    m = np.asarray(light.matrix, np.float64)
    r[L_POS:L_POS + 3] = m[:3, 3] if light.kind == "AREA" else np.asarray(light.position, np.float64)
    try:
        r[L_INV:L_INV + 9] = np.linalg.inv(m[:3, :3]).ravel()
    except np.linalg.LinAlgError:  # a zero-scaled light: its cone is measured unscaled
        r[L_INV:L_INV + 9] = np.eye(3).ravel()
    sv = np.linalg.svd(r[L_INV:L_INV + 9].reshape(3, 3), compute_uv=False)
    r[L_COND] = sv[0] / sv[-1] if sv[-1] > 0.0 and np.isfinite(sv[0] / sv[-1]) else 1e30
    r[L_COSHALF] = np.cos(0.5 * light.spot_size)
    r[L_BLEND] = max(light.spot_blend, 0.0)
    r[L_RADIUS] = max(light.radius, 0.0)
    if light.kind == "AREA":
        _, ax, ay, area = area_geometry(light)
        r[L_AX:L_AX + 3], r[L_AY:L_AY + 3], r[L_AREA] = ax, ay, area
        nrm = -m[:3, 2]
        r[L_NORMAL:L_NORMAL + 3] = nrm / max(np.linalg.norm(nrm), 1e-30)
        r[L_NORMALIZE] = 1.0 if light.normalize else 0.0
        r[L_ROUND] = 1.0 if light.shape in ("DISK", "ELLIPSE") else 0.0
    r[L_CHANNEL] = channel
    r[L_BEAM] = beam
    r[L_INDIRECT] = 1.0 if light.indirect else 0.0
    return r


def incident(light: Light, points, u=None):
    """(direction (N,3), irradiance RGB (N,3)) of ``light`` at world ``points`` (N,3).

    ``u`` (N,2) in [0,1): jitter for lights with an extent (sphere radius, area emitters)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if u is None:
        if light.kind == "AREA":
            return area_incident(light, points)
        u = np.full((len(points), 2), 0.5)
    d, e = light_sample(pack_light(light), points, u[:, 0], u[:, 1])[:2]
    return d, e


def irradiance(light: Light, points) -> np.ndarray:
    """The irradiance RGB (N,3, W/m^2) of ``incident(light, points)`` without its direction
    (an area light's emitter integral then skips Lambert's vector, half its cost)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if light.kind == "AREA":
        return area_incident(light, points, direction=False)[1]
    return incident(light, points)[1]


POLYGON_SIDES = 24  # sides of the polygon that stands for a disc or ellipse emitter


def emitter_polygon(light: Light) -> np.ndarray:
    """Corners (V,3, world m, in order round the edge) of an AREA light's emitter: the
    rectangle's four, or for a disc or ellipse a ``POLYGON_SIDES``-gon of the same area."""
    c, ax, ay, _ = area_geometry(light)
    if light.shape in ("DISK", "ELLIPSE"):
        n = POLYGON_SIDES
        t = 2.0 * np.pi * np.arange(n) / n
        grow = np.sqrt(2.0 * np.pi / (n * np.sin(2.0 * np.pi / n)))  # polygon area = ellipse's
        return c + grow * (np.cos(t)[:, None] * ax + np.sin(t)[:, None] * ay)
    return c + np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float64) @ np.stack([ax, ay])


def area_incident(light: Light, points, direction: bool = True):
    """(direction (N,3), irradiance RGB (N,3)) of an AREA light integrated over its emitter:
    a Lambertian emitter of radiance L (W/(m^2 sr)) brings sum of L cos(theta_l) dA / d^2 =
    L Omega, Omega the solid angle (sr) the emitter subtends at the point (Van Oosterom and
    Strackee's formula on a fan of triangles), on the emitting side only; the direction is
    that of the light's mean propagation, minus Lambert's vector irradiance of the polygon
    (the sum over its edges of the angle each subtends times its unit normal, halved).  Exact
    also next to a large emitter, where one point of it read alone (1 / d^2) is not: a point
    1 mm above a 4 m square reads 2 pi L.  ``direction=False``: None for the direction."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    rec = pack_light(light)
    c = np.asarray(light.matrix, np.float64)[:3, 3]
    normal = rec[L_NORMAL:L_NORMAL + 3]
    area = rec[L_AREA]
    radiance = np.asarray(light.strength, np.float64).reshape(3) / np.pi / \
        (area if (light.normalize and area > 0.0) else 1.0)
    r = emitter_polygon(light)[None, :, :] - points[:, None, :]      # (N,V,3)
    ln = np.maximum(np.linalg.norm(r, axis=2), 1e-300)
    omega = np.zeros(len(points))
    a, la = r[:, 0], ln[:, 0]
    for i in range(1, r.shape[1] - 1):
        b, c2, lb, lc = r[:, i], r[:, i + 1], ln[:, i], ln[:, i + 1]
        num = np.abs(np.einsum("ij,ij->i", a, np.cross(b, c2)))
        den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc
               + np.einsum("ij,ij->i", a, c2) * lb + np.einsum("ij,ij->i", b, c2) * la)
        omega += 2.0 * np.arctan2(num, den)
    front = (points - c) @ normal > 0.0
    e = np.where(front, omega, 0.0)[:, None] * radiance[None, :]
    if not direction:
        return None, e
    u = r / ln[..., None]
    un = np.roll(u, -1, axis=1)
    cr = np.cross(u, un)
    gamma = np.arccos(np.clip(np.einsum("nvk,nvk->nv", u, un), -1.0, 1.0))
    vec = 0.5 * np.einsum("nv,nvk->nk", gamma / np.maximum(np.linalg.norm(cr, axis=2), 1e-300), cr)
    towards = c - points
    vec *= np.where(np.einsum("ij,ij->i", vec, towards) < 0.0, -1.0, 1.0)[:, None]
    nv = np.linalg.norm(vec, axis=1)
    far = np.linalg.norm(towards, axis=1)
    d = np.where((nv > 1e-12)[:, None], -vec / np.maximum(nv, 1e-300)[:, None],
                 -towards / np.maximum(far, 1e-300)[:, None])
    return d, e


def spot_attenuation(light: Light, from_light):
    """Cone factor (N,) for propagation directions ``from_light`` (N,3) of a SPOT light."""
    pts = np.asarray(light.position, np.float64) + np.asarray(from_light, np.float64)
    unit = Light("SPOT", light.name, np.full(3, 4.0 * np.pi), position=light.position,
                 direction=light.direction, matrix=light.matrix, spot_size=light.spot_size,
                 spot_blend=light.spot_blend)
    _, e = incident(unit, pts)
    dist2 = np.einsum("ij,ij->i", pts - unit.position, pts - unit.position)
    return e[:, 0] * np.maximum(dist2, 1e-8)


def outside_spot(light: Light, points, reach: float) -> np.ndarray:
    """(N,) bool: the ``points`` (N,3, m) round which a ball of radius ``reach`` (m) lies
    wholly outside a SPOT light's cone, with its emitter's radius and the cone measured in
    the light's local frame as ``incident`` does (its irradiance there is 0); all False for
    the other kinds and for points within reach + radius of the light."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if light.kind != "SPOT":
        return np.zeros(len(points), bool)
    rec = pack_light(light)
    v = points - rec[L_POS:L_POS + 3]
    dist = np.sqrt(np.einsum("ij,ij->i", v, v))
    near = dist <= reach + max(float(rec[L_RADIUS]), 0.0)
    safe = np.where(near, 1.0, dist)
    loc = v @ rec[L_INV:L_INV + 9].reshape(3, 3).T
    cos = -loc[:, 2] / np.maximum(np.sqrt(np.einsum("ij,ij->i", loc, loc)), 1e-30)
    theta = np.arccos(np.clip(cos, -1.0, 1.0))
    ball = np.arcsin(np.clip((reach + max(float(rec[L_RADIUS]), 0.0)) / safe, 0.0, 1.0))
    spread = SPOT_GATE_MARGIN * min(float(rec[L_COND]), 1e6) * ball
    return ~near & (theta - spread > np.arccos(np.clip(rec[L_COSHALF], -1.0, 1.0)))


def towards_light(light: Light, points):
    """(unit directions (N,3) from ``points`` to the light's centre, distances (N,) in m;
    inf and the reversed propagation direction for the sun)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if light.kind == "SUN":
        d = -np.asarray(light.direction, np.float64)
        return np.broadcast_to(d / np.linalg.norm(d), points.shape).copy(), np.full(len(points), np.inf)
    pos = np.asarray(light.matrix, np.float64)[:3, 3] if light.kind == "AREA" else \
        np.asarray(light.position, np.float64)
    v = pos - points
    dist = np.linalg.norm(v, axis=1)
    return v / np.maximum(dist, 1e-30)[:, None], dist


def is_dark(light: Light) -> bool:
    """True when the light emits nothing (zero or negative strength)."""
    return not np.any(np.asarray(light.strength, np.float64) > 0.0)
