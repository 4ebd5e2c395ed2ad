"""Camera view plane and primary rays, as Blender and Cycles compute them (no bpy).

Conventions (see :class:`mpp_render.scene.Camera`):

* Camera space: the camera looks down its local -Z with +Y up and +X to the right.
* The view plane (xmin, xmax, ymin, ymax) is given on the plane z = -1 for PERSP (so the
  values are tangents of the half angles, dimensionless) and in metres for ORTHO.
* Pixel coordinates are continuous: ``px`` in [0, width) from left to right, ``py`` in
  [0, height) from the *top* edge down, so pixel (x, y) covers [x, x+1) x [y, y+1) and its
  centre is (x + 0.5, y + 0.5).
* Clipping is planar, as in Cycles: a point is kept when its axial depth (distance along the
  camera's forward axis) lies in [clip_start, clip_end].
"""
from __future__ import annotations

import numpy as np

SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")


def camera_plane(projection, lens_mm, sensor_width, sensor_height, sensor_fit, shift_x, shift_y,
                 ortho_scale, width, height, pixel_aspect_x=1.0, pixel_aspect_y=1.0):
    """Return the view plane (xmin, xmax, ymin, ymax) of a Blender camera.

    Follows Blender's ``BKE_camera_params_compute_viewplane``:

    * ``projection``: 'PERSP' or 'ORTHO'.  ``lens_mm``, ``sensor_width``, ``sensor_height``:
      focal length and sensor size in millimetres.  ``ortho_scale``: metres.
    * ``sensor_fit``: 'AUTO' fits ``sensor_width`` to the larger of the two (pixel-aspect
      corrected) image sides; 'HORIZONTAL' fits ``sensor_width`` to the width; 'VERTICAL'
      fits ``sensor_height`` to the height.
    * ``shift_x``/``shift_y``: lens shift in units of the fitted side (Blender's convention).
    * ``width``/``height``: image size in pixels (after the resolution percentage);
      ``pixel_aspect_x/y``: Blender's pixel aspect (a pixel is x:y wide:tall).

    PERSP values lie on the plane z = -1 (tangents); ORTHO values are metres.
    """
    projection = str(projection).upper()
    sensor_fit = str(sensor_fit).upper()
    if sensor_fit not in SENSOR_FITS:
        raise ValueError(f"unknown sensor fit {sensor_fit!r}")
    width = float(width)
    height = float(height)
    ycor = float(pixel_aspect_y) / float(pixel_aspect_x)

    if projection == "ORTHO":
        size = float(ortho_scale)
    elif projection in ("PERSP", "PANO"):
        # Size of the plane at unit distance: sensor / focal length (a panorama's rays do not
        # use it; the world fog's box of a panorama is a cube, worldfog.frustum_box).
        size = (float(sensor_height) if sensor_fit == "VERTICAL" else float(sensor_width)) / float(lens_mm)
    else:
        raise ValueError(f"unknown projection {projection!r}")

    if sensor_fit == "AUTO":
        horizontal = pixel_aspect_x * width >= pixel_aspect_y * height
    else:
        horizontal = sensor_fit == "HORIZONTAL"
    viewfac = width if horizontal else ycor * height
    pixsize = size / viewfac

    dx = float(shift_x) * viewfac
    dy = float(shift_y) * viewfac
    xmin = (-0.5 * width + dx) * pixsize
    xmax = (0.5 * width + dx) * pixsize
    ymin = (-0.5 * ycor * height + dy) * pixsize
    ymax = (0.5 * ycor * height + dy) * pixsize
    return (xmin, xmax, ymin, ymax)


def aperture_points(camera, lens) -> np.ndarray:
    """Points (N,2) on the camera's aperture, in metres in the lens plane, for uniform
    ``lens`` (N,2) in [0, 1): uniform over a disc of radius ``camera.aperture``, or over the
    regular polygon of ``camera.blades`` corners (circumradius ``aperture``, the first corner
    at ``blade_rotation``), the x squeezed by ``aperture_ratio`` (Cycles'
    camera_sample_aperture)."""
    lens = np.asarray(lens, np.float64).reshape(-1, 2)
    blades = int(camera.blades)
    if blades < 3:
        r = np.sqrt(lens[:, 0])
        phi = 2.0 * np.pi * lens[:, 1]
        xy = np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)
    else:   # a triangle of the fan, then a uniform point in it
        k = np.minimum((lens[:, 0] * blades).astype(np.int64), blades - 1)
        u = lens[:, 0] * blades - k
        v = lens[:, 1]
        a0 = float(camera.blade_rotation) + 2.0 * np.pi * k / blades
        a1 = a0 + 2.0 * np.pi / blades
        c0 = np.stack([np.cos(a0), np.sin(a0)], axis=1)
        c1 = np.stack([np.cos(a1), np.sin(a1)], axis=1)
        s = np.sqrt(u)
        xy = c0 * (s * (1.0 - v))[:, None] + c1 * (s * v)[:, None]
    xy[:, 0] /= max(float(camera.aperture_ratio), 1e-9)
    return xy * float(camera.aperture)


def _fisheye(theta, u, v, r):
    """Blender camera-local directions (x right, y up, -z forward) at angle ``theta`` from
    the view axis, towards the image point (u, v) at radius r from the image centre
    (Cycles' fisheye_to_direction in its panorama frame)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        cu = np.where(r > 0.0, u / np.where(r > 0.0, r, 1.0), 1.0)
        cv = np.where(r > 0.0, v / np.where(r > 0.0, r, 1.0), 0.0)
    s = np.sin(theta)
    return np.stack([cu * s, cv * s, -np.cos(theta)], axis=1)


def panorama_directions(camera, u, v):
    """(directions (N,3) unit in the camera's local frame, valid (N,) bool) of a panoramic
    camera at image coordinates ``u`` (0 left .. 1 right) and ``v`` (0 bottom .. 1 top),
    Cycles' panorama_to_direction (intern/cycles/kernel/camera/projection.h) turned into
    Blender's camera frame as Cycles' Blender sync turns it (its panorama looks along +x).
    Points outside a fisheye's circle or a mirror ball are not valid (Cycles renders them
    black)."""
    p = camera.panorama or {}
    kind = str(p.get("type", "EQUIRECTANGULAR")).upper()
    u = np.asarray(u, np.float64)
    v = np.asarray(v, np.float64)
    valid = np.ones(len(u), bool)
    if kind == "EQUIRECTANGULAR":
        lon0, lon1 = p.get("longitude", (-np.pi, np.pi))
        lat0, lat1 = p.get("latitude", (-0.5 * np.pi, 0.5 * np.pi))
        phi = (lon0 - lon1) * u - lon0
        theta = (lat0 - lat1) * v - lat0 + 0.5 * np.pi
        # Cycles' (sin t cos p, sin t sin p, cos t), its +x forward, in Blender's camera frame
        d = np.stack([-np.sin(theta) * np.sin(phi), np.cos(theta),
                      -np.sin(theta) * np.cos(phi)], axis=1)
    elif kind == "MIRRORBALL":
        x, z = 2.0 * u - 1.0, 2.0 * v - 1.0
        valid = x * x + z * z <= 1.0
        y = -np.sqrt(np.maximum(1.0 - x * x - z * z, 0.0))
        # the reflection of (0, -1, 0) about the ball's normal, in Cycles' mirror-ball frame
        # (looking along -y), whose (x, y, z) is Blender's camera (x, -z, y)... i.e. camera
        # x = x, camera y = z, camera z = y
        dot = -y
        rx, ry, rz = 2.0 * dot * x, 2.0 * dot * y + 1.0, 2.0 * dot * z
        d = np.stack([rx, rz, ry], axis=1)
    else:
        sw, sh = (float(s) for s in p.get("sensor", (36.0, 24.0)))
        fov = float(p.get("fov", np.pi))
        if kind == "FISHEYE_EQUIDISTANT":
            x, y = (u - 0.5) * 2.0, (v - 0.5) * 2.0
            r = np.hypot(x, y)
            valid = r <= 1.0
            theta = r * fov * 0.5
        elif kind == "FISHEYE_LENS_POLYNOMIAL":
            x, y = (u - 0.5) * sw, (v - 0.5) * sh
            r = np.hypot(x, y)
            k = [float(c) for c in p.get("polynomial", (0.0, -0.03, 0.0, 0.0, 0.0))]
            theta = -(k[0] + k[1] * r + k[2] * r ** 2 + k[3] * r ** 3 + k[4] * r ** 4)
            valid = np.abs(theta) <= 0.5 * fov
        else:   # FISHEYE_EQUISOLID
            lens = float(p.get("lens", 10.5))
            x, y = (u - 0.5) * sw, (v - 0.5) * sh
            r = np.hypot(x, y)
            valid = r <= 2.0 * lens * np.sin(0.25 * fov)
            theta = 2.0 * np.arcsin(np.clip(r / (2.0 * lens), -1.0, 1.0))
        d = _fisheye(theta, x, y, r)
    d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    return d, valid & np.all(np.isfinite(d), axis=1)


def primary_rays(camera, px, py, lens=None):
    """World-space primary rays through continuous pixel coordinates.

    ``camera``: a :class:`mpp_render.scene.Camera`.  ``px``, ``py``: float arrays of the same
    shape (flattened to N), ``py = 0`` the top edge of the image.  ``lens``: (N,2) uniform
    numbers in [0, 1) for a camera with depth of field (``camera.aperture`` > 0): the ray
    leaves a point of the aperture (``aperture_points``) towards where the pinhole ray meets
    the plane in focus, ``focus_distance`` along the view axis (Cycles' thin lens); without
    them, or without an aperture, the pinhole.

    Returns ``(origins (N,3), directions (N,3) unit, t_min (N,), t_max (N,), axial (N,))``,
    all float64, lengths in metres.  ``axial`` = dot(direction, camera forward), so the axial
    depth of the point at ray parameter t is ``t * axial``.  Clipping is planar:
    PERSP rays start at the camera position with t in [clip_start, clip_end] / axial;
    ORTHO rays start on the camera's z = 0 plane with t in [clip_start, clip_end], axial = 1.
    """
    px = np.asarray(px, dtype=np.float64).ravel()
    py = np.asarray(py, dtype=np.float64).ravel()
    if px.shape != py.shape:
        raise ValueError("px and py must have the same number of elements")
    xmin, xmax, ymin, ymax = (float(v) for v in camera.plane)
    u = px / float(camera.width)
    v = py / float(camera.height)
    x = xmin + u * (xmax - xmin)
    y = ymax - v * (ymax - ymin)          # py = 0 is the top edge

    m = np.asarray(camera.cam_to_world, dtype=np.float64)
    rot = m[:3, :3]
    loc = m[:3, 3]
    forward = -rot[:, 2]
    n = px.shape[0]

    thin = lens is not None and float(getattr(camera, "aperture", 0.0)) > 0.0
    focus = max(float(getattr(camera, "focus_distance", 1.0)), 1e-5)
    if str(camera.projection).upper() == "PANO":
        dl, valid = panorama_directions(camera, px / float(camera.width),
                                        1.0 - py / float(camera.height))
        p_lens = np.zeros((n, 3))
        if thin:   # Cycles' thin lens across the panorama's direction
            ab = aperture_points(camera, lens)
            a1 = np.cross(dl, np.array([0.0, 1.0, 0.0]))
            bad = np.linalg.norm(a1, axis=1) < 1e-9
            a1[bad] = np.array([1.0, 0.0, 0.0])
            a1 /= np.linalg.norm(a1, axis=1, keepdims=True)
            a2 = np.cross(a1, dl)
            p_lens = a1 * ab[:, :1] + a2 * ab[:, 1:2]
            dl = dl * focus - p_lens
            dl /= np.linalg.norm(dl, axis=1, keepdims=True)
        directions = dl @ rot.T
        t_min = np.full(n, float(camera.clip_start))
        # a point outside the lens circle sees nothing: an empty interval
        t_max = np.where(valid, float(camera.clip_end), 0.0)
        return p_lens @ rot.T + loc, directions, t_min, t_max, np.ones(n)
    if str(camera.projection).upper() == "ORTHO":
        local = np.stack([x, y, np.zeros(n)], axis=1)
        if thin:
            ab = aperture_points(camera, lens)
            dl = np.stack([-ab[:, 0], -ab[:, 1], -np.full(n, focus)], axis=1)
            dl /= np.linalg.norm(dl, axis=1, keepdims=True)
            local = local + np.stack([ab[:, 0], ab[:, 1], np.zeros(n)], axis=1)
            directions = dl @ rot.T
            axial = -dl[:, 2]
            return (local @ rot.T + loc, directions, float(camera.clip_start) / axial,
                    float(camera.clip_end) / axial, axial)
        origins = local @ rot.T + loc
        directions = np.broadcast_to(forward, (n, 3)).copy()
        axial = np.ones(n)
        t_min = np.full(n, float(camera.clip_start))
        t_max = np.full(n, float(camera.clip_end))
        return origins, directions, t_min, t_max, axial

    local = np.stack([x, y, -np.ones(n)], axis=1)
    if thin:
        ab = aperture_points(camera, lens)
        p_lens = np.stack([ab[:, 0], ab[:, 1], np.zeros(n)], axis=1)
        dl = local * focus - p_lens          # to the point in focus (z = -focus)
        length = np.sqrt(np.einsum("ij,ij->i", dl, dl))
        dl /= length[:, None]
        axial = -dl[:, 2]
        return (p_lens @ rot.T + loc, dl @ rot.T, float(camera.clip_start) / axial,
                float(camera.clip_end) / axial, axial)
    length = np.sqrt(np.einsum("ij,ij->i", local, local))
    local /= length[:, None]
    directions = local @ rot.T
    axial = 1.0 / length                  # cos of the angle to the view axis
    origins = np.broadcast_to(loc, (n, 3)).copy()
    t_min = float(camera.clip_start) / axial
    t_max = float(camera.clip_end) / axial
    return origins, directions, t_min, t_max, axial


def towards_camera(camera, points):
    """Unit directions (N,3) from world ``points`` (N,3, m) to the camera: to its position
    for PERSP, its view axis reversed (+Z of the camera) for ORTHO, the same for every point."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    c2w = np.asarray(camera.cam_to_world, np.float64)
    if str(camera.projection).upper() == "ORTHO":
        return np.broadcast_to(c2w[:3, 2], points.shape)
    v = c2w[:3, 3] - points
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-30)
