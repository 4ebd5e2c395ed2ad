"""The memory budget (budget.py): grids whose precompute fields do not fit are box-downsampled
by integer factors, keep their world box and optical depth, and are reported."""
import numpy as np
import pytest

from mpp_render.budget import (MB, apply_budget, box_downsample, downsampled_transform,
                               field_bytes, fit_media, plan, reduced_shape)
from mpp_render.render import render
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, World

SUN = Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.3, 0.2, -0.93]))
DARK = Light("POINT", "off", np.zeros(3), position=np.array([0.0, 0.0, 3.0]))


def cloud(n, size=2.0, name="cloud", seed=0):
    """A soft ball of noisy density filling an n^3 grid of side ``size`` m at the origin."""
    x = (np.arange(n) + 0.5) / n * 2 - 1
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    rng = np.random.default_rng(seed)
    d = np.clip(1 - np.sqrt(X ** 2 + Y ** 2 + Z ** 2), 0, None) * (0.6 + 0.4 * rng.random((n,) * 3))
    i2w = np.eye(4)
    i2w[:3, :3] *= size / n
    i2w[:3, 3] = -size / 2 + size / n / 2
    return Medium(name, d.astype(np.float32), i2w, np.full(3, 3.0), np.full(3, 0.3), 0.2)


def cell_box(i2w, shape):
    """World corners of the grid's cell box (index -0.5 .. n - 0.5)."""
    lo = np.asarray(i2w) @ np.array([-0.5, -0.5, -0.5, 1.0])
    hi = np.asarray(i2w) @ np.array([s - 0.5 for s in shape] + [1.0])
    return lo[:3], hi[:3]


def test_field_bytes_counts_density_lights_and_world():
    # 1 + 3 per emitting light (the dark one has no channels) + 6, on the padded grid
    assert field_bytes((10, 20, 30), [SUN, DARK]) == 4 * (1 + 3 + 6) * 12 * 22 * 32
    assert field_bytes((10, 20, 30), []) == 4 * 7 * 12 * 22 * 32


def test_the_beams_of_a_forward_scattering_medium_are_counted():
    """With multiple scattering on and a forward peak, each light has a beam channel too
    (precompute.FieldLayout.beam_channels): the budget counts what the precompute makes."""
    from mpp_render.budget import field_channels, has_beams
    from mpp_render.media import prepare
    from mpp_render.precompute import precompute
    m = cloud(8)   # g = 0.2
    assert has_beams([m], True) and not has_beams([m], False)
    iso = Medium("iso", m.density, m.index_to_world, m.sigma_s, m.sigma_a, 0.0)
    assert not has_beams([iso], True)
    cam = Camera("PERSP", np.eye(4), 4, 4, (-1, 1, -1, 1))
    world = World(np.array([0.1, 0.2, 0.3]))
    for media, multiple in (([m], True), ([m], False), ([iso], True)):
        pre = precompute([prepare(x) for x in media], [SUN, DARK], world, cam, n_dirs=4,
                         multiple=multiple)
        # (the budget counts the world's multiply scattered channels even when off)
        unused = 0 if multiple else 3
        assert pre.fields[0].shape[-1] == field_channels([SUN, DARK], has_beams(media, multiple)) - unused
    assert field_bytes((10, 20, 30), [SUN, DARK], True) == 4 * (1 + 6 + 6) * 12 * 22 * 32
    # multiple scattering: the march's flat level on the field's voxels (march.on_field) too
    assert field_bytes((10, 20, 30), [SUN, DARK], True, True) == 4 * (1 + 6 + 6 + 3) * 12 * 22 * 32
    # a budget that holds the field without beams but not with them
    need = field_bytes((64,) * 3, [SUN])
    assert fit_media([cloud(64)], [SUN], 1.1 * need / MB, [])[0].density.shape == (64,) * 3
    warnings = []
    (out,) = fit_media([cloud(64)], [SUN], 1.1 * need / MB, warnings, multiple=True)
    assert out.density.shape[0] < 64 and warnings


def test_plan_keeps_grids_that_fit_and_zero_is_unlimited():
    assert plan([(64, 64, 64)], [SUN], 0) == [1]
    assert plan([(64, 64, 64)], [SUN], 100) == [1]
    f = plan([(64, 64, 64)], [SUN], 3)
    assert f == [2] and field_bytes(reduced_shape((64,) * 3, 2), [SUN]) <= 3 * MB


def test_plan_shrinks_the_largest_grid_first():
    shapes = [(16, 16, 16), (128, 128, 128)]
    f = plan(shapes, [SUN], 12)
    assert f[0] == 1 and f[1] > 1
    assert sum(field_bytes(reduced_shape(s, k), [SUN]) for s, k in zip(shapes, f)) <= 12 * MB
    # with a tiny budget both shrink and end up about equally coarse
    f = plan(shapes, [SUN], 0.05)
    sizes = [max(reduced_shape(s, k)) for s, k in zip(shapes, f)]
    assert f[0] > 1 and abs(sizes[0] - sizes[1]) <= 2


def test_box_downsample_is_the_block_mean_when_the_factor_divides():
    rng = np.random.default_rng(1)
    d = rng.random((8, 12, 4)).astype(np.float32)
    got = box_downsample(d, 2)
    want = d.reshape(4, 2, 6, 2, 2, 2).mean(axis=(1, 3, 5))
    assert got.shape == (4, 6, 2) and got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=1e-6)


@pytest.mark.parametrize("shape,factor", [((7, 5, 9), 2), ((10, 3, 1), 3), ((13, 13, 13), 4)])
def test_box_downsample_keeps_the_integral(shape, factor):
    rng = np.random.default_rng(2)
    d = rng.random(shape).astype(np.float32)
    small = box_downsample(d, factor)
    assert small.shape == reduced_shape(shape, factor)
    cell = np.prod([n / m for n, m in zip(shape, small.shape)])
    assert small.sum() * cell == pytest.approx(d.sum(), rel=1e-5)
    assert small.min() >= d.min() - 1e-6 and small.max() <= d.max() + 1e-6
    ones = box_downsample(np.ones(shape, np.float32), factor)
    np.testing.assert_allclose(ones, 1.0, rtol=1e-6)  # no darkening at partial blocks


def test_downsampled_transform_keeps_the_world_box():
    i2w = np.array([[0.1, 0.02, 0, 1.0], [0, 0.2, 0, -2.0], [0, 0, 0.05, 0.5], [0, 0, 0, 1]])
    old, new = (13, 7, 20), reduced_shape((13, 7, 20), 3)
    m = downsampled_transform(i2w, old, new)
    for a, b in zip(cell_box(i2w, old), cell_box(m, new)):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_fit_media_downsamples_reports_and_leaves_the_rest():
    big, small = cloud(64, name="big"), cloud(8, name="small")
    twin = Medium("twin", big.density, big.index_to_world + 0, big.sigma_s, big.sigma_a)
    warnings = []
    out = fit_media([big, small, twin], [SUN], 6, warnings)
    assert out[1] is small
    assert out[0].density.shape == (32, 32, 32) and out[2].density is out[0].density
    assert big.density.shape == (64, 64, 64)  # the input is not touched
    assert warnings == ["medium 'big': grid 64^3 downsampled by 2 to fit the memory budget of "
                        "6 MB; now 32^3",
                        "medium 'twin': grid 64^3 downsampled by 2 to fit the memory budget of "
                        "6 MB; now 32^3"]
    assert sum(field_bytes(m.density.shape, [SUN]) for m in out) <= 6 * MB
    for a, b in zip(cell_box(big.index_to_world, (64,) * 3), cell_box(out[0].index_to_world, (32,) * 3)):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_non_cubic_grid_and_nan_voxels():
    m = cloud(30)
    m.density = m.density[:, :20, :10].copy()
    m.density[3, 4, 5] = np.nan
    m.density[4, 4, 5] = -1.0
    warnings = []
    (out,) = fit_media([m], [SUN], 0.1, warnings)
    assert np.all(np.isfinite(out.density)) and out.density.min() >= 0
    assert warnings[0] == "medium 'cloud': 2 voxels were NaN, infinite or negative and were set to 0"
    assert warnings[1].startswith("medium 'cloud': grid 30x20x10 downsampled by ")


def scene(media, budget_mb, width=40, height=40):
    cam = Camera("ORTHO", np.eye(4), width, height, (-1.2, 1.2, -1.2, 1.2))
    cam.cam_to_world[:3, 3] = [0, 0, 5]
    return SceneDescription(cam, [SUN], media, world=World(np.full(3, 0.05)),
                            settings=Settings(samples=1, memory_budget_mb=budget_mb, threads=2))


def test_settings_default_budget():
    assert Settings().memory_budget_mb == 2048
    desc = scene([cloud(16)], 2048)
    assert apply_budget(desc, []) is desc


def test_render_over_budget_is_close_to_the_full_grid_and_says_so():
    full = render(scene([cloud(64)], 0))
    desc = scene([cloud(64)], 3)
    small = render(desc)
    assert desc.media[0].density.shape == (64, 64, 64)  # the caller's scene is not changed
    msgs = [w for w in small.warnings if "memory budget" in w]
    assert msgs == ["medium 'cloud': grid 64^3 downsampled by 2 to fit the memory budget of 3 MB; "
                    "now 32^3"]
    assert not any("memory budget" in w for w in full.warnings)
    a, b = full.passes["Transmittance"], small.passes["Transmittance"]
    assert np.all(np.isfinite(b))
    # the optical depth is kept: the mean transmittance barely moves, pixels by a little
    assert abs(a.mean() - b.mean()) < 0.01
    assert np.abs(a - b).max() < 0.06
    s_a, s_b = full.passes["Volume Single"].sum(), small.passes["Volume Single"].sum()
    assert s_b == pytest.approx(s_a, rel=0.03)

