"""What volume materials cost: a shader node tree evaluated on a grid, and emission that
lights the scene.

    .venv/bin/python benchmarks/materials.py [--size 128] [--repeats 3] [--out docs]

1. A procedural cloud's density tree (Texture Coordinate (Object) -> Noise Texture (3D fBm,
   Detail 4) -> Color Ramp -> Math x 10, the suite's p_noise_cloud) evaluated at every voxel
   of a ``--size``^3 grid (textures.graph.evaluate_lattice, the core without Blender), and
   the same with Detail 2 and with a Voronoi Texture (F1) in place of the noise; seconds, best
   of ``--repeats``, and nanoseconds per voxel.
2. The glowing plume (the suite's p_glowing_smoke: its density grid drives its emission,
   over a ground, no lamp) rendered through the core at its own settings, the default
   multiple scattering on and off, as it is and with its emission grid set to zero (the
   glow then lights nothing and costs nothing): the precompute seconds of each, side by side
   in one run (alternating, best of ``--repeats``).

Writes ``OUT/materials.json`` and ``OUT/materials.md``.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)
os.environ["MPP_CACHE_MB"] = "0"      # every precompute timed cold
SCENES = os.environ.get("MPP_SCENES") or os.path.join(os.path.dirname(REPO), "shared", "scenes")


def cloud_tree(detail: float, texture: str):
    """The p_noise_cloud density tree (a Voronoi Texture in place of the noise with
    ``texture`` 'voronoi')."""
    from mpp_render.textures.graph import Graph, Link, Node
    tex = Node("ShaderNodeTexNoise", {"noise_dimensions": "3D", "noise_type": "FBM",
                                      "normalize": True},
               {"Vector": Link("coords", "Object"), "Scale": 1.5, "Detail": detail,
                "Roughness": 0.55}) if texture == "noise" else \
        Node("ShaderNodeTexVoronoi", {"voronoi_dimensions": "3D", "feature": "F1",
                                      "distance": "EUCLIDEAN"},
             {"Vector": Link("coords", "Object"), "Scale": 1.5})
    out = "Fac" if texture == "noise" else "Distance"
    g = Graph({"coords": Node("ShaderNodeTexCoord"), "tex": tex,
               "ramp": Node("ShaderNodeValToRGB", {"elements": ((0.5, (0, 0, 0, 1)),
                                                                (0.72, (1, 1, 1, 1))),
                                                   "interpolation": "LINEAR",
                                                   "color_mode": "RGB"},
                            {"Fac": Link("tex", out)}),
               "mul": Node("ShaderNodeMath", {"operation": "MULTIPLY"},
                           {"Value": Link("ramp", "Color"), "Value_001": 10.0})})
    return g, Link("mul", "Value")


def tree_seconds(size: int, repeats: int):
    from mpp_render.textures.graph import VALUE, evaluate_lattice
    i2w = np.eye(4)
    i2w[:3, :3] *= 3.6 / size
    i2w[:3, 3] = -1.8
    rows = []
    for label, detail, texture in (("Noise, Detail 4", 4.0, "noise"),
                                   ("Noise, Detail 2", 2.0, "noise"),
                                   ("Voronoi F1", 0.0, "voronoi")):
        g, out = cloud_tree(detail, texture)
        best = np.inf
        for _ in range(repeats):
            t = time.perf_counter()
            grid = evaluate_lattice(g, out, VALUE, (size,) * 3, i2w)
            best = min(best, time.perf_counter() - t)
        rows.append({"tree": label, "size": size, "seconds": best,
                     "ns_per_voxel": 1e9 * best / size ** 3,
                     "occupied": float(np.mean(grid > 0))})
        print(rows[-1], flush=True)
    return rows


def glow_seconds(repeats: int):
    from mpp_render.blender import batch
    from mpp_render.blender.properties import settings_from_scene
    from mpp_render.blender.translate import scene_from_depsgraph
    from mpp_render.render import render

    bpy = batch.register()
    bpy.ops.wm.open_mainfile(filepath=os.path.join(SCENES, "p_glowing_smoke", "scene.blend"))
    dg = bpy.context.evaluated_depsgraph_get()
    desc = scene_from_depsgraph(dg, settings_from_scene(dg.scene_eval))
    dark = dataclasses.replace(desc, media=[
        dataclasses.replace(m, emission_grid=None if m.emission_grid is None
                            else np.zeros_like(m.emission_grid),
                            emission=np.zeros(3)) for m in desc.media])
    rows = []
    for multiple in (True, False):
        best = {"glowing": np.inf, "dark": np.inf}
        for r in range(repeats):
            for key in (("glowing", "dark") if r % 2 == 0 else ("dark", "glowing")):
                d = desc if key == "glowing" else dark
                d = dataclasses.replace(d, settings=dataclasses.replace(d.settings,
                                                                        multiple=multiple))
                out = render(d)
                best[key] = min(best[key], out.timings.get("precompute", 0.0))
        rows.append({"multiple": multiple, "glowing_precompute_s": best["glowing"],
                     "dark_precompute_s": best["dark"],
                     "glow_adds_s": best["glowing"] - best["dark"],
                     "paths": desc.settings.multiple_paths})
        print(rows[-1], flush=True)
    return rows


def write(out_dir, trees, glow):
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, "materials.json"), "w") as f:
        json.dump({"trees": trees, "glow": glow}, f, indent=1)
    lines = ["# What volume materials cost", "",
             f"Generated by `benchmarks/materials.py` on {time.strftime('%Y-%m-%d')} "
             f"({os.cpu_count()} cores; a shared machine: read the seconds as rough).", "",
             "## A node tree evaluated on a grid", "",
             "The suite's procedural cloud density tree (Texture Coordinate -> texture -> "
             "Color Ramp -> Math), evaluated at every voxel by the numpy core "
             "(`textures.graph.evaluate_lattice`, one thread), best of the repeats. A mesh "
             "volume's grid is evaluated once and kept in the cache across frames while the "
             "tree does not change.", "",
             "| tree | grid | seconds | ns per voxel |", "|---|---|---|---|"]
    for r in trees:
        lines.append(f"| {r['tree']} | {r['size']}^3 | {r['seconds']:.2f} | "
                     f"{r['ns_per_voxel']:.0f} |")
    lines += ["", "## Emission that lights the scene", "",
              "p_glowing_smoke (its density grid drives its emission; a ground; no lamp) at "
              "its own settings, rendered as it is and with its emission set to zero, "
              "alternating, best of the repeats: the precompute seconds (the glow's light "
              "paths are traced there; the march reads them with the sky's light at no "
              "extra cost).", "",
              "| multiple scattering | glowing: precompute s | no emission: precompute s | "
              "the glow adds |", "|---|---|---|---|"]
    for r in glow:
        lines.append(f"| {'on' if r['multiple'] else 'off'} | {r['glowing_precompute_s']:.2f} | "
                     f"{r['dark_precompute_s']:.2f} | {r['glow_adds_s']:.2f} s |")
    with open(os.path.join(out_dir, "materials.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=os.path.join(REPO, "docs"))
    a = ap.parse_args()
    trees = tree_seconds(a.size, a.repeats)
    glow = glow_seconds(a.repeats)
    write(a.out, trees, glow)


if __name__ == "__main__":
    main()
