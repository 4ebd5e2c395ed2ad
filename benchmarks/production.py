"""Production size: our default render (F12) at 1920x1080 against Cycles CPU at equal error,
every public scene, all in one run on one machine.

    .venv/bin/python benchmarks/production.py [--scenes a,b] [--size 1920x1080]
        [--cycles-spp 1,4,16,64] [--out docs] [--rows OUT/production_rows.json]

For each scene, in this order and in the same run:

1. ours at the suite's resolution with the defaults an artist gets: its rel_rmse_4 against
   ``ref_s*.exr`` (metrics.md) is our error;
2. Cycles at the suite's resolution at ``--cycles-spp`` (the reference settings, no
   adaptive sampling): its error curve;
3. ours at ``--size`` with the defaults: seconds of the render call and of its stages, the
   samples per pixel adaptive sampling took, march samples per second per core;
4. Cycles at ``--size`` with 1 and ``HD_SPP`` samples: seconds per sample (the difference
   over the samples between them) and its fixed cost (the rest of the 1-sample render).  A
   difference of 1 and 2 samples moved by up to 40 % between two runs of the same scene (the
   fixed cost's own spread), so the difference spans more samples.

Cycles' seconds at ``--size`` to reach our error = fixed cost + n x seconds per sample, n
interpolated log-log on the curve of step 2 (our error and the curve are measured at the
suite's resolution: the images at ``--size`` have no reference).  Where the curve does not
reach our error within its last point, n is extrapolated as Monte Carlo noise falls,
error ~ n^-1/2, from the last point, and the row says "extrapolated".  The equal-error
speedup is that time over ours at ``--size``.  Writes ``OUT/production.md``,
``OUT/production.png`` (Cycles' seconds to our error against ours, per scene) and
``OUT/production.json``, and the summary into ``OUT/error_vs_time.md`` (block
``production``, beside that page's tables at the suite's size; error_vs_time.py keeps it);
each scene's row is also appended to ``--rows`` as it completes.
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
sys.path.insert(0, REPO)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import docblocks  # noqa: E402
# Cycles' samples at --size besides the one-sample render: its seconds per sample are the
# difference over the samples between them
HD_SPP = 4
SCENES = os.environ.get("MPP_SCENES") or os.path.join(os.path.dirname(REPO), "shared", "scenes")


def samples_to_reach(err: float, curve) -> tuple:
    """(samples per pixel at which Cycles' ``curve`` [(spp, err)] reaches ``err``,
    extrapolated?): log-log interpolation between points, error ~ spp^-1/2 beyond the last."""
    pts = sorted((s, e) for s, e in curve if e and e > 0)
    if not pts or not err or err <= 0:
        return None, False
    if err >= pts[0][1]:
        return float(pts[0][0]), False
    for (s0, e0), (s1, e1) in zip(pts, pts[1:]):
        if e1 <= err <= e0:
            if e0 == e1:
                return float(s0), False
            f = (np.log(err) - np.log(e0)) / (np.log(e1) - np.log(e0))
            return float(np.exp(np.log(s0) + f * (np.log(s1) - np.log(s0)))), False
    s_last, e_last = pts[-1]
    return float(s_last * (e_last / err) ** 2), True


def commit() -> str:
    """The short git commit of the tree measured, or "unknown" outside a git checkout."""
    import subprocess
    try:
        return subprocess.run(["git", "-C", REPO, "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def open_scene(name):
    import bpy
    bpy.ops.wm.open_mainfile(filepath=os.path.join(SCENES, name, "scene.blend"))
    return bpy.context.scene


def measure(name, size, cycles_spp, tmp):
    from mpp_render import metrics
    from mpp_render.blender import batch
    from mpp_render.exr import read_passes

    refs = [read_passes(p, names=("Combined",))["Combined"]
            for p in metrics.reference_paths(os.path.join(SCENES, name), False)]
    row = {"scene": name, "commit": commit()}
    sc = open_scene(name)
    sc.render.engine = 'MPP_RENDER'              # the file's own MPP settings: F12
    rec = batch.render_current(sc, os.path.join(tmp, f"{name}_ours.exr"))
    m = metrics.compare(rec["_passes"]["Combined"], refs)
    row["ours_small"] = {"seconds": rec["render"], "rel_rmse_4": m["rel_rmse_4"],
                         "floor_4": m["floor_4"], "bias": m["bias"]}
    curve = []
    for spp in cycles_spp:
        sc = open_scene(name)
        batch.set_cycles_reference(sc, spp, seed=2000 + spp)
        rec = batch.render_current(sc, os.path.join(tmp, f"{name}_c{spp}.exr"))
        m = metrics.compare(rec["_passes"]["Combined"], refs)
        curve.append({"spp": spp, "seconds": rec["render"], "rel_rmse_4": m["rel_rmse_4"]})
    row["cycles_small"] = curve
    w, h = size
    sc = open_scene(name)
    sc.render.engine = 'MPP_RENDER'
    sc.render.resolution_x, sc.render.resolution_y, sc.render.resolution_percentage = w, h, 100
    rec = batch.render_current(sc, os.path.join(tmp, f"{name}_ours_hd.exr"))
    out = rec["_frame"].output
    threads = max(1, int(out.stats.get("threads", 1)))
    march_s = rec["march"] or 0.0
    row["ours_hd"] = {"seconds": rec["render"], "translate": rec["translate"],
                      "precompute": rec["precompute"], "march": march_s,
                      "pixel_samples": out.stats.get("pixel_samples"),
                      "march_samples": out.stats.get("march_samples", 0.0),
                      "samples_per_s_per_core": out.stats.get("march_samples", 0.0)
                      / max(march_s, 1e-9) / threads}
    hd = {}
    for spp in (1, HD_SPP):
        sc = open_scene(name)
        batch.set_cycles_reference(sc, spp, seed=3000 + spp)
        sc.render.resolution_x, sc.render.resolution_y = w, h
        sc.render.resolution_percentage = 100
        rec = batch.render_current(sc, os.path.join(tmp, f"{name}_chd{spp}.exr"))
        hd[spp] = rec["render"]
    per = max((hd[HD_SPP] - hd[1]) / (HD_SPP - 1), 1e-3)
    row["cycles_hd"] = {"seconds_1spp": hd[1], f"seconds_{HD_SPP}spp": hd[HD_SPP],
                        "per_sample": per, "fixed": max(hd[1] - per, 0.0)}
    n, extrap = samples_to_reach(row["ours_small"]["rel_rmse_4"],
                                 [(c["spp"], c["rel_rmse_4"]) for c in curve])
    row["cycles_spp_needed"], row["extrapolated"] = n, extrap
    if n is not None:
        t = row["cycles_hd"]["fixed"] + n * per
        row["cycles_hd_seconds_at_our_error"] = t
        row["speedup"] = t / row["ours_hd"]["seconds"]
    print(json.dumps(row), flush=True)
    return row


def measured_commits(rows) -> list:
    """The commits the ``rows`` measured, sorted, each once ("unknown" for a row without)."""
    return sorted({r.get("commit", "unknown") for r in rows})


def slowest(rows) -> str:
    """The scene of the ``rows`` with the lowest equal-error speedup (rows without one last)."""
    return min(rows, key=lambda r: r.get("speedup") or 1e9)["scene"]


def hd_samples(rows) -> str:
    """The sample counts beside 1 of the rows' Cycles renders at production size ("2", "4",
    "2 or 4"): rows from runs before HD_SPP was 4 hold 2."""
    got = sorted({int(k[len("seconds_"):-len("spp")]) for r in rows for k in r["cycles_hd"]
                  if k.startswith("seconds_") and k.endswith("spp") and k != "seconds_1spp"})
    return " or ".join(str(n) for n in got) if got else str(HD_SPP)


def write_report(rows, out, size):
    w, h = size
    sp = [r["speedup"] for r in rows if r.get("speedup")]
    L = ["# Production size: our defaults against Cycles at equal error", "",
         f"Generated by `benchmarks/production.py` on {time.strftime('%Y-%m-%d')}, "
         f"{os.cpu_count()} cores, every number from one run (ours and Cycles side by side, one "
         "scene after the other; the machine is shared, so single timings carry some tens of "
         "per cent). Ours: the scene's own settings, as F12 renders them (Final quality, "
         f"adaptive sampling), at {w}x{h}. Cycles: the reference settings (CPU, no adaptive "
         f"sampling, no denoising), its seconds per sample at {w}x{h} from 1- and "
         f"{hd_samples(rows)}-sample renders, the samples it needs to reach our error from its error curve at the "
         "suite's resolution in the same run (our error measured there too: the large images "
         "have no reference). \"extrapolated\": Cycles did not reach our error within the "
         "curve's last point, and error ~ samples^-1/2 took it further.", ""]
    commits = measured_commits(rows)
    L += [f"Commit{'s' if len(commits) > 1 else ''} measured: {', '.join(commits)}.", ""]
    if sp:
        L += [f"Equal-error speedup over the {len(sp)} scenes: median {np.median(sp):.1f}x, "
              f"worst {min(sp):.1f}x ({slowest(rows)}), best {max(sp):.1f}x.", ""]
    L += [f"| scene | our error (rel_rmse_4) | ours at {w}x{h}: s (precompute / march) | "
          "samples per pixel | march M samples/s/core | Cycles s per sample | Cycles fixed s | "
          "Cycles samples to our error | Cycles s to our error | speedup |",
          "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        o, c = r["ours_hd"], r["cycles_hd"]
        n = r.get("cycles_spp_needed")
        speed = f"{r['speedup']:.1f}x" if r.get("speedup") else "–"
        L.append(f"| {r['scene']} | {r['ours_small']['rel_rmse_4']:.4f} | {o['seconds']:.1f} "
                 f"({o['precompute'] or 0:.1f} / {o['march']:.1f}) | {o['pixel_samples'] or 0:.2f} | "
                 f"{o['samples_per_s_per_core'] / 1e6:.1f} | {c['per_sample']:.2f} | "
                 f"{c['fixed']:.1f} | {'–' if n is None else f'{n:.0f}'}"
                 f"{' (extrapolated)' if r.get('extrapolated') else ''} | "
                 f"{r.get('cycles_hd_seconds_at_our_error', 0):.0f} | "
                 f"{speed} |")
    L += ["", "![our seconds against Cycles' at equal error](production.png)"]
    with open(os.path.join(out, "production.md"), "w") as f:
        f.write("\n".join(L) + "\n")
    with open(os.path.join(out, "production.json"), "w") as f:
        json.dump(rows, f, indent=1)
    plot(rows, os.path.join(out, "production.png"), size)
    docblocks.put_block(os.path.join(out, "error_vs_time.md"), "production",
                        summary_lines(rows, size))


def summary_lines(rows, size) -> list:
    """Markdown lines for docs/error_vs_time.md: per scene our error, our seconds at ``size``,
    Cycles' seconds to reach that error there and the speedup, then the median and worst."""
    w, h = size
    sp = [r["speedup"] for r in rows if r.get("speedup")]
    L = [f"## At {w}x{h}, the defaults (F12)", "",
         f"From [production.md](production.md) (`benchmarks/production.py`, commit "
         f"{', '.join(measured_commits(rows))}; {time.strftime('%Y-%m-%d')}): ours at {w}x{h} as F12 renders "
         f"it, Cycles' seconds per sample at {w}x{h} in the same run, the samples it needs to "
         "reach our error from its curve at the suite's size, also in the same run."]
    if sp:
        L += ["", f"Equal-error speedup over {len(sp)} scenes: median {np.median(sp):.1f}x, "
              f"worst {min(sp):.1f}x ({slowest(rows)}); {sum(v >= 100.0 for v in sp)} scenes at 100x "
              f"or more, {sum(v < 30.0 for v in sp)} below 30x."]
    L += ["", f"| scene | our error | ours at {w}x{h}, s | Cycles s to our error | speedup |",
          "|---|---|---|---|---|"]
    for r in rows:
        t = r.get("cycles_hd_seconds_at_our_error")
        speed = f"{r['speedup']:.1f}x" if r.get("speedup") else "–"
        cycles = "–" if t is None else f"{t:.0f}"
        L.append(f"| {r['scene']} | {r['ours_small']['rel_rmse_4']:.4f} | "
                 f"{r['ours_hd']['seconds']:.1f} | {cycles} | {speed} |")
    return L + ["", "![our seconds against Cycles' at equal error](production.png)"]


def plot(rows, path, size):
    """``path``: per scene, Cycles' seconds to reach our error against ours at ``size``,
    log-log, with the lines of equal speedup 1x, 30x and 100x."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    pts = [(r["ours_hd"]["seconds"], r["cycles_hd_seconds_at_our_error"], r["scene"])
           for r in rows if r.get("cycles_hd_seconds_at_our_error")]
    fig, ax = plt.subplots(figsize=(7.5, 6.0))
    if pts:
        xs, ys, names = zip(*pts)
        lo = min(min(xs), min(ys) / 100.0) / 2.0
        hi = max(max(xs) * 100.0, max(ys)) * 2.0
        for k, style in ((1.0, ":"), (30.0, "--"), (100.0, "-")):
            ax.loglog([lo, hi], [lo * k, hi * k], style, color="grey", lw=0.8,
                      label=f"{k:g}x")
        ax.loglog(xs, ys, "o", color="C0")
        for x, y, name in pts:
            ax.annotate(name, (x, y), fontsize=6, xytext=(3, 2), textcoords="offset points")
        ax.set_xlim(min(xs) / 2.0, max(xs) * 2.0)
        ax.set_ylim(min(ys) / 2.0, max(ys) * 2.0)
    w, h = size
    ax.set_xlabel(f"ours at {w}x{h}, defaults (s)")
    ax.set_ylabel(f"Cycles at {w}x{h} to our error (s)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, title="equal-error speedup", title_fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default=None, help="comma-separated scene names (default: all)")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--cycles-spp", default="1,4,16,64")
    ap.add_argument("--out", default=os.path.join(REPO, "docs"))
    ap.add_argument("--rows", default=None, help="JSON lines file each scene's row is appended to")
    ap.add_argument("--report-only", action="store_true", help="write the report from --rows")
    args = ap.parse_args(argv)
    size = tuple(int(v) for v in args.size.lower().split("x"))
    if args.report_only:
        with open(args.rows) as f:
            rows = [json.loads(line) for line in f if line.strip()]
        os.makedirs(args.out, exist_ok=True)
        write_report(rows, args.out, size)
        return 0
    os.environ["MPP_CACHE_MB"] = "0"   # every render cold: the precompute's seconds count
    from mpp_render.metrics import scene_names
    from mpp_render.blender import batch
    batch.register()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in scene_names(SCENES, args.scenes):
            rows.append(measure(name, size, [int(s) for s in args.cycles_spp.split(",")], tmp))
            if args.rows:
                with open(args.rows, "a") as f:
                    f.write(json.dumps(rows[-1]) + "\n")
    os.makedirs(args.out, exist_ok=True)
    write_report(rows, args.out, size)
    return 0


if __name__ == "__main__":
    sys.exit(main())
