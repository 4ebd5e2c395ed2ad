"""What Cycles renders where a mesh volume's face lies in a surface's plane (p_haze_sun_ground).

    .venv/bin/python benchmarks/cycles_coplanar.py [--samples 64] [--size 80x60]

p_haze_sun_ground's haze box (density 0.2, 4 x 4 x 2 m) stands on the ground: its bottom
face lies in the ground's plane.  This renders the scene with Cycles (single scattering:
Volume Bounces 0, Diffuse Bounces 0) in these variants, each printed as the mean of the
ground seen under the box (the image rows 40-55 of 60, columns 16-63 of 80; the red channel,
the green one under the green world):

* ``coplanar``: the scene as it is, the world black (the sun alone);
* ``gap``: the ground 2 mm lower;
* ``no_haze``: the box hidden;
* ``gap_shadow_x2``: the ground 2 mm lower and a copy of the box that only shadow rays see
  (the sun's light crossing the haze twice over);
* ``coplanar_green`` / ``gap_green``: the sun hidden, the world pure green of strength 1
  (the ground lit by the sky alone).

What it showed (2026-11-27, 64 spp, 80 x 60; means over the block): under the sun the
coplanar ground is 0.122, the gap's 0.188, without haze 0.280, and with the sun's light
crossing the haze twice 0.160: the coplanar ground is darker than a doubled shadow.  Under
the green sky it is *brighter* than the gap's (0.570 against 0.295; the green channel).  A
share of Cycles' camera rays that reach the ground there (about half in the box's middle
rows) pass through it and see the world below: with a black world the ground is dark, with
a bright one bright.  That is Cycles' coincident-face artefact, not light transport; our
renderer draws the ground of the gap variant (docs/method.md §10).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

SCENE = os.path.join(REPO, "..", "shared", "scenes", "p_haze_sun_ground", "scene.blend")
GAP = 0.002  # m the ground is lowered by in the gap variants


def render(variant: str, samples: int, size, out: str) -> np.ndarray:
    """Cycles' Combined (H, W, 3) of ``variant`` (see the module docstring)."""
    import bpy
    from mpp_render.blender import batch
    from mpp_render.exr import read_passes
    bpy.ops.wm.open_mainfile(filepath=SCENE)
    sc = bpy.context.scene
    batch.set_cycles_reference(sc, samples, multiple=True, seed=11)
    sc.cycles.volume_bounces = 0
    sc.cycles.diffuse_bounces = 0
    sc.render.resolution_x, sc.render.resolution_y = size
    sc.render.resolution_percentage = 100
    bg = sc.world.node_tree.nodes["Background"]
    if variant.endswith("green"):
        bg.inputs["Color"].default_value = (0.0, 1.0, 0.0, 1.0)
        bg.inputs["Strength"].default_value = 1.0
        sc.objects["sun"].hide_render = True
    else:
        bg.inputs["Strength"].default_value = 0.0
    if variant.startswith("gap"):
        sc.objects["Plane"].location.z -= GAP
    cube = sc.objects["Cube"]
    if variant == "no_haze":
        cube.hide_render = True
    if variant == "gap_shadow_x2":
        twin = cube.copy()
        twin.data = cube.data.copy()
        sc.collection.objects.link(twin)
        for flag in ("visible_camera", "visible_diffuse", "visible_glossy",
                     "visible_transmission", "visible_volume_scatter"):
            setattr(twin, flag, False)
    batch.set_multilayer_exr(sc)
    bpy.ops.render.render()
    bpy.data.images["Render Result"].save_render(filepath=out, scene=sc)
    return read_passes(out)["Combined"][..., :3]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--size", default="80x60")
    args = ap.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    h, w = size[1], size[0]
    rows, cols = slice(40 * h // 60, 56 * h // 60), slice(16 * w // 80, 64 * w // 80)
    with tempfile.TemporaryDirectory() as tmp:
        for variant in ("coplanar", "gap", "no_haze", "gap_shadow_x2", "coplanar_green",
                        "gap_green"):
            img = render(variant, args.samples, size, os.path.join(tmp, variant + ".exr"))
            block = img[rows, cols, 1 if variant.endswith("green") else 0]
            by_row = [round(float(v), 3) for v in block.reshape(4, -1, block.shape[1]).mean(axis=(1, 2))]
            print(f"{variant:16s} ground under the box: mean {block.mean():.3f}, by row band {by_row}",
                  flush=True)


if __name__ == "__main__":
    main()
