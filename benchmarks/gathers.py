"""What the surfaces' gathers read of the traced multiple scattering, side by side in one run:
the paths' moments read towards the surface (``Tuning.gather_moments``, the default) against
the camera's M (what the gathers read before), on the public scenes with surfaces.

    .venv/bin/python benchmarks/gathers.py [--scenes a,b] [--repeats 2] [--out docs]

Each scene is rendered at the suite's resolution with its own settings (the defaults an artist
gets) both ways, ``--repeats`` times each, the two alternating and their order reversed from
scene to scene, with no precompute cache (every render pays for its paths).  Reported: the
fastest precompute, march and render seconds of each way, and the error of the last render of
each against the scene's Cycles references (rel_rmse_4 and bias of
shared/reference/metrics.md).  Writes ``OUT/gathers.json`` and ``OUT/gathers.md``.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)
os.environ["MPP_CACHE_MB"] = "0"   # every render computes its own paths
SCENES = os.environ.get("MPP_SCENES") or os.path.join(os.path.dirname(REPO), "shared", "scenes")
DEFAULT_SCENES = ("p_slab_over_ground,p_fog_area,p_fog_point,p_fog_spot_shafts,"
                  "p_haze_sun_ground,smoke_plume")
WAYS = (("moments", True), ("camera M", False))


def measure(name, repeats, reverse):
    """One scene: ``repeats`` renders each way; the fastest stage times and the last image's
    error against the references."""
    from mpp_render import metrics
    from mpp_render.blender import batch
    from mpp_render.blender.properties import settings_from_scene
    from mpp_render.blender.translate import scene_from_depsgraph
    from mpp_render.exr import read_passes
    from mpp_render.render import render

    bpy = batch.register()
    scene_dir = os.path.join(SCENES, name)
    bpy.ops.wm.open_mainfile(filepath=os.path.join(scene_dir, "scene.blend"))
    dg = bpy.context.evaluated_depsgraph_get()
    desc = scene_from_depsgraph(dg, settings_from_scene(dg.scene_eval))
    refs = [read_passes(p, names=("Combined",))["Combined"][..., :3]
            for p in metrics.reference_paths(scene_dir)]
    row = {"scene": name, "size": [int(desc.camera.width), int(desc.camera.height)]}
    ways = WAYS[::-1] if reverse else WAYS
    for _ in range(repeats):
        for label, on in ways:
            d = dataclasses.replace(desc, settings=dataclasses.replace(
                desc.settings, tuning=dataclasses.replace(desc.settings.tuning,
                                                          gather_moments=on)))
            out = render(d)
            got = row.setdefault(label, {"precompute_s": 1e300, "march_s": 1e300,
                                         "render_s": 1e300})
            t = out.timings
            got["precompute_s"] = min(got["precompute_s"], t["precompute"])
            got["march_s"] = min(got["march_s"], t["march"])
            got["render_s"] = min(got["render_s"], t["precompute"] + t["march"])
            m = metrics.compare(out.passes["Combined"][..., :3], refs)
            got["rel_rmse_4"], got["bias"] = m["rel_rmse_4"], m["bias"]
    print(json.dumps(row), flush=True)
    return row


def write_md(rows, path):
    lines = ["# What the surfaces' gathers read", "",
             "`benchmarks/gathers.py`: each public scene with surfaces at the suite's "
             f"resolution and its own settings, {os.cpu_count()} cores, both ways in one run "
             "(the fastest of the repeats; the machine is shared, so read the seconds as "
             "rough). *Moments*: the traced paths' moments read towards the surface "
             "(docs/method.md §8, §9.9; the default). *Camera M*: the gathers read the light "
             "scattered towards the camera, as before. Error: rel_rmse_4 (bias) of the full "
             "render against the Cycles references.", "",
             "| scene | camera M: error | moments: error | camera M: precompute / march s "
             "| moments: precompute / march s |",
             "|---|---|---|---|---|"]
    for r in rows:
        a, b = r["camera M"], r["moments"]
        lines.append(f"| {r['scene']} | {a['rel_rmse_4']:.4f} ({a['bias']:+.4f}) | "
                     f"{b['rel_rmse_4']:.4f} ({b['bias']:+.4f}) | "
                     f"{a['precompute_s']:.2f} / {a['march_s']:.2f} | "
                     f"{b['precompute_s']:.2f} / {b['march_s']:.2f} |")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default=DEFAULT_SCENES)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", default=os.path.join(REPO, "docs"))
    a = ap.parse_args()
    rows = [measure(n, a.repeats, i % 2 == 1) for i, n in enumerate(a.scenes.split(","))]
    os.makedirs(a.out, exist_ok=True)
    with open(os.path.join(a.out, "gathers.json"), "w") as f:
        json.dump(rows, f, indent=1)
    write_md(rows, os.path.join(a.out, "gathers.md"))


if __name__ == "__main__":
    main()
