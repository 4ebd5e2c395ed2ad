"""Cameras as in Cycles.  Depth of field as Cycles' thin lens (camera.aperture_points,
camera.primary_rays): a lit smoke cube far behind the plane in focus, seen through a
six-bladed, squeezed aperture, renders as Cycles renders it (single scattering, rel_rmse_4
within 0.03), while the same camera as a pinhole misses by far; the aperture's points fill
the polygon uniformly.  Panoramic cameras (camera.panorama_directions): equirectangular,
the three fisheyes and the mirror ball, each within 0.03 of Cycles."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render import metrics  # noqa: E402
from mpp_render.blender import batch, frame  # noqa: E402
from mpp_render.camera import aperture_points  # noqa: E402
from mpp_render.scene import Camera  # noqa: E402
from parts import add_cube, add_light, render_cycles, volume_material  # noqa: E402

pytestmark = pytest.mark.usefixtures("registered")


def lens_scene(sc, res=(48, 36)):
    """A 2 m smoke cube (density 1.5, albedo 0.9) under a sun, 5 m from a 50 mm camera at
    f/0.1 focused 1.5 m away (lens radius 0.25 m: a circle of confusion about 8 pixels
    wide on the cube); black world."""
    sc.world = None
    add_cube(sc, "Smoke", mat=volume_material("SmokeVol", density=1.5, anisotropy=0.3))
    add_light(sc, energy=4.0, rotation=(0.7, 0.2, 0.4))
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    sc.collection.objects.link(cam)
    cam.location = (0.4, -5.0, 0.3)
    cam.rotation_euler = (np.pi / 2, 0, 0)
    cam.data.lens = 50.0
    dof = cam.data.dof
    dof.use_dof = True
    dof.focus_distance = 1.5
    dof.aperture_fstop = 0.1
    dof.aperture_blades = 6
    dof.aperture_rotation = 0.3
    dof.aperture_ratio = 1.4
    sc.camera = cam
    sc.render.resolution_x, sc.render.resolution_y = res
    sc.render.resolution_percentage = 100
    return cam


def render_mpp(sc, spp):
    batch.set_mpp(sc, spp, multiple=False)
    sc.mpp.voxel_resolution = 48
    return frame.render_mpp().output


def test_depth_of_field_matches_cycles(empty_scene, tmp_path):
    cam = lens_scene(empty_scene)
    ref = render_cycles(empty_scene, tmp_path, 512, seed=2)
    out = render_mpp(empty_scene, 128)   # 0.026 at 64 spp, 0.011 at 256: our noise
    assert not any("depth of field" in w for w in out.warnings)
    got = metrics.compare(out.passes["Combined"][..., :3], [ref])
    print("depth of field: rel_rmse_4", got["rel_rmse_4"], "bias", got["bias"])
    assert got["rel_rmse_4"] < 0.03, got
    cam.data.dof.use_dof = False
    pinhole = render_mpp(empty_scene, 64)
    far = metrics.compare(pinhole.passes["Combined"][..., :3], [ref])
    print("the same camera as a pinhole: rel_rmse_4", far["rel_rmse_4"])
    assert far["rel_rmse_4"] > 0.1


def test_the_aperture_is_filled_uniformly():
    """Points of a hexagon of circumradius 1 (ratio 1): inside it, mean at its centre, and
    the share of points within the inscribed circle equals its area's share."""
    cam = Camera("PERSP", np.eye(4), 8, 8, (-1, 1, -1, 1), aperture=1.0, blades=6,
                 blade_rotation=0.3)
    p = aperture_points(cam, np.random.default_rng(3).random((200000, 2)))
    ang = np.arctan2(p[:, 1], p[:, 0]) - 0.3
    sector = np.mod(ang, np.pi / 3) - np.pi / 6
    apothem = np.cos(np.pi / 6)
    assert np.all(np.hypot(p[:, 0], p[:, 1]) * np.cos(sector) <= apothem + 1e-9)
    assert np.allclose(p.mean(axis=0), 0.0, atol=0.01)
    inner = np.mean(np.hypot(p[:, 0], p[:, 1]) < apothem)
    area_hex = 1.5 * np.sqrt(3.0)
    assert inner == pytest.approx(np.pi * apothem ** 2 / area_hex, abs=0.01)
    squeezed = aperture_points(Camera("PERSP", np.eye(4), 8, 8, (-1, 1, -1, 1), aperture=1.0,
                                      aperture_ratio=2.0), np.random.default_rng(4).random((1000, 2)))
    assert np.abs(squeezed[:, 0]).max() <= 0.5 + 1e-9 and np.abs(squeezed[:, 1]).max() > 0.9


@pytest.mark.parametrize("kind, res", [("EQUIRECTANGULAR", (64, 32)),
                                       ("FISHEYE_EQUIDISTANT", (48, 48)),
                                       ("FISHEYE_EQUISOLID", (48, 36)),
                                       ("FISHEYE_LENS_POLYNOMIAL", (48, 36)),
                                       ("MIRRORBALL", (48, 48))])
def test_panoramic_cameras_match_cycles(empty_scene, tmp_path, kind, res):
    """A smoke cube seen by each of Cycles' panoramic cameras (pointed off the cube, so that
    it falls off the image's centre): single scattering within 0.03 of Cycles."""
    sc = empty_scene
    cam = lens_scene(sc, res)
    cam.data.dof.use_dof = False
    cam.data.type = "PANO"
    cam.data.panorama_type = kind
    cam.location = (0.8, -2.4, 0.4)
    cam.rotation_euler = (np.pi / 2 - 0.2, 0.0, 0.35)
    if kind == "EQUIRECTANGULAR":
        cam.data.longitude_min, cam.data.longitude_max = -2.0, 2.5
    ref = render_cycles(sc, tmp_path, 512, seed=2)
    out = render_mpp(sc, 128)
    assert not any("not supported" in w for w in out.warnings), out.warnings
    assert float(ref.mean()) > 0.001          # the cube is in view (black: 0)
    # scored on the 4-pixel blocks round the cube: the rest of a panorama is black in both
    lit = np.argwhere(ref.mean(axis=-1) > 0.01 * ref.max())
    (y0, x0), (y1, x1) = (lit.min(axis=0) // 4) * 4, (lit.max(axis=0) // 4 + 1) * 4
    crop = (slice(y0, y1), slice(x0, x1))
    got = metrics.compare(out.passes["Combined"][..., :3][crop], [ref[crop]])
    print(kind, "rel_rmse_4", got["rel_rmse_4"], "bias", got["bias"], "blocks", (y1 - y0) // 4,
          (x1 - x0) // 4)
    assert got["rel_rmse_4"] < 0.03, got
