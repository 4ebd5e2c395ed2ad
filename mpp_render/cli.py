"""Command line: ``python -m mpp_render render|compare|demo|package``.

* ``render FILE.blend -o OUT.exr [--frame N | --frames A:B[:STEP]] [--samples N]
  [--no-multiple] [--seed N] [--engine mpp|cycles] [--resolution-percentage P]`` renders one
  frame of the file's active view layer and writes a multilayer EXR (every pass) and a PNG
  preview of Combined beside it (same name, ``.png``).  ``--frames`` renders frames A to B
  (inclusive) into ``OUT_####.exr`` (the frame number, 4 digits; a run of ``#`` in OUT
  gives the place and the width instead), reusing what did not change between frames
  (``mpp_render.cache``).  ``--engine cycles`` renders the reference instead, with the
  settings of ``shared/reference/metrics.md`` (CPU, no denoising, no adaptive sampling, no
  clamping, 1024 bounces -- volume bounces 0 with ``--no-multiple`` -- 1 px box filter).
* ``compare OUT.exr SCENE_DIR [--single]`` scores OUT.exr's Combined pass against the scene's
  ``ref_s*.exr`` (``ss_s*.exr`` with ``--single``) and prints the metrics as JSON.
* ``demo [-o out/demo]`` builds the demo cloud in code, renders it with MPP and writes
  ``out/demo.exr`` and ``out/demo.png``, then renders it with Cycles (reference settings,
  32 spp) to ``out/demo_cycles.exr`` and prints our error against that render.

``render`` and ``demo`` print one JSON line last on stdout, times in seconds::

    {"translate": s, "precompute": s, "march": s, "write": s, "total": s, "warnings": [...], ...}

``total`` is the wall time of the render call plus writing the files (Blender start-up and
opening the file excluded); ``render`` is the render call alone.  For Cycles the three stage
times are null.  With ``--frames`` the line is ``{"frames": [one record per frame, with
"frame"], "seconds_per_frame": s, "total": s, "warnings": [...], "cancelled": bool}``.
Blender's own log lines may come before the JSON line.

Bad input (a missing or unreadable file, a bad ``--frames`` spec, an output that cannot be
written, a scene folder without references) is answered with one line on stderr saying what
is wrong and what to do, and exit status 2; any other error also prints one line (exit 1)
unless ``--debug`` is given, which shows the traceback instead.  A failed or cancelled render
exits 1 after the JSON line.

This module holds the argument parsing, the checks of the input and the dispatch; Blender's
module is not loaded here.  The Blender work is done by ``mpp_render.blender.batch``,
imported by the command that needs it.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import sys

BLEND_MAGICS = (b"BLENDER", b"\x1f\x8b", b"\x28\xb5\x2f\xfd")  # plain, gzip, zstd


class CliError(Exception):
    """Bad input: ``message`` (what is wrong and what to do) is printed as one line and the
    command exits with ``code`` (2: a usage error)."""

    def __init__(self, message: str, code: int = 2):
        super().__init__(message)
        self.code = code


class Parser(argparse.ArgumentParser):
    """argparse with its errors on one line (the usage is one ``--help`` away)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def parse_frames(text: str) -> range:
    """``"A:B"`` or ``"A:B:STEP"`` (inclusive, STEP >= 1) as a range; ValueError otherwise."""
    parts = text.split(":")
    if len(parts) not in (2, 3) or not all(p.strip().lstrip("-").isdigit() for p in parts):
        raise ValueError(f"--frames wants A:B or A:B:STEP (integers), got '{text}'")
    a, b = int(parts[0]), int(parts[1])
    step = int(parts[2]) if len(parts) == 3 else 1
    if step < 1 or b < a:
        raise ValueError(f"--frames {text}: need A <= B and STEP >= 1")
    return range(a, b + 1, step)


def frame_path(output: str, frame: int) -> str:
    """The file of ``frame`` for ``-o output``: its last run of '#' replaced by the frame
    number zero-padded to the run's length, else ``_####`` added before the extension."""
    runs = list(re.finditer(r"#+", output))
    if runs:
        r = runs[-1]
        return output[:r.start()] + f"{frame:0{len(r.group())}d}" + output[r.end():]
    stem, ext = os.path.splitext(output)
    return f"{stem}_{frame:04d}{ext or '.exr'}"


# --- checks of the input, before Blender starts ------------------------------------------

def check_blend(path: str) -> str:
    """``path`` if it is a readable .blend file (plain or compressed); CliError otherwise."""
    if not os.path.exists(path):
        raise CliError(f"{path}: no such file; give the path of a .blend file")
    if os.path.isdir(path):
        raise CliError(f"{path} is a folder; give the path of a .blend file in it")
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError as e:
        raise CliError(f"cannot read {path}: {e.strerror}; check its permissions") from e
    if not head.startswith(BLEND_MAGICS):
        raise CliError(f"{path} is not a .blend file; give a file saved by Blender")
    return path


def check_output(path: str, option: str = "-o") -> None:
    """Create the folder of the output file ``path``; CliError when it cannot be written."""
    full = os.path.abspath(path)
    if os.path.isdir(full):
        raise CliError(f"{option} {path} is a folder; give a file name (e.g. {os.path.join(path, 'out.exr')})")
    folder = os.path.dirname(full)
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as e:
        raise CliError(f"cannot create the folder of {option} {path}: {e.strerror}; "
                       f"choose another {option}") from e
    if not os.access(folder, os.W_OK):
        raise CliError(f"cannot write {option} {path}: {folder} is not writable; "
                       f"choose another {option}")


def _open_scene(path: str):
    from .blender import batch

    try:
        return batch.open_blend(path)
    except batch.BatchError as e:
        raise CliError(str(e)) from e


# --- the commands ------------------------------------------------------------------------

def cmd_render(args) -> dict:
    try:
        frames = parse_frames(args.frames) if args.frames else None
    except ValueError as e:
        raise CliError(f"{e}; e.g. --frames 1:24 or --frames 1:24:2") from e
    if frames is not None and args.frame is not None:
        raise CliError("use either --frame or --frames, not both")
    if args.resolution_percentage is not None and args.resolution_percentage < 1:
        raise CliError(f"--resolution-percentage {args.resolution_percentage}: give a percentage >= 1")
    check_blend(args.file)
    outputs = [frame_path(args.output, f) for f in frames] if frames is not None else [args.output]
    for out in dict.fromkeys(outputs):
        check_output(out)
    scene = _open_scene(args.file)
    from .blender import batch

    if frames is None and args.frame is not None:
        scene.frame_set(args.frame)
    batch.configure(scene, args.engine, args.samples, not args.no_multiple, args.seed,
                    args.resolution_percentage)
    if frames is not None:
        return batch.render_frames(scene, list(zip(frames, outputs)))
    return batch.public(batch.render_current(scene, args.output))


def cmd_demo(args) -> dict:
    """Build the demo cloud, render it with MPP, then with Cycles at the reference settings
    (``cycles_samples`` spp, 0 to skip) and score ours against it (``batch.demo``)."""
    stem = args.output[:-4] if args.output.endswith(".exr") else args.output
    check_output(stem + ".exr")
    from .blender import batch

    return batch.demo(stem, args.samples, not args.no_multiple,
                      int(getattr(args, "cycles_samples", 32) or 0))


def cmd_compare(args) -> dict:
    from .exr import read_passes
    from .metrics import compare_files, reference_paths

    what = "ss_s*.exr" if args.single else "ref_s*.exr"
    if not os.path.isfile(args.candidate):
        raise CliError(f"{args.candidate}: no such file; give the EXR written by 'render'")
    if not os.path.isdir(args.scene_dir):
        raise CliError(f"{args.scene_dir}: no such folder; give a scene folder holding {what}")
    if not reference_paths(args.scene_dir, args.single):
        hint = "" if args.single else " (or --single for ss_s*.exr)"
        raise CliError(f"no {what} in {args.scene_dir}; give a scene folder of the suite{hint}")
    try:
        has = read_passes(args.candidate, names=("Combined",))
    except (OSError, RuntimeError) as e:
        raise CliError(f"{args.candidate} is not an EXR file that can be read; give the "
                       "multilayer EXR written by 'render'") from e
    if "Combined" not in has:
        raise CliError(f"{args.candidate} has no Combined pass; give the multilayer EXR "
                       "written by 'render'")
    try:
        return compare_files(args.candidate, args.scene_dir, single=args.single)
    except ValueError as e:  # the resolutions do not match
        raise CliError(f"{e}; render at the references' resolution or 1/f of it") from e


DEBUG_HELP = "show the traceback of an error (for bug reports)"


def build_parser() -> argparse.ArgumentParser:
    ap = Parser(prog="python -m mpp_render", description=__doc__.split("\n")[0])
    ap.add_argument("--debug", action="store_true", help=DEBUG_HELP)
    sub = ap.add_subparsers(dest="command", required=True)

    def command(name, **kw):
        p = sub.add_parser(name, **kw)
        p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=DEBUG_HELP)
        return p

    r = command("render", help="render one frame of a .blend file")
    r.add_argument("file", help="the .blend file")
    r.add_argument("-o", "--output", required=True, help="multilayer EXR to write (PNG beside it)")
    r.add_argument("--frame", type=int, help="frame to render (default: the file's current)")
    r.add_argument("--frames", metavar="A:B[:STEP]",
                   help="render frames A..B (inclusive) to OUT_####.exr (or OUT's '#' run)")
    r.add_argument("--samples", type=int, help="samples per pixel (default: the file's)")
    r.add_argument("--no-multiple", action="store_true",
                   help="single scattering only (Cycles: volume_bounces 0)")
    r.add_argument("--seed", type=int, help="random seed (Cycles default 0)")
    r.add_argument("--engine", choices=("mpp", "cycles"), default="mpp")
    r.add_argument("--resolution-percentage", type=int, help="1..100, scales the file's resolution")
    r.set_defaults(func=cmd_render)

    c = command("compare", help="score an EXR against a scene's Cycles references")
    c.add_argument("candidate", help="EXR with a Combined pass")
    c.add_argument("scene_dir", help="folder holding ref_s*.exr / ss_s*.exr")
    c.add_argument("--single", action="store_true", help="score against ss_s*.exr")
    c.set_defaults(func=cmd_compare)

    d = command("demo", help="render the built-in demo cloud")
    d.add_argument("-o", "--output", default=os.path.join("out", "demo"),
                   help="output stem: writes STEM.exr and STEM.png (default out/demo)")
    d.add_argument("--samples", type=int, help="samples per pixel (default 16)")
    d.add_argument("--no-multiple", action="store_true", help="single scattering only")
    d.set_defaults(func=cmd_demo)

    from .package import cmd_package  # stdlib only: cheap to import here

    k = command("package", help="build the installable extension zip (kernels as a wheel)")
    k.add_argument("--output-dir", default="dist", help="folder for the zip (default dist)")
    k.add_argument("--source-dir", help="extension source (default: this checkout's root)")
    k.set_defaults(func=cmd_package)
    return ap


def one_line(text: str) -> str:
    """``text`` with its line breaks and runs of blanks folded into single spaces."""
    return " ".join(str(text).split())


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    debug = bool(getattr(args, "debug", False))
    try:
        rec = args.func(args)
    except CliError as e:
        if debug:
            raise
        print(f"mpp_render: error: {one_line(e)}", file=sys.stderr, flush=True)
        return e.code
    except KeyboardInterrupt:
        print("mpp_render: interrupted", file=sys.stderr, flush=True)
        return 130
    except Exception as e:  # a bug or a failure of the machine: one line unless --debug
        if debug:
            raise
        print(f"mpp_render: {args.command} failed: {type(e).__name__}: {one_line(e)} "
              "(run again with --debug for the traceback)", file=sys.stderr, flush=True)
        return 1
    sys.stdout.flush()
    print(json.dumps(rec), flush=True)
    if rec.get("failed") or rec.get("cancelled"):
        return 1
    return 0
