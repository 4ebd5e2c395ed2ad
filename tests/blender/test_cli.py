"""``python -m mpp_render render|compare`` in a subprocess, on the public slab scene."""
import json
import math
import os
import subprocess
import sys

import numpy as np

from mpp_render import exr

from conftest import REPO

TIMING_KEYS = ("translate", "precompute", "march", "write", "total")


def run_cli(*args, timeout=120):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env.pop("MPP_TEST_BREAK_AFTER_S", None)
    p = subprocess.run([sys.executable, "-m", "mpp_render", *map(str, args)], cwd=str(REPO),
                       env=env, capture_output=True, text=True, timeout=timeout)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    return json.loads(p.stdout.strip().splitlines()[-1])


def test_cli_render_and_compare(scenes_dir, tmp_path):
    scene = scenes_dir / "slab_forward"
    out = tmp_path / "slab.exr"
    rec = run_cli("render", scene / "scene.blend", "-o", out, "--resolution-percentage", 25,
                  "--samples", 1, "--no-multiple")
    for key in TIMING_KEYS:
        assert isinstance(rec[key], float) and rec[key] >= 0.0, key
    assert rec["total"] >= rec["march"] and isinstance(rec["warnings"], list)
    assert rec["resolution"] == [40, 30]

    passes = exr.read_passes(str(out))
    assert set(passes) == {"Combined", "Volume Single", "Emission", "Transmittance", "Depth"}
    assert passes["Combined"].shape == (30, 40, 4)
    assert np.all(np.isfinite(passes["Combined"]))
    assert (tmp_path / "slab.png").is_file()

    m = run_cli("compare", out, scene, "--single")
    assert not m["failed"] and m["ref_downsample"] == 4
    for key in ("rel_rmse", "floor", "bias", "rel_rmse_4", "floor_4"):
        assert isinstance(m[key], float) and math.isfinite(m[key]), key


def test_cli_render_a_damaged_blend(scenes_dir, tmp_path):
    """A file with a .blend header that Blender cannot read: one line on stderr, exit 2 (the
    cases caught before Blender starts are in tests/test_cli_errors.py)."""
    damaged = tmp_path / "damaged.blend"
    damaged.write_bytes((scenes_dir / "slab_forward" / "scene.blend").read_bytes()[:2000])
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    p = subprocess.run([sys.executable, "-m", "mpp_render", "render", str(damaged), "-o",
                        str(tmp_path / "x.exr")], cwd=str(REPO), env=env, capture_output=True,
                       text=True, timeout=120)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1, p.stderr[-2000:]
    assert "Blender cannot open" in lines[0] and str(damaged) in lines[0]
    assert "Traceback" not in p.stderr + p.stdout
    assert not (tmp_path / "x.exr").exists()
