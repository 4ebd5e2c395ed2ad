"""The Rendered viewport's timings, driven without a window through the same code as Blender's
``view_update`` / ``view_draw`` (mpp_render/blender/viewport.py).

    .venv/bin/python benchmarks/viewport.py [--scene cloud_vdb] [--size 960x540] [--out docs]

A viewport of ``--size`` looks through the scene's camera (the view and window matrices
Blender gives a viewport in camera view, translate/view.py) at the engine's defaults (Final
quality, 16 viewport samples).  In one run, one after another as an artist would:

* ``open``: the first picture of a scene nothing was computed for (cold cache), then every
  stage to the last;
* ``unchanged precompute``: a change that needs no new precompute (the viewport samples
  changed: the scene is translated again, its precompute taken from the cache);
* ``orbit``: the view turned by 10 degrees about the scene's centre (``ViewSession.look``):
  the coarse picture takes the earlier position's precompute, the refined one computes its own;
* ``moved light``: the first light moved by 0.3 m (a point, spot or area light) or turned by
  5 degrees (a sun), its depsgraph updates read by ``changed_parts`` as Blender sends them:
  the lights alone are translated again, the world light is reused.

Each time is wall seconds from the change (translation included) to the picture.  Writes
``OUT/viewport.json``, ``OUT/viewport.md`` and ``OUT/images/viewport_progression.png`` (the
open case's stages: coarse, 1, 4, 16 samples).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
SCENES = os.environ.get("MPP_SCENES") or os.path.join(os.path.dirname(REPO), "shared", "scenes")

from accuracy import tone, write_png  # noqa: E402

os.environ["MPP_CACHE_MB"] = "2048"   # the viewport lives on the cache (accuracy.py turns it off)


def view_camera(bpy, cam, w, h):
    from mpp_render.blender.translate.view import camera_from_matrices
    dg = bpy.context.evaluated_depsgraph_get()
    window = cam.calc_matrix_camera(dg, x=w, y=h)
    return camera_from_matrices(cam.matrix_world.inverted(), window, w, h)


def timed_stages(session, gen, t0, stages):
    """Wall seconds from ``t0`` to each of ``stages`` of generation ``gen``, and the pictures."""
    times, images = [], []
    for k in stages:
        img = session.progressive.wait(gen, stage=k, timeout=600)
        if img is None:
            raise RuntimeError(f"stage {k} never came: {session.progressive.errors}")
        times.append(time.perf_counter() - t0)
        images.append(img)
    return times, images


def orbit(bpy, cam, degrees, centre):
    from mathutils import Matrix
    rot = Matrix.Rotation(math.radians(degrees), 4, "Z")
    to = Matrix.Translation(centre)
    cam.matrix_world = to @ rot @ to.inverted() @ cam.matrix_world
    bpy.context.view_layer.update()


def move_light(light):
    if light.data.type == "SUN":
        light.rotation_euler.x += math.radians(5.0)
    else:
        light.location.x += 0.3


def progression_png(images, path, w, h):
    """The stages side by side, 2 x 2, each at half the viewport's size."""
    scale = float(np.percentile(images[-1].rgba[..., :3], 99.5)) or 1.0
    tiles = []
    for img in images:
        a = img.rgba[..., :3]
        k = max(1, (h // 2) // a.shape[0])
        a = np.repeat(np.repeat(a, k, 0), k, 1)                    # coarse: nearest up
        f = a.shape[0] // (h // 2)
        if f > 1:                                                  # full: box down
            a = a[:f * (h // 2), :f * (w // 2)].reshape(h // 2, f, w // 2, f, 3).mean((1, 3))
        tiles.append(tone(a[:h // 2, :w // 2], scale))
    while len(tiles) < 4:
        tiles.append(np.zeros_like(tiles[0]))
    grid = np.concatenate([np.concatenate(tiles[:2], 1), np.concatenate(tiles[2:4], 1)], 0)
    write_png(path, grid, zoom=1)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="cloud_vdb")
    ap.add_argument("--size", default="960x540")
    ap.add_argument("--out", default=os.path.join(REPO, "docs"))
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))

    from mpp_render.blender import batch, viewport
    from mpp_render.viewport import stages
    bpy = batch.register()
    bpy.ops.wm.open_mainfile(filepath=os.path.join(SCENES, args.scene, "scene.blend"))
    sc = bpy.context.scene
    cam = sc.camera
    light = next(o for o in sc.objects if o.type == "LIGHT")
    dg = bpy.context.evaluated_depsgraph_get()
    session = viewport.ViewSession()
    rows = {}
    try:
        t0 = time.perf_counter()
        session.update(dg, {"all"}, view_camera(bpy, cam, w, h))
        n_stages = len(stages(sc.mpp.viewport_samples))
        times, images = timed_stages(session, 1, t0, range(n_stages))
        rows["open"] = {"stages_s": times, "sizes": [list(i.rgba.shape[1::-1]) for i in images],
                        "precompute_s": [i.timings.get("precompute") for i in images]}
        os.makedirs(os.path.join(args.out, "images"), exist_ok=True)
        progression_png(images, os.path.join(args.out, "images", "viewport_progression.png"),
                        w, h)
        gen = 1

        def case(name, start):
            nonlocal gen
            t0 = time.perf_counter()
            start()
            gen += 1
            times, images = timed_stages(session, gen, t0, (0, 1))
            rows[name] = {"stages_s": times[:2],
                          "precompute_s": [i.timings.get("precompute") for i in images],
                          "reused": [i.stats.get("reused") for i in images],
                          "stale_camera": bool(images[0].stats.get("stale_camera"))}
            print(json.dumps({name: rows[name]}))

        def samples_changed():
            sc.mpp.viewport_samples = 8
            session.update(dg, {"all"}, view_camera(bpy, cam, w, h))

        case("unchanged precompute", samples_changed)
        centre = sum((o.matrix_world.translation for o in sc.objects
                      if o.type in ("MESH", "VOLUME")), start=cam.location * 0) / max(
            1, sum(o.type in ("MESH", "VOLUME") for o in sc.objects))
        orbit(bpy, cam, 10.0, centre)
        case("orbit", lambda: session.look(view_camera(bpy, cam, w, h)))

        def light_moved():
            parts = viewport.parts_changed_by(lambda: move_light(light))
            rows["moved light parts"] = sorted(parts)
            session.update(dg, parts, view_camera(bpy, cam, w, h))

        case("moved light", light_moved)
    finally:
        session.close()
    report = {"scene": args.scene, "size": [w, h], "threads": os.cpu_count(), "cases": rows}
    with open(os.path.join(args.out, "viewport.json"), "w") as f:
        json.dump(report, f, indent=1)
    write_md(report, os.path.join(args.out, "viewport.md"))
    print(json.dumps(report))


def write_md(report, path):
    w, h = report["size"]
    c = report["cases"]
    lines = [
        "# The Rendered viewport: seconds to each picture",
        "",
        f"`benchmarks/viewport.py`: {report['scene']} in a {w} x {h} viewport looking through "
        f"its camera, on {report['threads']} cores, at the defaults (Final quality, 16 "
        "viewport samples), driven without a window through the code of `view_update` / "
        "`view_draw` (`mpp_render/blender/viewport.py`). Wall seconds from the change, "
        "translation included.",
        "",
        "| change | coarse picture (s) | full resolution, 1 sample (s) | precompute of each (s) |",
        "|---|---|---|---|",
    ]
    for name in ("open", "unchanged precompute", "orbit", "moved light"):
        r = c[name]
        pre = ", ".join(f"{p:.2f}" if p is not None else "-" for p in r["precompute_s"][:2])
        lines.append(f"| {name} | {r['stages_s'][0]:.2f} | {r['stages_s'][1]:.2f} | {pre} |")
    lines += [
        "",
        "The open case's later stages: " + ", ".join(
            f"{s[0]}x{s[1]} at {t:.1f} s" for s, t in zip(c["open"]["sizes"],
                                                         c["open"]["stages_s"])) + ".",
        f"A moved light's depsgraph updates named: {', '.join(c.get('moved light parts', []))}.",
        "",
        "![the progression](images/viewport_progression.png)",
        "",
        "Coarse (a quarter of the resolution, 1 sample, a sixteenth of the light paths and half the lattice points a side), "
        "then the full resolution at 1 sample (the same paths), 4 and 16 samples (the scene's "
        "million paths per light).",
    ]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
