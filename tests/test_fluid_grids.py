"""The bpy-free parts of fluid domains (mpp_render/blender/translate/fluid.py): Mantaflow's
flat x-fastest arrays to (x, y, z) grids, the live grids of the domain settings with and
without noise, the cell-centred map onto the texture space, the derived heat / temperature /
colour grids and Blender's cache file names."""
import numpy as np
import pytest

from mpp_render.blender.translate import fluid, fluidcache


class RNAArray:
    """Stands in for a float RNA array of the domain settings (len, foreach_get)."""

    def __init__(self, values):
        self.values = np.asarray(values, np.float32).ravel()

    def __len__(self):
        return self.values.size

    def foreach_get(self, buf):
        buf[:] = self.values


class Settings:
    def __init__(self, res, noise=1, **arrays):
        self.domain_resolution = res
        self.use_noise = noise > 1
        self.noise_scale = noise
        for name in ("density_grid", "flame_grid", "heat_grid", "temperature_grid", "color_grid"):
            setattr(self, name, RNAArray(arrays.get(name, [])))


def xyz_pattern(shape, channels=1):
    """A[x, y, z(, c)] = x + 10 y + 100 z (+ 1000 c) and its x-fastest flat layout."""
    x, y, z = np.indices(shape)
    a = (x + 10 * y + 100 * z).astype(np.float32)
    if channels > 1:
        a = np.stack([a + 1000 * c for c in range(channels)], axis=-1)
    flat = np.moveaxis(a, (0, 1, 2), (2, 1, 0)).ravel()  # z slowest, x fastest
    return a, flat


def test_flat_x_fastest_arrays_become_xyz_grids():
    a, flat = xyz_pattern((5, 3, 2))
    assert flat[1] == 1 and flat[5] == 10 and flat[15] == 100  # x, then y, then z
    np.testing.assert_array_equal(fluid.flat_to_grid(flat, (5, 3, 2)), a)
    b, flat4 = xyz_pattern((5, 3, 2), 4)
    np.testing.assert_array_equal(fluid.flat_to_grid(flat4, (5, 3, 2), 4), b)


def test_live_grids_shapes_with_noise_and_colour():
    res, hi = (4, 3, 2), (8, 6, 4)
    dens, dflat = xyz_pattern(hi)
    heat, hflat = xyz_pattern(res)
    rgba = np.zeros(hi + (4,), np.float32)
    rgba[..., 0], rgba[..., 1], rgba[..., 2] = 0.2 * dens, 0.4 * dens, 0.6 * dens
    rgba[..., 3] = dens
    rflat = np.moveaxis(rgba, (0, 1, 2), (2, 1, 0)).ravel()
    dse = Settings(res, noise=2, density_grid=dflat, heat_grid=hflat, color_grid=rflat,
                   flame_grid=np.zeros(dflat.size), temperature_grid=np.zeros(dflat.size))
    g = fluid.live_grids(dse)
    assert g.shape == hi and g.low_shape == res and g.source == "live"
    np.testing.assert_array_equal(g.grids["density"], dens)
    np.testing.assert_array_equal(g.grids["heat"], heat)  # heat stays low resolution
    assert g.shape_of("heat") == res and g.shape_of("density") == hi
    col = g.grids["color"]
    assert col.shape == hi + (3,)
    inside = dens > 0
    np.testing.assert_allclose(col[inside], np.tile([0.2, 0.4, 0.6], (int(inside.sum()), 1)),
                               rtol=1e-6)


def test_empty_or_mis_sized_live_grids_are_not_used():
    res = (4, 3, 2)
    n = int(np.prod(res))
    assert fluid.live_grids(Settings(res, density_grid=np.zeros(n))) is None
    assert fluid.live_grids(Settings(res, density_grid=np.ones(n - 1))) is None
    assert fluid.live_grids(Settings((0, 0, 0))) is None
    g = fluid.live_grids(Settings(res, density_grid=np.ones(n), flame_grid=np.ones(7)))
    assert set(g.grids) == {"density"}


def test_cells_are_centred_in_the_texture_space():
    lo, hi, shape = np.array([-1.0, 0.0, 2.0]), np.array([1.0, 1.0, 4.0]), (8, 4, 2)
    m = fluid.cell_to_object(lo, hi, shape)
    np.testing.assert_allclose(m @ [0, 0, 0, 1], [-1 + 0.125, 0.125, 2.5, 1])
    np.testing.assert_allclose(m @ [7, 3, 1, 1], [1 - 0.125, 1 - 0.125, 3.5, 1])
    # cell faces at -0.5 and n - 0.5 are the box
    np.testing.assert_allclose(m @ [-0.5, -0.5, -0.5, 1], [*lo, 1])
    np.testing.assert_allclose(m @ [7.5, 3.5, 1.5, 1], [*hi, 1])


def test_heat_temperature_and_colour_derive_like_blenders_arrays():
    dens = np.array([[[0.0, 0.5, 2.0]]], np.float32)
    flame = np.array([[[0.005, 0.5, 1.0]]], np.float32)
    heat = np.array([[[-1.0, 0.4, 2.0]]], np.float32)
    rgb = np.stack([0.1 * dens, 0.2 * dens, 0.3 * dens], axis=-1)
    g = fluid.derived_grids(fluid.DomainGrids((1, 1, 3), (1, 1, 3), "x"), dens, flame, heat, rgb,
                            ignition=1.5, max_temp=3.0)
    np.testing.assert_allclose(g.grids["heat"], heat * 0.5)
    np.testing.assert_allclose(g.grids["temperature"], [[[0.0, 1.5 + 0.75, 3.0]]])
    np.testing.assert_allclose(g.grids["color"][0, 0, 1:], [[0.1, 0.2, 0.3]] * 2, rtol=1e-6)
    assert np.all(g.grids["color"][0, 0, 0] == 0.0)


@pytest.mark.parametrize("kind,offset,frame,want", [("MODULAR", 2, 5, 3), ("ALL", -1, 5, 6),
                                                     ("REPLAY", 2, 5, 5)])
def test_cache_frame_and_file_names(kind, offset, frame, want):
    class D:
        cache_type, cache_frame_offset = kind, offset

    assert fluidcache.cache_frame(D, frame) == want
    assert fluidcache.cache_file("/c", 7).replace("\\", "/") == "/c/data/fluid_data_0007.vdb"
    assert fluidcache.cache_file("/c", 12, noise=True).replace("\\", "/") == "/c/noise/fluid_noise_0012.vdb"


# -- emission that grids drive, on the domain's lattices (vdb.lattice_emission, shared) ------

def test_low_resolution_grid_drives_emission_on_the_noise_lattice():
    from mpp_render import blackbody
    from mpp_render.blender.translate import vdb
    from mpp_render.blender.translate.emissionterms import AttributeEmissionTerm, BlackbodyTerm
    from mpp_render.blender.translate.materials import VolumeCoefficients
    lo, hi = np.zeros(3), np.array([2.0, 1.0, 1.0])
    heat = np.zeros((8, 4, 4), np.float32)
    heat[3, 1, 2], heat[4, 1, 2] = 1.0, 3.0            # low resolution: 0.25 m cells
    src = (heat, (0, 0, 0), fluid.cell_to_object(lo, hi, heat.shape))
    dst = (np.zeros((16, 8, 8), np.float32), (0, 0, 0), fluid.cell_to_object(lo, hi, (16, 8, 8)))
    bb = BlackbodyTerm(1.0, 1000.0, "heat", np.ones(3), weight=0.5,
                       constant=0.5 * blackbody.emission(1000.0, 1.0))
    glow = AttributeEmissionTerm(np.array([1.0, 0.5, 0.0]), "heat")
    co = VolumeCoefficients("density", emission=np.full(3, 0.1) + bb.constant,
                            emission_terms=[bb, glow])
    emission, grid, lost = vdb.lattice_emission(co, dst, {"heat": src})
    np.testing.assert_allclose(emission, 0.1)          # the constant 1000 K part replaced
    assert lost == {} and grid.shape == (16, 8, 8, 3)
    # noise cell (8, 2, 4) sits at low index (3.75, 0.75, 1.75): trilinear 0.25 x 1 + 0.75 x 3
    # along x, 0.75 along y (towards index 1) and 0.75 along z (towards index 2)
    v = (0.25 * 1.0 + 0.75 * 3.0) * 0.75 * 0.75
    np.testing.assert_allclose(grid[8, 2, 4], 0.5 * blackbody.emission(1000.0 * v, 1.0)
                               + v * np.array([1.0, 0.5, 0.0]), rtol=1e-5)
    assert np.all(grid[:4] == 0) and np.all(grid[12:] == 0)
    # a smoke grid without data (zero=): 0 K and strength 0, the constant part gone too
    emission, grid, _ = vdb.lattice_emission(co, dst, {}, zero=fluid.SCALAR_GRIDS)
    assert grid is None
    np.testing.assert_allclose(emission, 0.1)
    # a Volume object without the grid: the constant Temperature (and strength 0)
    emission, grid, _ = vdb.lattice_emission(co, dst, {})
    assert grid is None
    np.testing.assert_allclose(emission, 0.1 + bb.constant)


def test_the_support_box_covers_every_cell_an_emission_grid_reaches():
    from mpp_render.blender.translate import vdb
    lo, hi = np.zeros(3), np.ones(3)
    low = np.zeros((4, 4, 4), np.float32)
    low[2, 1, 3] = 1.0
    src = (low, (0, 0, 0), fluid.cell_to_object(lo, hi, low.shape))
    dst = (np.zeros((12, 12, 12), np.float32), (0, 0, 0), fluid.cell_to_object(lo, hi, (12,) * 3))
    first, last = fluid._support_box(src, dst)
    sampled, _ = vdb.resample(src, dst)
    reach = np.argwhere(sampled > 0)
    assert np.all(reach.min(axis=0) >= first) and np.all(reach.max(axis=0) <= last)
    assert np.all(last < 12) and np.all(first >= 0)
    assert np.all(last - first <= 3 * 3 + 2)            # about the reach, not the whole grid
    assert fluid._support_box((np.zeros((4, 4, 4), np.float32),) + src[1:], dst) is None
