"""Farm rendering (docs/farm.md): an animation's frames rendered by two separate processes,
as two workers would (frames 1-2 and 3-4), equal one process's frames bit for bit, in every
pass: the seeds follow from the file and the frame, the light paths sum in a fixed order
whatever the threads, and what a process caches between frames changes nothing."""
import os
import subprocess
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render import cache, exr  # noqa: E402
from parts import add_camera, add_cube, add_light, link, mpp_output, volume_material  # noqa: E402

from conftest import REPO  # noqa: E402

pytestmark = pytest.mark.usefixtures("registered")


def farm_scene(scene):
    """A smoke cube over a grey ground under a point light that moves over frames 1..4, a
    sun, multiple scattering by traced paths (few, for speed)."""
    add_cube(scene, "Smoke", mat=volume_material("SmokeVol", density=3.0, anisotropy=0.4))
    mesh = bpy.data.meshes.new("Ground")
    mesh.from_pydata([(-6, -6, -1.2), (6, -6, -1.2), (6, 6, -1.2), (-6, 6, -1.2)], [],
                     [(0, 1, 2, 3)])
    ground = link(scene, bpy.data.objects.new("Ground", mesh))
    mat = bpy.data.materials.new("GroundMat")
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.5, 0.5, 0.5, 1)
    ground.data.materials.append(mat)
    lamp = add_light(scene, name="Lamp", kind="POINT", energy=400.0, location=(1.5, -1.5, 1.5))
    lamp.location = (1.5, -1.5, 1.5)
    lamp.keyframe_insert("location", frame=1)
    lamp.location = (-1.5, -1.5, 2.0)
    lamp.keyframe_insert("location", frame=4)
    add_light(scene, energy=1.5, rotation=(0.5, 0.3, 0.0))
    add_camera(scene)
    mpp_output(scene, 24, 18, samples=2)
    scene.mpp.multiple_paths = 20000
    scene.mpp.multiple_resolution = 16
    scene.frame_start, scene.frame_end = 1, 4


def render_frames(blend, out, frames, cache_mb="256"):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env[cache.LIMIT_ENV] = cache_mb
    p = subprocess.run([sys.executable, "-m", "mpp_render", "render", str(blend), "-o", str(out),
                        "--frames", frames], cwd=str(REPO), env=env, capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]


def test_two_workers_render_the_frames_of_one(empty_scene, tmp_path):
    farm_scene(empty_scene)
    blend = tmp_path / "shot.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    render_frames(blend, tmp_path / "one" / "f.exr", "1:4")
    render_frames(blend, tmp_path / "two" / "f.exr", "1:2")
    render_frames(blend, tmp_path / "two" / "f.exr", "3:4", cache_mb="0")   # no cache at all
    for i in range(1, 5):
        a = exr.read_passes(str(tmp_path / "one" / f"f_{i:04d}.exr"))
        b = exr.read_passes(str(tmp_path / "two" / f"f_{i:04d}.exr"))
        assert sorted(a) == sorted(b)
        assert "Volume Multiple" in a and float(a["Volume Multiple"].mean()) > 0
        for name in a:
            assert np.array_equal(a[name], b[name]), (i, name)
    # the lamp moves: the frames differ from each other
    f1 = exr.read_passes(str(tmp_path / "one" / "f_0001.exr"))["Combined"]
    f4 = exr.read_passes(str(tmp_path / "one" / "f_0004.exr"))["Combined"]
    assert not np.array_equal(f1, f4)
