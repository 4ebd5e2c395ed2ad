"""A mesh volume's light pyramids summed once over levels and lights (precompute.flatten.flatten_levels):
the march reads one level instead of every level of every light, and renders what it did."""
from dataclasses import replace

import numpy as np
import pytest

from mpp_render import march
from mpp_render.render import render
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, World


def scene(projection="PERSP"):
    n = 24
    i2w = np.eye(4)
    i2w[:3, :3] *= 1.6 / n
    i2w[:3, 3] = -0.8 + 0.8 / n
    box = Medium("box", np.ones((n, n, n), np.float32), i2w, np.array([3.0, 2.2, 1.5]),
                 np.array([0.2, 0.4, 0.8]), 0.5, source="MESH")
    c2w = np.array([[1.0, 0, 0, 0.3], [0, 0, -1, -4.0], [0, 1, 0, 0.4], [0, 0, 0, 1]])
    cam = Camera(projection, c2w, 40, 30, (-0.3, 0.3, -0.225, 0.225) if projection == "PERSP"
                 else (-1.2, 1.2, -0.9, 0.9), 0.1, 100.0)
    lights = [Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.4, 0.5, -0.77])),
              Light("POINT", "pt", np.array([40.0, 60.0, 90.0]),
                    position=np.array([-1.5, -1.2, 0.3]))]
    return SceneDescription(cam, media=[box], lights=lights, world=World(color=np.full(3, 0.05)),
                            settings=Settings(samples=4, multiple=True, voxel_resolution=24))


@pytest.mark.parametrize("projection", ["PERSP", "ORTHO"])
def test_flattened_pyramids_render_what_the_levels_did(projection):
    # the exact first flight (firstflight.py) joins only the flattened level: compare the walk
    desc = scene(projection)
    walk = replace(desc.settings.tuning, first_flights=False)
    desc.settings = replace(desc.settings, tuning=walk)
    flat = render(desc).passes["Volume Multiple"][..., :3]
    desc.settings = replace(desc.settings, tuning=replace(walk, flatten=False))
    levels = render(desc).passes["Volume Multiple"][..., :3]
    lit = levels.sum(axis=2) > 0.05 * levels.sum(axis=2).max()
    rel = np.abs(flat - levels)[lit] / levels[lit]
    print(projection, "mean", flat.mean(), levels.mean(), "median rel", np.median(rel), rel.max())
    assert lit.sum() > 200
    assert abs(flat.mean() / levels.mean() - 1.0) < 0.01
    assert np.median(rel) < 0.002 and rel.max() < 0.01


def test_only_mesh_volumes_are_flattened():
    """A medium whose density varies reads its levels with the local density's weights."""
    desc = scene()
    from mpp_render.media import prepare
    from mpp_render.precompute import precompute
    pm = prepare(desc.media[0])
    pre = precompute([pm], desc.lights, desc.world, desc.camera, multiple=True)
    ctx = march.MarchContext([pm], pre.fields, pre.layout, desc.lights, 0.05, pre.multiple,
                             desc.camera)
    # the one level lies on the field's voxels (march.on_field): no level left to read
    assert all(m is None for m in ctx.multiple.per_medium[0])
    assert ctx.multiple.on_field[0].shape == pre.fields[0].shape[:3] + (3,)
    assert ctx.multiple.tables[0] is march.FLAT_TABLE
    cloud = prepare(Medium("cloud", np.linspace(0.1, 1.0, 24 ** 3, dtype=np.float32).reshape(
        (24,) * 3), desc.media[0].index_to_world, desc.media[0].sigma_s, desc.media[0].sigma_a, 0.5))
    pre = precompute([cloud], desc.lights, desc.world, desc.camera, multiple=True)
    ctx = march.MarchContext([cloud], pre.fields, pre.layout, desc.lights, 0.05, pre.multiple,
                             desc.camera)
    assert all(m is not None and len(m.levels) > 1 for m in ctx.multiple.per_medium[0])
    assert ctx.multiple.on_field is None


def pre_light_fields(pm, desc, **kw):
    """The per-light MultipleFields of ``pm`` before the flattening: the precompute's own
    stage (precompute.lightpyramid.multiple_field) with the flattening switched off at the
    end, i.e. the precompute run without a camera for the flattening step."""
    from mpp_render.precompute import run
    real = run.flattened
    got = []
    run.flattened = lambda pm_, ms, *a, **k: (got.append(ms), real(pm_, ms, *a, **k))[1]
    try:
        run.precompute([pm], desc.lights, desc.world, desc.camera, multiple=True, **kw)
    finally:
        run.flattened = real
    return got[0]


def test_the_first_flight_joins_the_flattened_level():
    """This box's blue channel flies far (sigma_t* 1.9 / m in a 1.6 m box): its first flights
    mostly leave, and the exact flight changes the flattened level there, not elsewhere."""
    from mpp_render import firstflight
    from mpp_render.media import prepare
    from mpp_render.precompute import precompute
    desc = scene()
    pm = prepare(desc.media[0])
    from mpp_render.precompute.flatten import flattened
    pre = precompute([pm], desc.lights, desc.world, desc.camera, multiple=True)
    assert len(pre.multiple[0][0].levels) == 1 and pre.multiple[0][1] is None  # flattened
    # the per-light pyramids and flights, as the precompute hands them to the flattening
    mfs = [multiple for multiple in pre_light_fields(pm, desc)]
    firsts = [m.first for m in mfs]
    assert all(f is not None for f in firsts)
    for f in firsts:
        assert f.weight[2] > 0.0 and np.all(np.isfinite(f.field)) and f.field[..., 2].max() > 0
    with_first = flattened(pm, mfs, desc.lights, desc.camera)[0].levels[0]
    assert np.array_equal(with_first, pre.multiple[0][0].levels[0])
    for m in mfs:
        m.first = None
    walk = flattened(pm, mfs, desc.lights, desc.camera)[0].levels[0]
    weight = np.max([f.weight for f in firsts], axis=0)
    for c in range(3):
        changed = not np.allclose(with_first[..., c], walk[..., c], rtol=1e-6, atol=0.0)
        assert changed == (weight[c] > 0.0), (c, weight)
