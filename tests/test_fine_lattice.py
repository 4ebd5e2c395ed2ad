"""What follows a narrow beam on a lattice finer than the walk's (precompute.source.fine_stride): the
forward peak's light and the exact first flights, and the flattened level that carries them;
the cells a spot's cone misses skipped without changing the irradiance (lights.outside_spot)."""
from types import SimpleNamespace

import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.lights import incident, outside_spot
from mpp_render.precompute import precompute
from mpp_render.precompute.lattice import lattice_shape
from mpp_render.precompute.source import FINE_POINTS, cell_mean_irradiance, fine_stride
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, World


def grid(shape, sharp=True):
    return SimpleNamespace(grid=SimpleNamespace(shape=tuple(shape)), sharp=sharp)


@pytest.mark.parametrize("stride, fine", [(1, 1), (2, 1), (3, 1), (4, 2), (5, 1), (6, 3),
                                          (8, 4)])
def test_the_fine_stride_divides_the_walks(stride, fine):
    assert fine_stride(grid((130, 54, 54)), stride) == fine


def test_a_medium_of_varying_density_keeps_the_walks_lattice():
    """A VDB grid or the world's fog: its first flights are the walk's, and the forward
    peak's light alone on the finer lattice cost smoke_plume three times the precompute."""
    assert fine_stride(grid((130, 54, 54), sharp=False), 2) == 2


def test_a_large_grid_keeps_the_walks_lattice():
    """The finer lattice's FFT beyond FINE_POINTS: the walk's stride (a 128^3 grid's first
    flights on its voxels would transform 270^3 points)."""
    assert fine_stride(grid((130, 130, 130)), 2) == 2
    n = int(round((FINE_POINTS / 8) ** (1 / 3)))   # about the largest cube that fits
    assert fine_stride(grid((n // 2,) * 3), 2) == 1


def beam_scene():
    """A long thin fog box lit along its length by a narrow spot: the first flights mostly
    leave it, on a grid of 48 x 16 x 16 voxels (50 padded) whose walk takes every second."""
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.1
    i2w[:3, 3] = [-2.35, -0.75, -0.75]
    fog = Medium("fog", np.ones((48, 16, 16), np.float32), i2w, np.full(3, 0.95),
                 np.full(3, 0.05), 0.85, source="MESH")
    c2w = np.array([[1.0, 0, 0, 0.0], [0, 0, -1, -6.0], [0, 1, 0, 0.0], [0, 0, 0, 1]])
    cam = Camera("PERSP", c2w, 48, 24, (-0.5, 0.5, -0.25, 0.25), 0.1, 100.0)
    spot = Light("SPOT", "spot", np.full(3, 2000.0), position=np.array([-4.0, 0.0, 0.0]),
                 direction=np.array([1.0, 0.0, 0.0]), radius=0.05,
                 spot_size=np.radians(8.0), spot_blend=0.1)
    spot.matrix = np.array([[0.0, 0, -1, -4.0], [0, 1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 1]])
    return SceneDescription(cam, media=[fog], lights=[spot], world=World(color=np.zeros(3)),
                            settings=Settings(samples=2, multiple=True, voxel_resolution=48,
                                              multiple_resolution=25))


def test_the_first_flights_and_the_flattened_level_take_the_finer_lattice():
    """The walk on every second voxel, the first flights on every voxel; the flattened level
    on the first flights' lattice is, at the walk's points, what it is with the first flights
    read there alone (the walk's levels are exact at their own points)."""
    from mpp_render.media import prepare
    desc = beam_scene()
    pm = prepare(desc.media[0])
    from mpp_render.precompute.flatten import flattened
    from test_flatten import pre_light_fields
    mfs = pre_light_fields(pm, desc, multiple_resolution=25)   # before the flattening
    msf = mfs[0]
    assert msf.stride == 2 and msf.first is not None and msf.first.stride == 1
    assert msf.first.field.shape[:3] == lattice_shape(pm.grid.shape, 1)
    assert np.all(np.isfinite(msf.first.field)) and msf.first.field.max() > 0.0
    one = flattened(pm, mfs, desc.lights, desc.camera)[0]
    flat, stride = one.levels[0], one.stride
    assert stride == 1 and flat.shape[:3] == lattice_shape(pm.grid.shape, 1)
    msf.first.field = np.ascontiguousarray(msf.first.field[::2, ::2, ::2])
    msf.first.stride = 2
    one = flattened(pm, mfs, desc.lights, desc.camera)[0]
    coarse, stride = one.levels[0], one.stride
    assert stride == 2
    sub = flat[::2, ::2, ::2]   # the walk's lattice has a point beyond the grid's last voxel
    coarse = coarse[:sub.shape[0], :sub.shape[1], :sub.shape[2]]
    assert np.allclose(sub, coarse, rtol=1e-5, atol=1e-7 * coarse.max())


def test_a_spots_cone_culls_only_dark_cells():
    """Points flagged outside the cone by a reach r: the spot's irradiance is 0 everywhere
    within r of them, for any point of its emitter; cell_mean_irradiance with the cull is
    the full n^3-point mean (both through the compiled light sample)."""
    spot = Light("SPOT", "spot", np.full(3, 500.0), position=np.array([0.0, 0.0, 0.0]),
                 direction=np.array([0.0, 0.0, -1.0]), radius=0.2,
                 spot_size=np.radians(20.0), spot_blend=0.3)
    rng = np.random.default_rng(3)
    pts = rng.uniform(-3.0, 3.0, (4000, 3))
    reach = 0.15
    out = outside_spot(spot, pts, reach)
    assert 0.5 < out.mean() < 0.99   # most of the box is dark, and some of it is lit
    for _ in range(8):
        d = rng.normal(size=(len(pts), 3))
        d *= (reach * rng.uniform(0, 1, len(pts)) ** (1 / 3) / np.linalg.norm(d, axis=1))[:, None]
        e = incident(spot, pts + d, rng.uniform(0, 1, (len(pts), 2)))[1]
        assert np.all(e[out] == 0.0)
    cell = np.eye(3) * 0.2
    got = cell_mean_irradiance(spot, pts, cell)
    t = np.array([-0.25, 0.25])
    offs = np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3) @ cell.T
    full = np.mean([incident(spot, pts + o, sample=kernels.light_sample)[1] for o in offs],
                   axis=0)
    assert np.array_equal(got, full)
    sun = Light("SUN", "sun", np.full(3, 2.0), direction=np.array([0.0, 0.0, -1.0]))
    assert not outside_spot(sun, pts, reach).any()


def test_no_finer_source_where_the_walk_serves(monkeypatch):
    """A dense small box (its first flights mostly stay in it: weight 0): the first flights are
    not made, and the finer lattice's source is not computed for them either."""
    from mpp_render.precompute import lightpyramid as pc
    from mpp_render.media import prepare
    desc = beam_scene()
    desc.media[0].sigma_s = np.full(3, 40.0)
    pm = prepare(desc.media[0])
    strides = []
    real = pc.source_and_density

    def counted(*args, **kw):
        strides.append(args[4])
        return real(*args, **kw)

    monkeypatch.setattr(pc, "source_and_density", counted)
    pre = precompute([pm], desc.lights, desc.world, desc.camera, multiple=True,
                     multiple_resolution=25)
    msf = pre.multiple[0][0]
    assert msf.stride == 2 and msf.first is None
    assert fine_stride(pm, 2) == 1 and strides == [2]
    # the thin box of the test above does compute it
    strides.clear()
    desc = beam_scene()
    pm = prepare(desc.media[0])
    precompute([pm], desc.lights, desc.world, desc.camera, multiple=True,
               multiple_resolution=25)
    assert strides == [2, 1]
