"""Robustness of the numeric core (no Blender): stiff and extreme input, a huge image, Esc.

    .venv/bin/python benchmarks/robustness.py [--quick] [--out docs]

* Every case of ``tests/test_stiff.py`` (its scene builders and its own assertions, run
  through a recording ``render``): whether the assertions hold, whether every pass is
  finite, the min/max of each pass over the case's renders, and seconds.
* A 4096 x 4096 render of a tiny scene (1 spp, a small cube): finite and right-sized
  (``--quick``: 1024 x 1024).
* Esc latency: seconds from ``should_cancel`` turning true to ``render`` returning, in each
  precompute stage and in the march at 1..16 samples per pixel (scenes of tests/test_cancel.py).
* The memory budget: a 192^3 cloud rendered unlimited and with a 16 MB budget.

Writes ``OUT/robustness.md`` (progress as JSON lines on stdout).  Slow (minutes): not a
test.
"""
from __future__ import annotations

import argparse
import inspect
import itertools
import json
import os
import sys
import time
import traceback

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)
sys.path.insert(0, os.path.join(REPO, "tests"))

from mpp_render import kernels  # noqa: E402
from mpp_render.parallel import POLL_S  # noqa: E402
from mpp_render.render import render  # noqa: E402
from mpp_render.scene import Tuning  # noqa: E402

TILE_RAYS = Tuning().tile_rays
STOP_EVERY = getattr(kernels._c, "STOP_EVERY", None)   # the tracer's paths between stop reads
from mpp_render.scene import Settings, World  # noqa: E402

import test_cancel  # noqa: E402  (scene builders of the Esc tests)
import test_stiff  # noqa: E402  (scene builders and assertions of the stiff cases)

# What each case of tests/test_stiff.py asserts, besides finite passes and non-negative
# passes other than Depth (every case checks those).
ASSERTS = {
    "test_optical_depth_extremes": "tau 1e-6: T = exp(-1e-6) (rel 1e-6); tau 1e4: T < 1e-6 and the lit "
                                   "face still scatters (Single > 0)",
    "test_albedo_zero_has_no_scattering_and_albedo_one_is_finite":
        "albedo 0: Single = Multiple = 0; albedo 1: Multiple > 0",
    "test_multiple_scattering_grows_with_albedo": "sum of Multiple grows over albedo 0.2, 0.6, 0.95",
    "test_anisotropy_extremes": "Single > 0",
    "test_density_over_six_orders_of_magnitude": "density 1e-3..1e3 in one grid renders",
    "test_voxel_sizes": "voxels of 1e-4 m / 100 m at optical depth ~2: T < 0.5",
    "test_point_light_inside_and_on_the_boundary": "Single > 0",
    "test_camera_inside_the_medium": "T = exp(-1.1 x 1.18) within 5 %",
    "test_sun_grazing_at_89_9_degrees": "sun 89.9 deg from the vertical renders",
    "test_one_pixel_image": "Combined is (1, 1, 4)",
    "test_zero_and_negative_light_power_and_no_lights":
        "0 W and -5 W lights: Single = Multiple = 0; no lights, black world: Combined = 0",
    "test_no_media_renders_the_background": "Combined = background 0.1, T = 1",
    "test_nan_inf_and_negative_voxels_are_sanitised": "a warning counts the 3 bad voxels",
    "test_zero_scale_medium_is_skipped_with_a_warning": "skipped with a 'degenerate' warning",
    "test_a_4096_by_4096_image": "4096^2, Combined only, 1 spp: finite, non-negative; 16 x 16 block "
                                 "means match a 256^2 render at 64 spp (rel rmse < 0.02), means "
                                 "within 1 %",
}


def cases(module):
    """(name, function, kwargs) of every test function of ``module``, parametrizations
    expanded."""
    for name, fn in inspect.getmembers(module, inspect.isfunction):
        if not name.startswith("test_") or fn.__module__ != module.__name__:
            continue
        axes = []
        for mark in getattr(fn, "pytestmark", []):
            if mark.name != "parametrize":
                continue
            names, values = mark.args[0], mark.args[1]
            names = [n.strip() for n in names.split(",")] if isinstance(names, str) else list(names)
            axes.append([dict(zip(names, v if len(names) > 1 else (v,))) for v in values])
        for combo in itertools.product(*axes):
            kw = {k: v for d in combo for k, v in d.items()}
            label = name + (f"[{', '.join(f'{k}={v}' for k, v in kw.items())}]" if kw else "")
            yield label, name, fn, kw


def run_case(fn, kw):
    """Run one test function with ``render`` recorded; its outputs, error and seconds."""
    outs = []

    def recording(desc, *a, **k):
        out = render(desc, *a, **k)
        outs.append(out)
        return out

    saved = test_stiff.render
    test_stiff.render = recording
    t = time.perf_counter()
    try:
        fn(**kw)
        error = None
    except Exception as e:  # an assertion that failed: reported in the table
        error = f"{type(e).__name__}: {e}".splitlines()[0][:160]
        traceback.print_exc()
    finally:
        test_stiff.render = saved
    return outs, error, time.perf_counter() - t


def pass_ranges(outs):
    """name -> (min, max) of each pass over all renders, and whether all are finite."""
    ranges, finite = {}, True
    for out in outs:
        for name, p in out.passes.items():
            finite &= bool(np.all(np.isfinite(p)))
            if name == "Combined":
                p = p[..., :3]  # colour; alpha is 1 (or coverage with film_transparent)
            lo, hi = float(np.nanmin(p)), float(np.nanmax(p))
            if name in ranges:
                lo, hi = min(lo, ranges[name][0]), max(hi, ranges[name][1])
            ranges[name] = (lo, hi)
    return ranges, finite


def stiff_table():
    rows = []
    for label, name, fn, kw in cases(test_stiff):
        outs, error, seconds = run_case(fn, kw)
        ranges, finite = pass_ranges(outs)
        rows.append({"case": label, "asserts": ASSERTS.get(name, " ".join((fn.__doc__ or "").split())),
                     "ok": error is None, "error": error, "finite": finite, "renders": len(outs),
                     "ranges": ranges, "seconds": seconds})
        print(json.dumps({k: rows[-1][k] for k in ("case", "ok", "finite", "seconds")}), flush=True)
    return rows


def huge_image(size):
    """A small cube (0.5 m, 8^3 voxels) in a size x size frame at 1 spp."""
    m = test_stiff.cube(sigma_s=2.0, size=0.5)
    desc = test_stiff.scene([m], size=2.0, width=size, height=size)
    desc.settings = Settings(samples=1, multiple=True)
    t = time.perf_counter()
    out = render(desc)
    seconds = time.perf_counter() - t
    ranges, finite = pass_ranges([out])
    shapes = {k: list(v.shape) for k, v in out.passes.items()}
    right = all(v[0] == size and v[1] == size for v in shapes.values())
    mb = sum(v.nbytes for v in out.passes.values()) / 2 ** 20
    covered = float(np.mean(out.passes["Transmittance"][..., 0] < 1.0))
    return {"size": size, "finite": finite, "right_size": right, "shapes": shapes, "ranges": ranges,
            "seconds": seconds, "timings": out.timings, "passes_mb": mb, "covered": covered,
            "tiles": out.stats.get("tiles")}


# a row whose Esc never came: its stage's progress message absent (the light pyramid where
# traced paths are the default) or the stage over before the delay
NOT_REACHED = "not reached (the stage absent, or over before the delay)"


def esc_latency():
    rows = []
    plans = [("precompute: light attenuation", None, 0.3, None),
             ("precompute: world light", None, 0.2, "World light"),
             ("precompute: light pyramid", None, 0.05, "Light pyramid"),
             ("precompute: light paths (1 000 000 a light)", "paths", 0.1, "Light paths")]
    plans += [(f"march, {spp} spp (48^3, 160x128)", spp, 0.1, "Tiles") for spp in (1, 4, 16)]
    plans += [(f"march, {spp} spp (96^3, 160x128)", ("big", spp), 0.1, "Tiles") for spp in (4, 16)]
    for label, spp, delay, stage in plans:
        lat = []
        for _ in range(3):
            if spp is None:
                desc = test_cancel.big_scene()
            elif spp == "paths":   # the traced paths' stage, each call of the tracer long
                desc = test_cancel.big_scene()
                desc.settings.multiple_paths = 1_000_000
            elif isinstance(spp, tuple):
                desc = test_cancel.big_scene(96, 160, 128, spp[1])
            else:
                desc = test_cancel.big_scene(48, 160, 128, spp)
            esc = test_cancel.Esc(delay, stage)
            out = render(desc, progress=esc.progress, should_cancel=esc)
            if out.cancelled:
                lat.append(time.perf_counter() - esc.flipped)
        rows.append({"stage": label, "latency": lat})
        print(json.dumps(rows[-1]), flush=True)
    return rows


def budget_demo():
    n = 192
    res = {}
    for budget in (0, 16):
        desc = test_cancel.big_scene(n, 160, 128, 1)
        desc.lights = desc.lights[:1]
        desc.world = World(np.full(3, 0.1))
        desc.settings = Settings(samples=1, threads=0, memory_budget_mb=budget)
        t = time.perf_counter()
        out = render(desc)
        res[budget] = {"seconds": time.perf_counter() - t, "timings": out.timings,
                       "warnings": [w for w in out.warnings if "memory budget" in w],
                       "T": out.passes["Transmittance"], "finite": bool(all(
                           np.all(np.isfinite(p)) for p in out.passes.values()))}
    diff = float(np.abs(res[0]["T"] - res[16]["T"]).max())
    mean = float(abs(res[0]["T"].mean() - res[16]["T"].mean()))
    for r in res.values():
        del r["T"]
    print(json.dumps({"budget": res, "max_dT": diff}), flush=True)
    return {"n": n, "runs": {str(k): v for k, v in res.items()}, "max_abs_dT": diff, "mean_dT": mean}


def fmt_range(r):
    return f"{r[0]:.3g} .. {r[1]:.3g}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="a 1024^2 image instead of 4096^2")
    ap.add_argument("--out", default=os.path.join(REPO, "docs"))
    args = ap.parse_args(argv)
    cores = os.cpu_count() or 1
    res = {"machine": {"cores": cores, "backend": kernels.backend(), "load_before": os.getloadavg()[0]}}
    res["stiff"] = stiff_table()
    res["huge"] = huge_image(1024 if args.quick else 4096)
    print(json.dumps({k: v for k, v in res["huge"].items() if k != "ranges"}), flush=True)
    res["esc"] = esc_latency()
    res["budget"] = budget_demo()
    res["machine"]["load_after"] = os.getloadavg()[0]

    os.makedirs(args.out, exist_ok=True)
    names = ["Combined", "Volume Single", "Volume Multiple", "Transmittance", "Depth"]
    heads = ["Combined RGB"] + names[1:]
    ok = sum(r["ok"] for r in res["stiff"])
    L = ["# Robustness", "",
         f"Generated by `benchmarks/robustness.py` on {time.strftime('%Y-%m-%d')}: {cores} cores, "
         f"kernels: {kernels.backend()}, 1-minute load average {res['machine']['load_before']:.1f} "
         f"before and {res['machine']['load_after']:.1f} after (timings are of a shared machine). "
         "Numeric core only (the Blender side of bad input is "
         "covered by `tests/blender/test_bad_input.py` and `test_cancel_engine.py`).", "",
         "## Stiff and extreme media (`tests/test_stiff.py`)", "",
         f"Each case runs the test's own scene builders and assertions; {ok} of "
         f"{len(res['stiff'])} cases hold. Every case also asserts finite passes and non-negative "
         "passes other than Depth. Ranges are min .. max over the case's renders (Depth: "
         "1e10 where no volume or surface is hit).", "",
         "| case | asserted | result | finite | " + " | ".join(heads) + " | seconds |",
         "|---|---|---|---|" + "---|" * len(names) + "---|"]
    for r in res["stiff"]:
        result = "ok" if r["ok"] else f"FAILED ({r['error']})"
        cols = [fmt_range(r["ranges"][n]) if n in r["ranges"] else "-" for n in names]
        L.append(f"| `{r['case']}` | {r['asserts']} | {result} | {'yes' if r['finite'] else 'NO'} | "
                 + " | ".join(cols) + f" | {r['seconds']:.2f} |")
    h = res["huge"]
    L += ["", f"## A {h['size']} x {h['size']} frame", "",
          "A 0.5 m cube of 8^3 voxels under a sun, 1 spp, multiple scattering on, every pass.", "",
          "| check | result |", "|---|---|",
          f"| every pass {h['size']} x {h['size']} | {'yes' if h['right_size'] else 'NO'} |",
          f"| every pass finite | {'yes' if h['finite'] else 'NO'} |",
          f"| tiles | {h['tiles']} |",
          f"| pixels seeing the cube | {100 * h['covered']:.2f} % |",
          f"| passes in memory | {h['passes_mb']:.0f} MB |",
          f"| seconds (precompute / march) | {h['seconds']:.1f} ({h['timings'].get('precompute', 0):.2f} / "
          f"{h['timings'].get('march', 0):.1f}) |"]
    L += [f"| {t} range | {fmt_range(h['ranges'][n])} |" for t, n in zip(heads, names)
          if n in h["ranges"]]
    L += ["", "## Esc latency", "",
          "Seconds from `should_cancel` turning true to `render` returning (3 tries each), on the "
          "scenes of `tests/test_cancel.py` (a noisy cloud, a sun, a point light, a grey sky, "
          "multiple scattering, 2 threads). The precompute polls Esc between chunks of a few "
          "hundredths of a second and after each light pyramid; while the light paths are "
          f"traced it polls every {POLL_S} s, and the tracer reads a stop flag every "
          f"{STOP_EVERY} paths. "
          "The march polls it between "
          f"tiles of at most {TILE_RAYS} rays (fewer pixels at more samples per pixel) and waits "
          "for the tiles being marched, so there the latency is about one tile's time, which "
          "grows with the grid but not with the samples per pixel.", "",
          "| stage | latency s |", "|---|---|"]
    L += [f"| {r['stage']} | {', '.join(f'{x:.3f}' for x in r['latency']) or NOT_REACHED} |"
          for r in res["esc"]]
    slow = [r["stage"] for r in res["esc"] if r["latency"] and max(r["latency"]) > 0.5]
    L += ["", ("Over the 0.5 s target: " + "; ".join(slow) + ". A tile being marched is not "
               "interrupted (render.py polls Esc between tiles only), so at many samples per "
               f"pixel Esc waits for up to a tile of {TILE_RAYS} rays.")
          if slow else "Every stage is within the 0.5 s target."]
    b = res["budget"]
    L += ["", "## Memory budget", "",
          f"A {b['n']}^3 cloud (sun and sky, 160x128, 1 spp): unlimited against a 16 MB budget.", "",
          "| budget | seconds | warning |", "|---|---|---|"]
    for k, r in b["runs"].items():
        L.append(f"| {'unlimited' if k == '0' else k + ' MB'} | {r['seconds']:.2f} | "
                 f"{'; '.join(r['warnings']) or '-'} |")
    L += ["", f"Transmittance against the unlimited render: largest pixel difference "
          f"{b['max_abs_dT']:.3f}, difference of the means {b['mean_dT']:.4f}."]
    with open(os.path.join(args.out, "robustness.md"), "w") as f:
        f.write("\n".join(L) + "\n")
    print(f"wrote {os.path.join(args.out, 'robustness.md')}")


if __name__ == "__main__":
    main()
