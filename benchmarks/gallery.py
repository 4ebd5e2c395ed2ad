"""The user guide's pictures: one small scene per feature, built in code, rendered with MPP
and (for most) with Cycles in the same run.

    .venv/bin/python benchmarks/gallery.py [--only cloud,fire] [--samples 16]
        [--cycles-samples 64] [--out docs]

Writes ``OUT/images/gallery_<feature>.png`` (ours | Cycles, each panel exposed alike, with a
caption strip) and ``OUT/gallery.json``: per scene the wall seconds of the render calls (ours,
Cycles) and, from ``mpp_render.metrics``, ``rel_rmse_4`` / ``bias`` of our Combined pass
against the Cycles image of the same run (a modest sample count, so the number includes
Cycles' own noise).  That image is the mean of two Cycles runs with different seeds at half
the samples each, so their spread also gives Cycles' noise (``cycles_noise_4``) and our error
with it taken out (``rel_rmse_4_less_noise``).  One JSON line per scene goes to stdout.  MPP runs at its default settings but for the
samples: ``--samples`` (16), half that for the mesh volumes and the world fog, whose march is
the slowest; Cycles at ``--cycles-samples`` (64; four times that for the small light panels).

Features (``FEATURES``): a VDB cloud under sun and sky; a coloured mesh volume; world fog with
a spot light and an occluder (god rays, single scattering in both renderers: Cycles' endless
fog with many bounces is too slow for a gallery); world fog that glows, its light scattered
in itself round a ground and two boxes (every bounce in both); blackbody fire from a VDB
temperature grid; a smoke plume lighting the ground under it; each light type on a fog box;
single against multiple scattering of the cloud (our Volume Single / Volume Multiple beside
Cycles' Volume Direct / Volume Indirect of the same run); the passes of the fire render.
Fluid domains are left out: the bpy module cannot simulate or load a Mantaflow cache, so
Cycles would render an empty domain there.

Every builder (``build_<feature>(directory, width, height)``) replaces the current file's
contents, writes any grid it needs into ``directory`` and returns the scene; the tests import
them.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if REPO not in sys.path:
    sys.path.insert(0, REPO)

import bpy  # noqa: E402

from mpp_render import metrics  # noqa: E402
from mpp_render.blender import batch  # noqa: E402
from mpp_render.blender import demo  # noqa: E402

WIDTH, HEIGHT = 320, 180  # one panel, pixels
LABEL_PX = 12  # font size of panel labels and captions


# -- scene helpers ----------------------------------------------------------------------------

def new_file():
    """An empty file: no objects, no world, Standard view (PNG previews are plain sRGB)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.view_settings.view_transform = 'Standard'
    return sc


def add_camera(sc, location, target, lens, width, height):
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.location = location
    cam.data.lens = lens
    sc.collection.objects.link(cam)
    demo._look_at(cam, target)
    sc.camera = cam
    r = sc.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
    return cam


def set_world(sc, color, strength=1.0):
    world = bpy.data.worlds.new("World")
    bg = world.node_tree.nodes.get("Background")
    bg.inputs["Color"].default_value = (*color, 1.0)
    bg.inputs["Strength"].default_value = strength
    sc.world = world
    return world


def volume_material(name, **inputs):
    """A material whose Volume output is one Principled Volume with ``inputs`` (socket names
    with spaces written with underscores)."""
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    nt.nodes.clear()
    pv = nt.nodes.new("ShaderNodeVolumePrincipled")
    for k, v in inputs.items():
        pv.inputs[k.replace("_", " ")].default_value = v
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(pv.outputs["Volume"], out.inputs["Volume"])
    return mat


def surface_material(name, base_color, roughness=1.0):
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    nt.nodes.clear()
    bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.inputs["Base Color"].default_value = (*base_color, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def add_light(sc, kind, energy, location=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0),
              color=(1.0, 1.0, 1.0), **attrs):
    """A light of ``kind`` ('POINT', 'SPOT', 'SUN', 'AREA'); ``energy`` in W (W/m^2 for a
    sun); ``rotation`` Euler XYZ in radians (lights shine along their local -Z)."""
    data = bpy.data.lights.new(kind.title(), kind)
    data.energy = energy
    data.color = color
    for k, v in attrs.items():
        setattr(data, k, v)
    ob = bpy.data.objects.new(kind.title(), data)
    ob.location = location
    ob.rotation_euler = rotation
    sc.collection.objects.link(ob)
    return ob


def add_mesh(kind, material, **kw):
    """A primitive (``bpy.ops.mesh.primitive_<kind>_add(**kw)``) with ``material``."""
    getattr(bpy.ops.mesh, f"primitive_{kind}_add")(**kw)
    ob = bpy.context.active_object
    ob.data.materials.append(material)
    return ob


def write_grids(path, grids, voxel_size):
    """Write float grids (name -> array [x, y, z], or [x, y, z, 3] for a vector grid) on one
    lattice with a uniform voxel size in metres; index (0, 0, 0) at the object's origin."""
    vdb = demo.openvdb_module()
    out = []
    for name, a in grids.items():
        g = vdb.Vec3SGrid() if np.ndim(a) == 4 else vdb.FloatGrid()   # (x, y, z, 3): a colour
        g.copyFromArray(np.ascontiguousarray(a, np.float32))
        g.transform = vdb.createLinearTransform(voxelSize=voxel_size)
        g.name = name
        out.append(g)
    vdb.write(path, grids=out)


def add_vdb(sc, path, material, location):
    vol = bpy.data.volumes.new(os.path.splitext(os.path.basename(path))[0])
    vol.filepath = path
    vol.render.precision = 'FULL'  # Cycles' default HALF rounds the grid (blender-notes)
    vol.materials.append(material)
    ob = bpy.data.objects.new(vol.name, vol)
    ob.location = location
    sc.collection.objects.link(ob)
    return ob


def fbm(n, rng, octaves=4, cells=3):
    """(n, n, n) fractal value noise in [0, 1] (demo.value_noise octaves)."""
    total = sum(0.5 ** o * demo.value_noise(n, cells * 2 ** o, rng) for o in range(octaves))
    return total / (2.0 - 0.5 ** (octaves - 1))


def plume_density(n=64, seed=3):
    """(n, n, n) density in [0, 1] indexed [x, y, z]: a column of smoke rising from the
    bottom of the grid's cube, widening and thinning with height, broken up by fBm."""
    rng = np.random.default_rng(seed)
    c = (np.arange(n) + 0.5) / n
    x, y, z = np.meshgrid(c - 0.5, c - 0.5, c, indexing="ij")
    bend = 0.08 * np.sin(z * 5.0)  # a gentle sway
    rho = np.sqrt((x - bend) ** 2 + y ** 2)
    radius = 0.06 + 0.22 * z
    d = np.exp(-(rho / radius) ** 2) * (1.0 - 0.5 * z)
    d = np.clip(d * (0.4 + 1.2 * fbm(n, rng)) - 0.08, 0.0, 1.0)
    fade = np.clip(np.minimum(z, 1.0 - z) / 0.06, 0.0, 1.0)  # no flat cut at the top
    return (d * fade).astype(np.float32)


def fire_grids(n=48, seed=5):
    """'density' and 'temperature' (n, n, n) [x, y, z] of a fire in a cube: a tapering flame
    (temperature up to about 2.4, times the material's 1000 K) under and inside a wider
    column of thin smoke."""
    rng = np.random.default_rng(seed)
    c = (np.arange(n) + 0.5) / n
    x, y, z = np.meshgrid(c - 0.5, c - 0.5, c, indexing="ij")
    rho = np.sqrt(x ** 2 + y ** 2)
    noise = fbm(n, rng)
    flame_r = 0.26 * np.clip(1.0 - z / 0.7, 0.0, 1.0) ** 0.6 * (0.7 + 0.6 * noise)
    core = np.clip(1.0 - rho / np.maximum(flame_r, 1e-6), 0.0, 1.0)
    temperature = 2.4 * np.sqrt(core) * np.clip(1.0 - 0.6 * z, 0.0, 1.0)
    smoke_r = 0.1 + 0.3 * z
    smoke = np.exp(-(rho / smoke_r) ** 2) * np.clip((z - 0.15) / 0.3, 0.0, 1.0)
    smoke = np.clip(smoke * (0.3 + 1.4 * noise) - 0.15, 0.0, 1.0)
    fade = np.clip(np.minimum(z, 1.0 - z) / 0.05, 0.0, 1.0)
    density = np.maximum(smoke, 0.15 * core) * fade
    return {"density": density.astype(np.float32),
            "temperature": (temperature * fade).astype(np.float32)}


# -- the feature scenes -----------------------------------------------------------------------

def build_cloud(directory, width=WIDTH, height=HEIGHT):
    """The README demo's cumulus (an fBm .vdb, 4 m) under a low sun and a blue sky."""
    sc = demo.build_demo_scene(directory, width, height)
    sc.camera.data.lens = 55.0  # closer than the demo: the cloud fills more of a small panel
    return sc


def build_mesh_volume(directory, width=WIDTH, height=HEIGHT):
    """A coloured Principled Volume sphere (warm scattering colour, bluish absorption) beside
    a blue-grey cube, lit by a warm sun and a blue point light, over a dim grey world."""
    sc = new_file()
    set_world(sc, (0.05, 0.05, 0.05))
    add_mesh("uv_sphere", volume_material(
        "Amber", Color=(0.95, 0.7, 0.35, 1.0), Density=4.0, Anisotropy=0.5,
        Absorption_Color=(0.2, 0.4, 0.9, 1.0)), radius=1.0, segments=48, ring_count=24,
        location=(-1.1, 0.0, 0.0))
    add_mesh("cube", volume_material(
        "Slate", Color=(0.6, 0.75, 0.95, 1.0), Density=2.0, Anisotropy=0.0),
        size=1.5, location=(1.3, 0.3, -0.2), rotation=(0.0, 0.0, math.radians(30)))
    add_light(sc, 'SUN', 3.0, rotation=(math.radians(60), 0.0, math.radians(70)),
              color=(1.0, 0.95, 0.9))
    add_light(sc, 'POINT', 300.0, location=(-2.6, -1.8, -0.6), color=(0.4, 0.6, 1.0),
              shadow_soft_size=0.0)
    add_camera(sc, (0.0, -7.5, 0.6), (0.1, 0.0, 0.0), 45.0, width, height)
    return sc


def build_god_rays(directory, width=WIDTH, height=HEIGHT):
    """World fog (Volume Scatter, 0.1 /m) with a spot light over a 1 m box: the box's shadow
    is a dark shaft in the lit cone; a grey floor; the sky is black through endless fog."""
    sc = new_file()
    world = set_world(sc, (0.3, 0.5, 1.0))
    nt = world.node_tree
    fog = nt.nodes.new("ShaderNodeVolumeScatter")
    fog.inputs["Density"].default_value = 0.1
    nt.links.new(fog.outputs["Volume"], nt.get_output_node("CYCLES").inputs["Volume"])
    grey = surface_material("Floor", (0.4, 0.4, 0.4))
    add_mesh("plane", grey, size=30.0, location=(0.0, 0.0, 0.0))
    add_mesh("cube", grey, size=1.0, location=(0.0, 1.0, 2.5))
    add_light(sc, 'SPOT', 3000.0, location=(0.0, 1.0, 5.5), spot_size=math.radians(60),
              spot_blend=0.15, shadow_soft_size=0.0)
    add_camera(sc, (0.0, -9.0, 2.0), (0.0, 2.0, 2.0 - 11.0 * math.tan(math.radians(5))),
               36.0, width, height)
    return sc


def build_glowing_fog(directory, width=WIDTH, height=HEIGHT):
    """World fog that glows and scatters (Principled Volume: density 0.2 /m, albedo 0.8,
    anisotropy 0.3, warm emission) over a grey ground, with a white box and a grey pillar; no
    lamps: the fog lights itself, less so beside the ground and the objects."""
    sc = new_file()
    world = set_world(sc, (0.0, 0.0, 0.0))
    nt = world.node_tree
    fog = nt.nodes.new("ShaderNodeVolumePrincipled")
    for k, v in (("Color", (0.8, 0.8, 0.8, 1.0)), ("Density", 0.2), ("Anisotropy", 0.3),
                 ("Emission Strength", 1.0), ("Emission Color", (1.0, 0.8, 0.6, 1.0))):
        fog.inputs[k].default_value = v
    nt.links.new(fog.outputs["Volume"], nt.get_output_node("CYCLES").inputs["Volume"])
    add_mesh("plane", surface_material("Ground", (0.5, 0.5, 0.5)), size=80.0,
             location=(0.0, 0.0, 0.0))
    add_mesh("cube", surface_material("Box", (0.8, 0.8, 0.8)), size=1.5,
             location=(0.6, 1.5, 0.75))
    add_mesh("cube", surface_material("Pillar", (0.3, 0.3, 0.3)), size=1.0,
             location=(-1.8, 3.5, 1.5), scale=(0.5, 0.5, 3.0))
    add_camera(sc, (0.0, -5.0, 1.2), (0.0, 4.0, 0.8), 30.0, width, height)
    return sc


def build_fire(directory, width=WIDTH, height=HEIGHT):
    """A fire .vdb ('density' and 'temperature' grids, 2 m cube): Principled Volume with
    Blackbody Intensity 1, Temperature 1000 K x the 'temperature' grid, dark smoke; a dim
    blue moonlight sun so the smoke also scatters."""
    sc = new_file()
    set_world(sc, (0.01, 0.012, 0.02))
    path = os.path.abspath(os.path.join(directory, "gallery_fire.vdb"))
    n, size = 48, 2.0
    write_grids(path, fire_grids(n), size / n)
    mat = volume_material("Fire", Color=(0.35, 0.35, 0.35, 1.0), Density=6.0, Anisotropy=0.2,
                          Blackbody_Intensity=1.0, Temperature=1000.0,
                          Temperature_Attribute="temperature")
    add_vdb(sc, path, mat, (-size / 2, -size / 2, 0.0))
    add_light(sc, 'SUN', 1.5, rotation=(math.radians(50), 0.0, math.radians(-60)),
              color=(0.6, 0.75, 1.0))
    add_camera(sc, (0.0, -5.5, 1.0), (0.0, 0.0, 0.9), 45.0, width, height)
    return sc


def build_coloured_smoke(directory, width=WIDTH, height=HEIGHT):
    """The smoke plume .vdb (64^3, 3 m) with a vector grid 'color' read by the Principled
    Volume's Color Attribute: warm orange at the bottom turning to a cool blue at the top,
    under a white sun and a dim sky."""
    sc = new_file()
    set_world(sc, (0.03, 0.035, 0.05))
    path = os.path.abspath(os.path.join(directory, "gallery_coloured.vdb"))
    n, size = 64, 3.0
    dens = plume_density(n)
    z = np.clip(((np.arange(n) + 0.5) / n - 0.2) / 0.5, 0.0, 1.0)[None, None, :, None]
    colour = (1.0 - z) * np.array([1.0, 0.55, 0.15]) + z * np.array([0.25, 0.5, 1.0])
    write_grids(path, {"density": dens, "color": colour * np.ones((n, n, n, 1))}, size / n)
    add_vdb(sc, path, volume_material("Tinted smoke", Color=(1.0, 1.0, 1.0, 1.0),
                                      Color_Attribute="color", Density=6.0, Anisotropy=0.3),
            (-size / 2, -size / 2, 0.0))
    add_light(sc, 'SUN', 3.0, rotation=(math.radians(55), 0.0, math.radians(35)))
    add_camera(sc, (0.0, -9.5, 1.5), (0.0, 0.0, 1.5), 50.0, width, height)
    return sc


def build_smoke_ground(directory, width=WIDTH, height=HEIGHT):
    """A smoke plume .vdb (64^3, 3 m) over a grey Principled ground, lit by a point light
    beside it: the ground is lit by the light, shadowed by the smoke and lit by the light the
    smoke scatters."""
    sc = new_file()
    set_world(sc, (0.02, 0.02, 0.025))
    path = os.path.abspath(os.path.join(directory, "gallery_plume.vdb"))
    n, size = 64, 3.0
    write_grids(path, {"density": plume_density(n)}, size / n)
    add_vdb(sc, path, volume_material("Smoke", Color=(0.7, 0.7, 0.7, 1.0), Density=6.0,
                                      Anisotropy=0.3), (-size / 2, -size / 2, 0.0))
    add_mesh("plane", surface_material("Ground", (0.5, 0.5, 0.5)), size=14.0)
    add_light(sc, 'POINT', 800.0, location=(1.4, -1.0, 1.4), shadow_soft_size=0.0)
    add_camera(sc, (0.0, -9.0, 2.4), (0.0, 0.0, 1.2), 32.0, width, height)
    return sc


LIGHT_SETUPS = {  # kind -> add_light keyword arguments, around a 2 m fog box at the origin
    "point": dict(kind='POINT', energy=400.0, location=(1.6, -1.3, 1.6), shadow_soft_size=0.0),
    "spot": dict(kind='SPOT', energy=1500.0, location=(0.0, 0.0, 3.2), spot_size=math.radians(30),
                 spot_blend=0.2, shadow_soft_size=0.0),
    "sun": dict(kind='SUN', energy=3.0, rotation=(math.radians(50), 0.0, math.radians(40))),
    "area": dict(kind='AREA', energy=600.0, location=(0.0, 0.0, 2.4), size=1.5),
}


def build_light(directory, width=WIDTH // 2, height=HEIGHT // 2, kind="point"):
    """A 2 m fog box (Principled Volume, density 1.5 /m, albedo 0.9, anisotropy 0.3) on a
    black background lit by one light of ``LIGHT_SETUPS[kind]``."""
    sc = new_file()
    set_world(sc, (0.0, 0.0, 0.0))
    add_mesh("cube", volume_material("Fog", Color=(0.9, 0.9, 0.9, 1.0), Density=1.5,
                                     Anisotropy=0.3), size=2.0)
    setup = dict(LIGHT_SETUPS[kind])
    add_light(sc, setup.pop("kind"), setup.pop("energy"), **setup)
    add_camera(sc, (0.0, -7.0, 1.6), (0.0, 0.0, 0.1), 40.0, width, height)
    return sc


# -- rendering --------------------------------------------------------------------------------

def render_ours(sc, tmp, tag, samples, multiple=True):
    """Our render of ``sc``: (passes, render seconds, warnings)."""
    batch.set_mpp(sc, samples, multiple=multiple, seed=0)
    rec = batch.render_current(sc, os.path.join(tmp, f"{tag}_mpp.exr"))
    return rec["_passes"], rec["render"], rec["warnings"]


def render_cycles(sc, tmp, tag, samples, multiple=True, seeds=(1, 2)):
    """Cycles at the reference settings (batch.set_cycles_reference) with the Volume Direct /
    Indirect passes on, ``samples`` spp split over one run per seed: (the runs' passes, render
    seconds of all runs together)."""
    runs, total = [], 0.0
    for seed in seeds:
        batch.set_cycles_reference(sc, max(1, samples // len(seeds)), multiple=multiple, seed=seed)
        vl = bpy.context.view_layer
        vl.cycles.use_pass_volume_direct = True
        vl.cycles.use_pass_volume_indirect = True
        rec = batch.render_current(sc, os.path.join(tmp, f"{tag}_cycles_s{seed}.exr"))
        runs.append(rec["_passes"])
        total += rec["render"]
    return runs, total


def mean_pass(runs, name):
    """The mean of the runs' pass ``name`` (RGB): the image of all their samples."""
    return np.mean([r[name][..., :3] for r in runs], axis=0)


def _r4(x):
    return None if x is None else round(float(x), 4)


def score(ours, runs):
    """Ours (H, W, >=3) against Cycles runs of the same pass: ``rel_rmse_4`` and ``bias``
    against their mean (one Cycles image of all their samples; the number includes its noise),
    ``rel_rmse_4_less_noise`` with the noise the runs' spread shows taken out, and
    ``cycles_noise_4`` that noise (metrics.compare's floor_4)."""
    ours = np.asarray(ours)[..., :3]
    runs = [np.asarray(r)[..., :3] for r in runs]
    one = metrics.compare(ours, [np.mean(runs, axis=0)])
    spread = metrics.compare(ours, runs)
    return {"rel_rmse_4": _r4(one["rel_rmse_4"]), "bias": _r4(one["bias"]),
            "rel_rmse_4_less_noise": _r4(spread["rel_rmse_4"]),
            "cycles_noise_4": _r4(spread["floor_4"])}


def error_text(m):
    return (f"rel_rmse_4 {m['rel_rmse_4']:.3f} ({m['rel_rmse_4_less_noise']:.3f} less Cycles' "
            f"noise), bias {m['bias']:+.3f}")


# -- pictures ---------------------------------------------------------------------------------

def tone(img, scale):
    """Linear RGB (H, W, >=3) -> display RGB in [0, 1]: divided by ``scale``, sRGB OETF."""
    from mpp_render.exr import srgb_oetf
    return srgb_oetf(np.nan_to_num(np.asarray(img)[..., :3], nan=0.0) / max(scale, 1e-12))


def exposure(*images, pct=99.5):
    """One scale for images shown side by side: the largest high percentile of their brightest
    channel after a 4x4 box downsample (so that Cycles' fireflies do not set it)."""
    vals = [np.percentile(metrics.box_downsample(np.asarray(i)[..., :3], 4).max(axis=2), pct)
            for i in images]
    return float(max(vals)) or 1.0


def depth_image(z):
    """Depth (H, W, 1) -> grey: near bright, far dark, no hit black."""
    z = np.asarray(z)[..., 0]
    hit = z < 1e9
    out = np.zeros(z.shape + (3,))
    if hit.any():
        lo, hi = float(z[hit].min()), float(z[hit].max())
        out[hit] = (1.0 - 0.8 * (z[hit] - lo) / max(hi - lo, 1e-9))[:, None]
    return out


def _text(buf, x, y, text, size=LABEL_PX, color=(1.0, 1.0, 1.0)):
    """Draw ``text`` into the OIIO ImageBuf ``buf``; False where no font can be found (the
    picture then has no words, the JSON still has them)."""
    import OpenImageIO as oiio
    try:
        return bool(oiio.ImageBufAlgo.render_text(buf, int(x), int(y), text, size, "",
                                                  list(color)))
    except Exception:  # noqa: BLE001 -- a missing font only costs the captions
        return False


def compose(panels, labels, caption, columns=None):
    """Panels (each (h, w, 3) in [0, 1], all one size) on a grid of ``columns``, each with its
    label in the top-left corner, over a caption strip (a list of lines).  Returns uint8."""
    import OpenImageIO as oiio
    columns = columns or len(panels)
    h, w = panels[0].shape[:2]
    rows = -(-len(panels) // columns)
    cap_h = 6 + (LABEL_PX + 3) * len(caption)
    img = np.zeros((rows * h + cap_h, columns * w, 3))
    img[rows * h:] = 0.12
    for i, p in enumerate(panels):
        r, c = divmod(i, columns)
        img[r * h:(r + 1) * h, c * w:(c + 1) * w] = p
    px = np.ascontiguousarray((np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8))
    buf = oiio.ImageBuf(oiio.ImageSpec(px.shape[1], px.shape[0], 3, oiio.UINT8))
    buf.set_pixels(oiio.ROI(), px)
    for i, label in enumerate(labels):
        r, c = divmod(i, columns)
        # a dark box behind the label keeps it readable on bright smoke
        x0, y0 = c * w, r * h
        box = oiio.ROI(x0, x0 + 7 * len(label) + 8, y0, y0 + LABEL_PX + 6)
        oiio.ImageBufAlgo.fill(buf, [0.0, 0.0, 0.0], box)
        _text(buf, x0 + 4, y0 + LABEL_PX + 1, label)
    for k, line in enumerate(caption):
        _text(buf, 6, rows * h + (LABEL_PX + 3) * (k + 1), line, color=(0.9, 0.9, 0.9))
    return buf.get_pixels(oiio.UINT8)


def write_png(path, px):
    import OpenImageIO as oiio
    spec = oiio.ImageSpec(px.shape[1], px.shape[0], 3, oiio.UINT8)
    spec.attribute("png:compressionLevel", 9)
    out = oiio.ImageOutput.create(path)
    if out is None or not out.open(path, spec):
        raise RuntimeError(f"cannot write {path}: {oiio.geterror()}")
    try:
        out.write_image(np.ascontiguousarray(px))
    finally:
        out.close()


def seconds(s):
    return f"{s:.1f} s" if s >= 1 else f"{s:.2f} s"


# -- the features -----------------------------------------------------------------------------

def compare_feature(name, build, title, tmp, args, multiple=True, ours_samples=None):
    """Render ``build``'s scene with ours and Cycles; the ours | Cycles picture and record.
    Returns (record, picture, ours passes, cycles passes)."""
    sc = build(tmp)
    spp = ours_samples or args.samples
    ours, t_ours, warnings = render_ours(sc, tmp, name, spp, multiple)
    runs, t_ref = render_cycles(sc, tmp, name, args.cycles_samples, multiple)
    m = score(ours["Combined"], [r["Combined"] for r in runs])
    ref = mean_pass(runs, "Combined")
    rec = {"feature": name, "title": title, "resolution": [sc.render.resolution_x,
                                                           sc.render.resolution_y],
           "multiple": multiple, "ours_samples": spp, "cycles_samples": args.cycles_samples,
           "ours_seconds": round(t_ours, 3), "cycles_seconds": round(t_ref, 3), **m,
           "warnings": warnings}
    scale = exposure(ref)
    pic = compose([tone(ours["Combined"], scale), tone(ref, scale)],
                  [f"MPP {spp} spp", f"Cycles {args.cycles_samples} spp"],
                  [title + ("" if multiple else " (single scattering in both)"),
                   f"MPP {seconds(t_ours)}, Cycles {seconds(t_ref)}; {error_text(m)}"])
    return rec, pic, ours, runs


def feature_cloud(tmp, args):
    """Two pictures from one render each: the cloud (ours | Cycles), and its single and
    multiple scattering (our passes beside Cycles' Volume Direct / Indirect)."""
    rec, pic, ours, runs = compare_feature(
        "cloud", build_cloud, "VDB cloud under sun and sky", tmp, args)
    yield rec, pic
    single, multi = ours["Volume Single"], ours["Volume Multiple"]
    direct, indirect = mean_pass(runs, "Volume Direct"), mean_pass(runs, "Volume Indirect")
    ms = score(single, [r["Volume Direct"] for r in runs])
    mm = score(multi, [r["Volume Indirect"] for r in runs])
    rec2 = {"feature": "single_multiple", "title": "single and multiple scattering of the cloud",
            "same_render_as": "cloud", "ours_seconds": rec["ours_seconds"],
            "cycles_seconds": rec["cycles_seconds"],
            "single": ms, "multiple": mm,
            "ours_single_mean": round(float(single.mean()), 5),
            "ours_multiple_mean": round(float(multi.mean()), 5),
            "cycles_direct_mean": round(float(direct[..., :3].mean()), 5),
            "cycles_indirect_mean": round(float(indirect[..., :3].mean()), 5)}
    scale = exposure(direct, indirect)
    pic2 = compose([tone(single, scale), tone(multi, scale),
                    tone(direct, scale), tone(indirect, scale)],
                   ["MPP Volume Single", "MPP Volume Multiple",
                    "Cycles Volume Direct", "Cycles Volume Indirect"],
                   ["The cloud's light scattered once (left) and more than once (right), one exposure",
                    f"single: {error_text(ms)}", f"multiple: {error_text(mm)}"], columns=2)
    yield rec2, pic2


def feature_mesh_volume(tmp, args):
    rec, pic, _, _ = compare_feature("mesh_volume", build_mesh_volume,
                                     "Mesh volumes: coloured Principled Volume sphere and cube",
                                     tmp, args, ours_samples=max(1, args.samples // 2))
    yield rec, pic


def feature_god_rays(tmp, args):
    rec, pic, _, _ = compare_feature("god_rays", build_god_rays,
                                     "World fog, a spot light and a box: god rays", tmp, args,
                                     multiple=False, ours_samples=max(1, args.samples // 2))
    yield rec, pic


def feature_glowing_fog(tmp, args):
    rec, pic, _, _ = compare_feature("glowing_fog", build_glowing_fog,
                                     "World fog that glows: its light scattered in itself",
                                     tmp, args, ours_samples=max(1, args.samples // 2))
    yield rec, pic


def feature_smoke_ground(tmp, args):
    rec, pic, _, _ = compare_feature("smoke_ground", build_smoke_ground,
                                     "Smoke plume over a Principled ground, point light",
                                     tmp, args)
    yield rec, pic


def feature_coloured_smoke(tmp, args):
    rec, pic, _, _ = compare_feature("coloured_smoke", build_coloured_smoke,
                                     "Smoke coloured per voxel by a VDB 'color' grid", tmp, args)
    yield rec, pic


def feature_fire(tmp, args):
    """The fire (ours | Cycles) and the passes of our render of it."""
    rec, pic, ours, _ = compare_feature("fire", build_fire,
                                        "Blackbody fire from a VDB temperature grid", tmp, args)
    yield rec, pic
    scale = exposure(ours["Combined"])
    names = ("Combined", "Volume Single", "Volume Multiple", "Emission", "Transmittance", "Depth")
    panels = []
    for n in names:
        if n == "Depth":
            panels.append(depth_image(ours[n]))
        elif n == "Transmittance":
            panels.append(np.clip(ours[n][..., :3], 0, 1))
        elif n in ("Volume Single", "Volume Multiple"):
            panels.append(tone(ours[n], exposure(ours[n])))
        else:
            panels.append(tone(ours[n], scale))
    rec2 = {"feature": "passes", "title": "the passes of one render (the fire)",
            "same_render_as": "fire", "ours_seconds": rec["ours_seconds"],
            "pass_means": {n: round(float(ours[n][..., :3].mean()), 5) for n in names[:-1]}}
    pic2 = compose(panels, list(names),
                   ["The passes of the fire render. Single and Multiple at their own exposure;",
                    "Transmittance as is (white: clear); Depth near bright, far dark, no hit black"],
                   columns=3)
    yield rec2, pic2


def feature_lights(tmp, args):
    """Each light type on the same fog box: ours on top, Cycles below."""
    rows, ours_panels, ref_panels = [], [], []
    cspp = 4 * args.cycles_samples  # small panels: Cycles can afford less noise here
    t_ours = t_ref = 0.0
    for kind in LIGHT_SETUPS:
        sc = build_light(tmp, kind=kind)
        ours, to, _ = render_ours(sc, tmp, f"light_{kind}", args.samples)
        runs, tr = render_cycles(sc, tmp, f"light_{kind}", cspp)
        m = score(ours["Combined"], [r["Combined"] for r in runs])
        ref = mean_pass(runs, "Combined")
        rows.append({"light": kind, "ours_seconds": round(to, 3), "cycles_seconds": round(tr, 3),
                     **m})
        t_ours += to
        t_ref += tr
        scale = exposure(ref)
        ours_panels.append(tone(ours["Combined"], scale))
        ref_panels.append(tone(ref, scale))
    rec = {"feature": "lights", "title": "point, spot, sun and area light on a fog box",
           "resolution": [WIDTH // 2, HEIGHT // 2], "ours_samples": args.samples,
           "cycles_samples": cspp, "ours_seconds": round(t_ours, 3),
           "cycles_seconds": round(t_ref, 3), "per_light": rows}
    errs = ", ".join(f"{r['light']} {r['rel_rmse_4']:.3f} ({r['bias']:+.2f})" for r in rows)
    pic = compose(ours_panels + ref_panels,
                  [f"MPP {k}" for k in LIGHT_SETUPS] + [f"Cycles {k}" for k in LIGHT_SETUPS],
                  [f"Each light type on a fog box: MPP {args.samples} spp (top, {seconds(t_ours)} "
                   f"for all four), Cycles {cspp} spp (bottom, {seconds(t_ref)})",
                   f"rel_rmse_4 (bias) against that Cycles image: {errs}"],
                  columns=len(LIGHT_SETUPS))
    yield rec, pic


FEATURES = {
    "cloud": feature_cloud,            # also writes single_multiple
    "mesh_volume": feature_mesh_volume,
    "god_rays": feature_god_rays,
    "glowing_fog": feature_glowing_fog,
    "fire": feature_fire,              # also writes passes
    "coloured_smoke": feature_coloured_smoke,
    "smoke_ground": feature_smoke_ground,
    "lights": feature_lights,
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", default=None, help="comma-separated features (default all): "
                    + ",".join(FEATURES))
    ap.add_argument("--samples", type=int, default=16, help="our samples per pixel")
    ap.add_argument("--cycles-samples", type=int, default=64,
                    help="Cycles samples per pixel (four times that for the small light panels)")
    ap.add_argument("--out", default=os.path.join(REPO, "docs"))
    args = ap.parse_args(argv)
    names = args.only.split(",") if args.only else list(FEATURES)
    batch.register()
    os.makedirs(os.path.join(args.out, "images"), exist_ok=True)
    json_path = os.path.join(args.out, "gallery.json")
    records, before = {}, None
    if args.only and os.path.exists(json_path):  # a partial run keeps the other scenes
        with open(json_path) as f:
            before = json.load(f)
        records = {r["feature"]: r for r in before["scenes"]}
    t0 = time.perf_counter()
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="mpp_gallery_") as tmp:
        for name in names:
            for rec, pic in FEATURES[name](tmp, args):
                path = os.path.join(args.out, "images", f"gallery_{rec['feature']}.png")
                write_png(path, pic)
                rec["png"] = os.path.relpath(path, args.out)
                rec["png_bytes"] = os.path.getsize(path)
                records[rec["feature"]] = rec
                print(json.dumps(rec), flush=True)
    order = ["cloud", "single_multiple", "mesh_volume", "god_rays", "glowing_fog", "fire",
             "passes",
             "coloured_smoke", "smoke_ground", "lights"]
    doc = {"generated": time.strftime("%Y-%m-%d"), "cores": os.cpu_count(),
           # other jobs on the machine slow both renderers; the 1-minute load at the start
           # and the end of the run say how busy it was
           "load_average": [round(load_before, 2), round(os.getloadavg()[0], 2)],
           "blender": bpy.app.version_string,
           "note": "seconds: wall time of the render calls; rel_rmse_4 and bias of our "
                   "Combined pass against the Cycles image of the same scene (the mean of two "
                   "seeds at half the samples each; includes Cycles' noise); "
                   "rel_rmse_4_less_noise: the same with the noise the two seeds show taken "
                   "out; cycles_noise_4: that noise (metrics floor_4)",
           "scenes": sorted(records.values(), key=lambda r: order.index(r["feature"])
                            if r["feature"] in order else len(order))}
    if before is not None:   # a partial run: the full run's date and load, and what changed
        doc["generated"], doc["load_average"] = before["generated"], before["load_average"]
        doc["updated"] = dict(before.get("updated", {}))
        for name in names:
            for feature in [name] + (["single_multiple"] if name == "cloud" else []) \
                    + (["passes"] if name == "fire" else []):
                doc["updated"][feature] = (time.strftime("%Y-%m-%d")
                                           + f" (gallery.py --only {name})")
    with open(json_path, "w") as f:
        json.dump(doc, f, indent=1)
    print(json.dumps({"total_seconds": round(time.perf_counter() - t0, 1)}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
