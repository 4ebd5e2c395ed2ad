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
    elif projection == "PERSP":
        # Size of the plane at unit distance: sensor / focal length.
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


def primary_rays(camera, px, py):
    """World-space primary rays through continuous pixel coordinates.

    ``camera``: a :class:`mpp_render.scene.Camera`.  ``px``, ``py``: float arrays of the same
    shape (flattened to N), ``py = 0`` the top edge of the image.

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

    if str(camera.projection).upper() == "ORTHO":
        local = np.stack([x, y, np.zeros(n)], axis=1)
        origins = local @ rot.T + loc
        directions = np.broadcast_to(forward, (n, 3)).copy()
        axial = np.ones(n)
        t_min = np.full(n, float(camera.clip_start))
        t_max = np.full(n, float(camera.clip_end))
        return origins, directions, t_min, t_max, axial

    local = np.stack([x, y, -np.ones(n)], axis=1)
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
