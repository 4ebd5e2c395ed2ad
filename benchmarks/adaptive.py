"""Adaptive sampling at production size: the default Noise Threshold, at one or more
first-round sizes, against every pixel taking all its samples, side by side in one run.

    .venv/bin/python benchmarks/adaptive.py [--scenes a,b] [--size 1920x1080] [--first 4,2]
                                            [--out docs]

Each scene is translated at ``--size`` with its own settings (the defaults an artist gets:
16 samples, the default Noise Threshold); its precompute runs once (timed) and is then shared
through the cache, so the renders differ only in the march: ``noise_threshold`` 0 (all 16
samples) and the default (adaptive) once per first-round size of ``--first`` (``Tuning.adaptive_first``:
the samples every pixel takes before its noise is judged), their order reversed from scene to
scene.
Reported: the march seconds of each, the mean samples per pixel the adaptive render took,
and how far its image is from the all-samples one (rel_rmse_4 of shared/reference/metrics.md,
the all-samples image as the reference: the noise adaptive sampling leaves).  Writes ``OUT/adaptive.json`` and
``OUT/adaptive.md``.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)
os.environ["MPP_CACHE_MB"] = "4096"   # the precompute is computed once and shared
SCENES = os.environ.get("MPP_SCENES") or os.path.join(os.path.dirname(REPO), "shared", "scenes")
DEFAULT_SCENES = "cloud_vdb,smoke_plume,slab_forward"   # p_fog_spot_shafts: over 20 min at 1080p


def measure(name, w, h, firsts, reverse):
    """One scene: its precompute once, then the all-samples render and one adaptive render
    per first-round size in ``firsts`` (in reverse order when ``reverse``)."""
    from mpp_render import metrics
    from mpp_render.blender import batch
    from mpp_render.blender.properties import settings_from_scene
    from mpp_render.blender.translate import scene_from_depsgraph
    from mpp_render.render import render

    bpy = batch.register()
    bpy.ops.wm.open_mainfile(filepath=os.path.join(SCENES, name, "scene.blend"))
    dg = bpy.context.evaluated_depsgraph_get()
    desc = scene_from_depsgraph(dg, settings_from_scene(dg.scene_eval), width=w, height=h)
    default = desc.settings.noise_threshold
    t = time.perf_counter()
    first = render(desc)
    row = {"scene": name, "size": [w, h], "threshold": default,
           "default_first": desc.settings.tuning.adaptive_first,
           "first_render_s": time.perf_counter() - t,
           "precompute_s": first.timings.get("precompute", 0.0), "adaptive": []}
    runs = [(0.0, None)] + [(default, f) for f in firsts]
    images = {}
    for th, f in (runs[::-1] if reverse else runs):
        tuning = desc.settings.tuning if f is None else \
            dataclasses.replace(desc.settings.tuning, adaptive_first=f)
        d = dataclasses.replace(desc, settings=dataclasses.replace(
            desc.settings, noise_threshold=th, tuning=tuning))
        out = render(d)
        images[f] = out.passes["Combined"][..., :3]
        if f is None:
            row["all_march_s"] = out.timings["march"]
        else:
            row["adaptive"].append({"first": f, "march_s": out.timings["march"],
                                    "spp": out.stats["pixel_samples"]})
    for a in row["adaptive"]:
        m = metrics.compare(images[a["first"]], [images[None]])
        a["vs_all_rel_rmse_4"], a["vs_all_bias"] = m["rel_rmse_4"], m["bias"]
        a["speedup"] = row["all_march_s"] / a["march_s"]
    print(json.dumps(row), flush=True)
    return row


def write_md(rows, path):
    w, h = rows[0]["size"]
    lines = ["# Adaptive sampling at production size", "",
             f"`benchmarks/adaptive.py`, {w} x {h}, each scene's own settings (16 samples at "
             f"most, Noise Threshold {rows[0]['threshold']}), {os.cpu_count()} cores; the "
             "renders of a scene share one precompute and ran one after the other in one run "
             "(their order reversed from scene to scene). *First*: the samples every pixel "
             "takes before its noise is judged (Tuning.adaptive_first; the default is "
             f"{rows[0]['default_first']}). *Difference*: rel_rmse_4 of the adaptive image against "
             "the all-samples image, the noise adaptive sampling leaves in.", "",
             "| scene | precompute (s) | march, all 16 samples (s) | first | march, adaptive (s) "
             "| speedup | samples per pixel | difference |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        for a in r["adaptive"]:
            lines.append(f"| {r['scene']} | {r['precompute_s']:.1f} | {r['all_march_s']:.1f} | "
                         f"{a['first']} | {a['march_s']:.1f} | {a['speedup']:.1f}x | "
                         f"{a['spp']:.2f} | {a['vs_all_rel_rmse_4']:.4f} |")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default=DEFAULT_SCENES)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--first", default="4,2",
                    help="first-round sizes to compare (comma-separated)")
    ap.add_argument("--out", default=os.path.join(REPO, "docs"))
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))
    firsts = [int(v) for v in args.first.split(",")]
    rows = [measure(n, w, h, firsts, i % 2 == 1) for i, n in enumerate(args.scenes.split(","))]
    with open(os.path.join(args.out, "adaptive.json"), "w") as f:
        json.dump(rows, f, indent=1)
    write_md(rows, os.path.join(args.out, "adaptive.md"))


if __name__ == "__main__":
    main()
