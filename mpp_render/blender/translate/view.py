"""The 3D viewport's view as a :class:`~mpp_render.scene.Camera` (for viewport rendering).

Blender's ``RegionView3D`` holds the view as two OpenGL-style 4x4 matrices (row-major,
acting on column vectors): ``view_matrix`` maps world to view space (metres; the view
looks down its -Z with +Y up, as a camera object) and ``window_matrix`` P maps view space
to clip space.  The Camera's ``cam_to_world`` is the inverse of the view matrix with any
scale removed.  From P, with r, l, t, b the view plane and n, f the clip distances:

* perspective (row 3 = (0, 0, -1, 0)): P00 = 2/(r-l), P02 = (r+l)/(r-l), likewise y, so at
  z = -1 the plane is x = (ndc + P02) / P00 (tangents); P22 = -(f+n)/(f-n),
  P23 = -2fn/(f-n), so n = P23/(P22-1), f = P23/(P22+1);
* orthographic (row 3 = (0, 0, 0, 1)): P03 = -(r+l)/(r-l), so x = (ndc - P03) / P00 in
  metres; P22 = -2/(f-n), P23 = -(f+n)/(f-n), so n = (P23+1)/P22, f = (P23-1)/P22.

Lens shift and the camera view's zoom and offset are the P02/P12 (P03/P13) terms.  A free
orthographic viewport clips from -E/2 to E/2, E the View3D's clip end (Blender's
BKE_camera_params_from_view3d; Cycles' viewport keeps that negative start): the Camera
keeps it as given (ORTHO rays start on the view plane with t from clip_start,
camera.primary_rays).  Any other off-diagonal term (a skewed or rotated projection)
cannot be a Camera and raises ValueError.
"""
from __future__ import annotations

import numpy as np

from ...scene import Camera
from .camera import rigid

_TOL = 1e-6
# entries of P that must be 0: (row, column) for perspective and orthographic matrices
_ZERO = {"PERSP": ((0, 1), (0, 3), (1, 0), (1, 3), (2, 0), (2, 1)),
         "ORTHO": ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))}


def _as_array(m, what: str) -> np.ndarray:
    try:
        a = np.array([list(row) for row in m], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{what} matrix is not a 4x4 matrix of numbers") from exc
    if a.shape != (4, 4) or not np.all(np.isfinite(a)):
        raise ValueError(f"{what} matrix must be a finite 4x4 matrix, got {a.shape}")
    return a


def camera_from_matrices(view_matrix, window_matrix, width: int, height: int) -> Camera:
    """A Camera seeing what ``view_matrix`` (world to view) and ``window_matrix`` (view to
    clip, OpenGL convention) show on an image of ``width`` x ``height`` pixels.  Both are
    ``mathutils.Matrix`` or numpy 4x4.  Raises ValueError for a singular or non-affine view
    matrix and for a window matrix that is neither a perspective nor an orthographic
    projection of a (possibly shifted) axis-aligned view plane."""
    v = _as_array(view_matrix, "view")
    p = _as_array(window_matrix, "window")
    if not np.allclose(v[3], (0.0, 0.0, 0.0, 1.0), atol=_TOL) or abs(np.linalg.det(v)) < 1e-12:
        raise ValueError(f"view matrix is singular or not affine:\n{v}")
    if np.allclose(p[3], (0.0, 0.0, -1.0, 0.0), atol=_TOL):
        projection = "PERSP"
    elif np.allclose(p[3], (0.0, 0.0, 0.0, 1.0), atol=_TOL):
        projection = "ORTHO"
    else:
        raise ValueError("window matrix is neither perspective (last row 0 0 -1 0) nor "
                         f"orthographic (last row 0 0 0 1):\n{p}")
    scale = max(abs(p[0, 0]), abs(p[1, 1]), 1.0)
    bad = [rc for rc in _ZERO[projection] if abs(p[rc]) > _TOL * scale]
    if bad:
        raise ValueError(f"{projection} window matrix has skew/rotation terms at {bad} that a "
                         f"camera cannot represent:\n{p}")
    degenerate = (1.0, -1.0) if projection == "PERSP" else (0.0,)
    if p[0, 0] == 0.0 or p[1, 1] == 0.0 or p[2, 2] in degenerate:
        raise ValueError(f"window matrix is singular (no view plane or clip range):\n{p}")
    if projection == "PERSP":
        x = [(s + p[0, 2]) / p[0, 0] for s in (-1.0, 1.0)]
        y = [(s + p[1, 2]) / p[1, 1] for s in (-1.0, 1.0)]
        near, far = p[2, 3] / (p[2, 2] - 1.0), p[2, 3] / (p[2, 2] + 1.0)
    else:
        x = [(s - p[0, 3]) / p[0, 0] for s in (-1.0, 1.0)]
        y = [(s - p[1, 3]) / p[1, 1] for s in (-1.0, 1.0)]
        near, far = (p[2, 3] + 1.0) / p[2, 2], (p[2, 3] - 1.0) / p[2, 2]
    if not (x[0] < x[1] and y[0] < y[1] and near < far and (near > 0.0 or projection == "ORTHO")):
        raise ValueError(f"window matrix gives no valid view: plane {x + y}, clip "
                         f"[{near}, {far}] (perspective needs 0 < near < far):\n{p}")
    return Camera(projection=projection, cam_to_world=rigid(np.linalg.inv(v)),
                  width=int(width), height=int(height),
                  plane=tuple(float(c) for c in x + y),
                  clip_start=float(near), clip_end=float(far))


def camera_from_region(region_data, width: int, height: int) -> Camera:
    """The Camera of a viewport: ``region_data`` a ``bpy.types.RegionView3D``, ``width`` x
    ``height`` the region's size in pixels.  It is the viewport's own projection, whatever
    ``view_perspective`` is: 'PERSP', 'ORTHO' (clip start negative, see the module) or
    'CAMERA', looking through the scene camera with the viewport's zoom and offset, whose
    window matrix Blender already builds.  The viewport view has no depth of field and no
    panorama: a camera's aperture and panoramic lens are not carried over (a pinhole or
    orthographic Camera)."""
    return camera_from_matrices(region_data.view_matrix, region_data.window_matrix,
                                width, height)
