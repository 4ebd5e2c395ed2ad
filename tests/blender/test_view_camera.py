"""The viewport's camera (translate.view) from Blender's view and window matrices.  Background
bpy has no viewport, so the matrices come from a scene camera (its world matrix inverted,
``calc_matrix_camera``) and the Camera built from them must give the same primary rays
(camera.primary_rays: origins, directions, planar clip range) as the Camera built from the
object (translate.camera.camera_from_object)."""
from types import SimpleNamespace

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render.blender.translate.camera import camera_from_object  # noqa: E402
from mpp_render.blender.translate.view import (camera_from_matrices,  # noqa: E402
                                               camera_from_region)
from mpp_render.camera import primary_rays  # noqa: E402

W, H = 64, 36


def scene_camera(sc, **data):
    """A rotated, moved, non-uniformly scaled camera with camera data ``data``."""
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    sc.collection.objects.link(cam)
    cam.location = (0.7, -4.0, 1.2)
    cam.rotation_euler = (1.3, 0.2, 0.4)
    cam.scale = (1.0, 2.0, 0.5)
    for k, v in data.items():
        setattr(cam.data, k, v)
    sc.camera = cam
    sc.render.resolution_x, sc.render.resolution_y = W, H
    sc.render.resolution_percentage = 100
    bpy.context.view_layer.update()
    return cam


def blender_matrices(sc, cam, w=W, h=H):
    """(view, window) as a viewport looking through ``cam`` holds them."""
    dg = bpy.context.evaluated_depsgraph_get()
    window = cam.calc_matrix_camera(dg, x=w, y=h, scale_x=sc.render.pixel_aspect_x,
                                    scale_y=sc.render.pixel_aspect_y)
    return cam.matrix_world.inverted(), window


def rays(camera):
    """Primary rays through the pixel corners and centres of the whole image."""
    yy, xx = np.mgrid[0:2 * camera.height + 1, 0:2 * camera.width + 1] * 0.5
    return primary_rays(camera, xx.ravel(), yy.ravel())


def float32_tolerance(camera):
    """(rtol, atol) of the clip distances read back from a float32 window matrix: a
    perspective far plane is known to about 1e-7 f/n relative, orthographic clips to about
    1e-7 (|n| + |f|) metres."""
    n, f = abs(camera.clip_start), abs(camera.clip_end)
    if camera.projection == "PERSP":
        return 2e-6 + 1e-7 * f / n, 0.0
    return 2e-6, 1e-7 * (n + f)


def assert_same_rays(got, want):
    o1, d1, tmin1, tmax1, ax1 = rays(got)
    o2, d2, tmin2, tmax2, ax2 = rays(want)
    assert got.projection == want.projection
    np.testing.assert_allclose(o1, o2, atol=1e-5)
    np.testing.assert_allclose(d1, d2, atol=1e-5)
    np.testing.assert_allclose(ax1, ax2, atol=1e-5)
    rtol, atol = float32_tolerance(want)
    np.testing.assert_allclose(tmin1, tmin2, rtol=2e-6, atol=atol)
    np.testing.assert_allclose(tmax1, tmax2, rtol=rtol, atol=atol)


@pytest.mark.parametrize("fit", ["AUTO", "HORIZONTAL", "VERTICAL"])
@pytest.mark.parametrize("size", [(W, H), (H, W)])
def test_perspective_camera(empty_scene, fit, size):
    cam = scene_camera(empty_scene, lens=42.0, sensor_width=36.0, sensor_height=20.0,
                       sensor_fit=fit, clip_start=0.3, clip_end=60.0)
    empty_scene.render.resolution_x, empty_scene.render.resolution_y = size
    view, window = blender_matrices(empty_scene, cam, *size)
    want = camera_from_object(cam, empty_scene, *size, [])
    got = camera_from_matrices(view, window, *size)
    assert_same_rays(got, want)
    np.testing.assert_allclose(got.plane, want.plane, rtol=1e-6)


@pytest.mark.parametrize("aspect", [(1.0, 1.0), (1.0, 1.6), (2.0, 1.0)])
def test_perspective_lens_shift(empty_scene, aspect):
    """Shift (and pixel aspect) put Blender's off-diagonal P02, P12 terms in the matrix."""
    sc = empty_scene
    cam = scene_camera(sc, lens=30.0, shift_x=0.25, shift_y=-0.15)
    sc.render.pixel_aspect_x, sc.render.pixel_aspect_y = aspect
    view, window = blender_matrices(sc, cam)
    assert abs(window[0][2]) > 0.1 and abs(window[1][2]) > 0.1   # the terms are there
    want = camera_from_object(cam, sc, W, H, [])
    assert_same_rays(camera_from_matrices(view, window, W, H), want)
    # numpy matrices give the same camera as mathutils ones
    got = camera_from_matrices(np.array(view), np.array(window), W, H)
    assert_same_rays(got, want)


@pytest.mark.parametrize("shift", [(0.0, 0.0), (0.3, 0.1)])
def test_orthographic_camera(empty_scene, shift):
    sc = empty_scene
    cam = scene_camera(sc, type="ORTHO", ortho_scale=3.5, shift_x=shift[0], shift_y=shift[1],
                       clip_start=0.5, clip_end=50.0)
    view, window = blender_matrices(sc, cam)
    assert tuple(window[3]) == (0.0, 0.0, 0.0, 1.0)
    want = camera_from_object(cam, sc, W, H, [])
    got = camera_from_matrices(view, window, W, H)
    assert_same_rays(got, want)
    np.testing.assert_allclose(got.plane, want.plane, atol=1e-6)


@pytest.mark.parametrize("kind, clip", [("PERSP", (0.05, 30.0)), ("PERSP", (2.5, 400.0)),
                                        ("ORTHO", (1e-3, 20.0)), ("ORTHO", (7.0, 300.0))])
def test_clip_distances(empty_scene, kind, clip):
    cam = scene_camera(empty_scene, type=kind, clip_start=clip[0], clip_end=clip[1])
    view, window = blender_matrices(empty_scene, cam)
    got = camera_from_matrices(view, window, W, H)
    rtol, atol = float32_tolerance(got)
    assert got.projection == kind
    assert got.clip_start == pytest.approx(clip[0], rel=2e-6, abs=atol)
    assert got.clip_end == pytest.approx(clip[1], rel=rtol, abs=atol)
    assert_same_rays(got, camera_from_object(cam, empty_scene, W, H, []))


def ortho_window(l, r, b, t, n, f):
    """OpenGL's glOrtho matrix, as Blender's orthographic_m4."""
    return np.array([[2 / (r - l), 0, 0, -(r + l) / (r - l)],
                     [0, 2 / (t - b), 0, -(t + b) / (t - b)],
                     [0, 0, -2 / (f - n), -(f + n) / (f - n)],
                     [0, 0, 0, 1.0]])


def test_orthographic_viewport_keeps_its_negative_clip_start():
    """A free orthographic viewport clips at [-clip_end / 2, clip_end / 2] (Blender's
    BKE_camera_params_from_view3d): the Camera keeps the negative start, and its rays start
    behind the view plane."""
    view = np.eye(4)
    view[:3, 3] = (-1.0, 2.0, -3.0)
    got = camera_from_matrices(view, ortho_window(-2.0, 2.0, -1.5, 1.0, -500.0, 500.0), 40, 25)
    assert got.projection == "ORTHO"
    assert got.clip_start == pytest.approx(-500.0) and got.clip_end == pytest.approx(500.0)
    np.testing.assert_allclose(got.plane, (-2.0, 2.0, -1.5, 1.0))
    np.testing.assert_allclose(got.cam_to_world[:3, 3], (1.0, -2.0, 3.0))
    t_min = rays(got)[2]
    assert np.all(t_min == pytest.approx(-500.0))


def test_camera_from_region_reads_the_region(empty_scene):
    sc = empty_scene
    cam = scene_camera(sc, lens=24.0, shift_x=-0.1)
    view, window = blender_matrices(sc, cam)
    region = SimpleNamespace(view_matrix=view, window_matrix=window,
                             view_perspective="CAMERA")
    assert_same_rays(camera_from_region(region, W, H), camera_from_object(cam, sc, W, H, []))


PERSP = np.array([[2.0, 0, 0.1, 0], [0, 3.0, 0, 0], [0, 0, -1.01, -0.2], [0, 0, -1.0, 0]])


def changed(m, **cells):
    out = np.array(m, dtype=np.float64)
    for key, value in cells.items():
        out[int(key[1]), int(key[2])] = value
    return out


@pytest.mark.parametrize("view, window, why", [
    (np.eye(4), changed(PERSP, p32=-0.5), "neither perspective"),     # not projective
    (np.eye(4), changed(PERSP, p30=0.2), "neither perspective"),
    (np.eye(4), changed(PERSP, p01=0.3), "skew"),                     # skewed plane
    (np.eye(4), changed(ortho_window(-1, 1, -1, 1, 0.1, 9), p12=0.3), "skew"),
    (np.eye(4), changed(PERSP, p22=-1.0), "singular"),                # no clip range
    (np.eye(4), changed(PERSP, p00=0.0), "singular"),
    (np.eye(4), changed(PERSP, p23=0.2), "no valid view"),            # near < 0
    (np.eye(4), np.zeros((4, 4)), "neither perspective"),
    (changed(np.eye(4), p11=0.0), PERSP, "view matrix"),              # singular view
    (changed(np.eye(4), p31=1.0), PERSP, "view matrix"),              # not affine
    (np.eye(4), np.eye(3), "4x4"),
    (np.eye(4), changed(PERSP, p00=np.nan), "finite"),
])
def test_bad_matrices_raise(view, window, why):
    with pytest.raises(ValueError, match=why):
        camera_from_matrices(view, window, W, H)
    # the unchanged matrices are fine
    assert camera_from_matrices(np.eye(4), PERSP, W, H).projection == "PERSP"
