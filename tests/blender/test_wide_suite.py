"""The wide suite (``shared/scenes/p_*``) held to bounds measured on it, at a cheap setting:
half the references' resolution (scored against them box-downsampled, metrics.compare), a few
samples, a twentieth of the default traced paths, seed 0.  One scene of every kind: lights inside mesh and VDB media (point, spot,
area), world fog with lamps, haze and a dense slab over a ground, backlit media, dense and
negatively anisotropic spheres, overlapping and mixed volumes, a third-party VDB, a chromatic
medium.  The bounds are our measurement at this setting plus 15 % (and 0.01 for the noise of
so few samples), set again with each change of the model (docs/accuracy.md has the default
setting's figures); they catch a regression, they are not the issue's targets.
``p_glowing_smoke`` (emission that lights the smoke and the ground) and ``p_noise_cloud`` (a
density from shader textures) are held too; the six original scenes are
tests/blender/test_accuracy.py's."""
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render import metrics  # noqa: E402
from mpp_render.blender import batch, frame  # noqa: E402
from mpp_render.exr import read_passes  # noqa: E402

PERCENT = 50
SAMPLES = {"single": 4, "full": 2}
PATHS = 150_000   # multiple scattering's traced paths per light (a twentieth of the default)
# rel_rmse_4 measured at this setting (tests/blender/test_wide_suite.py, seed 0), x 1.15 + 0.01.
# The full renders' bounds were set again when multiple scattering became traced paths
# (docs/method.md 9.9; measured before -> after: p_point_in_plume 15.4 -> 0.887,
# p_point_in_cube 0.926 -> 0.126, p_backlit_slab 0.510 -> 0.135, p_backlit_vdb 0.189 -> 0.078,
# p_sphere_thick 0.288 -> 0.144, p_area_in_box 0.233 -> 0.180, p_chromatic_box 0.133 ->
# 0.112, p_sphere_gneg 0.116 -> 0.084, p_vdb_and_fogbox 0.037 -> 0.027 down; p_spot_in_fogbox
# 0.029 -> 0.116 (its floor_4 0.069), p_dragon 0.063 -> 0.068, p_overlap 0.103 -> 0.116,
# p_fog_point 0.151 -> 0.172, p_fog_area 0.225 -> 0.245 up: the paths' noise at this setting,
# and the world fog traced inside its box only).  All set again (2026-11-25) when each pixel
# began to draw its own sample offsets (tiles.pixel_offsets; a tile's pixels had shared them,
# so at 2-4 spp whole rows erred together), rectangular lamps were sampled in their solid
# angle, and emission began to light the media: 29 of the 34 bounds went down (p_area_in_box
# single 0.192 -> 0.062, p_fog_area full 0.292 -> 0.047, p_point_in_plume full 1.031 ->
# 0.265), p_sphere_thick's and p_sphere_gneg's single stayed, p_overlap single 0.017 -> 0.018,
# p_haze_sun_ground full 0.144 -> 0.149 and p_spot_in_fogbox full 0.143 -> 0.175 (its
# references' floor_4 0.069) went up with the new draw of our noise; p_glowing_smoke and
# p_noise_cloud joined.  p_dragon (0.075, 0.080) -> (0.017, 0.072) when a Volume object's
# render space 'Object' began to scale its coefficients by 1 / the object's scale, as Cycles
# does (measured 0.0059 / 0.0541; the dragon is scaled by 0.5).  Full bounds lowered when a
# first scattering's path start began to follow the voxels' source within its lattice point's
# tent (paths.start_positions; a bound the new measurement would raise was kept):
# p_area_in_box 0.105 -> 0.103; p_backlit_slab 0.126 -> 0.122; p_backlit_vdb 0.073 -> 0.056;
# p_chromatic_box 0.061 -> 0.059; p_dragon 0.072 -> 0.056; p_fog_point 0.049 -> 0.047;
# p_noise_cloud 0.026 -> 0.024; p_slab_over_ground 0.133 -> 0.132; p_sphere_thick 0.176 ->
# 0.153; p_spot_in_fogbox 0.175 -> 0.150.  Lowered when the surfaces' gathers began to read
# the traced paths' moments towards the surface and the world fog beyond its grid
# (march.MarchContext.for_gathers, tiles.FrameMarch.fog_tail; measured single / full):
# p_fog_area 0.0061 / 0.0203, p_fog_point 0.0159 / 0.0273, p_haze_sun_ground 0.1014 /
# 0.1163, p_slab_over_ground full 0.0554 (the ground under the slab had 20-40 % too little of
# the slab's multiple scattering: the gathers read it towards the camera).  p_point_in_plume
# (0.301, 0.265) -> (0.158, 0.223) when a lamp's disc points began to get their own optical
# depth near it in uneven media (Tuning.disc_exact; measured 0.1291 / 0.1849).
# p_spot_in_fogbox full 0.150 -> 0.139 when the precompute began to read a spot's disc at a
# jitter per point (lights.point_jitter; measured 0.1125).  Lowered when the paths' lattice
# stopped counting the grid's padding (precompute.lattice.paths_lattice): p_sphere_thick full
# 0.153 -> 0.142, p_spot_in_fogbox full 0.139 -> 0.111 (measured 0.1145, 0.0879).  Lowered
# when the traced paths began to fly through every medium whose box overlaps theirs
# (paths.PathInputs.others): p_overlap full 0.140 -> 0.045, p_vdb_and_fogbox full 0.041 ->
# 0.022 (measured 0.0304, 0.0103).  p_sphere_thick full 0.142 -> 0.099 when a mesh volume's
# paths began to fly through its sharp surface and a dense one's surface voxels to take their
# source from points of their cells (paths.density_at, source.surface_band_source; measured
# 0.0773).  p_glowing_smoke (0.059, 0.104) -> (0.046, 0.087) when the ground's gathers
# began to be drawn towards emitting media too (gathers.Guides.of_emitters; measured 0.0313 /
# 0.0670).  Set again (2026-12-01) where the tiles' pixel samples began to be counter-based
# draws of (tile, pixel, sample) (pixelsamples.py), which redrew this setting's noise: seed 0
# put p_area_in_box single at 0.0787 (0.062 -> 0.101), p_point_in_plume full at 0.2830
# (0.223 -> 0.336) and p_sphere_gneg full at 0.0430 (0.042 -> 0.060); the seeds' spread is
# the same as before (seeds 0-3, before / after: p_area_in_box single 0.047 0.067 0.060
# 0.044 / 0.079 0.032 0.021 0.072, p_point_in_plume full 0.192 0.168 0.274 0.196 / 0.283
# 0.145 0.074 0.216); the other bounds hold and are kept.
# PATHS 100 000 -> 150 000 when the paths began to deposit at half a tentative point per
# lattice spacing (Tuning.path_deposits 0.5; the default paths 2 000 000 -> 3 000 000, the
# same trade): p_spot_in_fogbox full 0.111 -> 0.169 (measured 0.1386).  Its 2 samples' noise
# sets it: seeds 0-5 at the old setting 0.110 0.084 0.125 0.105 0.081 0.090 (seed 2 was past
# the old bound), at the new 0.139 0.094 0.131 0.117 0.076 0.086; at the default setting it
# went 0.028 -> 0.013 (docs/accuracy.md).  The other bounds hold and are kept.
# The full bounds lowered when the traced paths' lattice values moved from their tents'
# centroids to their points (precompute/nodal.py), at the new measurement x 1.15 + 0.01:
# p_area_in_box 0.103 -> 0.075; p_backlit_slab 0.122 -> 0.121; p_dragon 0.056 -> 0.047; p_fog_area
# 0.033 -> 0.031; p_fog_point 0.041 -> 0.040; p_glowing_smoke 0.087 -> 0.086; p_noise_cloud 0.024
# -> 0.023; p_overlap 0.045 -> 0.041; p_point_in_plume 0.336 -> 0.318; p_slab_over_ground 0.074 ->
# 0.065; p_sphere_gneg 0.060 -> 0.055; p_sphere_thick 0.099 -> 0.068; p_vdb_and_fogbox 0.022 ->
# 0.019; the others hold and are kept.  Lowered again when the world fog's far box took the
# setting's resolution and its tents' mass above the ground (method.md §7): p_fog_area
# 0.031 -> 0.020, p_fog_point 0.040 -> 0.036.  And when an area light's first scatterings
# took the depth of its emitter's points, not its centre's (lights.area_transmittance):
# p_area_in_box 0.075 -> 0.051.  Set again (2026-12-05) for the scenes whose surfaces'
# light changed (two surface bounces reading the volumes' light, the ground's and the sky's
# light out to 64 bounding radii; method.md §8, §9.8), measured single / full: p_fog_point
# 0.0104 / 0.0214 (0.028 -> 0.022, 0.036 -> 0.035), p_glowing_smoke full 0.0653 (0.086 ->
# 0.085); p_haze_sun_ground 0.1013 / 0.1348, p_slab_over_ground full 0.0595 hold and keep
# theirs (p_haze_sun_ground's against its reference's coplanar artefact, method.md §10).
BOUND = {  # scene: (single, full)
    "p_area_in_box": (0.101, 0.051),
    "p_backlit_slab": (0.079, 0.121),
    "p_backlit_vdb": (0.024, 0.056),
    "p_chromatic_box": (0.024, 0.059),
    "p_dragon": (0.017, 0.047),
    "p_fog_area": (0.017, 0.020),
    "p_fog_point": (0.022, 0.035),
    "p_glowing_smoke": (0.046, 0.085),
    "p_haze_sun_ground": (0.127, 0.144),
    "p_noise_cloud": (0.024, 0.023),
    "p_overlap": (0.018, 0.041),
    "p_point_in_cube": (0.075, 0.088),
    "p_point_in_plume": (0.158, 0.318),
    "p_slab_over_ground": (0.035, 0.065),
    "p_sphere_gneg": (0.026, 0.055),
    "p_sphere_thick": (0.036, 0.068),
    "p_spot_in_fogbox": (0.125, 0.169),
    "p_vdb_and_fogbox": (0.012, 0.019),
}
SCENE_NAMES = sorted(BOUND)


def render(scenes_dir, name, mode):
    batch.register()
    bpy.ops.wm.open_mainfile(filepath=str(scenes_dir / name / "scene.blend"))
    sc = bpy.context.scene
    sc.render.resolution_percentage = PERCENT
    batch.set_mpp(sc, SAMPLES[mode], multiple=(mode == "full"), seed=0)
    sc.mpp.multiple_paths = PATHS
    # every pixel takes SAMPLES: the bounds hold the model at a fixed cost (adaptive sampling
    # below 4 samples took none away before its pilot; docs/adaptive.md scores it)
    sc.mpp.noise_threshold = 0.0
    out = frame.render_mpp().output
    return out.passes


def measure(scenes_dir, name, mode):
    passes = render(scenes_dir, name, mode)
    runs = [read_passes(p, names=("Combined",))["Combined"]
            for p in metrics.reference_paths(str(scenes_dir / name), mode == "single")]
    m = metrics.compare(passes["Combined"], runs)
    print(f"{name} {mode}: rel_rmse_4 {m['rel_rmse_4']:.4f} floor_4 {m['floor_4']:.4f} "
          f"bias {m['bias']:+.4f}")
    return m


@pytest.mark.parametrize("mode", ["single", "full"])
@pytest.mark.parametrize("name", SCENE_NAMES)
def test_wide_suite_keeps_its_measured_error(scenes_dir, name, mode):
    m = measure(scenes_dir, name, mode)
    assert not m["failed"], m
    assert m["rel_rmse_4"] <= BOUND[name][mode == "full"], m
