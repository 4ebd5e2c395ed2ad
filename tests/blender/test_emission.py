"""Principled Volume emission reaches the Emission pass and Combined."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mpp_render.blender import batch, frame  # noqa: E402


def test_principled_volume_emission_renders(empty_scene):
    sc = empty_scene
    batch.register()
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    cube = bpy.context.active_object
    mat = bpy.data.materials.new("glow")
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    vol = nt.nodes.new("ShaderNodeVolumePrincipled")
    vol.inputs["Density"].default_value = 1.0
    vol.inputs["Emission Strength"].default_value = 2.0
    vol.inputs["Emission Color"].default_value = (1.0, 0.5, 0.25, 1.0)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(vol.outputs["Volume"], out.inputs["Volume"])
    cube.data.materials.append(mat)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    sc.collection.objects.link(cam)
    cam.location = (0, -6, 0)
    cam.rotation_euler = (np.pi / 2, 0, 0)
    sc.camera = cam
    sc.render.resolution_x, sc.render.resolution_y = 24, 16
    batch.set_mpp(sc, 1, multiple=True)
    sc.mpp.multiple_paths = 100_000   # the lamps' and the glow's paths: a tenth of the default
    p = frame.render_mpp().output.passes
    e = p["Emission"][8, 12]
    # through 2 m of sigma_t 1: 2 * (1, .5, .25) * (1 - e^-2)
    assert np.allclose(e, 2.0 * np.array([1.0, 0.5, 0.25]) * (1 - np.exp(-2.0)), rtol=0.03)
    assert np.all(p["Combined"][8, 12, :3] >= e - 1e-6)
    assert np.all(p["Emission"][0, 0] == 0)
