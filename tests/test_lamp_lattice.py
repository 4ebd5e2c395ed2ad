"""The traced paths' lattice round a lamp inside a medium (precompute.lattice.lamp_resolution):
its spacing at most half the lamp's radius, one voxel at the finest; elsewhere the user's
Multiple Scattering Resolution."""
import numpy as np
import pytest

from mpp_render.media import prepare
from mpp_render.precompute.lattice import lamp_resolution, paths_lattice
from mpp_render.scene import Light, Medium

VOXEL = 0.03   # m: 100 voxels over 3 m


@pytest.fixture(scope="module")
def cube():
    i2w = np.eye(4)
    i2w[:3, :3] *= VOXEL
    return prepare(Medium("smoke", np.ones((100, 100, 100), np.float32), i2w, np.ones(3),
                          np.zeros(3), 0.3))


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
