"""Esc inside Blender (``MPP_TEST_BREAK_AFTER_S``, as Blender's background mode has no Esc):
the engine returns within 0.5 s in the precompute and in the march, writes what it has,
and the next render of the same scene is complete."""
import time

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render.blender import engine, properties  # noqa: E402

LATENCY_S = 0.5


@pytest.fixture(autouse=True)
def registered():
    properties.register()
    engine.register()
    yield


def scene(sc, resolution, width, height, samples):
    """A Principled Volume cube voxelised at ``resolution``, a sun and a grey sky (so the
    world light is precomputed too), a camera 8 m away."""
    mat = bpy.data.materials.new("Vol")
    nt = mat.node_tree
    nt.nodes.clear()
    pv = nt.nodes.new("ShaderNodeVolumePrincipled")
    pv.inputs["Density"].default_value = 2.0
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(pv.outputs["Volume"], out.inputs["Volume"])
    mesh = bpy.data.meshes.new("Cube")
    v = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    f = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    mesh.from_pydata(v, [], f)
    mesh.materials.append(mat)
    sc.collection.objects.link(bpy.data.objects.new("Cube", mesh))
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", 'SUN'))
    sun.data.energy = 3.0
    sun.rotation_euler = (0.6, 0.2, 0.0)
    sc.collection.objects.link(sun)
    sc.world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.1, 0.1, 0.1, 1)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.location = (0.0, -8.0, 0.0)
    cam.rotation_euler = (np.pi / 2, 0.0, 0.0)
    sc.collection.objects.link(cam)
    sc.camera = cam
    r = sc.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
    r.engine = "MPP_RENDER"
    sc.mpp.samples = samples
    sc.mpp.voxel_resolution = resolution
    sc.mpp.threads = 2
    return sc


def render_with_esc(monkeypatch, after):
    """Render with Esc ``after`` s into the frame; (the frame's record, seconds from Esc to
    the core's return, i.e. to the engine writing the result)."""
    starts, returns = [], []
    check, write = engine.cancel_check, engine.write_result

    def cancel_check(test_break, start):
        starts.append(start)
        return check(test_break, start)

    def write_result(*args, **kw):
        returns.append(time.perf_counter())
        return write(*args, **kw)

    monkeypatch.setattr(engine, "cancel_check", cancel_check)
    monkeypatch.setattr(engine, "write_result", write_result)
    monkeypatch.setenv(engine.TEST_BREAK_ENV, str(after))
    bpy.ops.render.render()
    monkeypatch.delenv(engine.TEST_BREAK_ENV)
    last = engine.LAST_RENDER
    assert last.output.cancelled
    assert last.translate_s < after  # Esc came after the translation
    return last, returns[0] - (starts[0] + after)


def check_complete(last, shape):
    out = last.output
    assert not out.cancelled and "march" in out.timings
    for name, p in out.passes.items():
        assert p.shape[:2] == shape and np.all(np.isfinite(p)), name
    assert np.all(out.passes["Combined"][..., 3] == 1.0)  # every tile written
    T = out.passes["Transmittance"]
    assert T[shape[0] // 2, shape[1] // 2].max() < 0.5 and T[0, 0].min() == 1.0


def test_esc_during_the_precompute(empty_scene, monkeypatch):
    sc = scene(empty_scene, 96, 48, 36, 1)  # about 2.5 s of precompute
    last, latency = render_with_esc(monkeypatch, 0.5)
    assert "march" not in last.output.timings  # stopped in the precompute
    assert latency < LATENCY_S, f"{latency:.3f} s from Esc to return"
    bpy.ops.render.render()  # no Esc this time
    check_complete(engine.LAST_RENDER, (36, 48))
    assert sc.mpp.voxel_resolution == 96


def test_esc_during_the_march(empty_scene, monkeypatch):
    scene(empty_scene, 12, 640, 480, 4)  # a precompute of 0.1 s, a march of seconds
    last, latency = render_with_esc(monkeypatch, 1.0)
    assert "march" in last.output.timings  # stopped in the march
    assert latency < LATENCY_S, f"{latency:.3f} s from Esc to return"
    alpha = last.output.passes["Combined"][..., 3]
    assert 0 < alpha.mean() < 1  # some tiles written, not all
