"""Principled Volume blackbody emission and the Emission shader in a volume output, against
Cycles renders made in-process; VDB temperature grids become per-voxel emission."""
import os

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render import blackbody  # noqa: E402
from mpp_render.blender import batch, frame  # noqa: E402
from mpp_render.blender.translate import scene_from_depsgraph  # noqa: E402
from mpp_render.blender.translate.vdb import openvdb_module  # noqa: E402
from mpp_render.scene import Settings  # noqa: E402
from parts import node_material, render_cycles  # noqa: E402

SIGMA = 5.670373e-8 * 1e-6 / np.pi  # Cycles' Stefan-Boltzmann factor (W/(m^2 K^4) / pi, 1e-6)


def camera(sc, res=(24, 16)):
    """A camera 8 m in front of the origin looking along +y; no world (black)."""
    sc.world = None
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    sc.collection.objects.link(cam)
    cam.location = (0, -8, 0)
    cam.rotation_euler = (np.pi / 2, 0, 0)
    cam.data.lens = 80.0
    sc.camera = cam
    sc.render.resolution_x, sc.render.resolution_y = res
    sc.render.resolution_percentage = 100


def volume_material(kind="ShaderNodeVolumePrincipled", **inputs):
    return node_material("fire", kind, "Volume", **inputs)


def render_mpp(sc, spp=4):
    batch.register()
    batch.set_mpp(sc, spp, multiple=False)
    sc.mpp.voxel_resolution = 32
    return frame.render_mpp().output


def centre(img):
    h, w = img.shape[:2]
    return img[h // 2 - 2:h // 2 + 2, w // 2 - 2:w // 2 + 2].reshape(-1, 3).mean(axis=0)


def test_blackbody_cube_matches_cycles(empty_scene, tmp_path):
    """A 2 m absorbing cube (Color black, Density 1: no scattering) that glows by blackbody
    emission, no lights: the centre pixels carry L_e (1 - e^-2) in both renderers.  Cycles'
    noise is nil here (homogeneous, absorbing), so they agree to the blackbody colour and
    the voxelised cube: 1.5 %."""
    sc = empty_scene
    camera(sc)
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    mat, node = volume_material(**{"Color": (0, 0, 0, 1), "Density": 1.0,
                                   "Blackbody Intensity": 1.0})
    bpy.context.active_object.data.materials.append(mat)
    for t in (1000.0, 3000.0, 6500.0):
        node.inputs["Temperature"].default_value = t
        ref = centre(render_cycles(sc, tmp_path))
        ours = centre(render_mpp(sc).passes["Combined"][..., :3])
        expect = SIGMA * t ** 4 * blackbody.colour(t) * (1 - np.exp(-2.0))
        np.testing.assert_allclose(ours, expect, rtol=0.01, atol=1e-3 * expect.max())
        # Cycles keeps the out-of-gamut blue of 1000 K negative (-2 % of red); we give 0
        np.testing.assert_allclose(ours, ref, rtol=0.015, atol=0.025 * ref.max())
        assert ours[0] > ours[2] if t < 6000 else ours[2] > 0.9 * ours[0]


def test_emission_shader_in_a_volume_output_matches_cycles(empty_scene, tmp_path):
    """An Emission shader as a cube's volume: Cycles emits Color x Strength per metre
    (no extinction), so 2 m through the cube give 2 x that."""
    sc = empty_scene
    camera(sc)
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    mat, _ = volume_material("ShaderNodeEmission", **{"Color": (1.0, 0.5, 0.25, 1),
                                                      "Strength": 0.75})
    bpy.context.active_object.data.materials.append(mat)
    ref = centre(render_cycles(sc, tmp_path))
    ours = centre(render_mpp(sc).passes["Combined"][..., :3])
    expect = 2.0 * 0.75 * np.array([1.0, 0.5, 0.25])
    np.testing.assert_allclose(ref, expect, rtol=0.01)
    np.testing.assert_allclose(ours, expect, rtol=0.01)


def write_fire_vdb(path, n=8, voxel=0.25):
    """Grids 'density' (1 everywhere, n^3) and 'temperature' (rising along x from 0.5 to 1.5)
    on the same lattice, and 'flame', a coarser temperature (voxel x 2, offset), about
    centred on the origin."""
    vdb = openvdb_module()
    grids = []
    lo = -(n // 2)
    ramp = np.linspace(0.5, 1.5, n, dtype=np.float32)[:, None, None] * np.ones((n, n, n), np.float32)
    for name, values, vox, origin in (("density", np.ones((n, n, n), np.float32), voxel, lo),
                                      ("temperature", ramp, voxel, lo),
                                      ("flame", ramp[::2, ::2, ::2].copy(), 2 * voxel, lo // 2)):
        g = vdb.FloatGrid()
        g.name = name
        g.transform = vdb.createLinearTransform(voxelSize=vox)
        g.copyFromArray(np.ascontiguousarray(values), ijk=(origin,) * 3)
        grids.append(g)
    vdb.write(str(path), grids=grids)
    return str(path)


def test_vdb_temperature_grid_becomes_per_voxel_emission(empty_scene, tmp_path):
    sc = empty_scene
    camera(sc, res=(32, 16))
    vol = bpy.data.volumes.new("Fire")
    vol.filepath = write_fire_vdb(tmp_path / "fire.vdb")
    ob = bpy.data.objects.new("Fire", vol)
    sc.collection.objects.link(ob)
    mat, node = volume_material(**{"Color": (0, 0, 0, 1), "Density": 1.0,
                                   "Blackbody Intensity": 1.0, "Temperature": 2000.0,
                                   "Emission Strength": 0.1})
    vol.materials.append(mat)
    desc = scene_from_depsgraph(bpy.context.evaluated_depsgraph_get(), Settings())
    (m,) = desc.media
    assert m.emission_grid.shape == m.density.shape + (3,)
    t = 2000.0 * np.linspace(0.5, 1.5, 8)
    np.testing.assert_allclose(m.emission_grid[:, 3, 3], blackbody.emission(t, 1.0), rtol=1e-5)
    np.testing.assert_allclose(m.emission, [0.1, 0.1, 0.1], rtol=1e-6)  # constant part left
    # 'flame' is on another lattice (twice the voxel): resampled trilinearly
    node.inputs["Temperature Attribute"].default_value = "flame"
    desc = scene_from_depsgraph(bpy.context.evaluated_depsgraph_get(), Settings())
    (m2,) = desc.media
    inner = m2.emission_grid[1:-2, 3, 3]   # lattice points between flame's voxel centres
    assert np.all(np.diff(inner[:, 0]) > 0)
    assert not any("outside the box" in w for w in desc.warnings)
    # rendered: the hot side (+x, right of the image) glows far more than the cold side
    node.inputs["Temperature Attribute"].default_value = "temperature"
    e = render_mpp(sc).passes["Emission"][..., 0]
    cols = e[6:10].mean(axis=0)
    lit = cols[cols > 0.05 * cols.max()]
    q = len(lit) // 4
    assert len(lit) >= 8 and lit[-q:].mean() > 5 * lit[:q].mean()
    assert np.all(np.diff(lit[:2 * q]) > 0)
    # without the grid the constant Temperature (2000 K) glows evenly
    node.inputs["Temperature Attribute"].default_value = "no such grid"
    desc = scene_from_depsgraph(bpy.context.evaluated_depsgraph_get(), Settings())
    (m3,) = desc.media
    assert m3.emission_grid is None
    np.testing.assert_allclose(m3.emission, blackbody.emission(2000.0, 1.0) + 0.1, rtol=1e-6)


def test_a_blackbody_node_colours_an_emission_shader_as_cycles_does(empty_scene, tmp_path):
    """An Emission shader as a cube's volume, its Color from a Blackbody node whose
    Temperature rises across the cube (Generated x through Map Range, 1200 K to 9000 K), no
    extinction: each column of pixels carries 2 m of that colour, in both renderers.  The
    columns' colours (channel shares) against Cycles' within 0.01 (0.0036 measured), their sum
    within 2 % (0.999x measured), and red over blue
    turning to blue over red across the cube, so a constant colour (the node unsupported,
    its default 1500 K) fails."""
    sc = empty_scene
    camera(sc, res=(40, 16))
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    mat, emit = volume_material("ShaderNodeEmission", **{"Strength": 1.0})
    nt = mat.node_tree
    coords = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    rng = nt.nodes.new("ShaderNodeMapRange")
    rng.inputs["To Min"].default_value = 1200.0
    rng.inputs["To Max"].default_value = 9000.0
    body = nt.nodes.new("ShaderNodeBlackbody")
    nt.links.new(coords.outputs["Generated"], sep.inputs[0])
    nt.links.new(sep.outputs["X"], rng.inputs["Value"])
    nt.links.new(rng.outputs["Result"], body.inputs["Temperature"])
    nt.links.new(body.outputs["Color"], emit.inputs["Color"])
    bpy.context.active_object.data.materials.append(mat)
    ref = render_cycles(sc, tmp_path)
    batch.register()
    batch.set_mpp(sc, 4, multiple=False)
    sc.mpp.voxel_resolution = 64
    ours = frame.render_mpp().output.passes["Combined"][..., :3]
    a, b = ours.mean(axis=0), ref.mean(axis=0)       # columns: x across the cube
    cols = np.flatnonzero(b.sum(axis=1) > 0.2 * b.sum(axis=1).max())[2:-2]
    a, b = a[cols], b[cols]
    # the colour (each channel's share): the samples' noise is common to the channels
    np.testing.assert_allclose(a / a.sum(axis=1, keepdims=True),
                               b / b.sum(axis=1, keepdims=True), atol=0.01)
    np.testing.assert_allclose(a.sum(), b.sum(), rtol=0.02)
    assert a[0, 0] > 1.5 * a[0, 2] and a[-1, 2] > a[-1, 0]
