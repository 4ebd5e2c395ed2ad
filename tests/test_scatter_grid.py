"""A scattering colour that varies per voxel (Medium.scatter_grid): the field channels, both
march twins, the exact single scattering it gives, bad values, and the memory budget."""
import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.budget import fit_media
from mpp_render.media import prepare
from mpp_render.precompute import precompute
from mpp_render.render import render
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, World
from rays import march_inputs, march_twins

needs_c = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")

LEFT, RIGHT = np.array([1.6, 0.5, 0.2]), np.array([0.2, 0.7, 1.5])


def tinted_medium(shape=(12, 6, 8), emission_grid=False):
    """A smoke grid whose scattering colour's factor is LEFT for x < 0 and RIGHT for x > 0."""
    rng = np.random.default_rng(5)
    d = (0.5 + rng.random(shape)).astype(np.float32)
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([0.2, 0.25, 0.2])
    i2w[:3, 3] = [-1.1, -0.625, -0.7]
    left = (np.arange(shape[0]) < shape[0] // 2)[:, None, None, None]
    factor = np.where(left, LEFT, RIGHT) * np.ones(shape + (3,))
    em = None
    if emission_grid:
        em = (rng.random(shape + (3,)) * 0.2).astype(np.float32)
    return Medium("tinted", d, i2w, np.array([0.8, 0.8, 0.8]), np.array([0.3, 0.3, 0.3]), 0.4,
                  emission_grid=em, scatter_grid=factor.astype(np.float32))


def camera():
    return Camera("PERSP", np.eye(4), 4, 4, (-1, 1, -1, 1))


def test_field_layout_puts_the_scatter_grid_after_the_emission():
    media = [prepare(tinted_medium(emission_grid=True)), prepare(tinted_medium())]
    lights = [Light("POINT", "pt", np.full(3, 100.0), position=np.array([0.0, 0.0, 3.0]))]
    pre = precompute(media, lights, World(), camera())
    c = pre.layout.channels
    assert pre.layout.emission_channels == [c, None]
    assert pre.layout.scatter_channels == [c + 3, c]
    assert pre.fields[0].shape[3] == c + 6 and pre.fields[1].shape[3] == c + 3
    np.testing.assert_array_equal(pre.fields[0][..., c + 3:c + 6], media[0].scatter_grid)
    np.testing.assert_array_equal(pre.fields[1][..., c:c + 3], media[1].scatter_grid)
    # padded like the density, the edge voxels repeated (the density fades there, not the colour)
    sg = media[1].scatter_grid
    assert sg.shape == media[1].grid.shape + (3,)
    np.testing.assert_array_equal(sg[0, 3, 3], LEFT.astype(np.float32))
    np.testing.assert_array_equal(sg[-1, 3, 3], RIGHT.astype(np.float32))


def march_args(rng, media, lights, pre, n=2000):
    sc = [-1 if c is None else c for c in pre.layout.scatter_channels]
    return march_inputs(rng, media, lights, pre, n, 1.2, 0.05, scatter_channels=sc)


@needs_c
def test_march_twins_agree_with_scatter_grids():
    rng = np.random.default_rng(2)
    media = [prepare(tinted_medium())]
    lights = [Light("POINT", "pt", np.full(3, 100.0), position=np.array([0.3, 0.0, 2.0]))]
    pre = precompute(media, lights, World(), camera())
    inputs = march_args(rng, media, lights, pre)
    a, b = march_twins(inputs)
    assert a.single.max() > 0.01
    # without the grid the colour is the mean's: red and blue change places across the rays
    plain = kernels.march(inputs.replace(scatter_channels=None), backend="c")
    np.testing.assert_array_equal(plain.T, b.T)               # the extinction is the same
    assert np.abs(plain.single - b.single).max() > 0.1 * b.single.max()


@needs_c
def test_march_rejects_a_scatter_channel_outside_the_fields():
    rng = np.random.default_rng(1)
    media = [prepare(tinted_medium())]
    pre = precompute(media, [], World(), camera())
    inputs = march_args(rng, media, [], pre, n=10)
    for bad in ([pre.fields[0].shape[3] - 2], [0], [1, 1], "x"):
        with pytest.raises((ValueError, TypeError)):
            kernels.march(inputs.replace(scatter_channels=bad), backend="c")


def render_single(medium, backend=None):
    cam = np.eye(4)
    cam[:3, 3] = [0.0, 0.0, 5.0]
    sun = Light("SUN", "sun", np.full(3, 2.0), direction=np.array([0.3, 0.2, -1.0]))
    desc = SceneDescription(Camera("ORTHO", cam, 24, 12, (-1.2, 1.2, -0.6, 0.6)),
                            media=[medium], lights=[sun],
                            settings=Settings(samples=1, multiple=False))
    return render(desc).passes


def test_single_scattering_takes_each_points_colour():
    """Orthographic rays straight down a grid whose colour changes only along x: each ray
    keeps one colour, so its single scattering is exactly that of the mean-coloured medium
    times the factor, and its transmittance is unchanged (the extinction does not follow the
    colour)."""
    m = tinted_medium()
    ours = render_single(m)
    plain = render_single(Medium(m.name, m.density, m.index_to_world, m.sigma_s, m.sigma_a,
                                 m.g))
    s, p = ours["Volume Single"][..., :3], plain["Volume Single"][..., :3]
    np.testing.assert_array_equal(ours["Transmittance"], plain["Transmittance"])
    # pixel columns over x < -0.25 and over x > 0.15 (a voxel clear of the colour's change)
    cols = (np.arange(24) + 0.5) / 24 * 2.4 - 1.2
    left, right = cols < -0.25, cols > 0.15
    assert p[:, left].min() > 0.0 and p[:, right].min() > 0.0
    np.testing.assert_allclose(s[:, left], p[:, left] * LEFT, rtol=1e-5)
    np.testing.assert_allclose(s[:, right], p[:, right] * RIGHT, rtol=1e-5)


def test_a_constant_factor_is_the_scaled_coefficient():
    """A uniform factor k renders as sigma_s k with the same extinction (single scattering;
    the traced paths read the medium's sigma_s, which translate makes the mean)."""
    m = tinted_medium()
    k = np.array([0.5, 0.8, 0.3])
    m.scatter_grid = np.broadcast_to(k, m.density.shape + (3,)).astype(np.float32)
    ours = render_single(m)
    ss = m.sigma_s * k
    scaled = render_single(Medium(m.name, m.density, m.index_to_world, ss,
                                  m.sigma_s + m.sigma_a - ss, m.g))
    for name in ("Volume Single", "Transmittance", "Combined"):
        np.testing.assert_allclose(ours[name], scaled[name], rtol=2e-5, atol=1e-7)


def assert_rgb_grid_sanitised(m, field, prepared, what):
    """prepare() sets the NaN and negative values of medium ``m``'s RGB grid ``field`` to 0
    with a warning naming ``what``, and drops a grid of ones and one of the wrong shape
    (warned); ``prepared`` names its padded copy on the PreparedMedium."""
    g = getattr(m, field).copy()
    g[1, 1, 3] = np.nan
    g[2, 2, 3, 1] = -4.0
    setattr(m, field, g)
    warnings = []
    out = getattr(prepare(m, warnings), prepared)
    assert np.all(np.isfinite(out)) and out.min() >= 0
    assert out[2, 2, 4].tolist() == [0.0, 0.0, 0.0] and out[3, 3, 4, 1] == 0.0
    assert any(f"4 {what} values were NaN, infinite or negative" in w for w in warnings)
    setattr(m, field, np.ones(m.density.shape + (3,), np.float32))   # no change of colour
    assert getattr(prepare(m), prepared) is None
    setattr(m, field, np.ones((2, 2, 2, 3), np.float32))             # wrong shape
    warnings = []
    assert getattr(prepare(m, warnings), prepared) is None
    assert any(f"{what} grid of shape" in w for w in warnings)


def test_bad_scatter_values_are_sanitised_and_ones_dropped():
    assert_rgb_grid_sanitised(tinted_medium(), "scatter_grid", "scatter_grid", "scatter colour")


def assert_budget_weighs_rgb_grid_by_density(field):
    """The memory budget downsamples medium grid ``field`` (a factor per voxel) with each
    block's mean weighted by the density."""
    shape = (40, 40, 40)
    d = np.zeros(shape, np.float32)
    d[::2] = 1.0                                   # every other slice holds all the smoke
    f = np.zeros(shape + (3,), np.float32)
    f[::2] = [2.0, 1.0, 0.5]                       # and the colour; empty slices 0
    m = Medium("m", d, np.eye(4), np.full(3, 0.5), np.full(3, 0.1), **{field: f})
    warnings = []
    small = fit_media([m], [Light("POINT", "pt", np.full(3, 100.0))], 1.0, warnings)[0]
    got = getattr(small, field)
    assert small.density.shape != shape and got.shape == small.density.shape + (3,)
    # where a block holds smoke its factor is the smoke's, not halved by the empty slices
    inside = small.density > 0
    np.testing.assert_allclose(got[inside], np.broadcast_to(
        [2.0, 1.0, 0.5], (int(inside.sum()), 3)), rtol=1e-5)


def test_budget_downsamples_the_scatter_grid_weighted_by_the_density():
    assert_budget_weighs_rgb_grid_by_density("scatter_grid")


# -- the traced paths (paths.PathInputs.scatter) -----------------------------------------------

def path_inputs(rng, colour=True, n_paths=3000):
    """Paths through a 16^3 grid and another 12^3 medium overlapping it, both with a
    scatter colour grid (or neither)."""
    from test_paths_media import grid, towards
    from mpp_render.paths import PathInputs, PathMedium, from_power
    w2i, i2w, ls, pts = grid(16, 0.1, np.zeros(3))
    w2i2, _, ls2, pts2 = grid(12, 0.13, np.full(3, 0.4))
    starts = rng.random((5, 3)) * 1.4
    d = rng.normal(size=(5, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    w, cdf = from_power(rng.random((5, 3)) + 0.1)
    col = (rng.random((16, 16, 16, 3)) * 1.5).astype(np.float32) if colour else None
    col2 = (rng.random((12, 12, 12, 3)) * 1.5).astype(np.float32) if colour else None
    other = PathMedium(rng.random((12, 12, 12)).astype(np.float32), w2i2,
                       np.array([0.5, 0.6, 0.7]), np.array([1.0, 1.3, 1.6]), -0.4, 2,
                       towards(pts2), 4.0, scatter=col2)
    return PathInputs(rng.random((16, 16, 16)).astype(np.float32), w2i, i2w,
                      np.array([1.0, 1.2, 1.4]), np.array([2.0, 2.0, 2.5]), 0.6, 2,
                      towards(pts), starts, w, d, cdf, 5.0, n_paths, 5, others=(other,),
                      moments=True, scatter=col)


def assert_path_twins(inp, plain):
    """Both tracers' deposits on ``inp`` (paths.PathInputs) agree to 1e-9, and differ by
    over 1 % from those on ``plain`` (the same without the grid under test)."""
    from mpp_render.paths import trace_paths_media_np
    a = trace_paths_media_np(inp)
    b = kernels.trace_paths_media(inp, threads=2)
    for x, y in zip(a, b):
        assert x[..., :3].sum() > 0.0 and x.shape == y.shape
        assert np.abs(x - y).max() <= 1e-9 * np.abs(x).max()
    other = kernels.trace_paths_media(plain, threads=2)
    assert np.abs(other[0] - b[0]).max() > 0.01 * np.abs(b[0]).max()


@needs_c
def test_path_twins_agree_with_scatter_grids():
    # the colours change what the paths carry after their first collision
    assert_path_twins(path_inputs(np.random.default_rng(4)),
                      path_inputs(np.random.default_rng(4), colour=False))


@needs_c
def test_paths_reject_a_scatter_grid_of_another_shape():
    import dataclasses
    inp = path_inputs(np.random.default_rng(1), n_paths=10)
    bad = dataclasses.replace(inp, scatter=np.ones((16, 16, 15, 3), np.float32))
    with pytest.raises(ValueError):
        kernels.trace_paths_media(bad)
    bad = dataclasses.replace(inp, scatter=np.ones((16, 16, 16, 2), np.float32))
    with pytest.raises(ValueError):
        kernels.trace_paths_media(bad)


@pytest.mark.parametrize("backend", ["numpy", "c"])
def test_a_uniform_colour_on_the_paths_is_the_scaled_albedo(backend):
    """A factor k at every voxel multiplies each real collision's weight by k, as sigma_s k
    does: the same paths, the same deposits (to rounding)."""
    import dataclasses
    if backend == "c" and kernels._c is None:
        pytest.skip("compiled kernels not built")
    from mpp_render.paths import PathMedium
    inp = path_inputs(np.random.default_rng(7), colour=False)
    k = np.array([0.6, 0.9, 0.3])
    other = inp.others[0]
    coloured = dataclasses.replace(
        inp, scatter=np.broadcast_to(k, inp.density.shape + (3,)).astype(np.float32),
        others=(dataclasses.replace(other, scatter=np.broadcast_to(
            k, other.density.shape + (3,)).astype(np.float32)),))
    scaled = dataclasses.replace(inp, sigma_s=inp.sigma_s * k.astype(np.float32),
                                 others=(PathMedium(other.density, other.w2i,
                                                    other.sigma_s * k.astype(np.float32),
                                                    other.sigma_t, other.g, other.stride,
                                                    other.towards, other.rate),))
    a = kernels.trace_paths_media(coloured, backend=backend)
    b = kernels.trace_paths_media(scaled, backend=backend)
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-12 * np.abs(y).max())
