"""The demo scene, built in code: a procedural cumulus (fBm density in a .vdb file, loaded as
a Volume object) under a low sun and a sky-coloured world, seen by one camera.

``build_demo_scene(directory)`` writes ``<directory>/demo_cloud.vdb`` and replaces the current
file's contents; nothing is read from disk, so the demo runs on a fresh checkout.
"""
from __future__ import annotations

import math
import os
import sys

import bpy
import numpy as np

CLOUD_SIZE = 4.0  # metres, side of the cube the grid fills
GRID = 80  # voxels per side
VDB_NAME = "demo_cloud.vdb"


def openvdb_module():
    """Blender's bundled ``openvdb`` Python module (it lives in Blender's own site-packages,
    which the bpy wheel does not put on ``sys.path``)."""
    path = os.path.join(bpy.utils.system_resource('PYTHON'), "lib",
                        f"python{sys.version_info.major}.{sys.version_info.minor}", "site-packages")
    if path not in sys.path:
        sys.path.append(path)
    import openvdb

    return openvdb


def value_noise(n: int, cells: int, rng) -> np.ndarray:
    """(n, n, n) smooth value noise in [0, 1]: random values on a (cells+1)^3 lattice,
    interpolated with a smoothstep-weighted trilinear blend."""
    lattice = rng.random((cells + 1,) * 3)
    x = np.linspace(0.0, cells, n, endpoint=False)
    i = np.minimum(x.astype(int), cells - 1)
    f = x - i
    f = f * f * (3.0 - 2.0 * f)
    out = np.zeros((n, n, n))
    for dx in (0, 1):
        wx = (f if dx else 1.0 - f)[:, None, None]
        for dy in (0, 1):
            wy = (f if dy else 1.0 - f)[None, :, None]
            for dz in (0, 1):
                wz = (f if dz else 1.0 - f)[None, None, :]
                out += wx * wy * wz * lattice[np.ix_(i + dx, i + dy, i + dz)]
    return out


LOBES = (  # (centre x, y, z, radius) in the grid's [-1, 1] cube: a cumulus of merged puffs
    (0.0, 0.0, -0.2, 0.5), (-0.4, 0.1, -0.35, 0.36), (0.38, -0.1, -0.3, 0.36),
    (0.12, 0.12, 0.22, 0.38), (-0.22, -0.12, 0.08, 0.32),
)


def cloud_density(n: int = GRID, seed: int = 7) -> np.ndarray:
    """(n, n, n) float32 density in [0, 1], indexed [x, y, z]: merged spherical puffs with a
    flat base, their surface displaced by five octaves of fBm value noise."""
    rng = np.random.default_rng(seed)
    fbm = sum(0.5 ** o * value_noise(n, 4 * 2 ** o, rng) for o in range(5)) / (2.0 - 0.5 ** 4)
    c = (np.arange(n) + 0.5) / n * 2.0 - 1.0  # [-1, 1] across the grid
    x, y, z = np.meshgrid(c, c, c, indexing="ij")
    base = np.full((n, n, n), -1.0)
    for cx, cy, cz, r in LOBES:
        dist = np.sqrt((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2)
        base = np.maximum(base, 1.0 - dist / r)
    base = np.where(z < -0.6, base - (-0.6 - z) * 8.0, base)
    d = np.clip((base + 1.4 * (fbm - 0.5)) * 2.5, 0.0, 1.0)
    # Fade to 0 over the outer 10 % of the grid so no puff is cut flat by the grid's bounds.
    edge = np.minimum.reduce([1.0 - np.abs(a) for a in (x, y, z)])
    return (d * np.clip(edge / 0.1, 0.0, 1.0)).astype(np.float32)


def write_vdb(path: str, density: np.ndarray, voxel_size: float) -> None:
    """Write ``density`` ([x, y, z]) as the float grid 'density' with a uniform voxel size in
    metres; index (0, 0, 0) sits at the object's origin."""
    vdb = openvdb_module()
    grid = vdb.FloatGrid()
    grid.copyFromArray(np.ascontiguousarray(density, np.float32))
    grid.transform = vdb.createLinearTransform(voxelSize=voxel_size)
    grid.name = "density"
    vdb.write(path, grids=[grid])


def _look_at(ob, target):
    """Point ``ob``'s local -Z at ``target`` (world metres) with +Y up."""
    from mathutils import Vector

    direction = Vector(target) - ob.location
    ob.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()


def build_demo_scene(directory: str, width: int = 480, height: int = 270):
    """Clear the current file and build the demo; returns the scene.  The cloud spans
    x, y in [-2, 2] m and z in [0, 4] m."""
    os.makedirs(directory, exist_ok=True)
    vdb_path = os.path.abspath(os.path.join(directory, VDB_NAME))
    write_vdb(vdb_path, cloud_density(), CLOUD_SIZE / GRID)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    col = scene.collection

    volume = bpy.data.volumes.new("Cloud")
    volume.filepath = vdb_path
    cloud = bpy.data.objects.new("Cloud", volume)
    cloud.location = (-CLOUD_SIZE / 2, -CLOUD_SIZE / 2, 0.0)
    col.objects.link(cloud)
    mat = bpy.data.materials.new("Cloud")
    tree = mat.node_tree
    tree.nodes.clear()
    pv = tree.nodes.new("ShaderNodeVolumePrincipled")
    pv.inputs["Color"].default_value = (0.98, 0.98, 0.98, 1.0)
    pv.inputs["Density"].default_value = 12.0
    pv.inputs["Anisotropy"].default_value = 0.8
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(pv.outputs["Volume"], out.inputs["Volume"])
    volume.materials.append(mat)

    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", 'SUN'))
    sun.data.energy = 4.0  # W/m^2
    sun.data.color = (1.0, 0.93, 0.82)
    sun.rotation_euler = (math.radians(55.0), 0.0, math.radians(-40.0))
    col.objects.link(sun)

    world = bpy.data.worlds.new("Sky")
    bg = world.node_tree.nodes.get("Background")
    bg.inputs["Color"].default_value = (0.32, 0.5, 0.85, 1.0)
    bg.inputs["Strength"].default_value = 0.6
    scene.world = world

    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.data.lens = 40.0
    cam.location = (1.5, -10.0, 1.6)
    _look_at(cam, (0.0, 0.0, 1.9))
    col.objects.link(cam)
    scene.camera = cam

    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
    scene.view_settings.view_transform = 'Standard'
    return scene
