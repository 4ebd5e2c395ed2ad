"""The README's demo: the procedural cloud builds, renders with MPP and scores against a
Cycles render of the same scene (at a quarter of the resolution to keep the test short)."""
import json
import types

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render import cli  # noqa: E402


def test_demo_renders_and_scores_against_cycles(tmp_path, monkeypatch):
    from mpp_render.blender import demo

    real_build = demo.build_demo_scene

    def small(directory):
        sc = real_build(directory)
        sc.render.resolution_percentage = 25
        return sc

    monkeypatch.setattr(demo, "build_demo_scene", small)
    args = types.SimpleNamespace(output=str(tmp_path / "demo"), samples=2, no_multiple=False,
                                 cycles_samples=4)
    rec = cli.cmd_demo(args)
    json.dumps(rec)  # the record the command prints is plain JSON
    assert rec["image"]["finite"] and rec["resolution"] == [120, 67]
    assert 0.0 < rec["image"]["mean_transmittance"] < 1.0   # the cloud is in view
    assert (tmp_path / "demo.exr").exists() and (tmp_path / "demo.png").exists()
    assert (tmp_path / "demo_cycles.exr").exists()
    c = rec["cycles"]
    assert np.isfinite(c["rel_rmse_4"]) and abs(c["bias"]) < 0.2, c
