"""Light emission as seen from points in the media, in Cycles' units.

``incident(light, points, u)`` returns, for world points (N,3), the propagation direction of
the arriving light (unit, from the light towards the point) and the RGB irradiance E (W/m^2)
it brings on a plane facing it, *before* attenuation by the media.  Single scattering at a
point is then sigma_s * p(cos) * E * T_light.

* POINT / SPOT: radiant intensity I = P / (4 pi) W/sr (Cycles' point and spot convention), so
  E = I / d^2.  A light with a radius is a sphere: the emission point is jittered over the
  disc of that radius facing the shading point, which softens the spot cone as Cycles' sphere
  lights do; inside the sphere d is held at the radius.
* SPOT cone: smoothstep((cos(theta) - cos(size/2)) / ((1 - cos(size/2)) * blend)), theta
  measured in the light's local frame (non-uniform scale included); no normalisation by the
  cone's solid angle.
* SUN: ``strength`` is already the irradiance; a directional light along ``direction``.
* AREA: one point per call is picked on the emitter from ``u``; the estimate is
  L_e cos(theta_l) A / d^2 with L_e = P / (pi A) (``normalize``) or P / pi; only the front
  (local -Z) side emits.  Averaging calls with stratified ``u`` converges to the integral.
"""
from __future__ import annotations

import numpy as np

from .scene import Light


def smoothstep01(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def spot_attenuation(light: Light, from_light):
    """Cone factor for propagation directions ``from_light`` (N,3) (light -> point)."""
    m = np.asarray(light.matrix, np.float64)[:3, :3]
    local = from_light @ np.linalg.inv(m).T  # into the light's local frame, scale undone
    local /= np.maximum(np.linalg.norm(local, axis=1, keepdims=True), 1e-30)
    cos_t = -local[:, 2]  # the light shines along local -Z
    cos_half = np.cos(0.5 * light.spot_size)
    blend = max(light.spot_blend, 0.0)
    if blend <= 0.0:
        return (cos_t > cos_half).astype(np.float64)
    return smoothstep01((cos_t - cos_half) / ((1.0 - cos_half) * blend))


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


def _disc_point(u, shape_round):
    """Map u in [0,1)^2 to the square [-1,1]^2 or the unit disc (concentric mapping)."""
    a = 2.0 * u[:, 0] - 1.0
    b = 2.0 * u[:, 1] - 1.0
    if not shape_round:
        return a, b
    r = np.where(np.abs(a) > np.abs(b), a, b)
    phi = np.where(np.abs(a) > np.abs(b), (np.pi / 4) * b / np.where(a == 0, 1, a),
                   np.pi / 2 - (np.pi / 4) * a / np.where(b == 0, 1, b))
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def incident(light: Light, points, u=None):
    """(direction (N,3), irradiance RGB (N,3)) of ``light`` at world ``points`` (N,3).

    ``u`` (N,2) in [0,1): jitter for lights with an extent (sphere radius, area emitters)."""
    points = np.asarray(points, np.float64)
    n = len(points)
    strength = np.asarray(light.strength, np.float64).reshape(1, 3)
    if u is None:
        u = np.full((n, 2), 0.5)
    if light.kind == "SUN":
        d = np.asarray(light.direction, np.float64)
        d = d / np.linalg.norm(d)
        return np.broadcast_to(d, (n, 3)).copy(), np.broadcast_to(strength, (n, 3)).copy()
    if light.kind in ("POINT", "SPOT"):
        centre = np.asarray(light.position, np.float64)
        v = points - centre
        dist = np.linalg.norm(v, axis=1)
        src = np.broadcast_to(centre, (n, 3))
        if light.radius > 0.0:
            axis = v / np.maximum(dist, 1e-30)[:, None]
            from .phase import orthonormal_basis
            t1, t2 = orthonormal_basis(axis)
            a, b = _disc_point(u, True)
            src = centre + light.radius * (t1 * a[:, None] + t2 * b[:, None])
            v = points - src
            dist = np.linalg.norm(v, axis=1)
        d = v / np.maximum(dist, 1e-30)[:, None]
        r2 = np.maximum(dist * dist, max(light.radius, 1e-4) ** 2)
        e = strength / (4.0 * np.pi) / r2[:, None]
        if light.kind == "SPOT":
            e = e * spot_attenuation(light, d)[:, None]
        return d, e
    if light.kind == "AREA":
        centre, ax, ay, area = area_geometry(light)
        a, b = _disc_point(u, light.shape in ("DISK", "ELLIPSE"))
        src = centre + ax * a[:, None] + ay * b[:, None]
        v = points - src
        dist2 = np.maximum(np.einsum("ij,ij->i", v, v), 1e-8)
        dist = np.sqrt(dist2)
        d = v / dist[:, None]
        normal = -np.asarray(light.matrix, np.float64)[:3, 2]
        normal = normal / np.linalg.norm(normal)
        cos_l = np.maximum(d @ normal, 0.0)
        radiance = strength / np.pi / (area if (light.normalize and area > 0) else 1.0)
        e = radiance * (cos_l * area / dist2)[:, None]
        return d, e
    raise ValueError(f"unsupported light type {light.kind!r}")


def is_dark(light: Light) -> bool:
    """True when the light emits nothing (zero or negative strength)."""
    return not np.any(np.asarray(light.strength, np.float64) > 0.0)
