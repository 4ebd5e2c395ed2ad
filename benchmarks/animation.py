"""Seconds per frame of an animation, cold against reusing what did not change (cache.py).

    .venv/bin/python benchmarks/animation.py [--quick] [--frames N] [--no-blender] [--out docs]

Each frame is rendered twice, side by side in one run: *cold* (an empty cache that keeps
nothing) and *reused* (a cache kept from the previous frame), and the two images are checked
to be identical.  Cases of the numeric core (the synthetic cloud of performance.py, 96^3,
one sun, a sky, multiple scattering on, 160 x 120 at 1 spp):

* ``static``: nothing moves (a re-render, or a held shot): the whole precompute is reused;
* ``light``: the sun's power changes every frame: the world light is reused;
* ``camera_orbit``: the camera moves every frame: the world light (which depends on the
  camera position) is recomputed, and with multiple scattering on the light fields and
  pyramids too (the pyramids drift towards what the camera sees, precompute.drift_levels).

With Blender (bpy) also ``blender_static``: ``render.render()`` of a scene with a 128^3
voxelised mesh volume, cold (cache off) and reused (the voxelisation and the precompute
kept), translation included.  Writes ``OUT/animation.json`` and ``OUT/animation.md`` and
prints one JSON line per case: seconds per frame (median over frames 2..N) and the ratio.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from mpp_render import cache  # noqa: E402
from mpp_render.render import render  # noqa: E402
from performance import camera, scene  # noqa: E402


def orbit(desc, angle):
    """``desc`` with the camera turned by ``angle`` (rad) about the vertical axis through the
    cloud's centre."""
    c, s = np.cos(angle), np.sin(angle)
    rz = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    desc.camera.cam_to_world = rz @ desc.camera.cam_to_world
    return desc


def frame_scene(case, f, n, w, h):
    desc = scene(n=n, w=w, h=h)
    if case == "light":
        desc.lights[0].strength = np.full(3, 4.0 + 0.5 * f)
    elif case == "camera_orbit":
        orbit(desc, 0.05 * f)
    return desc


def timed(desc, store):
    cache.CACHE = store
    t = time.perf_counter()
    out = render(desc)
    return time.perf_counter() - t, out


def core_case(case, frames, n, w, h):
    cold_store, warm_store = cache.Cache(limit=0), cache.Cache(limit=4 << 30)
    rows = []
    for f in range(frames):
        t_cold, a = timed(frame_scene(case, f, n, w, h), cold_store)
        t_warm, b = timed(frame_scene(case, f, n, w, h), warm_store)
        same = all(np.array_equal(a.passes[k], b.passes[k]) for k in a.passes)
        rows.append({"frame": f + 1, "cold_s": t_cold, "reused_s": t_warm,
                     "reused": b.stats.get("reused", []), "identical": same,
                     "cold_precompute_s": a.timings["precompute"],
                     "reused_precompute_s": b.timings["precompute"]})
    return summary(case, rows)


def summary(case, rows):
    later = rows[1:] or rows
    cold = statistics.median(r["cold_s"] for r in later)
    warm = statistics.median(r["reused_s"] for r in later)
    return {"case": case, "frames": len(rows), "cold_s_per_frame": round(cold, 3),
            "reused_s_per_frame": round(warm, 3), "speedup": round(cold / warm, 2),
            "reused": later[-1]["reused"], "identical": all(r["identical"] for r in rows),
            "rows": rows}


def blender_case(frames, resolution):
    """render.render() of a 128^3 voxelised cube volume, cache off against on."""
    import bpy

    from mpp_render.blender import engine, frame, properties
    properties.register()
    engine.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.world = bpy.data.worlds.new("World")
    sc.world.color = (0.05, 0.05, 0.06)
    me = bpy.data.meshes.new("Cloud")
    v = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    me.from_pydata(v, [], [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4),
                           (1, 5, 7, 3)])
    mat = bpy.data.materials.new("Vol")
    nt = mat.node_tree
    nt.nodes.clear()
    pv = nt.nodes.new("ShaderNodeVolumePrincipled")
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(pv.outputs["Volume"], out.inputs["Volume"])
    me.materials.append(mat)
    sc.collection.objects.link(bpy.data.objects.new("Cloud", me))
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.rotation_euler = (0.5, 0.3, 0.0)
    sc.collection.objects.link(sun)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.location, cam.rotation_euler = (0.0, -8.0, 0.0), (np.pi / 2, 0.0, 0.0)
    sc.collection.objects.link(cam)
    sc.camera = cam
    sc.render.engine = "MPP_RENDER"
    sc.render.resolution_x, sc.render.resolution_y, sc.render.resolution_percentage = 160, 120, 100
    sc.mpp.samples = 1
    sc.mpp.voxel_resolution = resolution
    cold_store, warm_store = cache.Cache(limit=0), cache.Cache(limit=4 << 30)
    rows = []
    for f in range(frames):
        times, outs = [], []
        for store in (cold_store, warm_store):
            cache.CACHE = store
            t = time.perf_counter()
            last = frame.render_mpp()
            times.append(time.perf_counter() - t)
            outs.append(last)
        same = all(np.array_equal(outs[0].output.passes[k], outs[1].output.passes[k])
                   for k in outs[0].output.passes)
        rows.append({"frame": f + 1, "cold_s": times[0], "reused_s": times[1],
                     "reused": outs[1].output.stats.get("reused", []), "identical": same,
                     "cold_translate_s": outs[0].translate_s,
                     "reused_translate_s": outs[1].translate_s})
    return summary(f"blender_static_{resolution}^3", rows)


def write_docs(res, out_dir):
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, "animation.json"), "w") as f:
        json.dump(res, f, indent=1)
    lines = ["# Animation: seconds per frame, cold against reused", "",
             "Generated by `benchmarks/animation.py` (cold and reused renders of each frame side "
             f"by side in one run; {res['machine']['cores']} cores, kernels "
             f"{res['machine']['backend']}).  Median over frames 2..N; *identical*: the cold and "
             "the reused image of every frame are bit-identical.", "",
             "| case | frames | cold s/frame | reused s/frame | speed-up | reused parts | identical |",
             "|---|---|---|---|---|---|---|"]
    for c in res["cases"]:
        lines.append(f"| {c['case']} | {c['frames']} | {c['cold_s_per_frame']:.3f} | "
                     f"{c['reused_s_per_frame']:.3f} | {c['speedup']:.2f}x | "
                     f"{', '.join(c['reused']) or 'none'} | {'yes' if c['identical'] else 'NO'} |")
    with open(os.path.join(out_dir, "animation.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (a smoke test)")
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--no-blender", action="store_true", help="skip the bpy case")
    ap.add_argument("--out", default=os.path.join(REPO, "docs"))
    args = ap.parse_args(argv)
    from mpp_render import kernels
    n, w, h = (32, 40, 30) if args.quick else (96, 160, 120)
    res = {"machine": {"cores": os.cpu_count() or 1, "backend": kernels.backend()}, "cases": []}
    for case in ("static", "light", "camera_orbit"):
        rec = core_case(case, args.frames, n, w, h)
        res["cases"].append(rec)
        print(json.dumps({k: v for k, v in rec.items() if k != "rows"}), flush=True)
    if not args.no_blender:
        try:
            import bpy  # noqa: F401
        except ImportError:
            bpy = None
        if bpy is not None:
            rec = blender_case(args.frames, 32 if args.quick else 128)
            res["cases"].append(rec)
            print(json.dumps({k: v for k, v in rec.items() if k != "rows"}), flush=True)
    write_docs(res, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
