"""Animations: ``render.render(animation=True)`` (what ``blender -b -a`` runs) renders and
writes every frame with the MPP engine; work that did not change between frames is reused
(the precompute parts, voxelised meshes) and the frames equal cold renders; ``python -m
mpp_render render --frames A:B`` writes OUT_####.exr; *Clear MPP Caches* empties the store."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render import cache, exr  # noqa: E402
from mpp_render import precompute as pre_mod  # noqa: E402
from mpp_render.blender import engine, frame  # noqa: E402
from parts import add_camera, add_cube, add_light, mpp_output, volume_material  # noqa: E402

from conftest import REPO  # noqa: E402

W, H = 32, 24
pytestmark = pytest.mark.usefixtures("registered")


@pytest.fixture
def frames(monkeypatch):
    """(frame, parts of the precompute reused, precompute calls so far) per rendered frame."""
    seen, calls = [], []
    real_frame, real_pre = engine.render_frame, pre_mod.precompute

    def spy_frame(eng, depsgraph):
        last = real_frame(eng, depsgraph)
        seen.append((last.frame, list(last.output.stats.get("reused", [])), len(calls)))
        return last

    def spy_pre(media, lights, *a, **kw):
        calls.append("lights" if lights else "world")
        return real_pre(media, lights, *a, **kw)

    monkeypatch.setattr(engine, "render_frame", spy_frame)
    monkeypatch.setattr(pre_mod, "precompute", spy_pre)
    return seen


def animated_scene(scene, out_dir, animate_light=True):
    """A volume cube, a sun whose power goes 1 -> 3 W/m^2 over frames 1..3 (or stays 2), a
    grey world, a fixed camera; frames written to ``out_dir/f_####.exr`` (multilayer)."""
    add_cube(scene, "Cloud", mat=volume_material("CloudVol", density=3.0, color=None))
    sun = add_light(scene, energy=2.0, rotation=(0.5, 0.3, 0.0))
    if animate_light:
        sun.data.energy = 1.0
        sun.data.keyframe_insert("energy", frame=1)
        sun.data.energy = 3.0
        sun.data.keyframe_insert("energy", frame=3)
    scene.world.color = (0.05, 0.05, 0.06)
    add_camera(scene)
    r = mpp_output(scene, W, H).render
    scene.frame_start, scene.frame_end = 1, 3
    ims = r.image_settings
    ims.media_type = "MULTI_LAYER_IMAGE"
    ims.file_format = "OPEN_EXR_MULTILAYER"
    ims.color_depth = "32"
    r.filepath = os.path.join(str(out_dir), "f_")
    return sun


def test_animation_renders_every_frame_and_reuses_what_did_not_change(empty_scene, tmp_path,
                                                                      warm, frames):
    animated_scene(empty_scene, tmp_path)
    bpy.ops.render.render(animation=True)
    assert sorted(os.listdir(tmp_path)) == ["f_0001.exr", "f_0002.exr", "f_0003.exr"]
    assert [f for f, _, _ in frames] == [1, 2, 3]
    # the sun's power changes every frame: its optical depths are recomputed, the world
    # light (same media, world and camera) is reused
    assert frames[0][1] == [] and frames[1][1] == ["world"] and frames[2][1] == ["world"]
    assert frames[-1][2] == 3  # precompute calls: everything, then the light part twice
    stats = cache.CACHE.stats()
    assert stats["hits"].get("voxels", 0) >= 2  # the cube voxelised once
    means = [float(exr.read_passes(str(tmp_path / f"f_000{i}.exr"))["Volume Single"].mean())
             for i in (1, 2, 3)]
    assert means[0] < means[1] < means[2]  # the sun brightens: 1, 2, 3 W/m^2
    # the sun's single scattering grows with its power, the world's stays
    np.testing.assert_allclose(means[2] - means[1], means[1] - means[0], rtol=1e-3)

    # frame 2 rendered alone and cold equals frame 2 of the animation
    cache.clear()
    empty_scene.frame_set(2)
    cold = frame.render_mpp().output
    assert cold.stats["reused"] == []
    anim = exr.read_passes(str(tmp_path / "f_0002.exr"))
    for name in ("Combined", "Volume Single", "Volume Multiple", "Transmittance"):
        np.testing.assert_array_equal(anim[name], cold.passes[name], err_msg=name)


def test_a_static_animation_precomputes_once(empty_scene, tmp_path, warm, frames):
    animated_scene(empty_scene, tmp_path, animate_light=False)
    bpy.ops.render.render(animation=True)
    assert [r for _, r, _ in frames] == [[], ["lights", "world"], ["lights", "world"]]
    assert frames[-1][2] == 1
    a, b = (exr.read_passes(str(tmp_path / f"f_000{i}.exr")) for i in (1, 3))
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    # a re-render of the current frame reuses everything too
    bpy.ops.render.render()
    assert frames[-1][1] == ["lights", "world"] and frames[-1][2] == 1


def test_clear_caches_empties_the_store(empty_scene, tmp_path, warm):
    import operators  # the repository root's ``operators`` package

    animated_scene(empty_scene, tmp_path, animate_light=False)
    bpy.ops.render.render()
    assert len(cache.CACHE) > 0
    held = cache.CACHE.bytes / cache.MB
    rec = operators.clear_caches()
    assert rec["cache_mb"] == pytest.approx(held) and rec["cache_mb"] > 0
    assert len(cache.CACHE) == 0
    assert "reusable precompute" in operators.clear_summary(rec)
    assert frame.render_mpp().output.stats["reused"] == []


def test_cli_frames_writes_one_exr_per_frame(empty_scene, tmp_path):
    animated_scene(empty_scene, tmp_path / "unused")
    blend = tmp_path / "anim.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env[cache.LIMIT_ENV] = "256"
    p = subprocess.run([sys.executable, "-m", "mpp_render", "render", str(blend), "-o",
                        str(tmp_path / "out" / "shot.exr"), "--frames", "1:3", "--samples", "1"],
                       cwd=str(REPO), env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    rec = json.loads(p.stdout.strip().splitlines()[-1])
    assert [r["frame"] for r in rec["frames"]] == [1, 2, 3]
    assert sorted(f for f in os.listdir(tmp_path / "out") if f.endswith(".exr")) == \
        ["shot_0001.exr", "shot_0002.exr", "shot_0003.exr"]
    assert [r["reused"] for r in rec["frames"]] == [[], ["world"], ["world"]]
    assert rec["seconds_per_frame"] > 0 and not rec["cancelled"]
    m1, m2, m3 = (float(exr.read_passes(str(tmp_path / "out" / f"shot_000{i}.exr"))
                        ["Volume Single"].mean()) for i in (1, 2, 3))
    assert m1 < m2 < m3
    np.testing.assert_allclose(m3 - m2, m2 - m1, rtol=1e-3)  # the sun: 1, 2, 3 W/m^2
