"""Small scene-building helpers for the Blender tests: a Principled Volume material, a unit
cube mesh volume, a sun, a camera looking along +Y and the MPP output settings.  Every helper
links what it makes into the scene it is given and returns it."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

CUBE_VERTS = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
CUBE_FACES = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]


def link(scene, ob):
    scene.collection.objects.link(ob)
    return ob


def volume_material(name, density=4.0, color=(0.9, 0.9, 0.9), anisotropy=None):
    """A Principled Volume material of ``density``; ``color`` (the albedo) None and
    ``anisotropy`` None keep Blender's defaults."""
    inputs = {"Density": density}
    if color is not None:
        inputs["Color"] = (*color, 1.0)
    if anisotropy is not None:
        inputs["Anisotropy"] = anisotropy
    return node_material(name, "ShaderNodeVolumePrincipled", "Volume", **inputs)[0]


def node_material(name, node, output="Volume", **inputs):
    """``(material, node)``: one shader ``node`` (a bl_idname) with ``inputs`` (socket name
    -> default value) linked to the material output's ``output`` socket."""
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    nt.nodes.clear()
    n = nt.nodes.new(node)
    for k, v in inputs.items():
        n.inputs[k].default_value = v
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(n.outputs[0], out.inputs[output])
    return mat, n


def add_cube(scene, name, location=(0.0, 0.0, 0.0), mat=None, scale=(1, 1, 1)):
    """A 2 m cube mesh (scaled by ``scale``) with material ``mat`` (default: volume_material
    of density 4)."""
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(CUBE_VERTS, [], CUBE_FACES)
    mesh.materials.append(mat if mat is not None else volume_material(f"{name}Vol"))
    ob = link(scene, bpy.data.objects.new(name, mesh))
    ob.location, ob.scale = location, scale
    return ob


def add_light(scene, name="Sun", kind="SUN", energy=3.0, location=(0.0, -4.0, 4.0),
              rotation=(0.6, 0.2, 0.0)):
    """A light of ``kind`` (W/m^2 for a sun, W otherwise)."""
    ob = link(scene, bpy.data.objects.new(name, bpy.data.lights.new(name, kind)))
    ob.data.energy = energy
    ob.location = location
    ob.rotation_euler = rotation
    return ob


def add_camera(scene, distance=8.0):
    """The scene's camera, ``distance`` metres along -Y from the origin, looking along +Y."""
    cam = link(scene, bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera")))
    cam.location = (0.0, -distance, 0.0)
    cam.rotation_euler = (np.pi / 2, 0.0, 0.0)
    scene.camera = cam
    return cam


def mpp_output(scene, width, height, samples=4, voxels=16):
    """Render with the MPP engine at ``width`` x ``height``, ``samples`` per pixel and
    ``voxels`` a side (coarse defaults keep a render well under a second)."""
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
    r.engine = "MPP_RENDER"
    scene.mpp.samples = samples
    scene.mpp.voxel_resolution = voxels
    return scene


def render_cycles(scene, tmp_path, spp=16, seed=0, multiple=False):
    """Cycles' single scattering (Volume Bounces 0; with ``multiple`` every bounce; the
    reference settings, 2 threads) of ``scene``: the Combined RGB (H,W,3), written through
    ``tmp_path/cycles_<seed>.exr``."""
    from mpp_render import exr
    from mpp_render.blender import batch
    batch.set_cycles_reference(scene, spp, multiple=multiple, seed=seed)
    scene.render.threads_mode = 'FIXED'
    scene.render.threads = 2
    path = str(tmp_path / f"cycles_{seed}.exr")
    batch.set_multilayer_exr(scene)
    bpy.ops.render.render()
    bpy.data.images["Render Result"].save_render(filepath=path, scene=scene)
    return exr.read_passes(path, layer=bpy.context.view_layer.name)["Combined"][..., :3]
