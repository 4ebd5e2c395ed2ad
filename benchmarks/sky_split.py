"""The sky's multiple scattering alone, ours against Cycles'.

    .venv/bin/python benchmarks/sky_split.py [--scenes p_sphere_lowalbedo,cloud_vdb] [--samples 512]

Each scene is opened with its lights hidden, so the constant world (the sky) is the only
light.  Cycles renders it with Volume Bounces 0 (single scattering) and with the reference's
bounces (``batch.set_cycles_reference``, seed 1, ``--samples`` spp); the difference of the
two images' means is the sky's multiply scattered light.  Ours renders it at the defaults
(16 spp); its Volume Multiple pass's mean is ours.  Prints, per scene, the means and the
ratio.  Minutes (Cycles); not a test.

What it showed (512 spp, 160x120), ours over Cycles': with the collided model
(2026-12-05) 0.616 (p_sphere_lowalbedo), 0.843 (p_sphere_thick), 0.973 (p_dragon), 0.989
(cloud_vdb), 1.092 (slab_isotropic), 1.239 (p_sphere_gneg); with the absorption's flights
traced (precompute/skydeficit.py, 2026-12-06) 0.961, 0.978, 0.979, 0.990, 0.965, 0.972, and
the image means within 0.2 % of Cycles' on twelve scenes (docs/method.md §9.8).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
os.environ["MPP_CACHE_MB"] = "0"
sys.path.insert(0, REPO)

SCENES = os.environ.get("MPP_SCENES") or os.path.join(os.path.dirname(REPO), "shared", "scenes")
DEFAULT = ("p_sphere_lowalbedo", "p_sphere_gneg", "cloud_vdb")


def _open_sky(name: str):
    """The scene ``name`` with its lights hidden from the render."""
    from mpp_render.blender import batch
    sc = batch.open_blend(os.path.join(SCENES, name, "scene.blend"))
    for ob in sc.objects:
        if ob.type == "LIGHT":
            ob.hide_render = True
    return sc


def split(name: str, samples: int, tmp: str) -> dict:
    """Cycles' single and full means and ours (combined, Volume Multiple) with the sky alone."""
    from mpp_render.blender import batch
    cyc = {}
    for multiple in (False, True):
        sc = _open_sky(name)
        batch.set_cycles_reference(sc, samples, multiple=multiple, seed=1)
        out = os.path.join(tmp, f"{name}_cycles_{int(multiple)}.exr")
        cyc[multiple] = float(batch.render_current(sc, out)["_passes"]["Combined"][..., :3].mean())
    sc = _open_sky(name)
    batch.set_mpp(sc, 16, multiple=True)
    passes = batch.render_current(sc, os.path.join(tmp, f"{name}_ours.exr"))["_passes"]
    return {"cycles_single": cyc[False], "cycles_full": cyc[True],
            "cycles_multiple": cyc[True] - cyc[False],
            "ours_combined": float(passes["Combined"][..., :3].mean()),
            "ours_multiple": float(passes["Volume Multiple"][..., :3].mean())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default=",".join(DEFAULT))
    ap.add_argument("--samples", type=int, default=512)
    args = ap.parse_args(argv)
    from mpp_render.blender import batch
    batch.register()
    tmp = tempfile.mkdtemp(prefix="sky_split_")
    for name in args.scenes.split(","):
        r = split(name, args.samples, tmp)
        ratio = r["ours_multiple"] / r["cycles_multiple"] if r["cycles_multiple"] > 0 else float("nan")
        print(f"{name}: sky alone, Cycles single {r['cycles_single']:.5f} full {r['cycles_full']:.5f} "
              f"multiple {r['cycles_multiple']:.5f}; ours combined {r['ours_combined']:.5f} "
              f"multiple {r['ours_multiple']:.5f} = {ratio:.3f}x", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
