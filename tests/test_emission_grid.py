"""Per-voxel emission (Medium.emission_grid): the field channels, both march twins, the
sanitising of bad values, the memory budget, and blackbody colours (blackbody.py)."""
import numpy as np
import pytest

from mpp_render import blackbody, kernels
from mpp_render.budget import fit_media
from mpp_render.media import prepare
from mpp_render.precompute import precompute
from mpp_render.render import render
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, World
from rays import march_inputs, march_twins

needs_c = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")


def hot_medium(shape=(10, 9, 8), emission=(0.0, 0.0, 0.0)):
    """A smoke grid whose emission grid grows along x (hot at high x)."""
    rng = np.random.default_rng(3)
    d = (rng.random(shape) * 2).astype(np.float32)
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([0.3, 0.35, 0.4])
    i2w[:3, 3] = [-1.4, -1.3, -1.5]
    x = np.linspace(0.0, 1.0, shape[0])[:, None, None, None]
    grid = (x * np.array([3.0, 2.0, 1.0]) * np.ones(shape + (3,))).astype(np.float32)
    grid[:, :, :2] = 0.0   # some voxels with density but no emission
    d[:, :, -1] = 0.0      # and some with emission but no density
    return Medium("fire", d, i2w, np.array([1.0, 1.0, 1.0]), np.array([0.5, 0.5, 0.5]), 0.3,
                  emission=np.array(emission, np.float64), emission_grid=grid)


def march_args(rng, media, lights, pre, n=2000):
    ec = [-1 if c is None else c for c in pre.layout.emission_channels]
    return march_inputs(rng, media, lights, pre, n, 1.5, 0.07,
                        emissions=[np.maximum(m.medium.emission, 0) for m in media],
                        bricks=[m.march_bricks for m in media], adapt_tau=0.1,
                        emission_channels=ec)


def two_media():
    plain = Medium("plain", np.ones((4, 4, 4), np.float32), np.diag([0.3, 0.3, 0.3, 1.0]),
                   np.full(3, 1.0), np.full(3, 0.2), emission=np.array([0.2, 0.1, 0.0]))
    return [prepare(hot_medium(emission=(0.1, 0.0, 0.05))), prepare(plain)]


def test_field_layout_puts_the_emission_grid_last():
    media = two_media()
    lights = [Light("POINT", "pt", np.full(3, 100.0), position=np.array([0.0, 0.0, 3.0]))]
    pre = precompute(media, lights, World(), Camera("PERSP", np.eye(4), 4, 4, (-1, 1, -1, 1)))
    c = pre.layout.channels
    assert pre.layout.emission_channels == [c, None]
    assert pre.fields[0].shape[3] == c + 3 and pre.fields[1].shape[3] == c
    np.testing.assert_array_equal(pre.fields[0][..., c:c + 3], media[0].emission_grid)
    assert media[0].emission_grid.shape == media[0].grid.shape + (3,)   # padded like density


@needs_c
def test_march_twins_agree_with_emission_grids():
    rng = np.random.default_rng(11)
    media = two_media()
    lights = [Light("POINT", "pt", np.full(3, 100.0), position=np.array([0.5, 0.0, 3.0]))]
    pre = precompute(media, lights, World(), Camera("PERSP", np.eye(4), 4, 4, (-1, 1, -1, 1)))
    inputs = march_args(rng, media, lights, pre)
    a, b = march_twins(inputs)
    assert a.emission.max() > 0.1
    # the grid adds to the constant emission: without it the Emission pass is smaller
    no_grid = kernels.march(inputs.replace(emission_channels=None), backend="numpy")
    assert np.all(no_grid.emission <= a.emission + 1e-12)
    assert no_grid.emission.sum() < 0.9 * a.emission.sum()


@needs_c
def test_march_rejects_an_emission_channel_outside_the_fields():
    rng = np.random.default_rng(1)
    media = two_media()
    pre = precompute(media, [], World(), Camera("PERSP", np.eye(4), 4, 4, (-1, 1, -1, 1)))
    inputs = march_args(rng, media, [], pre, n=10)
    for bad in ([pre.fields[0].shape[3] - 2, -1], [-1, pre.layout.channels], [-1, 0], [1]):
        with pytest.raises(ValueError):
            kernels.march(inputs.replace(emission_channels=bad), backend="c")


def test_emission_grid_only_shines_in_the_emission_pass_where_it_is_hot():
    """Rendered through the core: the hot end (high x) is brighter in the Emission pass, and
    the emission reaches it through voxels without density too."""
    m = hot_medium()
    cam = np.eye(4)
    cam[:3, 3] = [0.0, 0.0, 6.0]
    desc = SceneDescription(Camera("ORTHO", cam, 24, 8, (-1.8, 1.8, -0.6, 0.6)), media=[m],
                            settings=Settings(samples=1, multiple=False))
    out = render(desc)
    e = out.passes["Emission"]
    assert np.all(np.isfinite(e)) and e.min() >= 0
    cols = e[:, :, 0].mean(axis=0)
    assert cols[-6:].mean() > 3 * cols[:6].mean() > 0
    # no lights: the only light scattered is the glow's (precompute.emissionlight), once
    single = out.passes["Volume Single"]
    assert single.max() > 0 and single.min() >= 0
    assert single[:, -6:, 0].mean() > single[:, :6, 0].mean()
    comb = out.passes["Combined"][..., :3]
    np.testing.assert_allclose(comb, e + single, rtol=1e-5, atol=1e-6)


def test_bad_emission_values_are_sanitised_with_a_warning():
    m = hot_medium()
    g = m.emission_grid.copy()
    g[1, 1, 3] = np.nan
    g[2, 2, 3, 1] = -4.0
    g[3, 3, 3, 2] = np.inf
    m.emission_grid = g
    warnings = []
    pm = prepare(m, warnings)
    assert np.all(np.isfinite(pm.emission_grid)) and pm.emission_grid.min() >= 0
    assert pm.emission_grid[2, 2, 4].tolist() == [0.0, 0.0, 0.0]   # NaN voxel, all colours
    assert pm.emission_grid[3, 3, 4, 1] == 0.0 and pm.emission_grid[4, 4, 4, 2] == 0.0
    assert any("5 emission values were NaN, infinite or negative" in w for w in warnings)
    m.emission_grid = np.ones((2, 2, 2, 3), np.float32)          # wrong shape
    warnings = []
    assert prepare(m, warnings).emission_grid is None
    assert any("does not match the density" in w for w in warnings)


def test_budget_downsamples_the_emission_grid_with_the_density():
    m = hot_medium(shape=(40, 40, 40))
    lights = [Light("POINT", "pt", np.full(3, 100.0))]
    warnings = []
    small = fit_media([m], lights, 1.0, warnings)[0]
    assert small.density.shape != m.density.shape
    assert small.emission_grid.shape == small.density.shape + (3,)
    # box filter: the mean emission is kept (up to the partial cells at the ends)
    np.testing.assert_allclose(small.emission_grid.mean(axis=(0, 1, 2)),
                               m.emission_grid.mean(axis=(0, 1, 2)), rtol=0.05)


# -- blackbody colours --------------------------------------------------------------------

def test_blackbody_colour_has_unit_luminance_and_reddens_when_cooler():
    t = np.array([1000.0, 2000.0, 3000.0, 4500.0, 6500.0, 10000.0])
    raw = blackbody.colour_exact(t)
    np.testing.assert_allclose(raw @ [0.2126, 0.7152, 0.0722], 1.0, rtol=5e-4)  # rounded weights
    c = blackbody.colour(t)
    assert np.all(np.diff(c[:, 0]) < 0) and np.all(np.diff(c[:, 2]) > 0)
    # D65 is the white of Rec.709: a 6504 K blackbody lies close to it (about 0.3 % in xy)
    np.testing.assert_allclose(blackbody.colour(6504.0), 1.0, atol=0.05)
    # clamped outside [800, 12000] K; NaN counts as 800 K
    np.testing.assert_allclose(blackbody.colour([300.0, np.nan]), blackbody.colour([800.0] * 2))
    np.testing.assert_allclose(blackbody.colour(5e4), blackbody.colour(12000.0))
    fine = np.linspace(800, 12000, 2001)
    np.testing.assert_allclose(blackbody.colour(fine), np.maximum(blackbody.colour_exact(fine), 0),
                               atol=1e-4 * 5.5)


def test_blackbody_emission_follows_stefan_boltzmann():
    e = blackbody.emission(np.array([1000.0, 2000.0]), 1.0)
    lum = e @ [0.2126, 0.7152, 0.0722]
    sigma = 5.670373e-8 * 1e-6 / np.pi
    assert lum[1] == pytest.approx(sigma * 2000.0 ** 4, rel=1e-3)  # blue is 0 at 2000 K already
    half = blackbody.emission(2000.0, 0.5, tint=(1.0, 0.5, 0.0))
    expect = sigma * (0.5 + 0.5 * 2000.0 ** 4) * blackbody.colour(2000.0) * [1.0, 0.5, 0.0]
    np.testing.assert_allclose(half, expect, rtol=1e-12)
    assert np.all(blackbody.emission(np.array([3000.0, -5.0, np.nan]), 0.0) == 0)
    assert np.all(blackbody.emission(np.array([-5.0, np.nan]), 1.0) == 0)


def test_march_does_not_skip_a_glow_where_there_is_no_density():
    """Empty-space skipping reads brick bounds of the density; a medium's emission grid shines
    whatever the density, so its bricks (march_bricks) keep the glowing super-steps: the same
    Emission pass as with no skipping, where density-only bounds would lose the glow."""
    shape = (12, 12, 12)
    d = np.zeros(shape, np.float32)
    d[0, 0, 0] = 1.0                     # a speck of smoke in a corner
    glow = np.zeros(shape + (3,), np.float32)
    glow[4:8, 4:8, 4:8] = (2.0, 1.0, 0.5)   # fire without smoke in the middle
    i2w = np.diag([0.25, 0.25, 0.25, 1.0])
    i2w[:3, 3] = -1.5
    pm = prepare(Medium("fire", d, i2w, np.full(3, 1.0), np.full(3, 0.5), emission_grid=glow))
    pre = precompute([pm], [], World(), Camera("PERSP", np.eye(4), 4, 4, (-1, 1, -1, 1)))
    rng = np.random.default_rng(5)
    base = march_args(rng, [pm], [], pre, n=400)
    out = {}
    for name, bricks in (("none", None), ("march", [pm.march_bricks]), ("density", [pm.bricks])):
        inputs = base.replace(bricks=bricks, adapt_tau=0.1)
        out[name] = [kernels.march(inputs, backend="numpy").emission]
        if kernels._c is not None:
            out[name].append(kernels.march(inputs, backend="c").emission)
    assert out["none"][0].sum() > 1.0
    for a, b in zip(out["march"], out["none"]):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)
    assert out["density"][0].sum() < 0.5 * out["none"][0].sum()
    assert np.all(pm.march_bricks[..., 1] >= pm.bricks[..., 1])
