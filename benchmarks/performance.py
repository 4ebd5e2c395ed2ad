"""Speed of the numeric core (no Blender): precompute and march on a synthetic cloud.

    .venv/bin/python benchmarks/performance.py [--quick] [--out docs]

Measures, in one run on this machine: precompute seconds against grid size (32^3..256^3, one
sun); march samples per second per core (1 thread and all cores); seconds against image size
(160x120..1920x1080) and number of lights; and what skipping saves (dark lights, multiple
scattering off, a medium that cannot scatter).  Writes ``OUT/performance.md``,
``OUT/performance.json`` and ``OUT/performance.png``.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from mpp_render import kernels  # noqa: E402
from mpp_render.camera import camera_plane  # noqa: E402
from mpp_render.render import render  # noqa: E402
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, World  # noqa: E402


def cloud(n, seed=0, albedo=0.98):
    """An n^3 fBm-like cloud in a 4 m box (density scale 12 /m, g 0.85)."""
    rng = np.random.default_rng(seed)
    x = np.linspace(-1, 1, n)
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    d = np.clip(1.0 - np.sqrt(X ** 2 + Y ** 2 + (1.4 * Z) ** 2) / 0.8, 0, 1)
    noise = np.zeros_like(d)
    for octave in range(4):
        k = 2 ** octave * 2
        ph = rng.uniform(0, 2 * np.pi, 3)
        noise += np.sin(k * np.pi * X + ph[0]) * np.sin(k * np.pi * Y + ph[1]) * \
            np.sin(k * np.pi * Z + ph[2]) / 2 ** octave
    d = np.clip(d * (1 + 0.6 * noise), 0, None).astype(np.float32)
    i2w = np.eye(4)
    i2w[:3, :3] *= 4.0 / n
    i2w[:3, 3] = -2.0
    return Medium("cloud", d, i2w, np.full(3, 12 * albedo), np.full(3, 12 * (1 - albedo)), 0.85)


def camera(w, h):
    c2w = np.eye(4)
    a = 1.536
    c2w[:3, :3] = [[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]
    c2w[:3, 3] = [0, -6, 0.3]
    return Camera("PERSP", c2w, w, h, camera_plane("PERSP", 40, 36, 24, "AUTO", 0, 0, 1, w, h))


def sun(i=0):
    d = np.array([0.3 + 0.1 * i, 0.6, -0.7])
    return Light("SUN", f"sun{i}", np.full(3, 4.0), direction=d / np.linalg.norm(d))


def run(desc):
    t = time.perf_counter()
    out = render(desc)
    return time.perf_counter() - t, out


def scene(n=96, w=160, h=120, lights=None, spp=1, multiple=True, threads=0, albedo=0.98):
    return SceneDescription(camera(w, h), lights if lights is not None else [sun()],
                            [cloud(n, albedo=albedo)], world=World(np.array([0.15, 0.21, 0.36])),
                            settings=Settings(samples=spp, multiple=multiple, threads=threads))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="smaller sizes (a smoke test)")
    ap.add_argument("--out", default=os.path.join(REPO, "docs"))
    args = ap.parse_args(argv)
    cores = os.cpu_count() or 1
    res = {"machine": {"cores": cores, "backend": kernels.backend()}}

    grids = [32, 64] if args.quick else [32, 64, 128, 256]
    res["grid"] = []
    for n in grids:
        for multiple in (False, True):
            s, out = run(scene(n=n, multiple=multiple))
            res["grid"].append({"n": n, "multiple": multiple, "precompute": out.timings["precompute"],
                                "march": out.timings["march"], "total": s})
            print(json.dumps(res["grid"][-1]), flush=True)

    res["threads"] = []
    for threads in sorted({1, cores}):
        for multiple in (False, True):
            s, out = run(scene(n=96, spp=4, multiple=multiple, threads=threads))
            sps = out.stats["march_samples"] / out.timings["march"]
            res["threads"].append({"threads": threads, "multiple": multiple, "march": out.timings["march"],
                                   "samples": out.stats["march_samples"], "samples_per_s": sps,
                                   "samples_per_s_per_core": sps / threads})
            print(json.dumps(res["threads"][-1]), flush=True)

    sizes = [(160, 120), (320, 240)] if args.quick else [(160, 120), (480, 270), (960, 540), (1920, 1080)]
    res["image"] = []
    for w, h in sizes:
        s, out = run(scene(n=96, w=w, h=h))
        res["image"].append({"width": w, "height": h, "precompute": out.timings["precompute"],
                             "march": out.timings["march"], "total": s})
        print(json.dumps(res["image"][-1]), flush=True)

    res["lights"] = []
    for k in ([1, 2] if args.quick else [1, 2, 4, 8]):
        s, out = run(scene(n=64, lights=[sun(i) for i in range(k)]))
        res["lights"].append({"lights": k, "precompute": out.timings["precompute"],
                              "march": out.timings["march"], "total": s})
        print(json.dumps(res["lights"][-1]), flush=True)

    base_s, _ = run(scene(n=64))
    dark = [sun(), Light("POINT", "dark", np.zeros(3), position=np.zeros(3))]
    dark_s, _ = run(scene(n=64, lights=dark))
    on_s, _ = run(scene(n=64, multiple=True))
    off_s, _ = run(scene(n=64, multiple=False))
    black_s, _ = run(scene(n=64, albedo=0.0))
    res["skipping"] = {"one_sun": base_s, "one_sun_plus_dark_light": dark_s,
                       "multiple_on": on_s, "multiple_off": off_s, "albedo_0_multiple_on": black_s}
    print(json.dumps(res["skipping"]), flush=True)

    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "performance.json"), "w") as f:
        json.dump(res, f, indent=1)
    L = [f"# Performance of the numeric core", "",
         f"Generated by `benchmarks/performance.py` on {time.strftime('%Y-%m-%d')}: {cores} cores, "
         f"kernels: {kernels.backend()}. Synthetic 4 m fBm cloud (density 12 /m, albedo 0.98, "
         "g 0.85), sun + sky, 1 spp unless stated, all measured in one run.", "",
         "## Grid size (160x120)", "", "| grid | multiple | precompute s | march s |", "|---|---|---|---|"]
    L += [f"| {r['n']}^3 | {r['multiple']} | {r['precompute']:.3f} | {r['march']:.3f} |" for r in res["grid"]]
    L += ["", "## March throughput (96^3, 160x120, 4 spp)", "",
          "| threads | multiple | march s | samples | samples/s | samples/s/core |", "|---|---|---|---|---|---|"]
    L += [f"| {r['threads']} | {r['multiple']} | {r['march']:.3f} | {r['samples']:.3g} | "
          f"{r['samples_per_s']:.3g} | {r['samples_per_s_per_core']:.3g} |" for r in res["threads"]]
    L += ["", "## Image size (96^3)", "", "| image | precompute s | march s | total s |", "|---|---|---|---|"]
    L += [f"| {r['width']}x{r['height']} | {r['precompute']:.3f} | {r['march']:.3f} | {r['total']:.3f} |"
          for r in res["image"]]
    L += ["", "## Number of lights (64^3)", "", "| lights | precompute s | march s | total s |", "|---|---|---|---|"]
    L += [f"| {r['lights']} | {r['precompute']:.3f} | {r['march']:.3f} | {r['total']:.3f} |" for r in res["lights"]]
    sk = res["skipping"]
    L += ["", "## What skipping saves (64^3, seconds of the whole render)", "",
          "| case | seconds |", "|---|---|",
          f"| one sun | {sk['one_sun']:.3f} |",
          f"| one sun + a 0 W light (skipped: no channel, no pyramid, no march work) | {sk['one_sun_plus_dark_light']:.3f} |",
          f"| multiple scattering on | {sk['multiple_on']:.3f} |",
          f"| multiple scattering off (no pyramids, no Volume Multiple) | {sk['multiple_off']:.3f} |",
          f"| albedo 0, multiple on (no pyramid for a medium that cannot scatter) | {sk['albedo_0_multiple_on']:.3f} |",
          "", "![performance](performance.png)"]
    with open(os.path.join(args.out, "performance.md"), "w") as f:
        f.write("\n".join(L) + "\n")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 3, figsize=(12, 3.4))
    for m in (False, True):
        g = [r for r in res["grid"] if r["multiple"] == m]
        ax[0].loglog([r["n"] ** 3 for r in g], [r["precompute"] for r in g], "o-",
                     label=f"precompute, multiple={m}")
    ax[0].set_xlabel("voxels")
    ax[0].set_ylabel("seconds")
    ax[0].legend(fontsize=7)
    ax[1].loglog([r["width"] * r["height"] for r in res["image"]], [r["total"] for r in res["image"]], "o-")
    ax[1].set_xlabel("pixels")
    ax[1].set_ylabel("seconds")
    ax[2].plot([r["lights"] for r in res["lights"]], [r["total"] for r in res["lights"]], "o-")
    ax[2].set_xlabel("lights")
    ax[2].set_ylabel("seconds")
    for a in ax:
        a.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "performance.png"), dpi=110)
    return 0


if __name__ == "__main__":
    sys.exit(main())
