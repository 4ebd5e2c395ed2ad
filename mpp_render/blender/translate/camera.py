"""The render camera: projection, view plane and rigid camera-to-world transform."""
from __future__ import annotations

from typing import List

import numpy as np

from ...camera import camera_plane
from ...scene import Camera
from .convert import matrix

# Blender's camera parameters for an active "camera" that is not a camera object
# (BKE_camera_params_init): 35 mm lens on a 36 x 24 mm sensor, clipping 0.1 .. 100 m.
FALLBACK = dict(type="PERSP", lens=35.0, sensor_width=36.0, sensor_height=24.0,
                sensor_fit="AUTO", shift_x=0.0, shift_y=0.0, ortho_scale=6.0,
                clip_start=0.1, clip_end=100.0)


def render_size(scene):
    """Image size in pixels: resolution x percentage / 100, as Blender rounds it."""
    r = scene.render
    pct = int(r.resolution_percentage)
    return max(1, int(r.resolution_x) * pct // 100), max(1, int(r.resolution_y) * pct // 100)


def _params(cam_ob, warnings: List[str]) -> dict:
    if cam_ob.type != "CAMERA":
        warnings.append(f"active camera '{cam_ob.name}' is a {cam_ob.type} object, not a camera; "
                        "using a 35 mm perspective lens")
        return dict(FALLBACK)
    cam = cam_ob.data
    p = {k: getattr(cam, k) for k in FALLBACK}
    if p["type"] not in ("PERSP", "ORTHO"):
        warnings.append(f"camera '{cam_ob.name}': {p['type']} cameras are not supported; "
                        "rendering as a perspective camera with its lens")
        p["type"] = "PERSP"
    dof = getattr(cam, "dof", None)
    if dof is not None and dof.use_dof:
        warnings.append(f"camera '{cam_ob.name}': depth of field is not supported; ignored")
    return p


def camera_from_object(cam_ob, scene, width: int, height: int, warnings: List[str]) -> Camera:
    """A :class:`~mpp_render.scene.Camera` for the evaluated object ``cam_ob`` rendering
    ``width`` x ``height`` pixels; the object's scale is removed, as Cycles does."""
    p = _params(cam_ob, warnings)
    r = scene.render
    plane = camera_plane(p["type"], p["lens"], p["sensor_width"], p["sensor_height"],
                         p["sensor_fit"], p["shift_x"], p["shift_y"], p["ortho_scale"],
                         width, height, r.pixel_aspect_x, r.pixel_aspect_y)
    return Camera(projection=p["type"], cam_to_world=rigid(matrix(cam_ob.matrix_world)),
                  width=int(width), height=int(height), plane=tuple(float(v) for v in plane),
                  clip_start=float(p["clip_start"]), clip_end=float(p["clip_end"]))


def rigid(m: np.ndarray) -> np.ndarray:
    """``m`` with unit-length axis columns (scale removed), translation kept."""
    out = np.array(m, dtype=np.float64)
    for a in range(3):
        n = np.linalg.norm(out[:3, a])
        if n > 0.0:
            out[:3, a] /= n
    return out


def default_camera(width: int, height: int) -> Camera:
    """A camera at the origin looking down -Z, for scenes without an active camera."""
    p = FALLBACK
    plane = camera_plane("PERSP", p["lens"], p["sensor_width"], p["sensor_height"],
                         p["sensor_fit"], 0.0, 0.0, p["ortho_scale"], width, height)
    return Camera("PERSP", np.eye(4), int(width), int(height), tuple(plane),
                  p["clip_start"], p["clip_end"])
