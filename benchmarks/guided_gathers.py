"""The surfaces' gathers drawn about the lamps inside the media (``Tuning.guided_gathers``,
gathers.py) against cosine-weighted gathers alone, side by side in one run.

    .venv/bin/python benchmarks/guided_gathers.py [--scenes a,b] [--seeds 4] [--size 480x270]
                                                  [--out docs]

For each scene (by default the public scenes with a surface and a lamp inside a medium),
both ways, alternating:

* the per-sample noise: ``--seeds`` renders at the suite's resolution with one sample in
  every pixel (Noise Threshold 0) and the seeds 0, 1, ...; the root mean square over the
  pixels of the seeds' standard deviation of Combined (mean of RGB), over the frame's mean;
* the error: the scene's own settings (an artist's F12: adaptive sampling) at the suite's
  resolution, rel_rmse_4 and bias of shared/reference/metrics.md against its references;
* the cost: the same F12 at ``--size`` (seconds of the precompute and the march, the
  samples per pixel that adaptive sampling took).

Writes ``OUT/guided_gathers.json`` and ``OUT/guided_gathers.md``.
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
SCENES = os.environ.get("MPP_SCENES") or os.path.join(os.path.dirname(REPO), "shared", "scenes")
DEFAULT_SCENES = "p_fog_point,p_fog_area,p_fog_spot_shafts"
WAYS = (("guided", 0.5), ("cosine", 0.0))


def description(name, width=None, height=None):
    from mpp_render.blender import batch
    from mpp_render.blender.properties import settings_from_scene
    from mpp_render.blender.translate import scene_from_depsgraph
    bpy = batch.register()
    bpy.ops.wm.open_mainfile(filepath=os.path.join(SCENES, name, "scene.blend"))
    sc = bpy.context.scene
    if width:
        sc.render.resolution_x, sc.render.resolution_y = width, height
        sc.render.resolution_percentage = 100
    dg = bpy.context.evaluated_depsgraph_get()
    return scene_from_depsgraph(dg, settings_from_scene(dg.scene_eval))


def way(desc, guided, **settings):
    tun = dataclasses.replace(desc.settings.tuning, guided_gathers=guided)
    return dataclasses.replace(desc, settings=dataclasses.replace(desc.settings, tuning=tun,
                                                                  **settings))


def measure(name, seeds, size, reverse):
    import numpy as np
    from mpp_render import metrics
    from mpp_render.exr import read_passes
    from mpp_render.render import render
    refs = [read_passes(p, names=("Combined",))["Combined"][..., :3]
            for p in metrics.reference_paths(os.path.join(SCENES, name))]
    desc = description(name)
    big = description(name, *size)
    row = {"scene": name, "size": list(size)}
    ways = WAYS[::-1] if reverse else WAYS
    for label, guided in ways:
        got = row.setdefault(label, {})
        frames = [render(way(desc, guided, samples=1, noise_threshold=0.0, seed=s))
                  .passes["Combined"][..., :3].mean(axis=2) for s in range(seeds)]
        a = np.stack(frames)
        got["noise"] = float(np.sqrt((a.std(axis=0, ddof=1) ** 2).mean()) / a.mean())
        m = metrics.compare(render(way(desc, guided)).passes["Combined"][..., :3], refs)
        got["rel_rmse_4"], got["bias"] = m["rel_rmse_4"], m["bias"]
    for label, guided in ways:
        t = time.perf_counter()
        out = render(way(big, guided))
        got = row[label]
        got["f12_s"] = time.perf_counter() - t
        got["precompute_s"], got["march_s"] = out.timings["precompute"], out.timings["march"]
        got["spp"] = float(out.stats["pixel_samples"])
    print(json.dumps(row), flush=True)
    return row


def write_md(rows, path, seeds):
    size = "x".join(str(v) for v in rows[0]["size"]) if rows else ""
    lines = ["# Gathers drawn about the lamps", "",
             "`benchmarks/guided_gathers.py`, one run, both ways alternating, "
             f"{os.cpu_count()} cores (the machine is shared: read the seconds as rough). "
             "*Guided*: half of a surface's 4 gathers drawn about the lamps inside the media, "
             "weighed by the balance heuristic (docs/method.md §8; the default). *Cosine*: "
             "all 4 cosine-weighted. Noise: one sample per pixel at the suite's resolution, "
             f"{seeds} seeds, the root mean square of the pixels' standard deviation over the "
             "frame's mean. Error: the scene's own settings (adaptive sampling) at the suite's "
             "resolution, rel_rmse_4 (bias) against the Cycles references. F12: the same "
             f"settings at {size}, seconds (precompute / march) and the samples per pixel "
             "adaptive sampling took.", "",
             "| scene | noise: cosine / guided | error: cosine | error: guided "
             "| F12 cosine: s (pre / march), spp | F12 guided: s (pre / march), spp | speedup |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        a, b = r["cosine"], r["guided"]
        lines.append(
            f"| {r['scene']} | {a['noise']:.4f} / {b['noise']:.4f} | "
            f"{a['rel_rmse_4']:.4f} ({a['bias']:+.4f}) | {b['rel_rmse_4']:.4f} ({b['bias']:+.4f}) | "
            f"{a['f12_s']:.1f} ({a['precompute_s']:.1f} / {a['march_s']:.1f}), {a['spp']:.2f} | "
            f"{b['f12_s']:.1f} ({b['precompute_s']:.1f} / {b['march_s']:.1f}), {b['spp']:.2f} | "
            f"{a['f12_s'] / b['f12_s']:.2f}x |")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default=DEFAULT_SCENES)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--size", default="480x270")
    ap.add_argument("--out", default=os.path.join(REPO, "docs"))
    a = ap.parse_args()
    size = tuple(int(v) for v in a.size.split("x"))
    rows = [measure(n, a.seeds, size, i % 2 == 1) for i, n in enumerate(a.scenes.split(","))]
    os.makedirs(a.out, exist_ok=True)
    with open(os.path.join(a.out, "guided_gathers.json"), "w") as f:
        json.dump(rows, f, indent=1)
    write_md(rows, os.path.join(a.out, "guided_gathers.md"), a.seeds)


if __name__ == "__main__":
    main()
