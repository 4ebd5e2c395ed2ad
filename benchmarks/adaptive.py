"""Adaptive sampling at production size: the default Noise Threshold against every pixel
taking all its samples, side by side in one run.

    .venv/bin/python benchmarks/adaptive.py [--scenes a,b] [--size 1920x1080] [--out docs]

Each scene is translated at ``--size`` with its own settings (the defaults an artist gets:
16 samples, Noise Threshold 0.01); its precompute runs once (timed) and is then shared
through the cache, so the two renders differ only in the march: ``noise_threshold`` 0.01
(adaptive) and 0 (all 16 samples), which goes first alternating from scene to scene.
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


def measure(name, w, h, adaptive_first):
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
           "first_render_s": time.perf_counter() - t,
           "precompute_s": first.timings.get("precompute", 0.0)}
    images = {}
    for th in ((default, 0.0) if adaptive_first else (0.0, default)):
        d = dataclasses.replace(desc, settings=dataclasses.replace(desc.settings,
                                                                   noise_threshold=th))
        out = render(d)
        key = "adaptive" if th > 0 else "all"
        row.setdefault(f"{key}_march_s", []).append(out.timings["march"])
        row[f"{key}_spp"] = out.stats["pixel_samples"]
        images[key] = out.passes["Combined"][..., :3]
    m = metrics.compare(images["adaptive"], [images["all"]])
    row["adaptive_vs_all_rel_rmse_4"] = m["rel_rmse_4"]
    row["adaptive_vs_all_bias"] = m["bias"]
    for key in ("adaptive", "all"):
        row[f"{key}_march_s"] = row[f"{key}_march_s"][0]
    row["speedup"] = row["all_march_s"] / row["adaptive_march_s"]
    print(json.dumps(row), flush=True)
    return row


def write_md(rows, path):
    w, h = rows[0]["size"]
    lines = ["# Adaptive sampling at production size", "",
             f"`benchmarks/adaptive.py`, {w} x {h}, each scene's own settings (16 samples at "
             f"most, Noise Threshold {rows[0]['threshold']}), {os.cpu_count()} cores; the two "
             "renders of a scene share one precompute and ran one after the other in one run "
             "(which first alternating). *Difference*: rel_rmse_4 of the adaptive image against the "
             "all-samples image, the noise adaptive sampling leaves in.", "",
             "| scene | precompute (s) | march, all 16 samples (s) | march, adaptive (s) | "
             "speedup | samples per pixel | difference |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['precompute_s']:.1f} | {r['all_march_s']:.1f} | "
                     f"{r['adaptive_march_s']:.1f} | {r['speedup']:.1f}x | "
                     f"{r['adaptive_spp']:.1f} | {r['adaptive_vs_all_rel_rmse_4']:.4f} |")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default=DEFAULT_SCENES)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--out", default=os.path.join(REPO, "docs"))
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))
    rows = [measure(n, w, h, i % 2 == 1) for i, n in enumerate(args.scenes.split(","))]
    with open(os.path.join(args.out, "adaptive.json"), "w") as f:
        json.dump(rows, f, indent=1)
    write_md(rows, os.path.join(args.out, "adaptive.md"))


if __name__ == "__main__":
    main()
