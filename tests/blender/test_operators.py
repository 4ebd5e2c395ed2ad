"""The extension's artist tools (``operators/``): Compare with Cycles and Clear MPP Caches,
run as operators on a tiny scene, and their plain functions."""
import json
import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import operators  # the repository root's ``operators`` package
from mpp_render.blender import frame
from parts import add_camera, add_cube, add_light, mpp_output, volume_material

W, H = 32, 24


@pytest.fixture(autouse=True)
def operators_registered(registered):
    operators.register()
    yield


def tiny_scene(scene):
    """A 2 m cube of Principled Volume (density 2, albedo 0.9) under a 3 W/m^2 sun, seen
    from 8 m at W x H; MPP at 4 samples and 16 voxels a side."""
    add_cube(scene, "Cube", mat=volume_material("Vol", density=2.0))
    add_light(scene)
    add_camera(scene)
    return mpp_output(scene, W, H)


def test_compare_with_cycles_stores_metrics_and_difference_image(empty_scene, capfd):
    sc = tiny_scene(empty_scene)
    sc.render.engine = "BLENDER_WORKBENCH"  # not MPP: the operator must put it back
    sc.cycles.samples = 7
    sc.cycles.volume_bounces = 3
    ims = sc.render.image_settings
    ims.file_format = 'PNG'
    ims.color_depth = '16'

    with frame.collect() as frames:
        assert bpy.ops.mpp.compare_with_cycles(samples=4) == {'FINISHED'}

    rec = json.loads(sc[operators.COMPARE_PROP])
    assert rec["cycles_samples"] == 4 and rec["resolution"] == [W, H]
    assert not rec["failed"] and not rec["cancelled"]
    for key in ("rel_rmse", "rel_rmse_4", "bias", "mpp_seconds", "cycles_seconds"):
        assert isinstance(rec[key], float) and math.isfinite(rec[key]), key
    assert rec["rel_rmse"] < 1.0  # the same cube, not a different picture
    img = bpy.data.images[operators.DIFF_IMAGE]
    assert tuple(img.size) == (W, H) and img.is_float
    px = np.array(img.pixels[:]).reshape(H, W, 4)
    assert np.all(np.isfinite(px)) and np.all(px[..., 1] == 0) and np.all(px[..., 3] == 1)
    assert px[..., [0, 2]].max() > 0  # some difference shows

    # Everything the comparison touched is back.
    assert sc.render.engine == "BLENDER_WORKBENCH"
    assert sc.cycles.samples == 7 and sc.cycles.volume_bounces == 3
    assert sc.cycles.use_denoising and sc.cycles.pixel_filter_type == 'BLACKMAN_HARRIS'
    assert ims.file_format == 'PNG' and ims.color_depth == '16'
    assert len(frames) == 1  # MPP's frame, handed back by the engine
    printed = capfd.readouterr()
    assert "MPP vs Cycles 4 spp: rel_rmse" in printed.out + printed.err  # self.report


def test_compare_report_and_second_run_resizes_the_image(empty_scene):
    sc = tiny_scene(empty_scene)
    sc.render.engine = "MPP_RENDER"
    rec = operators.compare_with_cycles(sc, samples=1)
    assert "rel_rmse" in operators.compare_summary(rec)
    sc.render.resolution_x, sc.render.resolution_y = 16, 12
    rec2 = operators.compare_with_cycles(sc, samples=1)
    assert rec2["resolution"] == [16, 12]
    assert tuple(bpy.data.images[operators.DIFF_IMAGE].size) == (16, 12)
    assert sc.render.engine == "MPP_RENDER"
    assert operators.last_compare(sc) == json.loads(json.dumps(rec2))


def test_difference_map_signs_and_scale():
    ref = np.full((2, 3, 4), 0.5, np.float32)
    ours = ref.copy()
    ours[0, 0, :3] = 1.0   # brighter: red
    ours[1, 2, :3] = 0.25  # darker: blue
    rgba, scale = operators.difference_map(ours, ref)
    assert scale == pytest.approx(0.5)
    assert rgba[0, 0].tolist() == pytest.approx([1.0, 0.0, 0.0, 1.0])
    assert rgba[1, 2].tolist() == pytest.approx([0.0, 0.0, 0.5, 1.0])
    assert rgba[0, 1, :3].tolist() == [0.0, 0.0, 0.0]
    _, scale0 = operators.difference_map(ours, np.zeros_like(ref))  # black reference
    assert scale0 == pytest.approx(1.0)


def test_clear_cache_clears_and_nothing_keeps_the_last_render(empty_scene):
    import gc
    import weakref

    from mpp_render import mpp

    sc = tiny_scene(empty_scene)
    sc.render.engine = "MPP_RENDER"
    last = frame.render_mpp()
    assert last is not None
    expect_mb = sum(a.nbytes for a in last.output.passes.values()) / (1 << 20)
    assert expect_mb > 0
    # The frame's record went back to the caller: the engine keeps no reference to it.
    held = weakref.ref(last.output)
    del last
    gc.collect()
    assert held() is None
    mpp.mean_sq_angle(0.3)  # fill a function cache
    rec = operators.clear_caches()
    assert "last_render_mb" not in rec and rec["cache_mb"] >= 0
    assert rec["functions"] >= 1 and rec["entries"] >= 1
    assert mpp._mean_sq_angle_cached.cache_info().currsize == 0
    assert "MB" in operators.clear_summary(rec)
    # As an operator (nothing left to release: still finishes and reports).
    assert bpy.ops.mpp.clear_cache() == {'FINISHED'}


def test_register_twice_and_unregister():
    operators.register()
    menu = bpy.types.TOPBAR_MT_render
    draw_funcs = menu._dyn_ui_initialize()
    assert sum(f is operators.draw_render_menu for f in draw_funcs) == 1
    assert hasattr(bpy.types, "MPP_PT_tools")
    operators.unregister()
    assert not operators.MPP_OT_clear_cache.is_registered
    assert operators.draw_render_menu not in menu._dyn_ui_initialize()
    operators.register()
    assert operators.MPP_OT_compare_with_cycles.is_registered
