"""The MPP RenderEngine inside Blender: registration, passes in the render result, the
multilayer EXR Blender writes, the compositor, warnings and Esc."""
import time

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render import exr
from mpp_render.blender import batch, engine, frame, properties
from mpp_render.passes import PASSES
from mpp_render.scene import Settings

from parts import add_camera, add_cube, add_light, mpp_output, volume_material

W, H = 32, 24


pytestmark = pytest.mark.usefixtures("registered")


def small_scene(scene, width=W, height=H, cubes=((0.0, 0.0, 0.0),)):
    """Cubes of Principled Volume (density 4, albedo 0.9, anisotropy 0.3) under a 3 W/m^2
    sun, a camera 8 m away; samples 4 and a coarse voxelisation (16 voxels a side) keep
    each render well under a second."""
    for i, loc in enumerate(cubes):
        add_cube(scene, f"Cube{i}", loc, volume_material(f"Vol{i}", anisotropy=0.3))
    add_light(scene)
    add_camera(scene)
    return mpp_output(scene, width, height)


def exr_parts(path):
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    names = []
    i = 0
    while inp.seek_subimage(i, 0):
        names.append(inp.spec().getattribute("name"))
        i += 1
    inp.close()
    return names


def test_engine_and_settings_register(empty_scene):
    empty_scene.render.engine = "MPP_RENDER"
    assert empty_scene.render.engine == "MPP_RENDER"
    assert empty_scene.mpp.samples == 16 and empty_scene.mpp.multiple
    assert empty_scene.mpp.multiple_resolution == Settings().multiple_resolution == 64
    empty_scene.mpp.samples = 7
    empty_scene.mpp.multiple_resolution = 24
    empty_scene.render.film_transparent = True
    st = properties.settings_from_scene(empty_scene)
    assert isinstance(st, Settings)
    assert st.samples == 7 and st.film_transparent and st.voxel_resolution == 128
    assert st.multiple_resolution == 24


def test_quality_presets_set_samples_paths_and_resolution(empty_scene):
    from mpp_render.scene import QUALITY_PRESETS
    assert properties.settings_from_scene(empty_scene).multiple_paths == Settings().multiple_paths
    for name in ("PREVIEW", "REFERENCE", "FINAL"):
        empty_scene.mpp.quality = name
        st = properties.settings_from_scene(empty_scene)
        for key, value in QUALITY_PRESETS[name].items():
            assert getattr(st, key) == value, (name, key)
    # the defaults are the Final preset
    assert all(getattr(Settings(), k) == v for k, v in QUALITY_PRESETS["FINAL"].items())


def test_render_writes_every_pass_to_blenders_multilayer_exr(empty_scene, tmp_path):
    sc = small_scene(empty_scene)
    ims = sc.render.image_settings
    ims.media_type = 'MULTI_LAYER_IMAGE'
    ims.color_depth = '32'
    ims.exr_codec = 'ZIP'
    sc.render.filepath = str(tmp_path / "frame.exr")
    sc.render.use_file_extension = False
    last = frame.render_mpp(write_still=True)

    parts = exr_parts(tmp_path / "frame.exr")
    for p in PASSES:
        assert f"ViewLayer.{p.name}" in parts
    got = exr.read_passes(str(tmp_path / "frame.exr"), layer="ViewLayer")
    ours = last.output.passes
    for p in PASSES:
        assert got[p.name].shape == (H, W, p.channels)
        # Same rows as the core's output (row 0 at the top): the engine's flip is right.
        np.testing.assert_allclose(got[p.name], ours[p.name], rtol=1e-6)
    T = got["Transmittance"]
    assert T[H // 2, W // 2].max() < 0.5 and T[0, 0].min() > 0.99
    assert got["Volume Single"][H // 2, W // 2].sum() > 0
    assert last.translate_s >= 0 and last.write_s >= 0


def exr_layout(path):
    """(part name, channel names, pixel type, compression, alpha and z channel) per part."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    parts = []
    i = 0
    while inp.seek_subimage(i, 0):
        sp = inp.spec()
        parts.append((sp.getattribute("name"), tuple(sp.channelnames), str(sp.format),
                      sp.getattribute("compression"), sp.tile_width, sp.alpha_channel,
                      sp.z_channel))
        i += 1
    inp.close()
    return parts


def test_the_command_lines_exr_has_blenders_layout(empty_scene, tmp_path):
    """exr.write_passes (what ``render`` writes) and Blender's own multilayer writer give the
    same parts, channels, pixel type and compression (Blender adds only header metadata)."""
    sc = small_scene(empty_scene)
    batch.set_multilayer_exr(sc)
    sc.render.filepath = str(tmp_path / "blender.exr")
    sc.render.use_file_extension = False
    last = frame.render_mpp(write_still=True)
    exr.write_passes(str(tmp_path / "ours.exr"), last.output.passes, layer=last.view_layer)
    theirs = exr_layout(tmp_path / "blender.exr")
    assert len(theirs) == len(PASSES)
    assert exr_layout(tmp_path / "ours.exr") == theirs


def test_render_depsgraph_returns_the_engines_frame(empty_scene, monkeypatch):
    """The plain function the engine calls, called directly on the scene's depsgraph, returns
    the same frame as a render through Blender (the engine only copies it into the result)."""
    small_scene(empty_scene)
    via_engine = frame.render_mpp()
    rec = frame.render_depsgraph(bpy.context.evaluated_depsgraph_get(), W, H)
    assert rec.view_layer == via_engine.view_layer == "ViewLayer"
    assert rec.frame == via_engine.frame and rec.write_s == 0.0 and rec.translate_s >= 0
    assert set(rec.output.passes) == set(via_engine.output.passes)
    for name, arr in via_engine.output.passes.items():
        np.testing.assert_array_equal(rec.output.passes[name], arr, err_msg=name)
    from mpp_render.blender import translate

    def unreadable(*args, **kwargs):
        raise ValueError("unreadable scene")

    monkeypatch.setattr(translate, "scene_from_depsgraph", unreadable)
    with pytest.raises(frame.TranslationError, match="unreadable scene"):
        frame.render_depsgraph(bpy.context.evaluated_depsgraph_get(), W, H)
    with frame.collect() as frames:  # through Blender: an error report, no frame handed back
        with pytest.raises(RuntimeError, match="cannot translate the scene: unreadable scene"):
            bpy.ops.render.render()
    assert frames == []


def test_passes_are_compositor_outputs(empty_scene, tmp_path):
    sc = small_scene(empty_scene)
    ng = bpy.data.node_groups.new("Comp", "CompositorNodeTree")
    ng.interface.new_socket("Image", in_out='OUTPUT', socket_type='NodeSocketColor')
    sc.compositing_node_group = ng
    rl = ng.nodes.new("CompositorNodeRLayers")
    out = ng.nodes.new("NodeGroupOutput")
    ng.links.new(rl.outputs["Transmittance"], out.inputs[0])
    bpy.context.view_layer.update_render_passes()
    enabled = [o.name for o in rl.outputs if o.enabled]
    for name in ("Volume Single", "Volume Multiple", "Transmittance", "Depth"):
        assert name in enabled

    sc.mpp.multiple = False  # the pass list follows the setting
    assert "Volume Multiple" not in [o.name for o in rl.outputs if o.enabled]

    ims = sc.render.image_settings
    ims.media_type = 'MULTI_LAYER_IMAGE'
    ims.color_depth = '32'
    sc.render.filepath = str(tmp_path / "comp.exr")
    sc.render.use_file_extension = False
    bpy.ops.render.render(write_still=True)
    comp = exr.read_passes(str(tmp_path / "comp.exr"), layer="Composite")["Combined"]
    layer = exr.read_passes(str(tmp_path / "comp.exr"), layer="ViewLayer")
    assert "Volume Multiple" not in layer
    # The compositor ran on our pass (bl_use_postprocess).
    np.testing.assert_allclose(comp[:, :, :3], layer["Transmittance"], atol=1e-5)


def test_unsupported_node_is_reported_and_the_rest_renders(empty_scene, capfd):
    sc = small_scene(empty_scene, cubes=((-1.5, 0.0, 0.0), (1.5, 0.0, 0.0)))
    # Cube1's density comes from a texture, which the translation does not evaluate.
    nt = bpy.data.materials["Vol1"].node_tree
    noise = nt.nodes.new("ShaderNodeTexBrick")
    nt.links.new(noise.outputs["Fac"], nt.nodes["Principled Volume"].inputs["Density"])
    last = frame.render_mpp()
    msgs = [w for w in last.output.warnings if "Brick Texture" in w]
    assert msgs, f"no warning about the unsupported node in {last.output.warnings}"
    printed = capfd.readouterr()
    assert msgs[0] in printed.out + printed.err  # shown by self.report
    T = last.output.passes["Transmittance"]
    left = T[:, : W // 2].min()
    assert left < 0.5  # the supported cube rendered


def test_empty_scene_renders_the_background_with_a_report(empty_scene):
    sc = small_scene(empty_scene, cubes=())
    bg = sc.world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0.2, 0.3, 0.4, 1.0)
    bg.inputs["Strength"].default_value = 1.0
    last = frame.render_mpp()
    assert engine.NO_MEDIA_MESSAGE in last.output.warnings
    comb = last.output.passes["Combined"]
    np.testing.assert_allclose(comb, np.broadcast_to([0.2, 0.3, 0.4, 1.0], comb.shape), atol=1e-6)
    np.testing.assert_allclose(last.output.passes["Transmittance"], 1.0)


def test_esc_stops_the_render_quickly(empty_scene, monkeypatch):
    sc = small_scene(empty_scene, width=640, height=480)
    sc.mpp.samples = 256  # tens of seconds uninterrupted
    monkeypatch.setenv(engine.TEST_BREAK_ENV, "0.2")
    t = time.perf_counter()
    last = frame.render_mpp()
    wall = time.perf_counter() - t
    assert last.output.cancelled
    assert wall < 3.0, f"Esc took {wall:.2f} s to stop the render"


INSTALL_SCRIPT = r"""
import sys, bpy, addon_utils
bpy.ops.extensions.package_install_files(filepath=sys.argv[1], repo="user_default",
                                         enable_on_install=True)
sc = bpy.context.scene
sc.render.engine = "MPP_RENDER"
assert sc.mpp.samples == 16
assert "bl_ext.user_default.mpp_render.mpp_render.blender.engine" in sys.modules
addon_utils.disable("bl_ext.user_default.mpp_render", default_set=True)
try:
    sc.render.engine = "MPP_RENDER"
except TypeError:
    print("UNREGISTERED")
"""


def test_extension_builds_installs_and_unregisters(tmp_path):
    """The repository root is a valid extension whose modules import relatively."""
    import os
    import subprocess
    import sys

    from conftest import REPO

    cli = os.path.join(bpy.utils.system_resource('SCRIPTS'), "addons_core", "bl_pkg", "cli",
                       "blender_ext.py")
    dist = tmp_path / "dist"
    dist.mkdir()
    subprocess.run([sys.executable, cli, "build", "--source-dir", str(REPO), "--output-dir",
                    str(dist)], check=True, capture_output=True, timeout=60)
    (zip_path,) = dist.glob("mpp_render-*.zip")
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "user"))
    env.pop("PYTHONPATH", None)
    p = subprocess.run([sys.executable, "-c", INSTALL_SCRIPT, str(zip_path)], cwd=str(tmp_path),
                       env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    assert "UNREGISTERED" in p.stdout


def test_what_is_left_out_is_reported_before_the_render_runs(empty_scene, monkeypatch, capfd):
    """Motion blur, an unsupported node: the translation hands them to the engine before the
    render runs (frame.render_depsgraph's on_translated), and the engine reports each once."""
    from mpp_render import render as render_mod
    sc = small_scene(empty_scene)
    sc.render.use_motion_blur = True
    nt = bpy.data.materials["Vol0"].node_tree
    noise = nt.nodes.new("ShaderNodeTexBrick")
    nt.links.new(noise.outputs["Fac"], nt.nodes["Principled Volume"].inputs["Density"])
    events = []
    real_render = render_mod.render

    def spy_render(*a, **kw):
        events.append(("render", None))
        return real_render(*a, **kw)

    monkeypatch.setattr(render_mod, "render", spy_render)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    frame.render_depsgraph(depsgraph, W, H, on_translated=lambda w: events.append(("told", w)))
    assert [k for k, _ in events] == ["told", "render"]
    told = events[0][1]
    assert any("motion blur" in m for m in told) and any("Brick Texture" in m for m in told)
    capfd.readouterr()
    frame.render_mpp()
    printed = capfd.readouterr()
    text = printed.out + printed.err
    for key in ("motion blur is not supported", "Brick Texture"):
        assert text.count(key) == 1, (key, text[-3000:])


def test_material_preview_shading_uses_eevee():
    assert engine.MPPRenderEngine.bl_use_eevee_viewport is True
