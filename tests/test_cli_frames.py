"""``--frames A:B[:STEP]`` of ``python -m mpp_render render`` and the per-frame file names."""
import pytest

from mpp_render.cli import build_parser, frame_path, parse_frames


def test_frame_ranges_are_inclusive_and_checked():
    assert list(parse_frames("1:3")) == [1, 2, 3]
    assert list(parse_frames("10:20:5")) == [10, 15, 20]
    assert list(parse_frames("-2:0")) == [-2, -1, 0]
    assert list(parse_frames("7:7")) == [7]
    for bad in ("3", "3:1", "1:5:0", "a:b", "1:2:3:4", "1.5:3"):
        with pytest.raises(ValueError):
            parse_frames(bad)


def test_frame_file_names():
    assert frame_path("out/shot.exr", 7) == "out/shot_0007.exr"
    assert frame_path("out/shot", 12) == "out/shot_0012.exr"
    assert frame_path("out/shot_##.exr", 7) == "out/shot_07.exr"
    assert frame_path("out/v#/shot.######.exr", 42) == "out/v#/shot.000042.exr"


def test_render_accepts_frames():
    args = build_parser().parse_args(["render", "f.blend", "-o", "o.exr", "--frames", "1:3"])
    assert args.frames == "1:3" and args.frame is None
