"""Speed levers, old against new, side by side in one run: an artist's F12 (the scene's own
settings) at a production size, alternating the two ways, and the error of each way at the
suite's resolution against the Cycles references.

    .venv/bin/python benchmarks/levers.py --lever casts|adapt|warp|halves [--scenes a,b] [--size 960x540]
                                          [--rounds 2] [--out docs]

Levers (each ``old`` is the code before the change, reproduced here):

* ``casts``: the surfaces' ray casts (surfaces.intersect: the gathers, shadow rays and
  bounces of every surface sample) in the compiled kernel (csrc/intersect.c) against its
  numpy twin (kernels_np.intersect_triangles), which held the GIL for most of its time; the
  same hits, so the same image (asserted);
* ``adapt``: the march's longer steps in thin media (``Tuning.adapt_tau``) also where a lamp
  with a radius or an area light is lit (its emitter sampled with jitter); ``old`` turns
  them off in such a scene, as the march did before;
* ``warp``: a surface's direct light from a rectangle light drawn in its solid angle warped
  towards the corners the surface faces (lights.cosine_warp); ``old`` draws it uniformly in
  the solid angle, without the surface's normal, as surfaces.shade did before;
* ``halves``: adaptive sampling reads a pixel's noise with the stratification's gain
  (pilot.stratified_gain, from the halves of its samples); ``old`` reads every sample as
  independent (the gain 1), as before.

Writes ``OUT/levers_<lever>.json`` and ``OUT/levers_<lever>.md``.
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import sys
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)
SCENES = os.environ.get("MPP_SCENES") or os.path.join(os.path.dirname(REPO), "shared", "scenes")
from guided_gathers import description  # noqa: E402  (a scene's description at a size)

DEFAULT_SCENES = {"casts": "p_fog_point,p_slab_over_ground,smoke_plume",
                  "adapt": "p_fog_point,p_fog_area,p_point_in_cube,p_area_in_box",
                  "warp": "p_fog_area",
                  "halves": "p_fog_point,p_fog_area,smoke_plume,p_slab_over_ground,cloud_vdb"}


@contextlib.contextmanager
def independent_samples():
    """Adaptive sampling as before: every sample read as independent (no gain)."""
    from mpp_render import pilot
    new = pilot.stratified_gain
    pilot.stratified_gain = lambda *a, **k: 1.0
    try:
        yield
    finally:
        pilot.stratified_gain = new


@contextlib.contextmanager
def uniform_solid_angle():
    """A surface's rectangle lights drawn as before: uniform in the solid angle (no normal)."""
    from mpp_render import lights
    new = lights.light_sample

    def plain(*args, normal=None, **kw):
        return new(*args, **kw)
    lights.light_sample = plain
    try:
        yield
    finally:
        lights.light_sample = new


@contextlib.contextmanager
def numpy_casts():
    """The surfaces' casts as they were: the numpy test (kernels_np.intersect_triangles)."""
    import functools
    from mpp_render import kernels
    new = kernels.intersect
    kernels.intersect = functools.partial(new, backend="numpy")
    try:
        yield
    finally:
        kernels.intersect = new


def jittered(desc) -> bool:
    return any(l.kind == "AREA" or (l.kind in ("POINT", "SPOT") and float(l.radius) > 0)
               for l in desc.lights)


def setup(lever, label, desc):
    """(description, context) of way ``label`` of ``lever``."""
    if lever == "casts":
        return desc, (numpy_casts() if label == "old" else contextlib.nullcontext())
    if lever == "warp":
        return desc, (uniform_solid_angle() if label == "old" else contextlib.nullcontext())
    if lever == "halves":
        return desc, (independent_samples() if label == "old" else contextlib.nullcontext())
    if label == "old" and jittered(desc):
        tun = dataclasses.replace(desc.settings.tuning, adapt_tau=0.0)
        desc = dataclasses.replace(desc, settings=dataclasses.replace(desc.settings, tuning=tun))
    return desc, contextlib.nullcontext()


def measure(lever, name, size, rounds, reverse):
    import numpy as np
    from mpp_render import cache, metrics
    from mpp_render.exr import read_passes
    from mpp_render.render import render
    refs = [read_passes(p, names=("Combined",))["Combined"][..., :3]
            for p in metrics.reference_paths(os.path.join(SCENES, name))]
    small, big = description(name), description(name, *size)
    row = {"scene": name, "size": list(size), "lever": lever}
    ways = ("new", "old") if reverse else ("old", "new")
    images = {}
    for label in ways:
        desc, ctx = setup(lever, label, small)
        cache.clear()
        with ctx:
            img = render(desc).passes["Combined"][..., :3]
        m = metrics.compare(img, refs)
        row.setdefault(label, {}).update(rel_rmse_4=m["rel_rmse_4"], bias=m["bias"])
        images[label] = img
    row["same_image"] = bool(np.array_equal(images["old"], images["new"]))
    for _ in range(rounds):
        for label in ways:
            desc, ctx = setup(lever, label, big)
            cache.clear()
            with ctx:
                t = time.perf_counter()
                out = render(desc)
                f12 = time.perf_counter() - t
            got = row[label]
            for key, v in (("f12_s", f12), ("precompute_s", out.timings["precompute"]),
                           ("march_s", out.timings["march"]),
                           ("spp", float(out.stats["pixel_samples"])),
                           ("march_msamples", float(out.stats["march_samples"]) / 1e6)):
                got.setdefault(key, []).append(v)
    print(json.dumps(row), flush=True)
    return row


def write_md(rows, path, lever, rounds):
    size = "x".join(str(v) for v in rows[0]["size"]) if rows else ""
    what = {"casts": "the surfaces' ray casts in numpy (old) and in the compiled kernel (new)",
            "adapt": "the march's longer steps in thin media off (old) and on (new) where a "
                     "lamp with a radius or an area light is lit",
            "warp": "a surface's rectangle lights drawn uniformly in their solid angle (old) "
                    "and warped towards the corners it faces (new)",
            "halves": "adaptive sampling reading each sample as independent (old) and with "
                      "the stratification's gain its halves show (new)"}[lever]
    lines = [f"# Lever: {lever}", "",
             f"`benchmarks/levers.py --lever {lever}`, one run, {what}, alternating, "
             f"{rounds} rounds, {os.cpu_count()} cores (a shared machine: read the seconds "
             f"as rough, the ratio of a round as the measure). F12: the scene's own settings "
             f"at {size}, the cache cleared before each render; seconds of the render (the "
             "precompute / the march), the samples per pixel adaptive sampling took, the "
             "march's samples. Error: the same settings at the suite's resolution, rel_rmse_4 "
             "(bias) against the Cycles references.", "",
             "| scene | error old | error new | same image | F12 old: s (pre / march) | "
             "F12 new: s (pre / march) | spp old / new | march M samples old / new | "
             "speedup |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        a, b = r["old"], r["new"]

        def runs(x, key):
            return ", ".join(f"{v:.1f}" for v in x[key])
        ratio = [p / q for p, q in zip(a["f12_s"], b["f12_s"])]
        lines.append(
            f"| {r['scene']} | {a['rel_rmse_4']:.4f} ({a['bias']:+.4f}) | "
            f"{b['rel_rmse_4']:.4f} ({b['bias']:+.4f}) | {'yes' if r['same_image'] else 'no'} | "
            f"{runs(a, 'f12_s')} ({a['precompute_s'][0]:.1f} / {a['march_s'][0]:.1f}) | "
            f"{runs(b, 'f12_s')} ({b['precompute_s'][0]:.1f} / {b['march_s'][0]:.1f}) | "
            f"{a['spp'][0]:.2f} / {b['spp'][0]:.2f} | "
            f"{a['march_msamples'][0]:.0f} / {b['march_msamples'][0]:.0f} | "
            + ", ".join(f"{x:.2f}x" for x in ratio) + " |")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lever", required=True, choices=sorted(DEFAULT_SCENES))
    ap.add_argument("--scenes", default=None)
    ap.add_argument("--size", default="960x540")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", default=os.path.join(REPO, "docs"))
    a = ap.parse_args()
    size = tuple(int(v) for v in a.size.split("x"))
    names = (a.scenes or DEFAULT_SCENES[a.lever]).split(",")
    rows = [measure(a.lever, n, size, a.rounds, i % 2 == 1) for i, n in enumerate(names)]
    os.makedirs(a.out, exist_ok=True)
    with open(os.path.join(a.out, f"levers_{a.lever}.json"), "w") as f:
        json.dump(rows, f, indent=1)
    write_md(rows, os.path.join(a.out, f"levers_{a.lever}.md"), a.lever, a.rounds)


if __name__ == "__main__":
    main()
