"""The traced paths' lattice round a light inside a medium (precompute.lattice.lamp_resolution):
its spacing at most half the radius of the core of the light's first scatterings (the lamp's
radius, half an area light's diagonal, or the mean free path there, whichever is less:
``core_radius``), one voxel at the finest; elsewhere the user's Multiple Scattering
Resolution."""
import numpy as np
import pytest

from mpp_render.media import prepare
from mpp_render.precompute.lattice import core_radius, lamp_resolution, paths_lattice
from mpp_render.scene import Light, Medium

VOXEL = 0.03   # m: 100 voxels over 3 m


def smoke(density):
    """A 3 m cube of 100 voxels a side, extinction ``density`` (1/m; albedo 1)."""
    i2w = np.eye(4)
    i2w[:3, :3] *= VOXEL
    grid = np.broadcast_to(np.asarray(density, np.float32), (100, 100, 100)).copy()
    return prepare(Medium("smoke", grid, i2w, np.ones(3), np.zeros(3), 0.3))


@pytest.fixture(scope="module")
def cube():
    return smoke(1.0)


def lamp(radius, at=(1.5, 1.5, 1.5), kind="POINT", power=100.0):
    return Light(kind, "lamp", np.full(3, power), position=np.array(at, float), radius=radius)


@pytest.mark.parametrize("radius,stride", [(0.3, 2), (0.12, 2), (0.1, 1), (0.05, 1), (0.0, 1)])
def test_a_lamp_inside_gets_a_lattice_half_its_radius_apart(cube, radius, stride):
    """At Resolution 64 the 100-voxel cube is on a lattice 2 voxels (6 cm) apart; a lamp
    inside it of radius r asks for a spacing of r / 2 at most, in whole voxels, one at the
    finest (a pure point light: the voxels)."""
    assert paths_lattice(cube, 64)[0] == 2
    for kind in ("POINT", "SPOT"):
        res = lamp_resolution(cube, [lamp(radius, kind=kind)], 64)
        got, _, h = paths_lattice(cube, res)
        assert got == stride, (kind, radius, res)
        assert h <= max(radius / 2, VOXEL) + 1e-9 or stride == 2


def test_lamps_outside_dark_or_distant_leave_the_resolution(cube):
    """A lamp outside the box, a dark one, a sun and an area light leave Resolution as set;
    a finer Resolution than the lamp needs is kept."""
    others = [lamp(0.05, at=(5.0, 1.5, 1.5)), lamp(0.05, power=0.0),
              Light("SUN", "sun", np.full(3, 3.0)),
              Light("AREA", "area", np.full(3, 50.0), position=np.array([1.5, 1.5, 1.5]))]
    assert lamp_resolution(cube, others, 64) == 64
    assert lamp_resolution(cube, [lamp(0.3)], 100) == 100


def area(size, at=(1.5, 1.5, 1.5), power=100.0):
    return Light("AREA", "area", np.full(3, power), position=np.array(at, float), size_x=size,
                 size_y=size)


def test_the_core_is_the_extent_or_the_mean_free_path():
    """core_radius: the lamp's radius (half an area light's diagonal) where the mean free path
    is longer; the mean free path where it is shorter; the extinction averaged where it is
    (an empty half of the cube round the light does not lengthen it); the extent where the
    cube round the light is empty."""
    thin, dense = smoke(1.0), smoke(10.0)
    assert core_radius(thin, lamp(0.3)) == pytest.approx(0.3)
    assert core_radius(thin, area(0.4)) == pytest.approx(0.2 * np.sqrt(2.0))
    assert core_radius(dense, lamp(0.3)) == pytest.approx(0.1)
    assert core_radius(dense, area(0.4)) == pytest.approx(0.1)
    half = np.zeros((100, 100, 100), np.float32)
    half[:, :, 50:] = 10.0
    assert core_radius(smoke(half), lamp(0.3)) == pytest.approx(0.1, rel=1e-6)
    assert core_radius(smoke(0.0), lamp(0.3)) == pytest.approx(0.3)


@pytest.mark.parametrize("density,stride", [(1.0, 2), (4.0, 2), (10.0, 1), (40.0, 1)])
def test_a_light_in_dense_smoke_gets_a_lattice_half_its_free_path_apart(density, stride):
    """A 0.3 m lamp and a 0.4 m area light inside smoke of mean free path l = 1 / density:
    the spacing at most min(extent, l) / 2, so the 6 cm lattice of Resolution 64 holds up to
    l = 12 cm (density 8) and turns to the voxels (3 cm) beyond."""
    med = smoke(density)
    for light in (lamp(0.3), area(0.4)):
        got, _, h = paths_lattice(med, lamp_resolution(med, [light], 64))
        assert got == stride, (density, light.kind)
        assert h <= max(0.5 * min(extent_of(light), 1.0 / density), VOXEL) + 1e-9


def extent_of(light):
    return light.radius if light.kind != "AREA" else 0.5 * np.hypot(light.size_x, light.size_y)


def test_the_refinement_stops_at_most_times_the_resolution(cube):
    """A pure point light asks for the voxels (100 here); ``most`` bounds the lattice at that
    many times the Resolution along the longest side (the memory and time the refinement
    adds on a large grid), and never coarsens a Resolution set above it."""
    assert lamp_resolution(cube, [lamp(0.0)], 64) == 100
    assert lamp_resolution(cube, [lamp(0.0)], 16, most=2) == 32
    assert paths_lattice(cube, lamp_resolution(cube, [lamp(0.0)], 16, most=2))[0] == 4
    assert lamp_resolution(cube, [lamp(0.0)], 16, most=1) == 16
    assert lamp_resolution(cube, [lamp(0.3)], 100, most=1) == 100


def test_a_wide_emitter_reads_a_bounded_cube():
    """A 30 m emitter in the 100-voxel cube: the extinction is averaged over at most
    CORE_CUBE voxels round it (here the dense half within them), not the whole grid."""
    from mpp_render.precompute.lattice import CORE_CUBE
    grid = np.ones((100, 100, 100), np.float32)
    grid[50 - CORE_CUBE:50 + CORE_CUBE + 1, 50 - CORE_CUBE:50 + CORE_CUBE + 1,
         50 - CORE_CUBE:50 + CORE_CUBE + 1] = 20.0
    assert core_radius(smoke(grid), area(30.0)) == pytest.approx(0.05, rel=1e-6)
