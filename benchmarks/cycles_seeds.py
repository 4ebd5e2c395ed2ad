"""More Cycles seeds for public scenes: is a reference pair as close to converged as its floor says?

    .venv/bin/python benchmarks/cycles_seeds.py --scenes a,b [--single] [--seeds 3,4,5,6]
        [--work DIR] [--out DIR] [--no-ours]
    .venv/bin/python benchmarks/cycles_seeds.py --rows A.json B.json [--out DIR]   # report only

A scene's references are two Cycles runs (seeds 1 and 2).  The metric
(shared/reference/metrics.md) subtracts their noise, estimated from how the two differ; with
two runs that estimate is one squared difference per pixel, unbiased but skewed: where a few
bright 4 x 4 blocks hold most of an image's squared error (a narrow beam, a lamp's
surroundings) it usually falls below the pair's real noise, and a render that matches
converged Cycles scores above the floor.  This renders more seeds of the scene with the
suite's own builder (``shared/scenes/build/suite.py``, whose seeds 1 and 2 reproduce the
shared runs bit for bit; the same samples per run) into ``--work`` (runs already there are
reused), and prints for each scene (rel_rmse_4 of metrics.md, the runs compared against
giving the floor that is subtracted):

* ``pair vs extra``: the pair's mean against the extra seeds; its own noise is not
  subtracted, so it is the pair's real noise (and any error of the pair beyond it), to be
  read beside ``pair floor_4``, what the pair's two runs say their noise is;
* ``extra halves``: the mean of the first two extra seeds against the rest, two runs that
  are independent by construction measured the same way: where ``pair vs extra`` is about
  this, the pair is an ordinary draw and only its floor's estimate is low;
* ``ours vs pair / extra / all``: our render with ``benchmarks/accuracy.py``'s settings
  against the pair, the extra seeds, and every run pooled (with ``--no-ours``, none).

Writes ``OUT/cycles_seeds.json`` (rows keyed by scene and render, merged with the file's
earlier rows) and ``OUT/cycles_seeds.md``.  The extra runs stay in ``--work``, never in the
repository or the shared suite: the suite's references are what the project is measured
against, and this report only says how far to trust them.
"""
from __future__ import annotations

import argparse
import glob
import importlib.util
import json
import os
import shutil
import sys
import tempfile
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

SCENES = os.environ.get("MPP_SCENES") or os.path.join(os.path.dirname(REPO), "shared", "scenes")
SEEDS = (3, 4, 5, 6)


def builder():
    """The suite's builder module (shared/scenes/build/suite.py)."""
    path = os.path.join(SCENES, "build", "suite.py")
    spec = importlib.util.spec_from_file_location("suite_builder", path)
    mod = importlib.util.module_from_spec(spec)
    sys.path.insert(0, os.path.dirname(path))
    spec.loader.exec_module(mod)
    return mod


def prefix(single: bool) -> str:
    return "ss" if single else "ref"


def spp_per_seed(name: str) -> int:
    """The samples per run of the scene's references (its meta.json)."""
    with open(os.path.join(SCENES, name, "meta.json")) as f:
        return int(json.load(f)["spp_per_seed"])


def extra_runs(name: str, seeds, single: bool, work: str) -> list:
    """Paths of the scene's runs at ``seeds`` in ``work``/name, rendering those not there
    (the suite's builder, at the samples per run of the scene's meta.json)."""
    src, dst = os.path.join(SCENES, name), os.path.join(work, name)
    os.makedirs(dst, exist_ok=True)
    for f in os.listdir(src):   # the .blend and what it reads (VDBs by relative path)
        if not f.endswith(".exr") and f != "meta.json" and not os.path.exists(os.path.join(dst, f)):
            shutil.copy2(os.path.join(src, f), os.path.join(dst, f))
    paths = [os.path.join(dst, f"{prefix(single)}_s{s}.exr") for s in seeds]
    missing = [s for s, p in zip(seeds, paths) if not os.path.exists(p)]
    if missing:
        suite = builder()
        spec = suite.all_scenes()[name]
        suite.render(work, name, spec, seeds=missing, spp=spp_per_seed(name), single=single)
    return paths


def read(paths) -> list:
    from mpp_render.exr import read_passes
    return [read_passes(p)["Combined"][..., :3] for p in paths]


def check(pair: list, extra: list, ours=None) -> dict:
    """The comparisons of the module docstring, from the pair's runs, the extra runs (at least
    two; "extra_halves" with four or more) and our image (or None): each {rel_rmse_4,
    floor_4, bias} of metrics.compare."""
    from mpp_render import metrics

    def cmp(x, refs):
        m = metrics.compare(x, refs)
        return {k: float(m[k]) for k in ("rel_rmse_4", "floor_4", "bias")}

    row = {"pair_floor_4": cmp(np.mean(pair, axis=0), pair)["floor_4"],
           "pair_vs_extra": cmp(np.mean(pair, axis=0), extra),
           "runs": [len(pair), len(extra)]}
    if len(extra) >= 4:   # two runs against at least two others (a floor needs two)
        row["extra_halves"] = cmp(np.mean(extra[:2], axis=0), extra[2:])
    if ours is not None:
        row["ours_vs_pair"] = cmp(ours, pair)
        row["ours_vs_extra"] = cmp(ours, extra)
        row["ours_vs_all"] = cmp(ours, list(pair) + list(extra))
    return row


def render_ours(name: str, single: bool, tmp: str):
    """Our Combined (H, W, 3) with benchmarks/accuracy.py's settings, and its seconds."""
    import bpy
    from mpp_render import metrics
    from mpp_render.blender import batch
    bpy.ops.wm.open_mainfile(filepath=os.path.join(SCENES, name, "scene.blend"))
    sc = bpy.context.scene
    spp = metrics.SINGLE_SCATTERING_SAMPLES.get(name, 16) if single else 16
    batch.set_mpp(sc, spp, multiple=not single)
    rec = batch.render_current(sc, os.path.join(tmp, f"{name}.exr"))
    return rec["_passes"]["Combined"][..., :3], rec["render"]


def _cell(m) -> str:
    return "%.4f (%.4f, %+.4f)" % (m["rel_rmse_4"], m["floor_4"], m["bias"])


def summary(rows: list) -> list:
    """Lines of the report: per render, our error over the scenes against the pair and
    against every run pooled (median and worst)."""
    lines = []
    for render in ("single", "full"):
        got = [r for r in rows if r["render"] == render and "ours_vs_all" in r]
        if not got:
            continue
        parts = []
        for key, what in (("ours_vs_pair", "against the pair"),
                          ("ours_vs_all", "against every run pooled")):
            vals = sorted((r[key]["rel_rmse_4"], r["scene"]) for r in got)
            parts.append("%s median %.4f, worst %.4f (%s)" % (
                what, float(np.median([v for v, _ in vals])), vals[-1][0], vals[-1][1]))
        lines.append("- %s, %d scenes: ours %s." % (
            "Single scattering" if render == "single" else "Full render", len(got),
            "; ".join(parts)))
    return lines


def write_report(rows: list, out: str) -> None:
    """OUT/cycles_seeds.md from the rows (each with scene, render, seeds, and check's keys)."""
    lines = ["# Cycles' reference pairs against more seeds", "",
             "Generated by `benchmarks/cycles_seeds.py` (module docstring: what each column "
             "compares). Each cell: rel_rmse_4 (the floor_4 of the runs compared against, "
             "bias). \"pair vs extra\" holds the pair's own noise, which \"pair floor_4\" "
             "estimates from its two runs; \"extra halves\" is the same comparison between "
             "two extra runs and the others. Where \"pair vs extra\" is near \"extra "
             "halves\" and both are well above the pair's floor_4, the pair is an ordinary "
             "draw whose two runs undercount its noise, and a render is scored against noise "
             "the metric does not subtract: \"ours vs all\" (every run pooled) is then the "
             "better estimate of our error.", "",
             "| scene | render | extra seeds (spp each) | pair floor_4 | pair vs extra | "
             "extra halves | ours vs pair | ours vs extra | ours vs all |",
             "|---|---|---|---|---|---|---|---|---|"]
    lines[-2:-2] = summary(rows) + [""]
    for r in sorted(rows, key=lambda r: (r["scene"], r["render"])):
        ours = [(_cell(r[k]) if k in r else "") for k in ("ours_vs_pair", "ours_vs_extra",
                                                           "ours_vs_all")]
        lines.append("| %s | %s | %s (%s) | %.4f | %s | %s | %s |" % (
            r["scene"], r["render"], ",".join(map(str, r["seeds"])), r.get("spp", ""),
            r["pair_floor_4"], _cell(r["pair_vs_extra"]),
            _cell(r["extra_halves"]) if "extra_halves" in r else "",
            " | ".join(ours)))
    with open(os.path.join(out, "cycles_seeds.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


def merge(paths, later=()) -> list:
    """Rows of the JSON files and then ``later``'s, each replacing earlier rows of the same
    scene and render."""
    merged = {}
    for path in paths:
        if os.path.exists(path):
            with open(path) as f:
                for row in json.load(f):
                    merged[(row["scene"], row["render"])] = row
    for row in later:
        merged[(row["scene"], row["render"])] = row
    return list(merged.values())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default=None)
    ap.add_argument("--single", action="store_true",
                    help="the single-scattering runs (ss_s*.exr), else the full ones")
    ap.add_argument("--seeds", default=",".join(map(str, SEEDS)))
    ap.add_argument("--work", default=os.path.join(tempfile.gettempdir(), "mpp_cycles_seeds"))
    ap.add_argument("--out", default=os.path.join(REPO, "docs"))
    ap.add_argument("--no-ours", action="store_true")
    ap.add_argument("--rows", nargs="*", default=None)
    args = ap.parse_args(argv)
    os.environ.setdefault("MPP_CACHE_MB", "0")   # our render timed cold, as accuracy.py's
    os.makedirs(args.out, exist_ok=True)
    store = os.path.join(args.out, "cycles_seeds.json")
    if args.rows:
        rows = merge(args.rows)
    else:
        from mpp_render import metrics
        from mpp_render.blender import batch
        batch.register()
        seeds = [int(s) for s in args.seeds.split(",")]
        if len(seeds) < 2:
            ap.error("--seeds: at least two (the extra runs' floor needs two; their halves four)")
        new = []
        with tempfile.TemporaryDirectory() as tmp:
            for name in metrics.scene_names(SCENES, args.scenes):
                t = time.perf_counter()
                extra = read(extra_runs(name, seeds, args.single, args.work))
                cycles_s = time.perf_counter() - t
                pair = read(metrics.reference_paths(os.path.join(SCENES, name), args.single))
                ours, secs = (None, None) if args.no_ours else render_ours(name, args.single, tmp)
                row = {"scene": name, "render": "single" if args.single else "full",
                       "seeds": seeds, "spp": spp_per_seed(name),
                       "cycles_seconds": round(cycles_s, 1), **check(pair, extra, ours)}
                if secs is not None:
                    row["ours_seconds"] = round(secs, 2)
                new.append(row)
                print(json.dumps(row), flush=True)
        rows = merge([store], new)
    with open(store, "w") as f:
        json.dump(sorted(rows, key=lambda r: (r["scene"], r["render"])), f, indent=1)
    write_report(rows, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
