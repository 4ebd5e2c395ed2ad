"""An extinction whose colour varies per voxel (Medium.extinction_grid): how prepare folds it,
the field channels, both march twins, both path twins, the transmittance it gives, the
renders it must equal, bad values and the memory budget."""
import dataclasses

import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.media import prepare
from mpp_render.precompute import precompute
from mpp_render.render import render
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, World
from rays import march_inputs, march_twins
from test_scatter_grid import (assert_budget_weighs_rgb_grid_by_density, assert_path_twins,
                               assert_rgb_grid_sanitised)

needs_c = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")

# factors on sigma_t left and right of x = 0 (an extinction that is red on the left, blue on
# the right); sigma_s = 0.4 stays below sigma_t = 1.1 times the smallest of them
LEFT, RIGHT = np.array([1.0, 0.5, 0.45]), np.array([0.45, 0.6, 1.0])


def tinted_medium(shape=(12, 6, 8), scatter=False, scale=1.0):
    """A smoke grid whose extinction's factor is LEFT for x < 0 and RIGHT for x > 0, times
    ``scale`` (above 1: prepare folds it into the density)."""
    rng = np.random.default_rng(5)
    d = (0.5 + rng.random(shape)).astype(np.float32)
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([0.2, 0.25, 0.2])
    i2w[:3, 3] = [-1.1, -0.625, -0.7]
    left = (np.arange(shape[0]) < shape[0] // 2)[:, None, None, None]
    factor = np.where(left, LEFT, RIGHT) * scale * np.ones(shape + (3,))
    sg = (0.6 + 0.4 * rng.random(shape + (3,))).astype(np.float32) if scatter else None
    return Medium("tinted", d, i2w, np.array([0.4, 0.4, 0.4]), np.array([0.7, 0.7, 0.7]), 0.4,
                  extinction_grid=factor.astype(np.float32), scatter_grid=sg)


def camera():
    return Camera("PERSP", np.eye(4), 4, 4, (-1, 1, -1, 1))


def coefficients(m, pm):
    """(sigma_t, sigma_s) per voxel (N,3) of the medium ``m`` and of the same voxels of its
    prepared ``pm`` (the padding left out)."""
    ext = m.extinction_grid if m.extinction_grid is not None else 1.0
    sc = m.scatter_grid if m.scatter_grid is not None else 1.0
    d = m.density[..., None]
    want = ((m.sigma_s + m.sigma_a) * ext * d, m.sigma_s * sc * d)
    inner = (slice(1, -1),) * 3
    pst = pm.sigma_t * pm.extinction_density[inner]
    psc = pm.scatter_grid[inner] if pm.scatter_grid is not None else 1.0
    pss = pm.sigma_s * psc * pm.grid[inner][..., None]
    return want, (pst, pss)


def test_prepare_folds_a_factor_over_one_into_the_density():
    """Every channel of the extinction density is at most the density (the bricks and the
    majorants bound it), and each voxel's coefficients are the medium's."""
    for scatter in (False, True):
        m = tinted_medium(scatter=scatter, scale=1.7)
        pm = prepare(m)
        assert pm.threshold < 0 and pm.scatter_grid is not None
        assert np.all(pm.extinction_density <= pm.grid[..., None])
        assert np.allclose(pm.extinction_density.max(axis=-1)[1:-1, 1:-1, 1:-1],
                           pm.grid[1:-1, 1:-1, 1:-1], rtol=1e-6)
        (st, ss), (pst, pss) = coefficients(m, pm)
        np.testing.assert_allclose(pst, st, rtol=1e-5)
        np.testing.assert_allclose(pss, ss, rtol=1e-5)


def test_parts_add_to_the_extinction():
    pm = prepare(tinted_medium())
    parts = pm.extinction_parts()
    assert len(parts) == 3 and all(p.extinction_parts() == [p] for p in parts)
    total = sum(p.grid[..., None] * p.sigma_t for p in parts)
    np.testing.assert_allclose(total, pm.extinction_density * pm.sigma_t, rtol=1e-6)
    plain = prepare(Medium("p", pm.medium.density, np.eye(4), np.full(3, 0.5), np.zeros(3)))
    assert plain.extinction_parts() == [plain] and plain.extinction_density is None


def test_field_layout_puts_the_extinction_last():
    media = [prepare(tinted_medium(scatter=True)), prepare(tinted_medium())]
    media.append(prepare(Medium("plain", media[0].medium.density, np.eye(4), np.full(3, 0.5),
                                np.zeros(3))))
    lights = [Light("POINT", "pt", np.full(3, 100.0), position=np.array([0.0, 0.0, 3.0]))]
    pre = precompute(media, lights, World(), camera())
    c = pre.layout.channels
    assert pre.layout.extinction_channels == [c + 3, c, None]
    assert pre.layout.scatter_channels == [c, None, None]
    assert [f.shape[3] for f in pre.fields] == [c + 6, c + 3, c]
    np.testing.assert_array_equal(pre.fields[0][..., c + 3:c + 6], media[0].extinction_density)


def march_args(rng, media, lights, pre, n=2000):
    xc = [-1 if c is None else c for c in pre.layout.extinction_channels]
    sc = [-1 if c is None else c for c in pre.layout.scatter_channels]
    return march_inputs(rng, media, lights, pre, n, 1.2, 0.05, scatter_channels=sc,
                        extinction_channels=xc)


@needs_c
def test_march_twins_agree_with_extinction_channels():
    rng = np.random.default_rng(2)
    media = [prepare(tinted_medium(scatter=True))]
    lights = [Light("POINT", "pt", np.full(3, 100.0), position=np.array([0.3, 0.0, 2.0]),
                    radius=0.2)]
    pre = precompute(media, lights, World(), camera())
    inputs = march_args(rng, media, lights, pre).replace(disc_reach=[3.0])
    a, b = march_twins(inputs)
    assert a.single.max() > 0.01 and b.T.min() < 0.9
    # without the channels the extinction is the density's: the transmittance changes
    plain = kernels.march(inputs.replace(extinction_channels=None), backend="c")
    assert np.abs(plain.T - b.T).max() > 0.05


@needs_c
def test_march_rejects_an_extinction_channel_outside_the_fields():
    rng = np.random.default_rng(1)
    media = [prepare(tinted_medium())]
    pre = precompute(media, [], World(), camera())
    inputs = march_args(rng, media, [], pre, n=10)
    for bad in ([pre.fields[0].shape[3] - 2], [0], [1, 1], "x"):
        with pytest.raises((ValueError, TypeError)):
            kernels.march(inputs.replace(extinction_channels=bad), backend="c")


def render_of(medium, multiple=False, world=(0.0, 0.0, 0.0), **settings):
    cam = np.eye(4)
    cam[:3, 3] = [0.0, 0.0, 5.0]
    sun = Light("SUN", "sun", np.full(3, 2.0), direction=np.array([0.3, 0.2, -1.0]))
    desc = SceneDescription(Camera("ORTHO", cam, 24, 12, (-1.2, 1.2, -0.6, 0.6)),
                            media=[medium], lights=[sun], world=World(color=np.array(world)),
                            settings=Settings(samples=1, multiple=multiple, **settings))
    return render(desc).passes


def test_transmittance_takes_each_points_colour():
    """Orthographic rays straight down a grid whose extinction's colour changes only along
    x: each ray's transmittance is the grey medium's raised to the factor of its side (the
    largest factor is 1, so the density and the march's steps are the grey medium's)."""
    m = tinted_medium()
    ours = render_of(m)
    plain = render_of(Medium(m.name, m.density, m.index_to_world, m.sigma_s, m.sigma_a, m.g))
    t, p = ours["Transmittance"][..., :3], plain["Transmittance"][..., :3]
    cols = (np.arange(24) + 0.5) / 24 * 2.4 - 1.2
    left, right = cols < -0.25, cols > 0.15
    assert p[:, left].max() < 0.9 and p[:, right].max() < 0.9
    np.testing.assert_allclose(t[:, left], p[:, left] ** LEFT, rtol=1e-4)
    np.testing.assert_allclose(t[:, right], p[:, right] ** RIGHT, rtol=1e-4)


@pytest.mark.parametrize("multiple", [False, True])
def test_a_constant_factor_is_the_scaled_coefficient(multiple):
    """A uniform factor k renders as sigma_t k with the same scattering: the sun's sweep, the
    sky's light (world_light), the camera's march and the traced paths all read it."""
    m = tinted_medium()
    k = np.array([0.95, 0.8, 0.75])
    m.extinction_grid = np.broadcast_to(k, m.density.shape + (3,)).astype(np.float32)
    ours = render_of(m, multiple, world=(0.2, 0.3, 0.5))
    st = (m.sigma_s + m.sigma_a) * k
    scaled = render_of(Medium(m.name, m.density, m.index_to_world, m.sigma_s, st - m.sigma_s,
                              m.g), multiple, world=(0.2, 0.3, 0.5))
    names = ("Volume Single", "Transmittance", "Combined") + (("Volume Multiple",)
                                                              if multiple else ())
    for name in names:
        np.testing.assert_allclose(ours[name], scaled[name], rtol=2e-4,
                                   atol=1e-6 * float(np.abs(scaled[name]).max()))


def test_bad_extinction_values_are_sanitised_and_ones_dropped():
    assert_rgb_grid_sanitised(tinted_medium(), "extinction_grid", "extinction_density",
                              "extinction colour")


def test_a_mesh_volume_with_an_extinction_grid_is_read_as_a_grid():
    m = dataclasses.replace(tinted_medium(), source="MESH")
    assert prepare(m).threshold < 0
    assert prepare(dataclasses.replace(m, extinction_grid=None)).threshold >= 0


def test_budget_downsamples_the_extinction_grid_weighted_by_the_density():
    assert_budget_weighs_rgb_grid_by_density("extinction_grid")


# -- the traced paths (paths.PathInputs.extinction) --------------------------------------------

def path_inputs(rng, extinction=True, n_paths=3000):
    """Paths through a 16^3 grid and another 12^3 medium overlapping it, both with an
    extinction density (at most their density) or neither."""
    from test_scatter_grid import path_inputs as coloured
    inp = coloured(rng, colour=False, n_paths=n_paths)
    if not extinction:
        return inp
    other = inp.others[0]
    e1 = (inp.density[..., None] * rng.uniform(0.2, 1.0, inp.density.shape + (3,)))
    e2 = (other.density[..., None] * rng.uniform(0.2, 1.0, other.density.shape + (3,)))
    return dataclasses.replace(
        inp, extinction=e1.astype(np.float32),
        others=(dataclasses.replace(other, extinction=e2.astype(np.float32)),))


@needs_c
def test_path_twins_agree_with_extinction_grids():
    assert_path_twins(path_inputs(np.random.default_rng(4)),
                      path_inputs(np.random.default_rng(4), extinction=False))


@needs_c
def test_paths_reject_an_extinction_grid_of_another_shape():
    inp = path_inputs(np.random.default_rng(1), n_paths=10)
    for shape in ((16, 16, 15, 3), (16, 16, 16, 2)):
        with pytest.raises(ValueError):
            kernels.trace_paths_media(dataclasses.replace(inp, extinction=np.ones(
                shape, np.float32)))


@pytest.mark.parametrize("backend", ["numpy", "c"])
def test_a_uniform_extinction_on_the_paths_is_the_scaled_coefficient(backend):
    """An extinction density k x density at every voxel takes the same collisions, with the
    same weights, as sigma_t k (both by spectral tracking): the same deposits (to
    rounding)."""
    if backend == "c" and kernels._c is None:
        pytest.skip("compiled kernels not built")
    from mpp_render.paths import PathMedium
    inp = path_inputs(np.random.default_rng(7), extinction=False)
    k = np.array([0.6, 0.9, 0.45])
    other = inp.others[0]
    dense = dataclasses.replace(
        inp, extinction=(inp.density[..., None] * k).astype(np.float32),
        others=(dataclasses.replace(other, extinction=(other.density[..., None] * k).astype(
            np.float32)),))
    scaled = dataclasses.replace(inp, sigma_t=inp.sigma_t * k,
                                 others=(PathMedium(other.density, other.w2i, other.sigma_s,
                                                    other.sigma_t * k, other.g, other.stride,
                                                    other.towards, other.rate),))
    a = kernels.trace_paths_media(dense, backend=backend)
    b = kernels.trace_paths_media(scaled, backend=backend)
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-9 * np.abs(y).max())
