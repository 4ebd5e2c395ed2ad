"""Depsgraph -> SceneDescription: lights, volume/surface materials, meshes, VDBs, world,
camera and the public scenes, checked against Cycles' formulas."""
import dataclasses
import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render.blender.translate import scene_from_depsgraph  # noqa: E402
from mpp_render.blender.translate.vdb import openvdb_module  # noqa: E402
from mpp_render.camera import primary_rays  # noqa: E402
from mpp_render.scene import Settings  # noqa: E402

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


# -- helpers ------------------------------------------------------------------------------

def translate(resolution=16, **kw):
    return scene_from_depsgraph(bpy.context.evaluated_depsgraph_get(),
                                Settings(voxel_resolution=resolution), **kw)


def link(ob):
    bpy.context.scene.collection.objects.link(ob)
    return ob


def cube(name="Cube", location=(0, 0, 0), scale=(1, 1, 1), rotation=(0, 0, 0), material=None,
         half=1.0):
    """A closed cube of half size ``half`` built from data (no operators)."""
    h = half
    verts = [(x, y, z) for x in (-h, h) for y in (-h, h) for z in (-h, h)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    ob = link(bpy.data.objects.new(name, me))
    ob.location, ob.scale, ob.rotation_euler = location, scale, rotation
    if material is not None:
        me.materials.append(material)
    return ob


def material(name="Mat"):
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    for n in list(nt.nodes):
        if n.bl_idname != "ShaderNodeOutputMaterial":
            nt.nodes.remove(n)
    return mat, nt, nt.get_output_node("CYCLES")


def volume_material(kind, name="Vol", **inputs):
    """A material whose Volume output is one node of ``kind`` with ``inputs`` set."""
    mat, nt, out = material(name)
    node = nt.nodes.new(kind)
    for k, v in inputs.items():
        node.inputs[k].default_value = v
    nt.links.new(node.outputs[0], out.inputs["Volume"])
    return mat, nt, node


def only_medium(desc):
    assert len(desc.media) == 1, desc.media
    return desc.media[0]


def rgb(*c):
    return np.array(c, dtype=np.float64)


def principled(color, density, absorption):
    c, a = np.asarray(color), np.sqrt(np.asarray(absorption))
    return c * density, np.maximum(1 - c, 0) * np.maximum(1 - a, 0) * density


# -- lights -------------------------------------------------------------------------------

def add_light(kind, name, location=(0, 0, 0), rotation=(0, 0, 0), **props):
    data = bpy.data.lights.new(name, kind)
    for k, v in props.items():
        setattr(data, k, v)
    ob = link(bpy.data.objects.new(name, data))
    ob.location, ob.rotation_euler = location, rotation
    return ob


def test_every_light_type(empty_scene):
    add_light("POINT", "pt", (1, 2, 3), energy=100.0, color=(1, 0.5, 0.25), shadow_soft_size=0.3)
    add_light("SPOT", "sp", (0, 0, 5), (0.3, 0, 0), energy=50.0, spot_size=0.5, spot_blend=0.2,
              shadow_soft_size=0.1, exposure=1.5)
    add_light("SUN", "sun", (0, 0, 9), (0.4, 0.2, 0), energy=3.0, angle=0.05)
    add_light("AREA", "ar", (0, 1, 0), energy=20.0, shape="RECTANGLE", size=2.0, size_y=0.5,
              normalize=False)
    add_light("AREA", "disk", energy=5.0, shape="DISK", size=0.7)
    warm = add_light("POINT", "warm", energy=10.0, color=(0.9, 0.9, 1.0), use_temperature=True,
                     temperature=3000.0, exposure=-1.0)
    desc = translate()
    lights = {lt.name: lt for lt in desc.lights}
    assert set(lights) == {"pt", "sp", "sun", "ar", "disk", "warm"}

    pt = lights["pt"]
    assert pt.kind == "POINT" and pt.radius == pytest.approx(0.3)
    np.testing.assert_allclose(pt.strength, [100, 50, 25], rtol=1e-6)
    np.testing.assert_allclose(pt.position, [1, 2, 3], atol=1e-6)

    sp = lights["sp"]
    np.testing.assert_allclose(sp.strength, 50 * 2 ** 1.5 * np.ones(3), rtol=1e-6)
    assert sp.spot_size == pytest.approx(0.5) and sp.spot_blend == pytest.approx(0.2)
    assert sp.radius == pytest.approx(0.1)
    mw = np.array(bpy.data.objects["sp"].matrix_world)
    np.testing.assert_allclose(sp.direction, -mw[:3, 2] / np.linalg.norm(mw[:3, 2]), atol=1e-6)
    np.testing.assert_allclose(sp.direction, [0, math.sin(0.3), -math.cos(0.3)], atol=1e-6)
    np.testing.assert_allclose(sp.matrix, mw, atol=1e-6)

    sun = lights["sun"]
    np.testing.assert_allclose(sun.strength, [3, 3, 3], rtol=1e-6)
    assert sun.angle == pytest.approx(0.05)
    assert np.linalg.norm(sun.direction) == pytest.approx(1.0)

    ar = lights["ar"]
    assert (ar.shape, ar.size_x, ar.size_y, ar.normalize) == ("RECTANGLE", 2.0, 0.5, False)
    disk = lights["disk"]
    assert (disk.shape, disk.size_x, disk.size_y, disk.normalize) == ("DISK", pytest.approx(0.7),
                                                                      pytest.approx(0.7), True)

    tc = np.array(bpy.data.lights["warm"].temperature_color)
    assert tc[0] > tc[2]  # 3000 K is reddish, so the colour really enters
    np.testing.assert_allclose(lights["warm"].strength, rgb(0.9, 0.9, 1.0) * tc * 10 * 0.5,
                               rtol=1e-6)
    assert warm.data.use_temperature
    assert desc.warnings == ["the scene has no camera; rendering from the origin looking down -Z"]


def test_light_node_strength_and_unsupported_spread(empty_scene):
    ob = add_light("AREA", "soft", energy=10.0, spread=0.5)
    ob.data.use_nodes = True
    emission = next(n for n in ob.data.node_tree.nodes if n.bl_idname == "ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 3.0
    emission.inputs["Color"].default_value = (1.0, 0.5, 0.5, 1.0)
    desc = translate()
    np.testing.assert_allclose(desc.lights[0].strength, [30, 15, 15], rtol=1e-6)
    assert any("'soft'" in w and "spread" in w for w in desc.warnings)


# -- volume materials ---------------------------------------------------------------------

def test_principled_volume_coefficients(empty_scene):
    mat, nt, node = volume_material(
        "ShaderNodeVolumePrincipled", **{"Color": (0.9, 0.5, 0.2, 1), "Density": 3.0,
                                         "Absorption Color": (0.25, 0.5, 1.0, 1),
                                         "Anisotropy": 0.4, "Emission Strength": 2.0,
                                         "Emission Color": (1.0, 0.5, 0.0, 1)})
    cube(material=mat)
    m = only_medium(translate())
    s, a = principled([0.9, 0.5, 0.2], 3.0, [0.25, 0.5, 1.0])
    np.testing.assert_allclose(m.sigma_s, s, rtol=1e-6)
    np.testing.assert_allclose(m.sigma_a, a, rtol=1e-6, atol=1e-7)
    assert m.g == pytest.approx(0.4)
    np.testing.assert_allclose(m.emission, [2.0, 1.0, 0.0], rtol=1e-6)
    assert m.source == "MESH" and m.name == "Cube"


def test_scatter_plus_absorption(empty_scene):
    mat, nt, out = material()
    sc = nt.nodes.new("ShaderNodeVolumeScatter")
    sc.inputs["Color"].default_value = (0.8, 0.6, 0.4, 1)
    sc.inputs["Density"].default_value = 2.0
    sc.inputs["Anisotropy"].default_value = 0.7
    ab = nt.nodes.new("ShaderNodeVolumeAbsorption")
    ab.inputs["Color"].default_value = (0.5, 0.25, 1.0, 1)
    ab.inputs["Density"].default_value = 4.0
    add = nt.nodes.new("ShaderNodeAddShader")
    nt.links.new(sc.outputs[0], add.inputs[0])
    nt.links.new(ab.outputs[0], add.inputs[1])
    nt.links.new(add.outputs[0], out.inputs["Volume"])
    cube(material=mat)
    m = only_medium(translate())
    np.testing.assert_allclose(m.sigma_s, [1.6, 1.2, 0.8], rtol=1e-6)
    np.testing.assert_allclose(m.sigma_a, [2.0, 3.0, 0.0], rtol=1e-6, atol=1e-7)
    assert m.g == pytest.approx(0.7)  # absorption has no sigma_s, so no say in g


def test_mix_shader_weights_and_anisotropy(empty_scene):
    mat, nt, out = material()
    s1 = nt.nodes.new("ShaderNodeVolumeScatter")
    s1.inputs["Color"].default_value = (1, 1, 1, 1)
    s1.inputs["Density"].default_value = 2.0
    s1.inputs["Anisotropy"].default_value = 0.6
    s2 = nt.nodes.new("ShaderNodeVolumeScatter")
    s2.inputs["Color"].default_value = (0.5, 0.5, 0.5, 1)
    s2.inputs["Density"].default_value = 4.0
    s2.inputs["Anisotropy"].default_value = -0.2
    mix = nt.nodes.new("ShaderNodeMixShader")
    mix.inputs[0].default_value = 0.25
    nt.links.new(s1.outputs[0], mix.inputs[1])
    nt.links.new(s2.outputs[0], mix.inputs[2])
    reroute = nt.nodes.new("NodeReroute")
    nt.links.new(mix.outputs[0], reroute.inputs[0])
    nt.links.new(reroute.outputs[0], out.inputs["Volume"])
    cube(material=mat)
    m = only_medium(translate())
    w1, w2 = 0.75 * 2.0, 0.25 * 0.5 * 4.0          # weighted mean sigma_s of each closure
    np.testing.assert_allclose(m.sigma_s, np.full(3, w1 + w2), rtol=1e-6)
    assert m.g == pytest.approx((w1 * 0.6 + w2 * -0.2) / (w1 + w2))


def test_volume_coefficients_node(empty_scene):
    mat, nt, node = volume_material(
        "ShaderNodeVolumeCoefficients", **{"Absorption Coefficients": (0.1, 0.2, 0.3),
                                           "Scatter Coefficients": (4.0, 5.0, 6.0),
                                           "Anisotropy": -0.3,
                                           "Emission Coefficients": (0.0, 1.0, 2.0)})
    cube(material=mat)
    m = only_medium(translate())
    np.testing.assert_allclose(m.sigma_a, [0.1, 0.2, 0.3], rtol=1e-6)
    np.testing.assert_allclose(m.sigma_s, [4, 5, 6], rtol=1e-6)
    np.testing.assert_allclose(m.emission, [0, 1, 2], rtol=1e-6)
    assert m.g == pytest.approx(-0.3)


def test_node_group_with_group_input_and_constant_nodes(empty_scene):
    ng = bpy.data.node_groups.new("Fog", "ShaderNodeTree")
    ng.interface.new_socket("Volume", in_out="OUTPUT", socket_type="NodeSocketShader")
    ng.interface.new_socket("Dens", in_out="INPUT", socket_type="NodeSocketFloat")
    gi, go = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    sc = ng.nodes.new("ShaderNodeVolumeScatter")
    colour = ng.nodes.new("ShaderNodeRGB")
    colour.outputs[0].default_value = (0.2, 0.4, 0.6, 1)
    ng.links.new(gi.outputs[0], sc.inputs["Density"])
    ng.links.new(colour.outputs[0], sc.inputs["Color"])
    ng.links.new(sc.outputs[0], go.inputs[0])
    mat, nt, out = material()
    group = nt.nodes.new("ShaderNodeGroup")
    group.node_tree = ng
    value = nt.nodes.new("ShaderNodeValue")
    value.outputs[0].default_value = 2.5
    nt.links.new(value.outputs[0], group.inputs[0])
    nt.links.new(group.outputs[0], out.inputs["Volume"])
    cube(material=mat)
    desc = translate()
    m = only_medium(desc)
    np.testing.assert_allclose(m.sigma_s, [0.5, 1.0, 1.5], rtol=1e-6)
    assert all("camera" in w for w in desc.warnings)
    nt.links.remove(group.inputs[0].links[0])          # now the group node's own value
    group.inputs[0].default_value = 4.0
    np.testing.assert_allclose(only_medium(translate()).sigma_s, [0.8, 1.6, 2.4], rtol=1e-6)


def test_texture_in_density_warns_and_keeps_the_rest(empty_scene):
    mat, nt, node = volume_material("ShaderNodeVolumePrincipled", "Smoky",
                                    **{"Color": (0.5, 0.5, 0.5, 1), "Density": 2.0})
    noise = nt.nodes.new("ShaderNodeTexBrick")   # a texture the node graphs do not evaluate
    noise.name = "My Noise"
    nt.links.new(noise.outputs["Fac"], node.inputs["Density"])
    cube("Box", material=mat)
    add_light("SUN", "sun", energy=2.0)
    desc = translate()
    m = only_medium(desc)
    np.testing.assert_allclose(m.sigma_s, [1, 1, 1], rtol=1e-6)   # the socket's own value, 2
    assert len(desc.lights) == 1
    msg = [w for w in desc.warnings if "My Noise" in w]
    assert len(msg) == 1
    assert "ShaderNodeTexBrick" in msg[0] and "'Smoky'" in msg[0] and "'Density'" in msg[0]
    assert "'Box'" in msg[0]


def test_unknown_volume_shader_and_phase_are_warned(empty_scene):
    mat, nt, out = material("Odd")
    diffuse = nt.nodes.new("ShaderNodeBsdfDiffuse")
    sc = nt.nodes.new("ShaderNodeVolumeScatter")
    sc.phase = "RAYLEIGH"
    add = nt.nodes.new("ShaderNodeAddShader")
    nt.links.new(diffuse.outputs[0], add.inputs[0])
    nt.links.new(sc.outputs[0], add.inputs[1])
    nt.links.new(add.outputs[0], out.inputs["Volume"])
    cube(material=mat)
    desc = translate()
    m = only_medium(desc)
    np.testing.assert_allclose(m.sigma_s, [0.8, 0.8, 0.8], rtol=1e-6)
    assert m.g == 0.0
    assert any("Diffuse BSDF" in w and "not a supported volume shader" in w for w in desc.warnings)
    assert any("RAYLEIGH" in w for w in desc.warnings)


# -- meshes -------------------------------------------------------------------------------

def test_cube_voxelisation_interior_and_bounds(empty_scene):
    mat, _, _ = volume_material("ShaderNodeVolumeScatter")
    cube(location=(1, 2, 3), scale=(2, 1, 1), material=mat)
    m = only_medium(translate(resolution=32))
    assert m.density.shape == (32, 16, 16) and m.density.dtype == np.float32
    assert np.all(m.density == 1.0)           # every voxel centre is inside the box
    h = 4.0 / 32
    first = m.index_to_world @ [0, 0, 0, 1]
    last = m.index_to_world @ [31, 15, 15, 1]
    np.testing.assert_allclose(first[:3], [-1 + h / 2, 1 + h / 2, 2 + h / 2], atol=1e-9)
    np.testing.assert_allclose(last[:3], [3 - h / 2, 3 - h / 2, 4 - h / 2], atol=1e-9)


def test_sphere_voxelisation_volume_and_rotated_box(empty_scene):
    mat, _, _ = volume_material("ShaderNodeVolumeScatter")
    bpy.ops.mesh.primitive_uv_sphere_add(segments=48, ring_count=24, radius=1.5,
                                         location=(0, 0, 5))
    bpy.context.object.data.materials.append(mat)
    box = cube("Box", rotation=(0.3, 0.5, 0.7), material=mat, half=0.5)
    desc = translate(resolution=48)
    media = {m.name: m for m in desc.media}
    sph = media["Sphere"]
    voxel = abs(np.linalg.det(sph.index_to_world[:3, :3]))
    assert sph.density.sum() * voxel == pytest.approx(4 / 3 * math.pi * 1.5 ** 3, rel=0.03)
    centre = sph.index_to_world @ [*(np.array(sph.density.shape) - 1) / 2, 1]
    np.testing.assert_allclose(centre[:3], [0, 0, 5], atol=1e-6)
    # the rotated box is voxelised in its own frame: every voxel centre maps into the box
    b = media["Box"]
    assert np.all(b.density == 1)
    ijk = np.stack(np.meshgrid(*[np.arange(n) for n in b.density.shape], indexing="ij"), -1)
    pts = ijk.reshape(-1, 3) @ b.index_to_world[:3, :3].T + b.index_to_world[:3, 3]
    local = (pts - np.array(box.location)) @ np.array(box.matrix_world.to_3x3())
    assert np.abs(local).max() < 0.5


def test_open_and_flat_volume_meshes_warn(empty_scene):
    mat, _, _ = volume_material("ShaderNodeVolumeScatter")
    open_box = cube("OpenBox", material=mat)
    bm_faces = [tuple(p.vertices) for p in open_box.data.polygons][1:]
    me = bpy.data.meshes.new("open")
    me.from_pydata([tuple(v.co) for v in open_box.data.vertices], [], bm_faces)
    me.materials.append(mat)
    open_box.data = me
    bpy.ops.mesh.primitive_plane_add()
    bpy.context.object.data.materials.append(mat)
    desc = translate()
    assert any("'OpenBox'" in w and "not closed" in w for w in desc.warnings)
    assert any("'Plane'" in w and "flat" in w for w in desc.warnings)
    assert [m.name for m in desc.media] == ["OpenBox"]


def test_opaque_surfaces(empty_scene):
    mat, nt, out = material("Paint")
    bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.inputs["Base Color"].default_value = (0.1, 0.2, 0.3, 1)
    bsdf.inputs["Emission Color"].default_value = (1, 0.5, 0, 1)
    bsdf.inputs["Emission Strength"].default_value = 4.0
    nt.links.new(bsdf.outputs[0], out.inputs["Surface"])
    cube("Painted", location=(0, 0, 2), scale=(2, 1, 1), material=mat)
    cube("Bare")
    dmat, dnt, dout = material("Matte")
    diffuse = dnt.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (0.3, 0.6, 0.9, 1)
    dnt.links.new(diffuse.outputs[0], dout.inputs["Surface"])
    two = cube("Two", material=mat)
    two.data.materials.append(dmat)
    two.data.polygons[0].material_index = 1
    desc = translate()
    surf = {s.name: s for s in desc.surfaces}
    assert set(surf) == {"Painted", "Bare", "Two [Paint]", "Two [Matte]"}
    assert not desc.media
    p = surf["Painted"]
    assert p.vertices.dtype == np.float64 and p.triangles.dtype == np.int64
    assert p.triangles.shape == (12, 3)
    np.testing.assert_allclose(p.vertices.min(0), [-2, -1, 1])
    np.testing.assert_allclose(p.vertices.max(0), [2, 1, 3])
    np.testing.assert_allclose(p.base_color, [0.1, 0.2, 0.3], rtol=1e-6)
    np.testing.assert_allclose(p.emission, [4, 2, 0], rtol=1e-6)
    np.testing.assert_allclose(surf["Bare"].base_color, [0.8, 0.8, 0.8])
    assert surf["Two [Matte]"].triangles.shape == (2, 3)
    assert surf["Two [Paint]"].triangles.shape == (10, 3)
    np.testing.assert_allclose(surf["Two [Matte]"].base_color, [0.3, 0.6, 0.9], rtol=1e-6)
    assert surf["Two [Matte]"].triangles.max() < len(surf["Two [Matte]"].vertices)


def test_collection_instances(empty_scene):
    coll = bpy.data.collections.new("Kit")
    light = bpy.data.objects.new("lamp", bpy.data.lights.new("lamp", "POINT"))
    light.location = (0, 0, 1)
    coll.objects.link(light)
    mat, _, _ = volume_material("ShaderNodeVolumeScatter")
    me = cube("Puff", material=mat, half=0.5)
    bpy.context.scene.collection.objects.unlink(me)
    coll.objects.link(me)
    for i, x in enumerate((-3.0, 3.0)):
        e = link(bpy.data.objects.new(f"inst{i}", None))
        e.instance_type, e.instance_collection, e.location = "COLLECTION", coll, (x, 0, 0)
    desc = translate(resolution=8)
    xs = sorted(lt.position[0] for lt in desc.lights)
    assert xs == pytest.approx([-3.0, 3.0])
    assert sorted(lt.position[2] for lt in desc.lights) == pytest.approx([1, 1])
    assert len(desc.media) == 2
    assert desc.media[0].density is desc.media[1].density   # one voxelisation for both
    centres = sorted((m.index_to_world @ [3.5, 3.5, 3.5, 1])[0] for m in desc.media)
    assert centres == pytest.approx([-3.0, 3.0])


# -- VDB volumes --------------------------------------------------------------------------

@pytest.fixture
def vdb_file(tmp_path):
    """A 4 x 3 x 2 float grid 'density' at voxel size 0.1 starting at ijk (10, 0, 0), with one
    NaN, one inf, one negative and one sub-clipping voxel; plus a grid 'heat'."""
    vdb = openvdb_module()
    grid = vdb.FloatGrid()
    grid.name = "density"
    grid.transform = vdb.createLinearTransform(voxelSize=0.1)
    acc = grid.getAccessor()
    for i in range(4):
        for j in range(3):
            for k in range(2):
                acc.setValueOn((10 + i, j, k), 1.0 + i)
    acc.setValueOn((10, 0, 0), float("nan"))
    acc.setValueOn((11, 0, 0), float("inf"))
    acc.setValueOn((12, 0, 0), -2.0)
    acc.setValueOn((13, 0, 0), 0.0004)
    heat = vdb.FloatGrid()
    heat.name = "heat"
    heat.getAccessor().setValueOn((0, 0, 0), 5.0)
    path = str(tmp_path / "grid.vdb")
    vdb.write(path, grids=[grid, heat])
    return path


def volume_object(path, name="Smoke", mat=None, location=(0, 0, 0)):
    vol = bpy.data.volumes.new(name)
    vol.filepath = path
    ob = link(bpy.data.objects.new(name, vol))
    ob.location = location
    if mat is not None:
        vol.materials.append(mat)
    return ob


def test_vdb_density_scale_sanitising_and_transform(empty_scene, vdb_file):
    mat, _, _ = volume_material("ShaderNodeVolumePrincipled",
                                **{"Color": (0.9, 0.9, 0.9, 1), "Density": 12.0})
    volume_object(vdb_file, mat=mat, location=(1, 0, 0))
    desc = translate()
    m = only_medium(desc)
    assert m.source == "VDB" and m.density.shape == (4, 3, 2)
    np.testing.assert_allclose(m.sigma_s, np.full(3, 0.9 * 12), rtol=1e-6)
    np.testing.assert_allclose(m.sigma_a, np.full(3, 0.1 * 12), rtol=1e-5)
    d = m.density
    assert np.all(np.isfinite(d)) and d.min() >= 0
    assert d[0, 0, 0] == d[1, 0, 0] == d[2, 0, 0] == 0.0      # NaN, inf, negative
    assert d[3, 0, 0] == 0.0                                  # below the 0.001 clipping
    assert d[3, 2, 1] == 4.0 and d[0, 1, 0] == 1.0
    assert any("3 voxels" in w and "'density'" in w and "'Smoke'" in w for w in desc.warnings)
    np.testing.assert_allclose(m.index_to_world @ [0, 0, 0, 1], [2.0, 0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(m.index_to_world @ [3, 2, 1, 1], [2.3, 0.2, 0.1, 1], atol=1e-6)


@pytest.mark.parametrize("scale", [(0.5, 0.5, 0.5), (1.0, 2.0, 4.0)])
def test_vdb_coefficients_follow_the_object_scale_in_object_space(empty_scene, vdb_file, scale):
    """Render space 'Object' (the default) keeps a scaled volume's look: Cycles multiplies
    every closure, emission included, by 1 / |M (1,1,1)/sqrt(3)|; 'World' does not."""
    mat, _, _ = volume_material("ShaderNodeVolumePrincipled",
                                **{"Color": (0.9, 0.9, 0.9, 1), "Density": 12.0,
                                   "Emission Strength": 2.0})
    ob = volume_object(vdb_file, mat=mat)
    ob.scale = scale
    ob.rotation_euler = (0.3, 0.0, 0.7)
    assert ob.data.render.space == "OBJECT"
    scaled = only_medium(translate())
    factor = 1.0 / np.linalg.norm(np.asarray(scale) / math.sqrt(3.0))
    assert factor != pytest.approx(1.0)
    np.testing.assert_allclose(scaled.sigma_s, np.full(3, 0.9 * 12 * factor), rtol=1e-5)
    np.testing.assert_allclose(scaled.sigma_a, np.full(3, 0.1 * 12 * factor), rtol=1e-5)
    ob.data.render.space = "WORLD"
    world = only_medium(translate())
    np.testing.assert_allclose(world.sigma_s, np.full(3, 0.9 * 12), rtol=1e-5)
    assert np.all(world.emission > 0)
    np.testing.assert_allclose(scaled.emission, world.emission * factor, rtol=1e-5)
    np.testing.assert_array_equal(scaled.density, world.density)


def test_vdb_without_material_is_a_default_principled_volume(empty_scene, vdb_file):
    volume_object(vdb_file)
    m = only_medium(translate())
    np.testing.assert_allclose(m.sigma_s, [0.5, 0.5, 0.5])
    np.testing.assert_allclose(m.sigma_a, [0.5, 0.5, 0.5])
    assert m.g == 0.0


def test_vdb_default_principled_matches_a_fresh_node(empty_scene, vdb_file):
    mat, _, _ = volume_material("ShaderNodeVolumePrincipled")
    volume_object(vdb_file, mat=mat)
    with_node = only_medium(translate())
    bpy.data.volumes["Smoke"].materials.clear()
    without = only_medium(translate())
    np.testing.assert_allclose(with_node.sigma_s, without.sigma_s)
    np.testing.assert_allclose(with_node.sigma_a, without.sigma_a)


def test_vdb_grids_by_attribute(empty_scene, vdb_file):
    """'Density Attribute' picks the grid; a missing grid is warned and renders nothing;
    an Attribute node linked into Density reads its grid."""
    mat, nt, node = volume_material("ShaderNodeVolumePrincipled", "Hot")
    node.inputs["Density Attribute"].default_value = "heat"
    volume_object(vdb_file, "A", mat)
    mat2, nt2, node2 = volume_material("ShaderNodeVolumePrincipled", "Missing")
    node2.inputs["Density Attribute"].default_value = "smoke"
    volume_object(vdb_file, "B", mat2)
    mat3, nt3, sc = volume_material("ShaderNodeVolumeScatter", "ByNode")
    attr = nt3.nodes.new("ShaderNodeAttribute")
    attr.attribute_name = "heat"
    nt3.links.new(attr.outputs["Factor"], sc.inputs["Density"])
    volume_object(vdb_file, "C", mat3)
    desc = translate()
    media = {m.name: m for m in desc.media}
    assert set(media) == {"A", "C"}
    assert media["A"].density.shape == (1, 1, 1) and media["C"].density[0, 0, 0] == 5.0
    msg = [w for w in desc.warnings if "'B'" in w]
    assert len(msg) == 1 and "'smoke'" in msg[0] and "'density'" in msg[0] and "renders nothing" in msg[0]


def test_vdb_uniform_closure_beside_a_grid(empty_scene, vdb_file):
    mat, nt, out = material("Both")
    pv = nt.nodes.new("ShaderNodeVolumePrincipled")
    sc = nt.nodes.new("ShaderNodeVolumeScatter")
    add = nt.nodes.new("ShaderNodeAddShader")
    nt.links.new(pv.outputs[0], add.inputs[0])
    nt.links.new(sc.outputs[0], add.inputs[1])
    nt.links.new(add.outputs[0], out.inputs["Volume"])
    volume_object(vdb_file, mat=mat)
    desc = translate()
    assert [m.name for m in desc.media] == ["Smoke:density", "Smoke:uniform"]
    uni = desc.media[1]
    np.testing.assert_allclose(uni.sigma_s, [0.8, 0.8, 0.8], rtol=1e-6)
    assert set(np.unique(uni.density)) <= {0.0, 1.0}
    assert any("approximated" in w for w in desc.warnings)


def test_missing_vdb_is_reported_by_name(empty_scene, tmp_path):
    missing = str(tmp_path / "gone.vdb")
    volume_object(missing, "Ghost")
    add_light("SUN", "sun")
    desc = translate()
    assert not desc.media and len(desc.lights) == 1
    msg = [w for w in desc.warnings if "'Ghost'" in w]
    assert len(msg) == 1 and missing in msg[0] and "not found" in msg[0]


# -- world --------------------------------------------------------------------------------

def test_world_background_and_volume(empty_scene):
    nt = empty_scene.world.node_tree
    bg = nt.nodes["Background"]
    bg.inputs["Color"].default_value = (0.2, 0.4, 0.8, 1)
    bg.inputs["Strength"].default_value = 2.5
    assert translate().world.color == pytest.approx([0.5, 1.0, 2.0])
    sky = nt.nodes.new("ShaderNodeTexSky")
    nt.links.new(sky.outputs[0], bg.inputs["Color"])
    vol = nt.nodes.new("ShaderNodeVolumeAbsorption")
    nt.links.new(vol.outputs[0], nt.get_output_node("CYCLES").inputs["Volume"])
    vol.inputs["Color"].default_value = (1.0, 0.5, 0.0, 1)
    vol.inputs["Density"].default_value = 0.25
    desc = translate()
    assert desc.world.color == pytest.approx([0.5, 1.0, 2.0])
    assert any("Sky Texture" in w and "'Color'" in w for w in desc.warnings)
    fog = desc.world.volume
    assert fog.source == "WORLD" and fog.sigma_a == pytest.approx([0.0, 0.125, 0.25])
    assert np.all(fog.sigma_s == 0) and np.all(fog.emission == 0)


def test_no_world_is_black(empty_scene):
    empty_scene.world = None
    assert np.all(translate().world.color == 0)


# -- camera -------------------------------------------------------------------------------

def add_camera(scene, **props):
    cam = bpy.data.cameras.new("cam")
    for k, v in props.items():
        setattr(cam, k, v)
    ob = link(bpy.data.objects.new("cam", cam))
    ob.location, ob.rotation_euler, ob.scale = (1, -5, 2), (1.2, 0.1, 0.3), (1.5, 1.5, 1.5)
    scene.camera = ob
    return ob


def frame_plane(ob, scene):
    """(xmin, xmax, ymin, ymax) of Blender's view_frame, on z = -1 for PERSP."""
    pts = np.array([tuple(v) for v in ob.data.view_frame(scene=scene)])
    if ob.data.type == "PERSP":
        pts = pts / -pts[:, 2:3]
    return pts[:, 0].min(), pts[:, 0].max(), pts[:, 1].min(), pts[:, 1].max()


CAMERAS = [
    ("PERSP", dict(), (1920, 1080, 1, 1)),
    ("PERSP", dict(sensor_fit="VERTICAL", sensor_height=20.0, lens=35.0), (640, 480, 1, 1)),
    ("PERSP", dict(sensor_fit="HORIZONTAL", lens=70.0), (300, 600, 1, 1)),
    ("PERSP", dict(sensor_fit="AUTO"), (300, 600, 1, 1)),
    ("PERSP", dict(shift_x=0.2, shift_y=-0.1), (400, 300, 1, 1)),
    ("PERSP", dict(), (400, 300, 2, 1)),
    ("ORTHO", dict(ortho_scale=7.5, shift_x=0.1), (400, 300, 1, 1)),
    ("ORTHO", dict(sensor_fit="VERTICAL", ortho_scale=3.0), (400, 300, 1, 1.5)),
]


@pytest.mark.parametrize("projection,props,res", CAMERAS)
def test_camera_plane_matches_view_frame(empty_scene, projection, props, res):
    sc = empty_scene
    sc.render.resolution_x, sc.render.resolution_y = res[0], res[1]
    sc.render.pixel_aspect_x, sc.render.pixel_aspect_y = res[2], res[3]
    sc.render.resolution_percentage = 50
    ob = add_camera(sc, type=projection, clip_start=0.5, clip_end=80.0, **props)
    cam = translate().camera
    assert (cam.width, cam.height) == (res[0] // 2, res[1] // 2)
    assert cam.projection == projection
    np.testing.assert_allclose(cam.plane, frame_plane(ob, sc), atol=1e-6)
    assert (cam.clip_start, cam.clip_end) == (pytest.approx(0.5), pytest.approx(80.0))
    m = np.array(ob.matrix_world.normalized())
    np.testing.assert_allclose(cam.cam_to_world, m, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(cam.cam_to_world[:3, :3], axis=0), 1, atol=1e-9)
    # the ray through the bottom-left image corner goes through view_frame's corner
    bl = np.array(tuple(ob.data.view_frame(scene=sc)[2]))
    o, d, *_ = primary_rays(cam, np.array([0.0]), np.array([float(cam.height)]))
    if projection == "PERSP":
        np.testing.assert_allclose(d[0], m[:3, :3] @ bl / np.linalg.norm(bl), atol=1e-6)
    else:
        np.testing.assert_allclose(o[0], m[:3, :3] @ [bl[0], bl[1], 0] + m[:3, 3], atol=1e-6)


def test_camera_override_size_and_unsupported_types(empty_scene):
    add_camera(empty_scene)
    other = add_camera(empty_scene, type="PANO")
    other.name = "cylinder"
    other.data.panorama_type = "CENTRAL_CYLINDRICAL"   # the one kind not rendered
    empty_scene.camera = bpy.data.objects["cam"]
    dg = bpy.context.evaluated_depsgraph_get()
    desc = scene_from_depsgraph(dg, Settings(), camera_override=other.evaluated_get(dg),
                                width=64, height=32)
    assert (desc.camera.width, desc.camera.height) == (64, 32)
    assert desc.camera.projection == "PERSP"
    assert any("'cylinder'" in w and "CENTRAL_CYLINDRICAL" in w for w in desc.warnings)
    other.data.panorama_type = "FISHEYE_EQUISOLID"
    dg = bpy.context.evaluated_depsgraph_get()
    desc = scene_from_depsgraph(dg, Settings(), camera_override=other.evaluated_get(dg),
                                width=64, height=32)
    assert desc.camera.projection == "PANO" and not desc.warnings
    assert desc.camera.panorama["type"] == "FISHEYE_EQUISOLID"


# -- whole scenes -------------------------------------------------------------------------

def test_description_holds_only_plain_data(empty_scene, vdb_file):
    add_camera(empty_scene)
    add_light("SPOT", "spot")
    mat, _, _ = volume_material("ShaderNodeVolumePrincipled")
    cube("Fog", material=mat)
    cube("Wall", location=(0, 3, 0))
    volume_object(vdb_file)
    desc = translate()

    def check(v, path):
        if dataclasses.is_dataclass(v):
            for f in dataclasses.fields(v):
                check(getattr(v, f.name), f"{path}.{f.name}")
        elif isinstance(v, (list, tuple)):
            for i, x in enumerate(v):
                check(x, f"{path}[{i}]")
        else:
            assert v is None or isinstance(v, (np.ndarray, float, int, str, bool, np.floating)), \
                (path, type(v))

    check(desc, "desc")
    assert len(desc.media) == 2 and len(desc.surfaces) == 1 and len(desc.lights) == 1
    bpy.ops.wm.read_factory_settings(use_empty=True)    # frees every Blender datablock
    assert desc.media[1].density.sum() > 0 and desc.surfaces[0].vertices.shape == (8, 3)


def test_a_failing_object_is_skipped_with_a_warning(empty_scene, monkeypatch):
    from mpp_render.blender.translate import meshes

    def boom(self, ob, *args, **kw):
        raise RuntimeError("broken mesh")

    cube("Bad")
    add_light("SUN", "sun")
    monkeypatch.setattr(meshes.MeshTranslator, "translate", boom)
    desc = translate()
    assert len(desc.lights) == 1 and not desc.surfaces
    assert any("'Bad'" in w and "broken mesh" in w for w in desc.warnings)


def test_fluid_domain_is_warned_in_a_subprocess(tmp_path):
    """A Mantaflow domain aborts the interpreter at exit, so this runs in its own process.
    The domain is not rendered as a mesh; without a material it renders nothing, as in Cycles
    (domains with data: tests/blender/test_fluid.py)."""
    script = textwrap.dedent(f"""
        import os, sys
        sys.path.insert(0, {REPO!r})
        import bpy
        from mpp_render.blender.translate import scene_from_depsgraph
        from mpp_render.scene import Settings
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.mesh.primitive_cube_add()
        mod = bpy.context.object.modifiers.new("Fluid", "FLUID")
        mod.fluid_type = "DOMAIN"
        desc = scene_from_depsgraph(bpy.context.evaluated_depsgraph_get(), Settings())
        print("RESULT", len(desc.media), len(desc.surfaces), "|".join(desc.warnings))
        sys.stdout.flush()
        os._exit(0)
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=120)
    line = next(ln for ln in run.stdout.splitlines() if ln.startswith("RESULT"))
    assert line.startswith("RESULT 0 0 ")
    assert "fluid domain 'Cube': no material" in line


def open_scene(scenes_dir, name):
    bpy.ops.wm.open_mainfile(filepath=str(scenes_dir / name / "scene.blend"))
    return translate(resolution=64)


@pytest.mark.parametrize("name", ["slab_forward", "slab_isotropic"])
def test_public_slabs(scenes_dir, name):
    desc = open_scene(scenes_dir, name)
    assert not desc.warnings
    (sun,) = desc.lights
    assert sun.kind == "SUN"
    np.testing.assert_allclose(sun.strength, [3, 3, 3], rtol=1e-6)
    m = only_medium(desc)
    assert m.source == "MESH" and m.density.shape == (64, 64, 64) and np.all(m.density == 1)
    np.testing.assert_allclose(m.sigma_s, np.full(3, 0.95 * 8), rtol=1e-6)
    np.testing.assert_allclose(m.sigma_a, np.full(3, 0.05 * 8), rtol=1e-5)
    assert m.g == pytest.approx(0.8 if name == "slab_forward" else 0.0)
    np.testing.assert_allclose(desc.world.color, [0.02, 0.02, 0.025], rtol=1e-6)
    assert (desc.camera.width, desc.camera.height) == (160, 120) and not desc.surfaces


def test_public_cloud_vdb(scenes_dir):
    desc = open_scene(scenes_dir, "cloud_vdb")
    assert not desc.warnings
    m = only_medium(desc)
    assert m.source == "VDB"
    assert all(40 <= n <= 96 for n in m.density.shape)
    assert 0.5 < m.density.max() <= 1.0
    np.testing.assert_allclose(m.sigma_s, np.full(3, 0.98 * 12), rtol=1e-6)
    np.testing.assert_allclose(m.sigma_a, np.full(3, 0.02 * 12), rtol=1e-4)
    assert m.g == pytest.approx(0.85)
    voxel = np.linalg.norm(m.index_to_world[:3, 0])
    assert voxel == pytest.approx(4.0 / 96, rel=1e-5)
    np.testing.assert_allclose(desc.world.color, np.array([0.25, 0.35, 0.6]) * 0.6, rtol=1e-6)
    assert desc.world.color[2] > desc.world.color[0]           # a blue sky
    assert [lt.kind for lt in desc.lights] == ["SUN"]


def test_public_smoke_plume(scenes_dir):
    desc = open_scene(scenes_dir, "smoke_plume")
    assert not desc.warnings
    (pt,) = desc.lights
    assert pt.kind == "POINT" and pt.radius == pytest.approx(0.05)
    np.testing.assert_allclose(pt.strength, [800, 800, 800])
    np.testing.assert_allclose(pt.position, [1.6, -1.0, 0.2], atol=1e-6)
    (ground,) = desc.surfaces
    assert ground.name == "Plane" and ground.triangles.shape == (2, 3)
    np.testing.assert_allclose(ground.vertices[:, 2], -1.5, atol=1e-6)
    np.testing.assert_allclose(ground.base_color, [0.5, 0.5, 0.5])
    m = only_medium(desc)
    assert m.source == "VDB"
    np.testing.assert_allclose(m.sigma_s, np.full(3, 0.7 * 6), rtol=1e-6)
    np.testing.assert_allclose(m.sigma_a, np.full(3, 0.3 * 6), rtol=1e-5)
    assert m.g == pytest.approx(0.3)


def test_public_fog_beam(scenes_dir):
    desc = open_scene(scenes_dir, "fog_beam")
    assert not desc.warnings
    (spot,) = desc.lights
    assert spot.kind == "SPOT" and spot.spot_size == pytest.approx(math.radians(8))
    np.testing.assert_allclose(spot.strength, [2000] * 3)
    np.testing.assert_allclose(spot.direction, [1, 0, 0], atol=1e-6)
    m = only_medium(desc)
    corner0 = m.index_to_world @ [0, 0, 0, 1]
    corner1 = m.index_to_world @ [*(np.array(m.density.shape) - 1), 1]
    half = (corner1[:3] - corner0[:3]) / 2 + np.abs(np.diag(m.index_to_world)[:3]) / 2
    np.testing.assert_allclose(half, [3.0, 1.2, 1.2], rtol=1e-6)   # the 6 m box
    np.testing.assert_allclose(m.sigma_s, np.full(3, 0.95), rtol=1e-6)
    assert m.g == pytest.approx(0.85)


def test_public_colored_sphere(scenes_dir):
    desc = open_scene(scenes_dir, "colored_sphere")
    assert not desc.warnings
    lights = {lt.kind: lt for lt in desc.lights}
    assert set(lights) == {"SUN", "POINT"}
    np.testing.assert_allclose(lights["SUN"].strength, [3.0, 2.85, 2.7], rtol=1e-6)
    np.testing.assert_allclose(lights["POINT"].strength, [120, 180, 300], rtol=1e-6)
    m = only_medium(desc)
    s, a = principled([0.95, 0.7, 0.35], 4.0, [0.2, 0.4, 0.9])
    np.testing.assert_allclose(m.sigma_s, s, rtol=1e-6)
    np.testing.assert_allclose(m.sigma_a, a, rtol=1e-5)
    assert m.g == pytest.approx(0.5)
    voxel = abs(np.linalg.det(m.index_to_world[:3, :3]))
    assert m.density.sum() * voxel == pytest.approx(4 / 3 * math.pi * 1.2 ** 3, rel=0.03)


def test_principled_surface_coat_parameters(scenes_dir):
    from mpp_render.blender.translate import scene_from_depsgraph
    from mpp_render.scene import Settings
    bpy.ops.wm.open_mainfile(filepath=str(scenes_dir / "smoke_plume" / "scene.blend"))
    desc = scene_from_depsgraph(bpy.context.evaluated_depsgraph_get(), Settings())
    (ground,) = desc.surfaces
    assert abs(ground.specular - 0.04) < 1e-6       # IOR 1.5, Specular IOR Level 0.5
    assert abs(ground.roughness - 1.0) < 1e-6       # as the file sets it
    assert np.allclose(ground.base_color, 0.5, atol=1e-6)
