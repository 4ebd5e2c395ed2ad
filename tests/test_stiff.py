"""Numerically stiff and extreme media render finite, non-negative, sensible passes."""
import math

import numpy as np
import pytest

from mpp_render.render import render
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, World


def cube(density=1.0, sigma_s=1.0, sigma_a=0.1, g=0.0, n=8, size=2.0, grid=None, source="VDB"):
    vox = size / n
    i2w = np.eye(4)
    i2w[:3, :3] *= vox
    i2w[:3, 3] = -size / 2 + vox / 2
    d = np.full((n, n, n), density, np.float32) if grid is None else grid
    return Medium("m", d, i2w, np.full(3, sigma_s), np.full(3, sigma_a), g, source=source)


def scene(media, lights=None, size=2.0, width=12, height=10, cam_z=None, world=0.1, multiple=True):
    cam = Camera("ORTHO", np.eye(4), width, height, (-0.8 * size, 0.8 * size, -0.6 * size, 0.6 * size))
    cam.cam_to_world[:3, 3] = [0, 0, 3 * size if cam_z is None else cam_z]
    cam.clip_start, cam.clip_end = 0.01 * size, 100.0 * size
    if lights is None:
        lights = [Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.3, 0.2, -0.93]))]
    return SceneDescription(cam, lights, media, world=World(np.full(3, world)),
                            settings=Settings(samples=1, multiple=multiple))


def check(out):
    for name, p in out.passes.items():
        assert np.all(np.isfinite(p)), name
        if name != "Depth":
            assert np.all(p >= 0), name
    return out.passes


@pytest.mark.parametrize("tau", [1e-6, 1e4])
def test_optical_depth_extremes(tau):
    p = check(render(scene([cube(sigma_s=tau / 2 * 0.9, sigma_a=tau / 2 * 0.1)])))
    T = p["Transmittance"][5, 6]
    if tau < 1:
        assert np.allclose(T, math.exp(-1e-6), rtol=1e-6)
    else:
        assert np.all(T < 1e-6)
        # a dense lit cube still shows single scattering from its surface
        assert p["Volume Single"][5, 6].min() > 0


def test_albedo_zero_has_no_scattering_and_albedo_one_is_finite():
    p = check(render(scene([cube(sigma_s=0.0, sigma_a=2.0)])))
    assert np.all(p["Volume Multiple"] == 0.0) and np.all(p["Volume Single"] == 0.0)
    p = check(render(scene([cube(sigma_s=2.0, sigma_a=0.0)])))
    assert p["Volume Multiple"].max() > 0


def test_multiple_scattering_grows_with_albedo():
    totals = []
    for albedo in (0.2, 0.6, 0.95):
        p = check(render(scene([cube(sigma_s=3 * albedo, sigma_a=3 * (1 - albedo))])))
        totals.append(p["Volume Multiple"].sum())
    assert totals[0] < totals[1] < totals[2]


@pytest.mark.parametrize("g", [-0.95, 0.0, 0.95, 0.999])
def test_anisotropy_extremes(g):
    p = check(render(scene([cube(sigma_s=2.0, g=g)])))
    assert p["Volume Single"].max() > 0


def test_density_over_six_orders_of_magnitude():
    grid = np.logspace(-3, 3, 8 ** 3).reshape(8, 8, 8).astype(np.float32)
    check(render(scene([cube(grid=grid, sigma_s=1.0)])))


@pytest.mark.parametrize("size", [1e-4 * 8, 800.0])
def test_voxel_sizes(size):
    # voxels of 1e-4 m and 100 m; coefficients scaled to keep an optical depth ~2
    p = check(render(scene([cube(size=size, sigma_s=2.0 / size, sigma_a=0.2 / size)], size=size)))
    assert p["Transmittance"][5, 6].max() < 0.5


@pytest.mark.parametrize("where", [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0)])
def test_point_light_inside_and_on_the_boundary(where):
    light = Light("POINT", "p", np.full(3, 100.0), position=np.array(where))
    p = check(render(scene([cube(sigma_s=1.0)], [light])))
    assert p["Volume Single"].max() > 0


def test_camera_inside_the_medium():
    desc = scene([cube(sigma_s=1.0)], cam_z=0.2)
    # 16 samples: the jittered steps' noise at the uniform cube's edges is one sample's
    # (a whole voxel a step in this sun-lit grid, render.auto_step: +-13 % in T at 1 sample)
    desc.settings.samples = 16
    p = check(render(desc))
    # from z = 0.2 - clip_start down to the bottom at -1: optical depth ~1.1 * 1.18
    assert np.allclose(p["Transmittance"][5, 6], math.exp(-1.1 * (1.2 - 0.02)), rtol=0.05)


def test_sun_grazing_at_89_9_degrees():
    a = math.radians(89.9)
    sun = Light("SUN", "sun", np.full(3, 3.0), direction=np.array([math.sin(a), 0.0, -math.cos(a)]))
    check(render(scene([cube(sigma_s=1.0)], [sun])))


def test_one_pixel_image():
    p = check(render(scene([cube(sigma_s=1.0)], width=1, height=1)))
    assert p["Combined"].shape == (1, 1, 4)


def test_a_4096_by_4096_image():
    """16.7 M pixels (the Combined pass only, as a farm frame that wants just the image): every
    pixel finite and non-negative, and the picture the same as a 256 x 256 render of the
    scene: the 16 x 16 block means of the big one match the small one's pixels (both are
    box-filtered averages of the same picture), the image means within 1 %."""
    def at(size, spp):
        desc = scene([cube(sigma_s=2.0, n=8)], width=size, height=size)
        desc.camera.plane = (-4.0, 4.0, -4.0, 4.0)   # the cube fills a tenth of the frame
        desc.settings.passes = ["Combined"]
        desc.settings.samples = spp
        return check(render(desc))["Combined"]
    big = at(4096, 1)
    assert big.shape == (4096, 4096, 4)
    small = at(256, 64)
    blocks = big.reshape(256, 16, 256, 16, 4).mean(axis=(1, 3))
    lit = small[..., :3].mean(-1) > small[0, 0, :3].mean() + 1e-3
    assert 0.05 < lit.mean() < 0.15
    assert abs(blocks[..., :3].mean() / small[..., :3].mean() - 1.0) < 0.01
    err = np.sqrt(np.mean((blocks[lit, :3] - small[lit, :3]) ** 2)) / small[lit, :3].mean()
    print("4096^2 block means against 256^2 at 64 spp: rel rmse", err)
    assert err < 0.02, err


def test_zero_and_negative_light_power_and_no_lights():
    dark = [Light("POINT", "zero", np.zeros(3), position=np.array([0, 0, 3.0])),
            Light("POINT", "neg", np.full(3, -5.0), position=np.array([0, 0, 3.0]))]
    p = check(render(scene([cube(sigma_s=1.0)], dark, world=0.0)))
    assert np.all(p["Volume Single"] == 0) and np.all(p["Volume Multiple"] == 0)
    p = check(render(scene([cube(sigma_s=1.0)], [], world=0.0)))
    assert np.all(p["Combined"][..., :3] == 0)


def test_no_media_renders_the_background():
    p = check(render(scene([])))
    assert np.allclose(p["Combined"][..., :3], 0.1) and np.all(p["Transmittance"] == 1)


def test_nan_inf_and_negative_voxels_are_sanitised():
    grid = np.ones((8, 8, 8), np.float32)
    grid[1, 2, 3] = np.nan
    grid[2, 2, 2] = np.inf
    grid[3, 3, 3] = -5
    out = render(scene([cube(grid=grid)]))
    check(out)
    assert any("3 voxels" in w for w in out.warnings), out.warnings


def test_zero_scale_medium_is_skipped_with_a_warning():
    m = cube()
    m.index_to_world = np.diag([0.0, 0.25, 0.25, 1.0])
    out = render(scene([m]))
    check(out)
    assert any("degenerate" in w for w in out.warnings), out.warnings
