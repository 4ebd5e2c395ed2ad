"""Whether a ray that crosses a lamp's disc inside a medium loses light in Cycles.

    .venv/bin/python benchmarks/cycles_lamp_crossing.py [--samples 512] [--seeds 3]

Cycles lets rays pass through a lamp with a radius (a soft-falloff point light is a disc
facing the ray's origin, kernel/light/point.h) wherever the lamp can be hit: for camera rays
when it is visible to the camera, for every ray when its *Multiple Importance* is on.  Such
a ray is cut at the disc and its volume segment behind it is marched again; reading
Cycles' kernel (integrator/shade_light.h, integrator_shade_light_forward) the path's random
numbers are not advanced there, as they are after a transparent surface or a volume's
boundary, so the segment behind the disc draws its scattering distance from the same number
as the one in front, which is known not to have scattered there (a finding of reading the
source, not a confirmed bug report).  This measures what that does, in a 4 m cube of
density 1 /m, albedo 1, g 0, a bright point light B (200 W, no radius) at (1, 0.8, 0) and a
dark lamp A (1 mW, radius 0.4 m by default) at the centre in view (48 x 48 pixels):

* ``single``: Volume Bounces 0, A visible to the camera against A hidden from it (its
  Multiple Importance on in both): the pixels whose camera rays cross A's disc against the
  rest.  A emits next to nothing, so any change is B's light scattered behind A;
* ``double``: Volume Bounces 1, A's Multiple Importance on against off (hidden from the
  camera in both), ``--seeds`` seeds each: the whole image's mean.

What it showed (2026-12-01, 2 cores, ``--samples 512 --seeds 2``): single: the disc's 32
pixels 0.828x, the ring just outside it 0.9925x, the rest, where no ray crosses it, 1.0000x:
a dark disc where nothing is (A's own light is 1e-5 of B's there).  Double, 1024 spp
(radius 0.6 m): 0.06205 / 0.06243 with A's MIS on, 0.06254 / 0.06298 off, 0.8 % less with
it on.  So in Cycles a ray that crosses a
lamp's disc inside a medium loses part of the light scattered behind the disc: for camera
rays where the lamp is visible, and for every later ray when its Multiple Importance is on,
which is where Cycles' default renders multiply scattered light round a lamp in smoke darker
than Cycles itself with the lamp's MIS off (benchmarks/cycles_lamp_mis.py; docs/method.md
section 10).  Our renderer does not imitate it.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)


def scene(radius: float, mis: bool, visible: bool):
    """Build the test scene in an empty file (module docstring); returns the scene."""
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    w = bpy.data.worlds.new("World")
    sc.world = w
    w.color = (0.0, 0.0, 0.0)                  # a black world: only the lamps light it
    if w.node_tree is not None:
        for node in w.node_tree.nodes:
            if node.bl_idname == "ShaderNodeBackground":
                node.inputs["Strength"].default_value = 0.0
    bpy.ops.mesh.primitive_cube_add(size=4.0)
    mat = bpy.data.materials.new("fog")
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    pv = nt.nodes.new("ShaderNodeVolumePrincipled")
    pv.inputs["Density"].default_value = 1.0
    pv.inputs["Color"].default_value = (1, 1, 1, 1)
    nt.links.new(pv.outputs[0], out.inputs["Volume"])
    bpy.context.active_object.data.materials.append(mat)
    for name, loc, energy, size in (("B", (1.0, 0.8, 0.0), 200.0, 0.0),
                                    ("A", (0.0, 0.0, 0.0), 0.001, radius)):
        data = bpy.data.lights.new(name, "POINT")
        data.energy, data.shadow_soft_size = energy, size
        ob = bpy.data.objects.new(name, data)
        ob.location = loc
        sc.collection.objects.link(ob)
        if name == "A":
            data.cycles.use_multiple_importance_sampling = mis
            ob.visible_camera = visible
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    cam.location, cam.rotation_euler = (0, -8, 0), (math.pi / 2, 0, 0)
    sc.collection.objects.link(cam)
    sc.camera = cam
    sc.render.resolution_x = sc.render.resolution_y = 48
    sc.render.resolution_percentage = 100
    return sc


def render(sc, spp, seed, bounces, tmp) -> np.ndarray:
    from mpp_render.blender import batch
    batch.register()
    batch.set_cycles_reference(sc, spp, multiple=bounces > 0, seed=seed)
    sc.cycles.volume_bounces = bounces
    rec = batch.render_current(sc, os.path.join(tmp, f"c_{seed}_{bounces}.exr"))
    return rec["_passes"]["Combined"][..., :3].mean(axis=-1)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=512)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--radius", type=float, default=0.4)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        seen = render(scene(args.radius, True, True), args.samples, 5, 0, tmp)
        hidden = render(scene(args.radius, True, False), args.samples, 5, 0, tmp)
        n = seen.shape[0]
        y, x = np.mgrid[:n, :n]
        r = np.hypot(x - (n - 1) / 2, y - (n - 1) / 2)
        disc = args.radius / 8.0 * 50.0 / 36.0 * n   # the disc's radius in pixels (lens 50)
        print(f"single scattering, A visible over A hidden (disc radius {disc:.1f} px):")
        for lo, hi, what in ((0, disc, "across the disc"), (disc, disc + 2, "the ring beside it"),
                             (disc + 2, n, "elsewhere")):
            m = (r >= lo) & (r < hi)
            print(f"  {what}: {seen[m].mean() / hidden[m].mean():.4f} ({m.sum()} pixels)")
        for mis in (True, False):
            means = [float(render(scene(max(args.radius, 0.6), mis, False), 2 * args.samples,
                                  11 + s, 1, tmp).mean()) for s in range(args.seeds)]
            print(f"double scattering, A's MIS {'on' if mis else 'off'}: "
                  + " ".join(f"{v:.5f}" for v in means) + f"  mean {np.mean(means):.5f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
