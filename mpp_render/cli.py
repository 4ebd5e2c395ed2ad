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
"""
from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time

import numpy as np


def _bpy():
    """Import bpy and register the engine and its settings (idempotent)."""
    import bpy

    from .blender import engine, properties

    properties.register()
    engine.register()
    return bpy


def set_cycles_reference(scene, samples=None, multiple=True, seed=0):
    """Cycles settings of the reference images (metrics.md; blender-notes section 4)."""
    scene.render.engine = 'CYCLES'
    c = scene.cycles
    c.device = 'CPU'
    if samples:
        c.samples = int(samples)
    c.seed = int(seed)
    c.use_animated_seed = False
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.max_bounces = 1024
    c.volume_bounces = 1024 if multiple else 0
    c.transparent_max_bounces = 1024
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.pixel_filter_type = 'BOX'
    c.filter_width = 1.0


def set_mpp(scene, samples=None, multiple=True, seed=None):
    """Select the MPP engine; override its samples / multiple scattering / seed."""
    scene.render.engine = 'MPP_RENDER'
    if samples:
        scene.mpp.samples = int(samples)
    scene.mpp.multiple = bool(multiple)
    if seed is not None:
        scene.mpp.seed = int(seed)


def set_multilayer_exr(scene):
    """Blender's own writer to a 32-bit ZIP multilayer EXR (media_type must come first)."""
    ims = scene.render.image_settings
    ims.media_type = 'MULTI_LAYER_IMAGE'
    ims.file_format = 'OPEN_EXR_MULTILAYER'
    ims.color_depth = '32'
    ims.exr_codec = 'ZIP'


def png_path(exr_path: str) -> str:
    return os.path.splitext(exr_path)[0] + ".png"


def image_stats(passes: dict) -> dict:
    """A few numbers that describe an image when there is no reference to compare with."""
    comb = passes["Combined"][:, :, :3]
    out = {
        "finite": bool(np.all(np.isfinite(comb))),
        "mean_rgb": [round(float(v), 6) for v in comb.reshape(-1, 3).mean(axis=0)],
        "max": float(np.max(comb)),
    }
    if "Transmittance" in passes:
        out["mean_transmittance"] = round(float(passes["Transmittance"].mean()), 6)
    return out


def render_current(scene, out_exr: str) -> dict:
    """Render ``scene``'s current frame (active view layer) with its engine, write
    ``out_exr`` (multilayer) and the PNG preview; return the timings record."""
    import bpy

    from . import exr
    from .blender import engine

    layer = bpy.context.view_layer.name
    out_exr = os.path.abspath(out_exr)
    os.makedirs(os.path.dirname(out_exr), exist_ok=True)
    engine.LAST_RENDER = None
    t0 = time.perf_counter()
    bpy.ops.render.render(layer=layer)
    render_s = time.perf_counter() - t0

    t1 = time.perf_counter()
    if scene.render.engine == 'MPP_RENDER':
        last = engine.LAST_RENDER
        if last is None:
            raise RuntimeError("the MPP engine produced no image (see the reports above)")
        passes = last.output.passes
        exr.write_passes(out_exr, passes, layer=last.view_layer)
        exr.write_preview_png(png_path(out_exr), passes["Combined"])
        rec = {"translate": last.translate_s,
               "precompute": last.output.timings.get("precompute"),
               "march": last.output.timings.get("march"),
               "reused": last.output.stats.get("reused", [])}
        extra_write = last.write_s
        warnings = list(last.output.warnings)
        cancelled = last.output.cancelled
    else:
        set_multilayer_exr(scene)
        bpy.data.images["Render Result"].save_render(filepath=out_exr, scene=scene)
        passes = exr.read_passes(out_exr, layer=layer)
        exr.write_preview_png(png_path(out_exr), passes["Combined"])
        rec = {"translate": None, "precompute": None, "march": None}
        extra_write = 0.0
        warnings = []
        cancelled = False
    write_s = time.perf_counter() - t1
    rec.update({"write": extra_write + write_s, "total": render_s + write_s,
                "warnings": warnings, "render": render_s, "engine": scene.render.engine,
                "cancelled": cancelled,
                "resolution": [scene.render.resolution_x * scene.render.resolution_percentage // 100,
                               scene.render.resolution_y * scene.render.resolution_percentage // 100],
                "exr": out_exr})
    rec["_passes"] = passes
    return rec


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


def _configure(scene, args) -> None:
    if args.resolution_percentage:
        scene.render.resolution_percentage = args.resolution_percentage
    if args.engine == "cycles":
        set_cycles_reference(scene, args.samples, not args.no_multiple, args.seed or 0)
    else:
        set_mpp(scene, args.samples, not args.no_multiple, args.seed)


def cmd_render(args) -> dict:
    frames = parse_frames(args.frames) if args.frames else None
    if frames is not None and args.frame is not None:
        raise SystemExit("use either --frame or --frames")
    bpy = _bpy()
    bpy.ops.wm.open_mainfile(filepath=os.path.abspath(args.file))
    scene = bpy.context.scene
    if frames is not None:
        return render_frames(scene, args, frames)
    if args.frame is not None:
        scene.frame_set(args.frame)
    _configure(scene, args)
    rec = render_current(scene, args.output)
    rec.pop("_passes")
    return rec


def render_frames(scene, args, frames) -> dict:
    """Render ``frames`` one after the other into ``frame_path(args.output, f)``; stops at a
    cancelled frame."""
    _configure(scene, args)
    records, warnings = [], []
    t0 = time.perf_counter()
    for f in frames:
        scene.frame_set(f)
        rec = render_current(scene, frame_path(args.output, f))
        rec.pop("_passes")
        rec["frame"] = f
        records.append(rec)
        warnings.extend(w for w in rec["warnings"] if w not in warnings)
        if rec["cancelled"]:
            break
    total = time.perf_counter() - t0
    return {"frames": records, "seconds_per_frame": total / max(1, len(records)),
            "total": total, "warnings": warnings,
            "cancelled": any(r["cancelled"] for r in records)}


def cmd_demo(args) -> dict:
    """Build the demo cloud, render it with MPP, then with Cycles at the reference settings
    (``cycles_samples`` spp, 0 to skip) and score ours against it (one Cycles run: the
    metrics of metrics.md without the noise correction, so the error includes Cycles' noise)."""
    _bpy()
    from .blender.demo import build_demo_scene
    from .metrics import compare

    stem = args.output[:-4] if args.output.endswith(".exr") else args.output
    scene = build_demo_scene(os.path.dirname(os.path.abspath(stem)))
    set_mpp(scene, args.samples, not args.no_multiple)
    rec = render_current(scene, stem + ".exr")
    ours = rec.pop("_passes")
    rec["image"] = image_stats(ours)
    spp = int(getattr(args, "cycles_samples", 32) or 0)
    if spp > 0:
        set_cycles_reference(scene, spp, not args.no_multiple, seed=1)
        ref = render_current(scene, stem + "_cycles.exr")
        m = compare(ours["Combined"], [ref.pop("_passes")["Combined"]])
        rec["cycles"] = {"samples": spp, "seconds": ref["render"], "exr": ref["exr"],
                         "rel_rmse": m["rel_rmse"], "rel_rmse_4": m["rel_rmse_4"], "bias": m["bias"]}
        set_mpp(scene, args.samples, not args.no_multiple)
    return rec


def cmd_compare(args) -> dict:
    from .metrics import compare_files

    return compare_files(args.candidate, args.scene_dir, single=args.single)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m mpp_render", description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render one frame of a .blend file")
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

    c = sub.add_parser("compare", help="score an EXR against a scene's Cycles references")
    c.add_argument("candidate", help="EXR with a Combined pass")
    c.add_argument("scene_dir", help="folder holding ref_s*.exr / ss_s*.exr")
    c.add_argument("--single", action="store_true", help="score against ss_s*.exr")
    c.set_defaults(func=cmd_compare)

    d = sub.add_parser("demo", help="render the built-in demo cloud")
    d.add_argument("-o", "--output", default=os.path.join("out", "demo"),
                   help="output stem: writes STEM.exr and STEM.png (default out/demo)")
    d.add_argument("--samples", type=int, help="samples per pixel (default 16)")
    d.add_argument("--no-multiple", action="store_true", help="single scattering only")
    d.set_defaults(func=cmd_demo)

    from .package import cmd_package  # stdlib only: cheap to import here

    k = sub.add_parser("package", help="build the installable extension zip (kernels as a wheel)")
    k.add_argument("--output-dir", default="dist", help="folder for the zip (default dist)")
    k.add_argument("--source-dir", help="extension source (default: this checkout's root)")
    k.set_defaults(func=cmd_package)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    rec = args.func(args)
    sys.stdout.flush()
    print(json.dumps(rec), flush=True)
    if rec.get("failed") or rec.get("cancelled"):
        return 1
    return 0
