"""Accuracy of every public scene against the Cycles references, with pictures.

    .venv/bin/python benchmarks/accuracy.py [--scenes a,b] [--samples 16] [--out docs]
    .venv/bin/python benchmarks/accuracy.py --keep-single docs/accuracy.json   # full only
    .venv/bin/python benchmarks/accuracy.py --rows A.json B.json [--out docs]   # report only

For each scene: our render with multiple scattering off against ``ss_s*.exr`` (Cycles with
``volume_bounces = 0``), and with it on against ``ref_s*.exr``; the metrics of
``shared/reference/metrics.md``, the wall seconds of the render call, and for the full render
our ``Volume Multiple`` pass beside the references' indirect light (Combined of ``ref`` minus
Combined of ``ss``, which is what Cycles' Volume Indirect holds in these scenes).  Writes
``OUT/accuracy.md``, ``OUT/accuracy.json`` and ``OUT/images/<scene>.png``: ours, Cycles, and
the signed difference (red: ours brighter, blue: darker) of the full render, above the same
for the multiple-scattering part.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# Every render is timed cold: the precompute cache (mpp_render/cache.py) kept between
# settings or repeats would hide the precompute's seconds.
os.environ["MPP_CACHE_MB"] = "0"
sys.path.insert(0, REPO)
from mpp_render.scene import NOISE_THRESHOLD  # noqa: E402  (the report states the default)

# the public scene suite: $MPP_SCENES, else shared/scenes beside the checkout
SCENES = os.environ.get("MPP_SCENES") or os.path.join(os.path.dirname(REPO), "shared", "scenes")


def tone(a, scale):
    """Linear RGB -> display [0, 1] (exposure to ``scale``, sRGB-like gamma)."""
    return np.clip(np.maximum(a, 0) / max(scale, 1e-12), 0, 1) ** (1 / 2.2)


def heat(diff, scale):
    """Signed difference (H, W) -> RGB: red where positive, blue where negative."""
    d = np.clip(diff / max(scale, 1e-12) * 4.0, -1, 1)
    out = np.zeros(diff.shape + (3,))
    out[..., 0] = np.maximum(d, 0)
    out[..., 2] = np.maximum(-d, 0)
    return out


def panel(ours, ref):
    scale = float(np.percentile(ref, 99.5)) or 1.0
    return np.concatenate([tone(ours, scale), tone(ref, scale),
                           heat((ours - ref).mean(axis=2), scale)], axis=1)


def render_scene(name, samples, tmp, single_row=None):
    import bpy

    from mpp_render import metrics
    from mpp_render.blender import batch
    from mpp_render.exr import read_passes

    scene_dir = os.path.join(SCENES, name)
    ss_runs = [read_passes(p)["Combined"][..., :3] for p in metrics.reference_paths(scene_dir, True)]
    ms_runs = [read_passes(p)["Combined"][..., :3] for p in metrics.reference_paths(scene_dir, False)]
    row = {"scene": name}
    images = {}
    for single in (True, False):
        if single and single_row is not None:
            row["single"] = single_row   # kept from an earlier run (--keep-single)
            images["single"] = None
            continue
        bpy.ops.wm.open_mainfile(filepath=os.path.join(scene_dir, "scene.blend"))
        sc = bpy.context.scene
        spp = metrics.SINGLE_SCATTERING_SAMPLES.get(name, samples) if single else samples
        batch.set_mpp(sc, spp, multiple=not single)
        rec = batch.render_current(sc, os.path.join(tmp, f"{name}_{int(single)}.exr"))
        passes = rec["_passes"]
        m = metrics.compare(passes["Combined"], ss_runs if single else ms_runs)
        key = "single" if single else "full"
        row[key] = {k: m[k] for k in ("rel_rmse", "floor", "rel_rmse_4", "floor_4", "bias")}
        row[key]["seconds"] = rec["render"]
        row[key]["spp"] = spp
        row[key]["warnings"] = rec["warnings"]
        images[key] = passes
    ref_full = np.mean(ms_runs, axis=0)
    ref_indirect = ref_full - np.mean(ss_runs, axis=0)
    ours_ms = images["full"].get("Volume Multiple")
    if ours_ms is not None:
        row["multiple_vs_indirect"] = {
            "ours_mean": float(ours_ms.mean()), "cycles_mean": float(ref_indirect.mean()),
            "rel_rmse_4": metrics.compare(ours_ms, [ref_indirect])["rel_rmse_4"]}
    pic = [panel(images["full"]["Combined"][..., :3], ref_full)]
    if ours_ms is not None:
        pic.append(panel(ours_ms, ref_indirect))
    return row, np.concatenate(pic, axis=0)


def write_png(path, img, zoom=2):
    import OpenImageIO as oiio
    img = np.repeat(np.repeat(img, zoom, 0), zoom, 1)
    buf = oiio.ImageBuf(oiio.ImageSpec(img.shape[1], img.shape[0], 3, oiio.UINT8))
    buf.set_pixels(oiio.ROI(), (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8))
    buf.write(path)


def distribution(rows, key):
    """(n, median, 90th percentile, worst scene and value) of rel_rmse_4 over ``rows``'
    ``key`` ('single' or 'full'): every scene."""
    vals = sorted((r[key]["rel_rmse_4"], r["scene"]) for r in rows)
    if not vals:
        return None
    v = np.array([a for a, _ in vals])
    return len(v), float(np.median(v)), float(np.percentile(v, 90)), vals[-1][1], vals[-1][0]


def summary_lines(rows):
    lines = ["## Distribution over the suite", "",
             "rel_rmse_4 over every scene of the suite.", "",
             "| render | scenes | median | 90th percentile | worst |", "|---|---|---|---|---|"]
    for key, label in (("single", "single scattering"), ("full", "full render")):
        d = distribution(rows, key)
        if d:
            lines.append(f"| {label} | {d[0]} | {d[1]:.4f} | {d[2]:.4f} | {d[4]:.4f} ({d[3]}) |")
    return lines + [""]


def write_report(rows, out, samples, merged_from=None, single_from=None):
    """accuracy.md and accuracy.json in ``out`` from ``rows``; ``merged_from``: the JSON
    files the rows were merged from (--rows), ``single_from`` the one whose single-scattering
    rows were kept (--keep-single), named in the report."""
    kept = [] if not single_from else [
        "The single-scattering rows are kept from an earlier run (`--keep-single`, from the "
        "rows then in `docs/`): the change measured was to multiple scattering alone, which "
        "a render with multiple scattering off does not run.", ""]
    merged = kept if not merged_from else kept + [
        "Rows merged from earlier runs (`--rows`), each scene's from the last of "
        + ", ".join(f"`{os.path.relpath(p, REPO)}`" for p in merged_from)
        + " that holds it: a change that leaves some scenes' images the same bits is "
        "measured on the others alone.", ""]
    lines = ["# Accuracy against Cycles", "",
             f"Generated by `benchmarks/accuracy.py` on {time.strftime('%Y-%m-%d')} "
             f"({os.cpu_count()} cores), at most {samples} spp (adaptive sampling at the "
             f"default Noise Threshold {NOISE_THRESHOLD:g}), at the suite's resolution. Metrics of "
             "`shared/reference/metrics.md`; seconds are the render call (this shared machine "
             "ran other work beside it: read the seconds as rough).", "",
             "How far each scene's two reference runs can be trusted, against more Cycles "
             "seeds of the same scene: [cycles_seeds.md](cycles_seeds.md) "
             "(`benchmarks/cycles_seeds.py`).", ""] + merged
    lines += summary_lines(rows) + [
             "## Single scattering (multiple off) against `ss_s*.exr`", "",
             "Samples per pixel at most as stated (`metrics.SINGLE_SCATTERING_SAMPLES`: where "
             "16 leave our own noise above the 0.03 target).", "",
             "| scene | spp | rel_rmse_4 | floor_4 | bias | rel_rmse | seconds |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        s = r["single"]
        lines.append(f"| {r['scene']} | {s['spp']} | {s['rel_rmse_4']:.4f} | {s['floor_4']:.4f} | "
                     f"{s['bias']:+.4f} | {s['rel_rmse']:.4f} | {s['seconds']:.2f} |")
    lines += ["", "## Full render (multiple scattering on) against `ref_s*.exr`", "",
              "| scene | rel_rmse_4 | floor_4 | bias | seconds | our Volume Multiple mean | "
              "Cycles indirect mean |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        s = r["full"]
        mv = r.get("multiple_vs_indirect", {})
        lines.append(f"| {r['scene']} | {s['rel_rmse_4']:.4f} | {s['floor_4']:.4f} | {s['bias']:+.4f} | "
                     f"{s['seconds']:.2f} | {mv.get('ours_mean', float('nan')):.5f} | "
                     f"{mv.get('cycles_mean', float('nan')):.5f} |")
    lines += ["", "Pictures: ours | Cycles | signed difference (red: ours brighter). Top row the "
              "full render, bottom row our Volume Multiple against Cycles' indirect light "
              "(ref minus ss).", ""]
    for r in rows:
        lines += [f"### {r['scene']}", "", f"![{r['scene']}](images/{r['scene']}.png)", ""]
    with open(os.path.join(out, "accuracy.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    with open(os.path.join(out, "accuracy.json"), "w") as f:
        json.dump(rows, f, indent=1)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default=None)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--out", default=os.path.join(REPO, "docs"))
    ap.add_argument("--keep-single", default=None,
                    help="an earlier accuracy.json whose single-scattering rows are kept "
                         "(render only the full images: for a change to multiple scattering "
                         "alone)")
    ap.add_argument("--rows", nargs="*", default=None,
                    help="write the report from the JSON rows of earlier runs (accuracy.json "
                         "files, later ones replacing earlier rows of the same scene) instead "
                         "of rendering; their pictures must already be in OUT/images")
    args = ap.parse_args(argv)
    if args.rows:
        merged = {}
        for path in args.rows:
            with open(path) as f:
                for row in json.load(f):
                    merged[row["scene"]] = row
        rows = [merged[k] for k in sorted(merged)]
        write_report(rows, args.out, args.samples, args.rows)
        for key in ("single", "full"):
            print(key, distribution(rows, key))
        return 0
    from mpp_render.metrics import scene_names
    names = scene_names(SCENES, args.scenes)
    from mpp_render.blender import batch
    batch.register()
    os.makedirs(os.path.join(args.out, "images"), exist_ok=True)
    kept = {}
    if args.keep_single:
        with open(args.keep_single) as f:
            kept = {r["scene"]: r["single"] for r in json.load(f)}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            row, pic = render_scene(name, args.samples, tmp, kept.get(name))
            write_png(os.path.join(args.out, "images", f"{name}.png"), pic)
            rows.append(row)
            print(json.dumps(row), flush=True)
    write_report(rows, args.out, args.samples, single_from=args.keep_single)
    return 0


if __name__ == "__main__":
    sys.exit(main())
