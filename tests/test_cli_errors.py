"""Bad input to ``python -m mpp_render``: one line on stderr saying what is wrong and what to
do, exit status 2, no traceback (unless ``--debug``).  Every case is caught before Blender
starts, so these run without the bpy module."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def run_cli(*args, cwd=None):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "mpp_render", *map(str, args)],
                          cwd=str(cwd or REPO), env=env, capture_output=True, text=True,
                          timeout=120)


def one_line_error(p, *words, code=2):
    """``p`` exited with ``code`` after one line on stderr holding every one of ``words``."""
    lines = p.stderr.strip().splitlines()
    assert p.returncode == code, (p.returncode, p.stderr[-2000:])
    assert len(lines) == 1, p.stderr[-2000:]
    assert "Traceback" not in p.stderr + p.stdout
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


@pytest.fixture
def blend(tmp_path):
    """A file that starts like a .blend (only its header is looked at before Blender starts)."""
    path = tmp_path / "scene.blend"
    path.write_bytes(b"BLENDER-v405" + bytes(64))
    return path


@pytest.fixture
def scene_dir(tmp_path):
    """A scene folder with one 8x6 reference run."""
    from mpp_render import exr

    d = tmp_path / "scene"
    exr.write_passes(str(d / "ref_s1.exr"), {"Combined": np.full((6, 8, 4), 0.5, np.float32)})
    return d


def test_render_a_missing_file(tmp_path):
    line = one_line_error(run_cli("render", "/nonexistent.blend", "-o", tmp_path / "x.exr"),
                          "/nonexistent.blend", "no such file")
    assert line.startswith("mpp_render: error:")
    assert not (tmp_path / "x.exr").exists()


def test_render_a_file_that_is_not_a_blend(tmp_path):
    text = tmp_path / "notes.blend"
    text.write_text("not a blend file\n")
    one_line_error(run_cli("render", text, "-o", tmp_path / "x.exr"), "not a .blend file")
    one_line_error(run_cli("render", tmp_path, "-o", tmp_path / "x.exr"), "is a folder")


def test_render_to_an_unwritable_output(tmp_path, blend):
    afile = tmp_path / "afile"
    afile.write_text("")
    one_line_error(run_cli("render", blend, "-o", afile / "x.exr"), "-o", "choose another -o")
    one_line_error(run_cli("render", blend, "-o", tmp_path), "is a folder")


@pytest.mark.parametrize("spec", ["3:1", "a:b", "1:5:0", "7"])
def test_render_a_bad_frames_spec(tmp_path, blend, spec):
    one_line_error(run_cli("render", blend, "-o", tmp_path / "x.exr", "--frames", spec),
                   "--frames", "e.g. --frames 1:24")


def test_render_frame_and_frames_together(tmp_path, blend):
    one_line_error(run_cli("render", blend, "-o", tmp_path / "x.exr", "--frame", 2,
                           "--frames", "1:3"), "either --frame or --frames")


def test_usage_errors_are_one_line():
    one_line_error(run_cli("render"), "required", "--help")
    one_line_error(run_cli("render", "x.blend", "-o", "x.exr", "--samples", "many"),
                   "--samples", "--help")
    one_line_error(run_cli("frobnicate"), "frobnicate", "--help")


def test_compare_a_file_that_is_not_an_exr(tmp_path, scene_dir):
    text = tmp_path / "render.exr"
    text.write_text("plain text, no image\n")
    one_line_error(run_cli("compare", text, scene_dir), "not an EXR file")
    one_line_error(run_cli("compare", tmp_path / "missing.exr", scene_dir), "no such file")


def test_compare_against_a_folder_without_references(tmp_path, scene_dir):
    from mpp_render import exr

    cand = tmp_path / "cand.exr"
    exr.write_passes(str(cand), {"Combined": np.full((6, 8, 4), 0.5, np.float32)})
    empty = tmp_path / "empty"
    empty.mkdir()
    one_line_error(run_cli("compare", cand, empty), "no ref_s*.exr", "--single")
    one_line_error(run_cli("compare", cand, scene_dir, "--single"), "no ss_s*.exr")
    one_line_error(run_cli("compare", cand, tmp_path / "nowhere"), "no such folder")


def test_compare_a_candidate_of_another_size_or_without_combined(tmp_path, scene_dir):
    from mpp_render import exr

    cand = tmp_path / "cand.exr"
    exr.write_passes(str(cand), {"Combined": np.full((5, 7, 4), 0.5, np.float32)})
    one_line_error(run_cli("compare", cand, scene_dir), "resolution")
    depth = tmp_path / "depth.exr"
    exr.write_passes(str(depth), {"Depth": np.ones((6, 8, 1), np.float32)})
    one_line_error(run_cli("compare", depth, scene_dir), "no Combined pass")


def test_compare_works_on_good_input(tmp_path, scene_dir):
    from mpp_render import exr

    cand = tmp_path / "cand.exr"
    exr.write_passes(str(cand), {"Combined": np.full((6, 8, 4), 0.5, np.float32)})
    p = run_cli("compare", cand, scene_dir)
    assert p.returncode == 0 and p.stderr == "", p.stderr
    assert '"rel_rmse"' in p.stdout.strip().splitlines()[-1]


def test_debug_shows_the_traceback(tmp_path):
    for args in (("--debug", "render"), ("render", "--debug")):
        p = run_cli(*args, "/nonexistent.blend", "-o", tmp_path / "x.exr")
        assert p.returncode != 0
        assert "Traceback" in p.stderr and "no such file" in p.stderr
