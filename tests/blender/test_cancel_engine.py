"""Esc inside Blender (``MPP_TEST_BREAK_AFTER_S``, as Blender's background mode has no Esc):
the engine returns within 0.5 s in the precompute and in the march, writes what it has,
and the next render of the same scene is complete."""
import time

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render.blender import engine, frame  # noqa: E402
from parts import add_camera, add_cube, add_light, mpp_output, volume_material  # noqa: E402

LATENCY_S = 0.5


pytestmark = pytest.mark.usefixtures("registered")


def scene(sc, resolution, width, height, samples):
    """A Principled Volume cube voxelised at ``resolution``, a sun and a grey sky (so the
    world light is precomputed too), a camera 8 m away."""
    add_cube(sc, "Cube", mat=volume_material("Vol", density=2.0, color=None))
    add_light(sc)
    sc.world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.1, 0.1, 0.1, 1)
    add_camera(sc)
    mpp_output(sc, width, height, samples, resolution)
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
    last = frame.render_mpp()
    monkeypatch.delenv(engine.TEST_BREAK_ENV)
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
    check_complete(frame.render_mpp(), (36, 48))  # no Esc this time
    assert sc.mpp.voxel_resolution == 96


def test_esc_during_the_march(empty_scene, monkeypatch):
    sc = scene(empty_scene, 12, 640, 480, 16)  # a precompute of 0.1 s, a march of seconds:
    sc.mpp.noise_threshold = 0.0               # every pixel takes its 16 samples
    last, latency = render_with_esc(monkeypatch, 1.0)
    assert "march" in last.output.timings  # stopped in the march
    assert latency < LATENCY_S, f"{latency:.3f} s from Esc to return"
    alpha = last.output.passes["Combined"][..., 3]
    assert 0 < alpha.mean() < 1  # some tiles written, not all
