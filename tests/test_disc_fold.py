"""A lamp's disc beyond the march's reach (precompute/discdepth.py): the depth change the
field stores makes the march's stretched read of the centre's depth average, over the disc,
to the disc points' own transmittance, where the smoke is uneven across the disc."""
import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.lights import (disc_transmittance, has_disc, light_sample, pack_light,
                               path_stretch)
from mpp_render.media import prepare
from mpp_render.precompute.discdepth import fold_disc
from mpp_render.precompute.layout import field_layout
from mpp_render.precompute.lightdepth import kernel_arrays, light_optical_depth
from mpp_render.scene import Light, Medium, Tuning


def split_medium():
    """A 2 m box of 0.04 m voxels, density 0.2 for y < 0 and 4 above (sigma_t 1 per
    density): a lamp's disc points' paths from beyond its reach run through either half."""
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.04
    i2w[:3, 3] = -1.0
    grid = np.full((51, 51, 51), 0.2, np.float32)
    grid[:, 26:, :] = 4.0
    return prepare(Medium("split", grid, i2w, np.full(3, 0.9), np.full(3, 0.1), 0.0))


def lamp(radius=0.3):
    return Light("POINT", "p", np.full(3, 60.0), position=np.array([-0.5, 0.0, 0.0]),
                 matrix=np.eye(4), radius=radius)


@pytest.mark.parametrize("stride", [1, 3])
def test_the_folded_depth_gives_the_disc_points_own_transmittance(stride):
    """At voxels 0.5-1.3 m from a 0.3 m lamp on the density step, the field's depth plus the
    stored change, stretched over the march's random disc points, averages to the mean
    of their exact transmittances (each disc point's path marched) within 2 % on the lattice
    (the disc's 16 nodes in this sharp step); between its points at stride 3 (3 voxels and
    more off the step: the lattice smooths what changes within its stride) closer than the
    stretched centre's depth, which misses by more than 5 % at some of them."""
    pm = split_medium()
    light = lamp()
    layout = field_layout([pm], [light], np.zeros(3), False)
    ch, dch = layout.light_channels[0], layout.disc_channels[0]
    assert has_disc(light) and dch is not None
    field = np.zeros(pm.grid.shape + (layout.channels,), np.float32)
    field[..., 0] = pm.grid
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in pm.grid.shape], indexing="ij"), -1)
    pts = pm.to_world(idx.reshape(-1, 3).astype(np.float64))
    step = 0.25 * pm.voxel_size
    field[..., ch:ch + 3] = light_optical_depth([pm], light, pts, step).reshape(
        pm.grid.shape + (3,))
    arrays = kernel_arrays([pm])

    def depth(p, d, t):
        return kernels.optical_depth(p, d, t, *arrays, step, 0.5, clip=True)

    marched = fold_disc(pm, field, ch, dch, light, depth, stride, Tuning.disc_fold_nodes)
    assert marched > 0
    rng = np.random.default_rng(4)
    picks = np.array([[35, 27, 25], [30, 24, 25], [40, 26, 30], [38, 23, 20], [44, 30, 25]])
    if stride == 3:   # lattice points by the step, and between them 3 voxels off it
        picks = np.array([[39, 27, 24], [30, 24, 24], [42, 27, 30], [39, 24, 21],
                          [45, 30, 24], [37, 31, 26], [31, 20, 26], [41, 32, 31],
                          [39, 19, 22], [45, 33, 26]])
    worst_stretched = 0.0
    for ijk in picks:
        x0 = pm.to_world(ijk[None].astype(np.float64))
        tau_c = field[tuple(ijk)][ch:ch + 3].astype(np.float64)
        change = field[tuple(ijk)][dch:dch + 3].astype(np.float64)
        m = 40000
        xs = np.repeat(x0, m, axis=0)
        wi, _, _, dc, ds = light_sample(pack_light(light), xs, rng.random(m), rng.random(m))
        st = path_stretch(ds, dc, pm.voxel_size)[:, None]
        exact = np.exp(-depth(xs, -wi, ds)).mean(axis=0)
        folded = np.exp(-np.maximum(tau_c * st + change, 0.0)).mean(axis=0)
        stretched = np.exp(-tau_c * st).mean(axis=0)
        err_f = float(np.max(np.abs(folded / exact - 1.0)))
        err_s = float(np.max(np.abs(stretched / exact - 1.0)))
        if stride == 1 or np.all(ijk % 3 == 0):   # on the lattice
            assert err_f < 0.02, (ijk, folded, exact)
        else:   # between its points: closer than the stretched depth, or within 1 %
            assert err_f < max(err_s, 0.01), (ijk, folded, stretched, exact)
        worst_stretched = max(worst_stretched, err_s)
    assert worst_stretched > 0.05


def test_a_lamp_without_a_radius_and_the_fold_off_add_no_channels():
    pm = split_medium()
    assert field_layout([pm], [lamp(0.0)], np.zeros(3), False).disc_channels is None
    assert field_layout([pm], [lamp()], np.zeros(3), False, disc=False).disc_channels is None
    sun = Light("SUN", "s", np.ones(3), direction=np.array([0.0, 0.0, -1.0]))
    got = field_layout([pm], [sun, lamp()], np.ones(3), True, peak=False)
    assert got.disc_channels == [None, 7] and got.ambient_channel == 10   # after the depths


def test_a_lamp_inside_a_homogeneous_medium_is_not_folded():
    """Inside a homogeneous box the disc points' paths stay in the medium and the stretch is
    exact: the pilot lattice finds no change, q stays 0 and only the pilot's points are
    marched; the split box's lamp marches the fine lattice too."""
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.04
    i2w[:3, 3] = -1.0
    pm = prepare(Medium("even", np.full((51, 51, 51), 2.0, np.float32), i2w, np.full(3, 0.9),
                        np.full(3, 0.1), 0.0))
    light = Light("POINT", "p", np.full(3, 60.0), position=np.zeros(3), matrix=np.eye(4),
                  radius=0.3)
    layout = field_layout([pm], [light], np.zeros(3), False)
    ch, dch = layout.light_channels[0], layout.disc_channels[0]

    def folded(medium):
        pts = medium.to_world(np.stack(np.meshgrid(*[np.arange(n) for n in medium.grid.shape],
                                                   indexing="ij"), -1)
                              .reshape(-1, 3).astype(np.float64))
        arrays = kernel_arrays([medium])

        def depth(p, d, t):
            return kernels.optical_depth(p, d, t, *arrays, 0.01, 0.5, clip=True)

        f = np.zeros(medium.grid.shape + (layout.channels,), np.float32)
        f[..., 0] = medium.grid
        f[..., dch:dch + 3] = 7.0   # overwritten
        f[..., ch:ch + 3] = light_optical_depth([medium], light, pts, 0.01).reshape(
            medium.grid.shape + (3,))
        return f, fold_disc(medium, f, ch, dch, light, depth, 2, 16)

    f, n = folded(pm)
    assert np.all(f[..., dch:dch + 3] == 0.0)
    assert 0 < n <= 8 ** 3       # the pilot: every 8th voxel (and the last) along each axis
    split = split_medium()
    f2, n2 = folded(split)
    assert n2 > 20 ** 3 and np.abs(f2[..., dch:dch + 3]).max() > 0.01


def test_the_paths_first_scatterings_take_the_same_disc():
    """The traced paths start where the lamp's light first scatters (source.py): with the
    light's disc channels each voxel's source is the stretched disc mean times e^-D, the
    light the march sees there; without them the stretched mean alone."""
    from mpp_render.precompute.lattice import lattice_shape
    from mpp_render.precompute.source import restricted_source
    pm = split_medium()
    light = lamp()
    layout = field_layout([pm], [light], np.zeros(3), False)
    ch, dch = layout.light_channels[0], layout.disc_channels[0]
    field = np.zeros(pm.grid.shape + (layout.channels,), np.float32)
    field[..., 0] = pm.grid
    pts = pm.to_world(np.stack(np.meshgrid(*[np.arange(n) for n in pm.grid.shape],
                                           indexing="ij"), -1).reshape(-1, 3).astype(float))
    field[..., ch:ch + 3] = light_optical_depth([pm], light, pts, 0.02).reshape(
        pm.grid.shape + (3,))
    arrays = kernel_arrays([pm])
    fold_disc(pm, field, ch, dch, light,
              lambda p, d, t: kernels.optical_depth(p, d, t, *arrays, 0.02, 0.5, clip=True),
              2, 16)
    shape = lattice_shape(pm.grid.shape, 1)
    plain = restricted_source(pm, field, light, ch, 1, shape)
    folded = restricted_source(pm, field, light, ch, 1, shape, disc_channel=dch)
    d = field[..., dch].reshape(-1).astype(float)
    lit = plain[:, 0] > 1e-6 * plain[:, 0].max()
    assert np.abs(d[lit]).max() > 0.05
    assert np.allclose(folded[lit, 0], plain[lit, 0] * np.exp(-d[lit]), rtol=1e-6)
