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
    if p["type"] == "PANO":
        kind = str(getattr(cam, "panorama_type", "FISHEYE_EQUISOLID"))
        if kind not in PANORAMAS:
            warnings.append(f"camera '{cam_ob.name}': {kind} panoramas are not supported; "
                            "rendering as a perspective camera with its lens")
            p["type"] = "PERSP"
    elif p["type"] not in ("PERSP", "ORTHO"):
        warnings.append(f"camera '{cam_ob.name}': {p['type']} cameras are not supported; "
                        "rendering as a perspective camera with its lens")
        p["type"] = "PERSP"
    return p


PANORAMAS = ("EQUIRECTANGULAR", "FISHEYE_EQUIDISTANT", "FISHEYE_EQUISOLID",
             "FISHEYE_LENS_POLYNOMIAL", "MIRRORBALL")


def panorama(cam, p: dict, width: int, height: int, aspect=(1.0, 1.0)) -> dict:
    """The Camera's ``panorama`` dict of Blender camera data ``cam`` (type ``PANORAMAS``):
    a fisheye's sensor follows the image's aspect as Cycles' sync sets it (the fitted side
    keeps the sensor's size)."""
    fx, fy = float(width) * aspect[0], float(height) * aspect[1]
    fit = str(p["sensor_fit"])
    horizontal = fx >= fy if fit == "AUTO" else fit == "HORIZONTAL"
    size = float(p["sensor_height"]) if fit == "VERTICAL" else float(p["sensor_width"])
    sensor = (size, size * fy / fx) if horizontal else (size * fx / fy, size)
    get = lambda name, default: float(getattr(cam, name, default))
    return dict(type=str(cam.panorama_type), fov=get("fisheye_fov", np.pi),
                lens=get("fisheye_lens", 10.5), sensor=sensor,
                longitude=(get("longitude_min", -np.pi), get("longitude_max", np.pi)),
                latitude=(get("latitude_min", -0.5 * np.pi), get("latitude_max", 0.5 * np.pi)),
                polynomial=tuple(get(f"fisheye_polynomial_k{i}", 0.0) for i in range(5)))


def depth_of_field(cam_ob, lens_mm: float, projection: str) -> dict:
    """Camera fields of the object's depth of field, as Cycles reads them: the lens radius
    (m) f / (2 N) from the focal length f and the f-stop N (an orthographic camera:
    1 / (2 N)), the focus distance (to the focus object along the view axis, else the
    distance set), the blades, their rotation and the aperture ratio.  {} without it."""
    dof = getattr(getattr(cam_ob, "data", None), "dof", None)
    if dof is None or not dof.use_dof:
        return {}
    fstop = max(float(dof.aperture_fstop), 1e-5)
    aperture = 1.0 / (2.0 * fstop) if projection == "ORTHO" else lens_mm * 1e-3 / (2.0 * fstop)
    focus = float(dof.focus_distance)
    if dof.focus_object is not None:
        m = rigid(matrix(cam_ob.matrix_world))
        target = np.asarray(matrix(dof.focus_object.matrix_world))[:3, 3]
        focus = abs(float(np.dot(m[:3, 2], m[:3, 3] - target)))
    return dict(aperture=float(aperture), focus_distance=max(focus, 1e-5),
                blades=int(dof.aperture_blades), blade_rotation=float(dof.aperture_rotation),
                aperture_ratio=max(float(dof.aperture_ratio), 1e-5))


def camera_from_object(cam_ob, scene, width: int, height: int, warnings: List[str]) -> Camera:
    """A :class:`~mpp_render.scene.Camera` for the evaluated object ``cam_ob`` rendering
    ``width`` x ``height`` pixels; the object's scale is removed, as Cycles does."""
    p = _params(cam_ob, warnings)
    r = scene.render
    plane = camera_plane(p["type"], p["lens"], p["sensor_width"], p["sensor_height"],
                         p["sensor_fit"], p["shift_x"], p["shift_y"], p["ortho_scale"],
                         width, height, r.pixel_aspect_x, r.pixel_aspect_y)
    lens = depth_of_field(cam_ob, float(p["lens"]), p["type"]) if cam_ob.type == "CAMERA" else {}
    if p["type"] == "PANO":
        lens["panorama"] = panorama(cam_ob.data, p, width, height,
                                    (float(r.pixel_aspect_x), float(r.pixel_aspect_y)))
    return Camera(projection=p["type"], cam_to_world=rigid(matrix(cam_ob.matrix_world)),
                  width=int(width), height=int(height), plane=tuple(float(v) for v in plane),
                  clip_start=float(p["clip_start"]), clip_end=float(p["clip_end"]), **lens)


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
