"""What Cycles renders round a lamp with a radius inside a medium, with its MIS on and off.

    .venv/bin/python benchmarks/cycles_lamp_mis.py [--samples 1024] [--seeds 2] [--cases plume,cube]

A point light with a radius is Cycles' soft-falloff lamp: a disc facing the shading point
(kernel/light/point.h).  Its light reaches a volume scattering vertex two ways, by next-event
estimation (a point drawn on the disc) and by the phase-sampled ray that hits the disc; with
the light's *Multiple Importance* on (Blender's default, and the suite's references) the two
are weighted by the power heuristic, with it off only the first is used.  Both estimate the
same integral, so the two renders should agree.  This renders, per case:

* Cycles' single scattering (Volume Bounces 0) and full render with the lamp's Multiple
  Importance on, then off (``light.cycles.use_multiple_importance_sampling``), ``--seeds``
  seeds each at ``--samples`` spp;
* ours at the defaults (16 spp);

and prints each one's multiple scattering (full minus single, image means) and our full
render's rel_rmse_4 / bias against either Cycles.

Cases: ``plume`` is p_point_in_plume as it is (a 0.3 m, 150 W lamp in a VDB plume of density
6, albedo 0.8, g 0.4); ``cube`` is p_point_in_cube with density 6, albedo 1, g 0, the lamp's
radius 0.3 m and the world black (a lamp deep in a dense cube: only multiply scattered light
leaves it).

What it showed (2026-11-28, 1024 spp, two seeds, 2 cores, 5 minutes in all): on the plume
Cycles' multiple scattering is 0.01828 with the lamp's MIS on and 0.01981 with it off (full
render per seed 0.04841 / 0.04855 and 0.05009 / 0.04988); ours 0.01945, 1.064x the first and
0.982x the second; the single scattering 0.03019 / 0.03018 / ours 0.02999.  In the dense
cube 0.02970 / 0.03485 / ours 0.03511 (1.182x and 1.008x); our full render's rel_rmse_4 is
0.469 against Cycles' default and 0.034 (floor_4 0.085, bias +0.008) against it without MIS.
With Cycles' light tree off (MIS on) the plume's is 0.01794, so the tree is not the cause.
So Cycles' default render loses 7-15 % of the multiply scattered light of a lamp with a radius
inside a medium (the more, the denser and whiter the medium) against its own render without
MIS, and ours follows the latter within 2 %.  Round the plume's lamp that difference is
p_point_in_plume's error (docs/method.md section 10).  Cycles without MIS is noisier
(next-event estimation alone meets the lamp's disc at grazing angles; one seed of a denser
plume came out 2x the other): compare the seeds before trusting one.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
os.environ["MPP_CACHE_MB"] = "0"
sys.path.insert(0, REPO)

SCENES = os.environ.get("MPP_SCENES") or os.path.join(os.path.dirname(REPO), "shared", "scenes")
CASES = ("plume", "cube")


def _open(case: str):
    """Open the case's scene and set it up (module docstring); returns the scene."""
    import bpy
    from mpp_render.blender import batch
    name = "p_point_in_plume" if case == "plume" else "p_point_in_cube"
    sc = batch.open_blend(os.path.join(SCENES, name, "scene.blend"))
    if case == "cube":
        for mat in bpy.data.materials:
            for node in (mat.node_tree.nodes if mat.node_tree else []):
                if node.type == "PRINCIPLED_VOLUME":
                    node.inputs["Density"].default_value = 6.0
                    node.inputs["Anisotropy"].default_value = 0.0
                    node.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
                    node.inputs["Absorption Color"].default_value = (0.0, 0.0, 0.0, 1.0)
        for node in sc.world.node_tree.nodes:
            if node.type == "BACKGROUND":
                node.inputs["Strength"].default_value = 0.0
        for ob in sc.objects:
            if ob.type == "LIGHT" and ob.data.type == "POINT":
                ob.data.shadow_soft_size = 0.3
    return sc


def cycles(case: str, samples: int, seed: int, multiple: bool, mis: bool, out: str):
    """Cycles' Combined (H, W, 3) of ``case``."""
    from mpp_render.blender import batch
    sc = _open(case)
    batch.set_cycles_reference(sc, samples, multiple=multiple, seed=seed)
    for ob in sc.objects:
        if ob.type == "LIGHT":
            ob.data.cycles.use_multiple_importance_sampling = mis
    return batch.render_current(sc, out)["_passes"]["Combined"][..., :3]


def ours(case: str, out: str):
    """Our Combined and Volume Multiple (H, W, 3) of ``case`` at the defaults, 16 spp."""
    from mpp_render.blender import batch
    sc = _open(case)
    batch.set_mpp(sc, 16, multiple=True)
    rec = batch.render_current(sc, out)
    return rec["_passes"]["Combined"][..., :3], rec["_passes"]["Volume Multiple"][..., :3]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=1024)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--cases", default=",".join(CASES))
    args = ap.parse_args(argv)
    if args.seeds < 2:
        ap.error("--seeds must be at least 2: the metric takes the references' noise from them")
    from mpp_render import metrics
    tmp = tempfile.mkdtemp(prefix="lamp_mis_")
    for case in args.cases.split(","):
        seeds = range(1, args.seeds + 1)
        single = {mis: np.mean([cycles(case, args.samples, s, False, mis,
                                       os.path.join(tmp, f"{case}_ss_{mis}_{s}.exr"))
                                for s in seeds], axis=0) for mis in (True, False)}
        full = {mis: [cycles(case, args.samples, s, True, mis,
                             os.path.join(tmp, f"{case}_full_{mis}_{s}.exr")) for s in seeds]
                for mis in (True, False)}
        mine, mine_ms = ours(case, os.path.join(tmp, f"{case}_ours.exr"))
        print(f"{case}: single scattering, Cycles MIS on {single[True].mean():.5f}, "
              f"off {single[False].mean():.5f}, ours {float((mine - mine_ms).mean()):.5f}")
        for mis in (True, False):
            ms = np.mean(full[mis], axis=0) - single[mis]
            per_seed = ", ".join(f"{float(r.mean()):.5f}" for r in full[mis])
            m = metrics.compare(mine, full[mis])
            print(f"{case}: Cycles MIS {'on ' if mis else 'off'}: multiple scattering "
                  f"{float(ms.mean()):.5f} (full per seed {per_seed}); ours "
                  f"{float(mine_ms.mean()):.5f} = {float(mine_ms.mean() / ms.mean()):.3f}x; "
                  f"our full render rel_rmse_4 {m['rel_rmse_4']:.4f} (floor_4 "
                  f"{m['floor_4']:.4f}), bias {m['bias']:+.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
