"""View plane and primary rays against values worked out by hand from Blender's formulas."""
import math

import numpy as np
import pytest

from mpp_render.camera import camera_plane, primary_rays
from mpp_render.scene import Camera


def _plane(**kw):
    args = dict(projection="PERSP", lens_mm=50.0, sensor_width=36.0, sensor_height=24.0,
                sensor_fit="AUTO", shift_x=0.0, shift_y=0.0, ortho_scale=6.0,
                width=160, height=120)
    args.update(kw)
    return np.array(camera_plane(**args))


def test_plane_auto_landscape():
    # Horizontal fit: half width = 18/50; the height follows the image aspect.
    np.testing.assert_allclose(_plane(), [-0.36, 0.36, -0.27, 0.27], rtol=1e-12)


def test_plane_auto_portrait_fits_width_to_height():
    # AUTO fits sensor_width to the larger side, here the height.
    np.testing.assert_allclose(_plane(width=120, height=160), [-0.27, 0.27, -0.36, 0.36], rtol=1e-12)


def test_plane_vertical_uses_sensor_height():
    np.testing.assert_allclose(_plane(sensor_fit="VERTICAL"), [-0.32, 0.32, -0.24, 0.24], rtol=1e-12)


def test_plane_horizontal_on_portrait_image():
    np.testing.assert_allclose(_plane(sensor_fit="HORIZONTAL", width=120, height=160),
                               [-0.36, 0.36, -0.48, 0.48], rtol=1e-12)


def test_plane_shift_is_in_units_of_the_fitted_side():
    # Horizontal fit: shift 0.25 moves the plane by 0.25 * 36/50 in x and y alike.
    np.testing.assert_allclose(_plane(shift_x=0.25, shift_y=-0.1),
                               [-0.36 + 0.18, 0.36 + 0.18, -0.27 - 0.072, 0.27 - 0.072], rtol=1e-12)
    # Vertical fit: the fitted side is the height (sensor 24 mm).
    np.testing.assert_allclose(_plane(sensor_fit="VERTICAL", shift_x=0.5),
                               [-0.32 + 0.24, 0.32 + 0.24, -0.24, 0.24], rtol=1e-12)


def test_plane_pixel_aspect():
    # Pixels twice as wide as tall: the image is 2*100 : 100 wide, horizontal fit.
    np.testing.assert_allclose(_plane(width=100, height=100, pixel_aspect_x=2.0, pixel_aspect_y=1.0),
                               [-0.36, 0.36, -0.18, 0.18], rtol=1e-12)
    # Pixels twice as tall: 100 : 2*100, AUTO now fits the height.
    np.testing.assert_allclose(_plane(width=100, height=100, pixel_aspect_x=1.0, pixel_aspect_y=2.0),
                               [-0.18, 0.18, -0.36, 0.36], rtol=1e-12)


def test_plane_ortho():
    np.testing.assert_allclose(_plane(projection="ORTHO"), [-3.0, 3.0, -2.25, 2.25], rtol=1e-12)
    np.testing.assert_allclose(_plane(projection="ORTHO", shift_x=0.5), [0.0, 6.0, -2.25, 2.25],
                               atol=1e-12)


def _camera(projection="PERSP", plane=(-0.36, 0.36, -0.27, 0.27), matrix=None, w=160, h=120):
    return Camera(projection=projection, cam_to_world=np.eye(4) if matrix is None else matrix,
                  width=w, height=h, plane=plane, clip_start=0.5, clip_end=100.0)


def test_centre_ray_points_down_minus_z():
    o, d, t0, t1, ax = primary_rays(_camera(), np.array([80.0]), np.array([60.0]))
    np.testing.assert_allclose(o, [[0, 0, 0]])
    np.testing.assert_allclose(d, [[0, 0, -1]], atol=1e-15)
    np.testing.assert_allclose([t0[0], t1[0], ax[0]], [0.5, 100.0, 1.0])


def test_corner_rays_of_a_50mm_lens():
    # Top-left corner of the image: x = -18/50, y = +13.5/50 at z = -1.
    o, d, t0, t1, ax = primary_rays(_camera(), np.array([0.0, 160.0]), np.array([0.0, 120.0]))
    v = np.array([[-0.36, 0.27, -1.0], [0.36, -0.27, -1.0]])
    n = np.linalg.norm(v, axis=1)
    np.testing.assert_allclose(d, v / n[:, None], rtol=1e-12)
    np.testing.assert_allclose(ax, 1.0 / n, rtol=1e-12)
    np.testing.assert_allclose(t0, 0.5 * n, rtol=1e-12)     # planar clipping
    np.testing.assert_allclose(t1, 100.0 * n, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    # Horizontal field of view of a 36 mm sensor behind a 50 mm lens.
    fov = 2.0 * math.atan(18.0 / 50.0)
    np.testing.assert_allclose(2 * math.atan2(-d[0, 0], -d[0, 2]), fov, rtol=1e-12)


def test_rays_are_rotated_and_translated():
    # Camera at (1, 2, 3) looking along +Y (rotation of 90 degrees about X).
    m = np.array([[1, 0, 0, 1], [0, 0, -1, 2], [0, 1, 0, 3], [0, 0, 0, 1]], float)
    o, d, _, _, ax = primary_rays(_camera(matrix=m), np.array([80.0, 160.0]), np.array([60.0, 60.0]))
    np.testing.assert_allclose(o, [[1, 2, 3], [1, 2, 3]])
    np.testing.assert_allclose(d[0], [0, 1, 0], atol=1e-15)
    # Right edge centre: camera +X stays world +X.
    np.testing.assert_allclose(d[1], np.array([0.36, 1.0, 0.0]) / math.hypot(0.36, 1.0), rtol=1e-12)
    np.testing.assert_allclose(ax[1], np.dot(d[1], [0, 1, 0]))


def test_ortho_rays():
    m = np.eye(4)
    m[:3, 3] = [0, 0, 5]
    cam = _camera("ORTHO", plane=(-3.0, 3.0, -2.25, 2.25), matrix=m)
    o, d, t0, t1, ax = primary_rays(cam, np.array([0.0, 80.0, 160.0]), np.array([0.0, 60.0, 120.0]))
    np.testing.assert_allclose(o, [[-3, 2.25, 5], [0, 0, 5], [3, -2.25, 5]])
    np.testing.assert_allclose(d, [[0, 0, -1]] * 3)
    np.testing.assert_allclose(t0, 0.5)
    np.testing.assert_allclose(t1, 100.0)
    np.testing.assert_allclose(ax, 1.0)


def test_pixel_rows_run_top_to_bottom():
    _, d, _, _, _ = primary_rays(_camera(), np.array([80.0, 80.0]), np.array([0.5, 119.5]))
    assert d[0, 1] > 0 > d[1, 1]


def test_bad_arguments():
    with pytest.raises(ValueError):
        _plane(sensor_fit="DIAGONAL")
    with pytest.raises(ValueError):
        _plane(projection="SPHERICAL")


def test_thin_lens_rays_of_a_pixel_meet_on_the_plane_in_focus():
    """Every ray through one pixel, whatever its point on the aperture, crosses the plane in
    focus where the pinhole ray does; their origins spread over the aperture."""
    from mpp_render.camera import primary_rays
    from mpp_render.scene import Camera
    c2w = np.eye(4)
    c2w[:3, 3] = (0.5, -2.0, 1.0)
    cam = Camera("PERSP", c2w, 40, 30, (-0.4, 0.4, -0.3, 0.3), aperture=0.2,
                 focus_distance=3.0, blades=5, blade_rotation=0.2, aperture_ratio=1.5)
    n = 500
    px, py = np.full(n, 12.3), np.full(n, 20.7)
    o, d, tmin, tmax, axial = primary_rays(cam, px, py, np.random.default_rng(1).random((n, 2)))
    o0, d0 = primary_rays(cam, px[:1], py[:1])[:2]
    fwd = -c2w[:3, 2]
    hit = o + d * (3.0 / (d @ fwd))[:, None]            # planar distance 3 m along the axis
    target = o0[0] + d0[0] * 3.0 / (d0[0] @ fwd)
    assert np.allclose(hit, target, atol=1e-9)
    spread = o - c2w[:3, 3]
    assert np.abs(spread @ fwd).max() < 1e-12          # on the lens plane
    assert 0.05 < np.abs(spread[:, 0]).max() <= 0.2 / 1.5 + 1e-9   # squeezed in x
    assert np.allclose(axial, d @ fwd)
