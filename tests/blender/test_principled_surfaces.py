"""Opaque surfaces against Cycles: the Principled BSDF's inputs reach scene.Surface, and three
ground planes (matte dielectric, glossy dielectric, tinted metal) under a point light, a sun
and a grey sky render as Cycles renders them, band by band from grazing to steep views."""
import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render.blender import batch  # noqa: E402
from mpp_render.blender.translate import scene_from_depsgraph  # noqa: E402
from mpp_render.scene import Settings  # noqa: E402

# plane name: (x centre in m, Principled inputs)
PLANES = {
    "matte": (-2.4, {"Base Color": (0.5, 0.5, 0.5, 1), "Roughness": 1.0}),
    "gloss": (0.0, {"Base Color": (0.2, 0.35, 0.6, 1), "Roughness": 0.35,
                    "Specular IOR Level": 0.7}),
    "metal": (2.4, {"Base Color": (0.95, 0.7, 0.35, 1), "Metallic": 1.0, "Roughness": 0.45,
                    "Specular Tint": (1.0, 0.9, 0.8, 1)}),
}
# image columns of each plane's middle, rows in bands of 6 from the far (grazing) edge down
COLUMNS = {"matte": (0, 28), "gloss": (36, 60), "metal": (68, 96)}
BANDS = [(r, r + 6) for r in range(14, 48, 6)]
CYCLES_SPP, OUR_SPP = 256, 16
# Measured (96 x 48 px, 2026-11-23): Cycles' own band means differ by <= 0.08 % between two
# seeds at 256 spp, ours by <= 0.4 % between seeds at 16 spp, and ours against Cycles lie within
# 0.4 % in every band.  1.5 % is four times our noise; the previous model (Lambert + an
# unlayered GGX coat) was 5.5 to 9.7 % too bright on the matte plane, worst at grazing views.
BAND_TOL = 0.015
MEAN_TOL = 0.005


def material(name, inputs, distribution=None):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    for k, v in inputs.items():
        bsdf.inputs[k].default_value = v
    if distribution:
        bsdf.distribution = distribution
    return mat, bsdf


def plane(name, x, mat, scale=(2.4, 12.0, 1.0), z=-1.5):
    bpy.ops.mesh.primitive_plane_add(size=1, location=(x, 2.0, z))
    ob = bpy.context.object
    ob.name = name
    ob.scale = scale
    ob.data.materials.append(mat)
    return ob


def build_scene(sc):
    sc.world.color = (0.05, 0.05, 0.05)
    for name, (x, inputs) in PLANES.items():
        plane(name, x, material(name, inputs)[0])
    pt = bpy.data.lights.new("point", "POINT")
    pt.energy, pt.shadow_soft_size = 800.0, 0.05
    ob = bpy.data.objects.new("point", pt)
    ob.location = (1.6, -1.0, 0.2)
    sc.collection.objects.link(ob)
    sun = bpy.data.lights.new("sun", "SUN")
    sun.energy, sun.angle = 2.0, math.radians(2)
    ob = bpy.data.objects.new("sun", sun)
    ob.rotation_euler = (math.radians(50), 0, math.radians(-30))
    sc.collection.objects.link(ob)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    cam.location = (0, -8, 0.5)
    cam.rotation_euler = (math.radians(78), 0, 0)
    sc.collection.objects.link(cam)
    sc.camera = cam
    sc.render.resolution_x, sc.render.resolution_y = 96, 48
    sc.render.resolution_percentage = 100


def test_planes_render_as_in_cycles(empty_scene, tmp_path):
    batch.register()
    sc = empty_scene
    build_scene(sc)
    batch.set_cycles_reference(sc, CYCLES_SPP, multiple=False, seed=1)
    ref = batch.render_current(sc, str(tmp_path / "cycles.exr"))["_passes"]["Combined"][..., :3]
    batch.set_mpp(sc, OUR_SPP, multiple=False, seed=0)
    rec = batch.render_current(sc, str(tmp_path / "mpp.exr"))
    assert all("no volumes" in w for w in rec["warnings"]), rec["warnings"]
    ours = rec["_passes"]["Combined"][..., :3]
    assert np.all(np.isfinite(ours))
    for name, (c0, c1) in COLUMNS.items():
        ratios = [ours[r0:r1, c0:c1].sum() / ref[r0:r1, c0:c1].sum() for r0, r1 in BANDS]
        print(name, " ".join(f"{q:.4f}" for q in ratios))
        assert np.all(np.abs(np.array(ratios) - 1.0) < BAND_TOL), (name, ratios)
    assert ours.sum() / ref.sum() == pytest.approx(1.0, abs=MEAN_TOL)
    # the bands differ: the test sees grazing and steep views, highlights and plain ground
    band_means = [ref[r0:r1, 36:60].mean() for r0, r1 in BANDS]
    assert max(band_means) > 2.5 * min(band_means)


def test_principled_inputs_reach_the_surface(empty_scene):
    mat, bsdf = material("Paint", {"Base Color": (0.9, 0.5, 0.1, 1), "Metallic": 0.25,
                                   "Roughness": 0.6, "IOR": 1.33, "Specular IOR Level": 0.25,
                                   "Specular Tint": (1.0, 0.5, 0.5, 1), "Coat Weight": 0.5,
                                   "Coat Roughness": 0.1, "Coat IOR": 1.6,
                                   "Coat Tint": (0.8, 0.9, 1.0, 1), "Diffuse Roughness": 0.3,
                                   "Emission Color": (1, 1, 0, 1), "Emission Strength": 2.0},
                            distribution="GGX")
    plane("P", 0.0, mat)
    desc = scene_from_depsgraph(bpy.context.evaluated_depsgraph_get(), Settings())
    (s,) = desc.surfaces
    assert not [w for w in desc.warnings if "'P'" in w]
    np.testing.assert_allclose(s.base_color, [0.9, 0.5, 0.1], rtol=1e-6)
    assert s.specular == pytest.approx(((0.33 / 2.33) ** 2) * 2 * 0.25, rel=1e-5)
    assert (s.metallic, s.roughness) == (pytest.approx(0.25), pytest.approx(0.6))
    np.testing.assert_allclose(s.specular_tint, [1.0, 0.5, 0.5], rtol=1e-6)
    assert (s.coat_weight, s.coat_roughness, s.coat_ior) == (
        pytest.approx(0.5), pytest.approx(0.1), pytest.approx(1.6))
    np.testing.assert_allclose(s.coat_tint, [0.8, 0.9, 1.0], rtol=1e-6)
    assert s.diffuse_roughness == pytest.approx(0.3)
    assert s.multiscatter is False and s.weight == 1.0
    np.testing.assert_allclose(s.emission, [2, 2, 0], rtol=1e-6)


def test_left_out_inputs_and_mixes_warn(empty_scene):
    mat, bsdf = material("Velvet", {"Sheen Weight": 0.5, "Transmission Weight": 0.2})
    plane("A", 0.0, mat)
    mix_mat = bpy.data.materials.new("Mixed")
    mix_mat.use_nodes = True
    nt = mix_mat.node_tree
    principled = nt.nodes["Principled BSDF"]
    principled.inputs["Base Color"].default_value = (1, 0, 0, 1)
    principled.inputs["Roughness"].default_value = 0.2
    diffuse = nt.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (0, 0, 1, 1)
    mix = nt.nodes.new("ShaderNodeMixShader")
    mix.inputs[0].default_value = 0.25
    nt.links.new(principled.outputs[0], mix.inputs[1])
    nt.links.new(diffuse.outputs[0], mix.inputs[2])
    nt.links.new(mix.outputs[0], nt.get_output_node("CYCLES").inputs["Surface"])
    plane("B", 6.0, mix_mat)
    desc = scene_from_depsgraph(bpy.context.evaluated_depsgraph_get(), Settings())
    surf = {s.name: s for s in desc.surfaces}
    lost = [w for w in desc.warnings if "'Velvet'" in w]
    assert len(lost) == 1 and "sheen" in lost[0] and "transmission" in lost[0]
    assert any("'Mixed'" in w and "2 surface BSDFs are mixed" in w for w in desc.warnings)
    b = surf["B"]
    np.testing.assert_allclose(b.base_color, [0.75, 0, 0.25], rtol=1e-6)
    assert b.specular == pytest.approx(0.75 * 0.04, rel=1e-4)   # the Diffuse BSDF has none
    assert b.roughness == pytest.approx(0.2)                    # only the Principled has one
