"""benchmarks/gallery.py (the user guide's pictures): its scene builders make scenes our engine
renders, and its picture layout is what the guide shows.  One feature scene, tiny and at
1 spp; the gallery itself is run by hand (it renders Cycles too)."""
import importlib.util
import pathlib

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render.blender import batch, frame  # noqa: E402

GALLERY = pathlib.Path(__file__).resolve().parents[2] / "benchmarks" / "gallery.py"


def load_gallery():
    spec = importlib.util.spec_from_file_location("mpp_gallery", GALLERY)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_fire_scene_renders_every_pass(tmp_path):
    """The fire (a .vdb with density and temperature grids under a sun): every pass finite,
    the radiance passes lit somewhere, the fire in view (Transmittance below 1, Depth hits)."""
    g = load_gallery()
    batch.register()
    sc = g.build_fire(str(tmp_path), 32, 24)
    assert (tmp_path / "gallery_fire.vdb").exists()
    batch.set_mpp(sc, 1, multiple=True, seed=0)
    sc.mpp.multiple_paths = 100_000   # the lamps' and the glow's paths: a tenth of the default
    sc.mpp.voxel_resolution = 32
    # one march step for both renders below: without its glow the smoke would march a whole
    # voxel a step (render.auto_step), and their difference would hold the step's change too
    sc.mpp.step_size = 0.02
    out = frame.render_mpp().output
    assert not out.cancelled and not out.warnings, out.warnings
    p = out.passes
    assert set(p) >= {"Combined", "Volume Single", "Volume Multiple", "Emission",
                      "Transmittance", "Depth"}
    for name, img in p.items():
        assert img.shape[:2] == (24, 32), name
        assert np.all(np.isfinite(img)), name
    for name in ("Combined", "Volume Single", "Volume Multiple", "Emission"):
        assert p[name][..., :3].max() > 0.0, name
    # the fire glows: blackbody emission is red-heavy, and it lights its smoke: without
    # the glow the smoke scatters less, and what the glow adds is red-heavy too
    # (precompute.emissionlight)
    e = p["Emission"].reshape(-1, 3).sum(axis=0)
    assert e[0] > e[2]
    for mat in bpy.data.materials:
        for node in (mat.node_tree.nodes if mat.node_tree else []):
            if node.bl_idname == "ShaderNodeVolumePrincipled":
                node.inputs["Blackbody Intensity"].default_value = 0.0
    dark = frame.render_mpp().output.passes
    assert dark["Emission"].max() == 0.0
    glow = (p["Volume Single"][..., :3] - dark["Volume Single"][..., :3]).reshape(-1, 3).sum(0)
    assert glow.min() > 0.0 and glow[0] > 2.0 * glow[2]
    t = p["Transmittance"]
    assert t.min() < 0.9 and t.max() <= 1.0 + 1e-6
    assert np.any(p["Depth"] < 1e9) and np.any(p["Depth"] >= 1e9)

    # the passes strip's layout: 3 columns x 2 rows of panels over a caption strip
    panels = [g.tone(p[n], g.exposure(p["Combined"])) for n in ("Combined", "Emission")]
    panels += [np.clip(t, 0, 1), g.depth_image(p["Depth"])]
    px = g.compose(panels, ["a", "b", "c", "d"], ["one caption line"], columns=3)
    assert px.dtype == np.uint8 and px.shape[1] == 3 * 32 and px.shape[0] > 2 * 24
    # below its label box (the top 18 rows) panel c (row 0, column 2) is the image itself
    expect = (np.clip(panels[2], 0, 1) * 255 + 0.5).astype(np.uint8)
    np.testing.assert_array_equal(px[19:24, 64:96], expect[19:24])


def test_coloured_smoke_scene_colours_each_voxel(tmp_path):
    """The coloured smoke (a .vdb with a vector grid 'color' read by Color Attribute): the
    medium scatters with each voxel's colour (Medium.scatter_grid), orange at the bottom
    and blue at the top, and nothing is warned."""
    from mpp_render.blender.translate import scene_from_depsgraph
    from mpp_render.scene import Settings
    g = load_gallery()
    batch.register()
    g.build_coloured_smoke(str(tmp_path), 32, 18)
    desc = scene_from_depsgraph(bpy.context.evaluated_depsgraph_get(), Settings())
    assert not desc.warnings, desc.warnings
    (m,) = desc.media
    assert m.scatter_grid is not None and m.scatter_grid.shape == m.density.shape + (3,)
    colour = m.scatter_grid * np.asarray(m.sigma_s) / 6.0   # Density 6, Color 1 x the grid
    rho = m.density.astype(np.float64)
    low = (colour[:, :, :12] * rho[:, :, :12, None]).sum((0, 1, 2)) / rho[:, :, :12].sum()
    high = (colour[:, :, -20:] * rho[:, :, -20:, None]).sum((0, 1, 2)) / rho[:, :, -20:].sum()
    np.testing.assert_allclose(low, [1.0, 0.55, 0.15], atol=0.02)
    np.testing.assert_allclose(high, [0.25, 0.5, 1.0], atol=0.02)
