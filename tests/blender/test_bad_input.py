"""Nothing breaks: bad input inside Blender gives a clear report naming the object (and the
file), and the rest of the frame renders.

Each scene: a good mesh volume (a Principled Volume cube) on the left, the bad thing on the
right, a sun, a camera 8 m away looking along +Y.  The frame is 32 x 24 pixels at 4 samples
and 16 voxels a side, so a render takes well under a second."""
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render.blender import engine, frame, properties  # noqa: E402
from mpp_render.blender.translate.vdb import openvdb_module  # noqa: E402
from parts import (add_camera, add_cube, add_light, link, mpp_output,  # noqa: E402
                   volume_material)

W, H = 32, 24
LEFT, RIGHT = (-1.5, 0.0, 0.0), (1.5, 0.0, 0.0)
pytestmark = pytest.mark.usefixtures("registered")


# -- scene building -----------------------------------------------------------------------

def add_volume(name, path, location=RIGHT, scale=(1, 1, 1)):
    vol = bpy.data.volumes.new(name)
    vol.filepath = str(path)
    vol.materials.append(volume_material(f"{name}Vol"))
    ob = link(bpy.context.scene, bpy.data.objects.new(name, vol))
    ob.location, ob.scale = location, scale
    return ob


def setup(scene, good=True, light=True):
    """Camera, render settings, the good cube on the left and (``light``) a sun."""
    if good:
        add_cube(scene, "Good", LEFT)
    if light:
        add_light(scene)
    add_camera(scene)
    return mpp_output(scene, W, H)


def write_vdb(path, values, name="density", voxel=0.25):
    """A float grid ``name`` holding ``values`` (n,n,n) at ``voxel`` metres, about centred on
    the object's origin (index -n/2 .. n/2 - 1)."""
    vdb = openvdb_module()
    g = vdb.FloatGrid()
    g.name = name
    g.transform = vdb.createLinearTransform(voxelSize=voxel)
    g.copyFromArray(np.ascontiguousarray(values, np.float32), ijk=(-(values.shape[0] // 2),) * 3)
    vdb.write(str(path), grids=[g])
    return str(path)


def good_vdb(tmp_path, name="good.vdb"):
    return write_vdb(tmp_path / name, np.ones((8, 8, 8), np.float32))


def render():
    """Render the frame; the engine's record of it.  The render must finish (not cancelled)
    with finite, non-negative passes of the right size."""
    with frame.collect() as frames:
        bpy.ops.render.render()
    last = frames[-1] if frames else None
    assert last is not None and not last.output.cancelled
    for name, p in last.output.passes.items():
        assert p.shape[:2] == (H, W), name
        assert np.all(np.isfinite(p)), name
        if name != "Depth":
            assert p.min() >= 0, name
    return last.output


def left_is_rendered(out):
    """The good cube on the left is in the image: opaque-ish and lit."""
    T = out.passes["Transmittance"]
    assert T[H // 2, W // 4].max() < 0.5
    assert out.passes["Volume Single"][H // 2, W // 4].sum() > 0


def right_is_empty(out):
    np.testing.assert_array_equal(out.passes["Transmittance"][:, 3 * W // 4:], 1.0)


def warnings_about(out, name):
    msgs = [w for w in out.warnings if f"'{name}'" in w]
    assert msgs, f"no warning names '{name}': {out.warnings}"
    return msgs


# -- bad VDB files --------------------------------------------------------------------------

@pytest.mark.parametrize("fraction", [0.05, 0.5, 0.95])
def test_truncated_vdb_is_reported_and_the_rest_renders(empty_scene, tmp_path, fraction):
    data = open(good_vdb(tmp_path), "rb").read()
    bad = tmp_path / "truncated.vdb"
    bad.write_bytes(data[:int(len(data) * fraction)])
    setup(empty_scene)
    add_volume("Cut", bad)
    out = render()
    msgs = warnings_about(out, "Cut")
    assert any(str(bad) in m for m in msgs), msgs
    left_is_rendered(out)
    right_is_empty(out)


def test_corrupt_vdb_is_reported_and_the_rest_renders(empty_scene, tmp_path):
    bad = tmp_path / "noise.vdb"
    bad.write_bytes(np.random.default_rng(7).integers(0, 256, 8192, dtype=np.uint8).tobytes())
    setup(empty_scene)
    add_volume("Noise", bad)
    out = render()
    msgs = warnings_about(out, "Noise")
    assert any(str(bad) in m for m in msgs), msgs
    left_is_rendered(out)
    right_is_empty(out)


def test_vdb_with_random_bytes_after_a_valid_header(empty_scene, tmp_path):
    """The header and grid descriptors intact, the voxel data replaced by noise."""
    data = bytearray(open(good_vdb(tmp_path), "rb").read())
    rng = np.random.default_rng(3)
    start = len(data) // 3
    data[start:] = rng.integers(0, 256, len(data) - start, dtype=np.uint8).tobytes()
    bad = tmp_path / "scrambled.vdb"
    bad.write_bytes(bytes(data))
    setup(empty_scene)
    add_volume("Scrambled", bad)
    out = render()
    left_is_rendered(out)
    # either a clean read of some values or a report naming the object and the file
    msgs = [w for w in out.warnings if "'Scrambled'" in w]
    assert all(str(bad) in m for m in msgs), msgs


def test_randomly_damaged_vdbs_never_crash(tmp_path):
    """Bytes overwritten at random places in 12 copies of a good file, each on its own
    Volume object: every one renders or is reported by object and file.  In a subprocess,
    because a crash inside openvdb would take the test run with it."""
    script = textwrap.dedent(f"""
        import pathlib
        import sys
        sys.path.insert(0, {os.path.dirname(os.path.dirname(os.path.dirname(__file__)))!r})
        sys.path.insert(0, {os.path.dirname(__file__)!r})
        import numpy as np
        import bpy
        import test_bad_input as t
        from mpp_render.blender import engine, frame, properties
        properties.register(); engine.register()
        bpy.ops.wm.read_factory_settings(use_empty=True)
        sc = bpy.context.scene
        sc.world = bpy.data.worlds.new("World")
        t.setup(sc)
        data = open(t.good_vdb(pathlib.Path({str(tmp_path)!r})), "rb").read()
        rng = np.random.default_rng(1)
        for i in range(12):
            b = bytearray(data)
            for _ in range(int(rng.integers(1, 20))):
                b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
            path = {str(tmp_path)!r} + f"/damaged{{i}}.vdb"
            open(path, "wb").write(bytes(b))
            t.add_volume(f"Damaged{{i}}", path, location=(1.5, 0.2 * i, 0.0))
        out = frame.render_mpp().output
        print("RESULT", len(out.warnings), all(np.all(np.isfinite(p)) for p in out.passes.values()))
        for w in out.warnings:
            print("WARNING", w)
        sys.stdout.flush()
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    result = next(ln for ln in run.stdout.splitlines() if ln.startswith("RESULT"))
    assert result.endswith("True")
    warned = [ln for ln in run.stdout.splitlines() if ln.startswith("WARNING")]
    for ln in warned:
        if "'Damaged" in ln:
            assert "damaged" in ln.split(":", 1)[1], ln  # names the file too
    assert sum("'Damaged" in ln for ln in warned) >= 6  # most copies are unreadable


def test_vdb_without_a_density_grid(empty_scene, tmp_path):
    path = write_vdb(tmp_path / "temperature.vdb", np.ones((8, 8, 8), np.float32),
                     name="temperature")
    setup(empty_scene)
    add_volume("Hot", path)
    out = render()
    msgs = warnings_about(out, "Hot")
    assert any("'density'" in m and "'temperature'" in m and path in m for m in msgs), msgs
    left_is_rendered(out)
    right_is_empty(out)


def test_nan_inf_and_negative_voxels_in_a_vdb_are_counted(empty_scene, tmp_path):
    values = np.ones((8, 8, 8), np.float32)
    values[2, 2, 2] = np.inf
    values[3, 3, 3] = -np.inf
    values[4, 4, 4] = -5.0
    path = write_vdb(tmp_path / "bad_values.vdb", values)
    vdb = openvdb_module()  # copyFromArray leaves NaN voxels inactive: set one by hand
    grid = vdb.read(path, "density")
    grid.getAccessor().setValueOn((-3, -2, -1), float("nan"))
    vdb.write(path, grids=[grid])
    setup(empty_scene)
    add_volume("Dirty", path)
    out = render()
    msgs = warnings_about(out, "Dirty")
    assert any("4 voxels" in m and "NaN" in m and path in m for m in msgs), msgs
    left_is_rendered(out)
    # the sanitised grid still renders on the right
    assert out.passes["Transmittance"][H // 2, 3 * W // 4].max() < 0.9


# -- scene content ------------------------------------------------------------------------

def test_no_lights(empty_scene):
    setup(empty_scene, light=False)
    bg = empty_scene.world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0.2, 0.2, 0.2, 1.0)
    out = render()
    T = out.passes["Transmittance"]
    assert T[H // 2, W // 4].max() < 0.5
    # lit by the world only: some scattered sky light, and no light from anywhere else
    assert 0 < out.passes["Volume Single"][H // 2, W // 4].max() < 0.2


def test_no_lights_and_a_black_world_is_reported(empty_scene):
    setup(empty_scene, light=False)
    empty_scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    out = render()
    assert any("no lights" in w for w in out.warnings), out.warnings
    assert np.all(out.passes["Combined"][..., :3] == 0)
    assert out.passes["Transmittance"][H // 2, W // 4].max() < 0.5


def test_no_media(empty_scene):
    setup(empty_scene, good=False)
    out = render()
    assert engine.NO_MEDIA_MESSAGE in out.warnings
    np.testing.assert_array_equal(out.passes["Transmittance"], 1.0)


@pytest.mark.parametrize("energy", [0.0, -5.0])
def test_zero_and_negative_light_power(empty_scene, energy):
    setup(empty_scene, light=False)
    empty_scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    add_light(empty_scene, "Dark", "POINT", energy=energy)
    out = render()
    assert any("no light of the scene has positive power" in w for w in out.warnings)
    assert any("'Dark'" in w and "negative" in w for w in out.warnings) == (energy < 0)
    assert np.all(out.passes["Volume Single"] == 0) and np.all(out.passes["Volume Multiple"] == 0)
    assert out.passes["Transmittance"][H // 2, W // 4].max() < 0.5


def test_negative_light_beside_a_positive_one(empty_scene):
    setup(empty_scene)
    add_light(empty_scene, "Dark", "POINT", energy=-500.0, location=(-1.5, -2.5, 0.0))
    out = render()
    assert warnings_about(out, "Dark") == ["light 'Dark': negative power is not supported; "
                                           "the light emits nothing"]
    assert not any("render black" in w for w in out.warnings)
    left_is_rendered(out)


@pytest.mark.parametrize("scale", [(0.0, 1.0, 1.0), (0.0, 0.0, 0.0)])
def test_zero_scale_mesh_volume(empty_scene, scale):
    setup(empty_scene)
    add_cube(empty_scene, "Flat", RIGHT, scale=scale)
    out = render()
    warnings_about(out, "Flat")
    left_is_rendered(out)
    right_is_empty(out)


@pytest.mark.parametrize("scale", [(0.0, 1.0, 1.0), (0.0, 0.0, 0.0)])
def test_zero_scale_volume_object(empty_scene, tmp_path, scale):
    setup(empty_scene)
    add_volume("Squashed", good_vdb(tmp_path), scale=scale)
    out = render()
    warnings_about(out, "Squashed")
    left_is_rendered(out)
    right_is_empty(out)


def test_good_vdb_renders_beside_the_mesh(empty_scene, tmp_path):
    """The control: the same scene with a good file renders both volumes, no warnings."""
    setup(empty_scene)
    add_volume("Fine", good_vdb(tmp_path))
    out = render()
    assert not [w for w in out.warnings if "'Fine'" in w], out.warnings
    left_is_rendered(out)
    assert out.passes["Transmittance"][H // 2, 3 * W // 4].max() < 0.5


def test_memory_budget_setting_downsamples_with_a_warning(empty_scene):
    setup(empty_scene)
    empty_scene.mpp.voxel_resolution = 64
    assert properties.settings_from_scene(empty_scene).memory_budget_mb == 2048
    empty_scene.mpp.memory_budget_mb = 1
    assert properties.settings_from_scene(empty_scene).memory_budget_mb == 1
    out = render()
    msgs = warnings_about(out, "Good")
    assert any("downsampled by" in m and "memory budget of 1 MB" in m for m in msgs), msgs
    left_is_rendered(out)
