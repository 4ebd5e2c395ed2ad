"""A flat level read with the field's own stencil (march.on_field): the march sets up one
trilinear stencil a sample instead of two, and reads what the level's own stencil read."""
import numpy as np
import pytest

from mpp_render import kernels, march
from mpp_render.kernels import LevelField, MultipleInputs
from mpp_render.media import prepare
from mpp_render.precompute import precompute
from rays import march_inputs, march_twins
from test_flatten import scene


@pytest.mark.parametrize("stride", [1, 2, 3])
def test_the_field_reads_the_levels_values(stride):
    rng = np.random.default_rng(stride)
    shape = (13, 11, 9)
    lat = tuple((s - 1 + stride - 1) // stride + 1 for s in shape)   # lattice.lattice_shape
    level = rng.random(lat + (3,)).astype(np.float32)
    on = march.on_field(level, stride, shape)
    assert on.shape == shape + (3,) and on.dtype == np.float32
    idx = rng.random((4000, 3)) * (np.array(shape) - 1)
    direct = kernels.trilinear(level, idx / stride)
    via = kernels.trilinear(on, idx)
    assert np.abs(via - direct).max() <= 2e-6 * np.abs(direct).max()
    # the lattice's points are field voxels j * stride
    sub = on[::stride, ::stride, ::stride]
    np.testing.assert_allclose(sub, level[:sub.shape[0], :sub.shape[1], :sub.shape[2]], rtol=1e-6)


def test_what_the_field_cannot_read_the_same_way():
    level = np.ones((5, 5, 5, 3), np.float32)
    assert march.on_field(level, 2, (9, 9, 9)) is not None
    assert march.on_field(level, 2, (10, 9, 9)) is None          # the lattice stops short
    assert march.on_field(level, 1.5, (7, 7, 7)) is None         # no integer stride
    assert march.on_field(np.ones((5, 5, 5, 12), np.float32), 2, (9, 9, 9)) is None  # moments


def flat_setup():
    desc = scene()
    pm = prepare(desc.media[0])
    pre = precompute([pm], desc.lights, desc.world, desc.camera, multiple=True)
    ctx = march.MarchContext([pm], pre.fields, pre.layout, desc.lights, 0.05, pre.multiple,
                             desc.camera)
    return desc, pm, pre, ctx


def test_the_march_renders_what_the_level_did():
    desc, pm, pre, ctx = flat_setup()
    ms = ctx.multiple
    assert ms.on_field is not None and ms.on_field[0] is not None
    # the same level read through its own stencil, as before the field held it
    ref = next(m for m in pre.multiple[0] if m is not None)
    total = sum(ctx.level_of(m) for m in pre.multiple[0] if m is not None)
    old = MultipleInputs(ms.ambient, [[LevelField([np.ascontiguousarray(total, np.float32)],
                                                  ref.stride, ref.h)]
                                      + [None] * (len(pre.multiple[0]) - 1)], ms.tables)
    rng = np.random.default_rng(3)
    inputs = march_inputs(rng, [pm], desc.lights, pre, 3000, 0.8, 0.03, multiple=ms)
    new_np, new_c = march_twins(inputs)
    old_c = kernels.march(inputs.replace(multiple=old), backend="c")
    assert old_c.multiple.max() > 0.0 and (old_c.multiple > 0).mean() > 0.2
    np.testing.assert_allclose(new_c.multiple, old_c.multiple, rtol=1e-5, atol=1e-9)
    np.testing.assert_array_equal(new_c.single, old_c.single)
    np.testing.assert_array_equal(new_c.T, old_c.T)


def test_the_kernel_refuses_a_level_it_cannot_read():
    desc, pm, pre, ctx = flat_setup()
    ms = ctx.multiple
    rng = np.random.default_rng(4)
    inputs = march_inputs(rng, [pm], desc.lights, pre, 10, 0.8, 0.03, multiple=ms)
    wrong = ms._replace(on_field=[ms.on_field[0][:-1]])
    with pytest.raises(ValueError, match="on_field"):
        kernels.march(inputs.replace(multiple=wrong), backend="c")
    table = ms.tables[0].copy()
    table[0, 1, 0] *= 2.0   # a table whose weight varies with the density: not flat
    with pytest.raises(ValueError, match="flat"):
        kernels.march(inputs.replace(multiple=ms._replace(tables=[table])), backend="c")
