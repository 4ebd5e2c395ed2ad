"""Hold-out scenes: variants of the public suite that no constant was fitted on, each with
its own Cycles references, rendered the way the suite is.

    .venv/bin/python benchmarks/holdout.py [--only v_area_lowalb,...] [--spp 1024]
        [--work DIR] [--out docs] [--keep]

Each variant (``VARIANTS``) opens a public scene, changes what its recipe says (the kinds of
change the suite's families vary: density, albedo, anisotropy, a lamp's radius, power and
place, the light's kind) and saves it under ``--work`` (a temporary folder unless given).
Cycles renders two full references (``ref_s1``, ``ref_s2``, ``--spp`` each, the suite's
settings: ``batch.set_cycles_reference``) and two single-scattering ones (``ss_s*``,
Volume Bounces 0); MPP renders the full image at the scene's own settings (F12) and single
scattering alone at 16 samples.  Both are scored with ``mpp_render.metrics`` (rel_rmse_4,
floor_4, bias).  Writes ``OUT/holdout.md`` and ``OUT/holdout.json``; one JSON line per
variant on stdout.  Minutes (Cycles at 1024 spp): not a test.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)
SCENES = os.path.join(REPO, "..", "shared", "scenes")

# name -> (public scene, what changes, the recipe: (function name, keyword arguments) pairs)
VARIANTS = {
    "v_lamp_dense": ("p_point_in_cube", "the lamp 40 W, radius 0.25 m; density 3, albedo 0.98, g 0.7",
                     [("volume", dict(density=3.0, color=0.98, anisotropy=0.7)),
                      ("lamp", dict(energy=40.0, radius=0.25))]),
    "v_fog_spot": ("p_fog_spot_shafts", "world fog density 0.08, g 0.7",
                   [("world_fog", dict(density=0.08, anisotropy=0.7))]),
    "v_haze_spot": ("p_haze_sun_ground", "haze density 0.35, g 0.6, lifted 5 cm off the ground; "
                    "a wide spot (100 deg, 4000 W) from above instead of the sun",
                    [("volume", dict(density=0.35, anisotropy=0.6)), ("lift", dict(dz=0.05)),
                     ("sun_to_spot", dict())]),
    "v_backlit_g9": ("p_backlit_vdb", "g 0.9, albedo 0.99",
                     [("volume", dict(anisotropy=0.9, color=0.99))]),
    "v_area_lowalb": ("p_area_in_box", "albedo 0.7, g 0.5",
                      [("volume", dict(color=0.7, anisotropy=0.5))]),
    "v_smoke_lamp_abs": ("smoke_plume", "v_smoke_lamp with the smoke absorbing only (Color 0: "
                         "the same extinction, no scattering)",
                         [("lamp_in_volume", dict(energy=200.0, radius=0.15, height=0.3)),
                          ("volume", dict(color=0.0))]),
    "v_plume_lamp2": ("p_point_in_plume", "the lamp 80 W, radius 0.1 m, moved to (0.3, 0.2, -0.2)",
                      [("lamp", dict(energy=80.0, radius=0.1, location=(0.3, 0.2, -0.2)))]),
    "v_plume_lamp2_r3": ("p_point_in_plume", "v_plume_lamp2 with the lamp's radius 0.3 m",
                         [("lamp", dict(energy=80.0, radius=0.3, location=(0.3, 0.2, -0.2)))]),
    "v_plume_lamp3": ("p_point_in_plume", "the lamp 60 W, radius 0.05 m, moved to (-0.3, 0, 0.3)",
                      [("lamp", dict(energy=60.0, radius=0.05, location=(-0.3, 0.0, 0.3)))]),
    "v_smoke_lamp": ("smoke_plume", "its point light (200 W, radius 0.15 m) inside the plume, "
                     "at 30 % of the grid's height",
                     [("lamp_in_volume", dict(energy=200.0, radius=0.15, height=0.3))]),
    # the kinds the lamps above left out (2026-12-04): spheres, slabs, grounds, overlaps,
    # world fog, a third-party grid and a fog box, each at other parameters
    "v_sphere_fwd_thick": ("p_sphere_g95", "density 15, g 0.85",
                           [("volume", dict(density=15.0, anisotropy=0.85))]),
    "v_sphere_midalb": ("p_sphere_lowalbedo", "density 4, albedo 0.75, g -0.1",
                        [("volume", dict(density=4.0, color=0.75, anisotropy=-0.1))]),
    "v_slab_ground_thin": ("p_slab_over_ground", "density 1.5, g 0.3",
                           [("volume", dict(density=1.5, anisotropy=0.3))]),
    "v_backlit_slab_dense": ("p_backlit_slab", "density 8, g 0.75",
                             [("volume", dict(density=8.0, anisotropy=0.75))]),
    "v_overlap_dense": ("p_overlap", "both media density 5, g 0.3",
                        [("volume", dict(density=5.0, anisotropy=0.3))]),
    "v_fog_point_dense": ("p_fog_point", "world fog density 0.12, g 0.2",
                          [("world_fog", dict(density=0.12, anisotropy=0.2))]),
    "v_dragon_g2": ("p_dragon", "density 25, g 0.2",
                    [("volume", dict(density=25.0, anisotropy=0.2))]),
    "v_fogbox_spot_dense": ("p_spot_in_fogbox", "density 0.8, g 0.3",
                            [("volume", dict(density=0.8, anisotropy=0.3))]),
    "v_chromatic_dense": ("p_chromatic_box", "density 5, g 0",
                          [("volume", dict(density=5.0, anisotropy=0.0))]),
    "v_cloud_lowalb": ("cloud_vdb", "albedo 0.85, g 0.3",
                       [("volume", dict(color=0.85, anisotropy=0.3))]),
    # the third set (2026-12-06): lamps of other kinds and places, and media the first two
    # left out (a back-scattering cloud, a forward and absorbing sphere)
    "v_cloud_lamp": ("cloud_vdb", "a point light (300 W, radius 0.2 m) inside the cloud at 40 % "
                     "of its height, beside the sun",
                     [("add_light", dict(kind="POINT", energy=300.0, radius=0.2, height=0.4))]),
    "v_plume_spot": ("p_point_in_plume", "its point light replaced by a spot (150 W, radius 0.1 m, "
                     "60 deg, blend 0.2) at the same place, pointing up",
                     [("hide_lights", dict(kind="POINT")),
                      ("add_light", dict(kind="SPOT", energy=150.0, radius=0.1,
                                         location=(0.0, 0.0, -0.6), rotation=(math.pi, 0.0, 0.0),
                                         spot_size=math.radians(60), spot_blend=0.2))]),
    "v_dragon_area": ("p_dragon", "a 1 m square area light (300 W) 1.5 m above the grid's top, "
                      "facing down, beside the sun",
                      [("add_light", dict(kind="AREA", energy=300.0, size=1.0, height=1.0,
                                          above=1.5))]),
    "v_cloud_gneg": ("cloud_vdb", "g -0.3, albedo 0.95",
                     [("volume", dict(color=0.95, anisotropy=-0.3))]),
    "v_sphere_g95_lowalb": ("p_sphere_g95", "albedo 0.6",
                            [("volume", dict(color=0.6))]),
    "v_slab_lamp_behind": ("p_backlit_slab", "its sun replaced by a point light (400 W, radius "
                           "0.2 m) 1.5 m behind the slab",
                           [("hide_lights", dict(kind="SUN")),
                            ("add_light", dict(kind="POINT", energy=400.0, radius=0.2,
                                               location=(0.0, 1.5, 0.3)))]),
    # the fourth set (2026-12-06, thirty-sixth session): the camera inside a mesh volume, as
    # an artist's fog box round a whole shot puts it
    "v_fogbox_camera": ("p_spot_in_fogbox", "the camera moved inside the fog box, 0.4 m from "
                        "its front face, looking in",
                        [("camera", dict(location=(0.0, -1.6, 0.0)))]),
    "v_cube_camera": ("p_point_in_cube", "density 0.5; the camera moved inside the cube, 0.9 m "
                      "from the lamp, looking at it",
                      [("volume", dict(density=0.5)),
                       ("camera", dict(location=(0.0, -0.8, 0.0), rotation=(1.35, 0.0, 0.0)))]),
    # the fifth set (2026-12-07, forty-fifth session): thick smoke that absorbs a tenth of
    # what it meets, where the paths' lattice is the voxels' own
    "v_sphere_thick_dark": ("p_sphere_thick", "albedo 0.9",
                            [("volume", dict(color=0.9))]),
    "v_haze_thick_dark": ("p_haze_sun_ground", "density 40, albedo 0.9, g 0.6 (thick dark "
                          "smoke), lifted 5 cm off the ground",
                          [("volume", dict(density=40.0, color=0.9, anisotropy=0.6)),
                           ("lift", dict(dz=0.05))]),
    # the sixth set (2026-12-07, forty-sixth session): the kinds no variant had tried yet:
    # emission lighting denser smoke, a shader-texture density made dense or backlit, world
    # fog that scatters forward round an area light, a spot and an area light in dense
    # white media
    "v_glow_dense": ("p_glowing_smoke", "density 12, albedo 0.95, g 0.6",
                     [("volume", dict(density=12.0, color=0.95, anisotropy=0.6))]),
    "v_glow_sun": ("p_glowing_smoke", "a sun (2 W/m^2) from the left and above beside its glow",
                   [("add_light", dict(kind="SUN", energy=2.0, radius=0.0, location=(0, 0, 5),
                                       rotation=(math.radians(50), 0.0, math.radians(-60))))]),
    "v_noise_dense": ("p_noise_cloud", "the noise's density 25 (from 10), albedo 0.9, g 0.3",
                      [("noise_density", dict(density=25.0)),
                       ("volume", dict(color=0.9, anisotropy=0.3))]),
    "v_noise_backlit": ("p_noise_cloud", "the sun behind the cloud, towards the camera; g 0.8",
                        [("sun", dict(rotation=(math.radians(-65), 0.0, math.radians(25)))),
                         ("volume", dict(anisotropy=0.8))]),
    "v_fog_area_fwd": ("p_fog_area", "world fog density 0.15, g 0.7",
                       [("world_fog", dict(density=0.15, anisotropy=0.7))]),
    "v_spot_dense_box": ("p_spot_in_fogbox", "density 3, g 0.5 (the spot's apex inside dense "
                         "fog)", [("volume", dict(density=3.0, anisotropy=0.5))]),
    "v_area_white": ("p_area_in_box", "density 2, albedo 0.99, g 0.8",
                     [("volume", dict(density=2.0, color=0.99, anisotropy=0.8))]),
    # the tenth set (2026-12-08, forty-ninth session): lights in smoke denser than they are
    # wide, built after the lattice's rule round a light's core (method.md §9.9) to check it
    "v_smoke_lamp_dense": ("smoke_plume", "v_smoke_lamp (200 W, radius 0.15 m, at 30 % of "
                           "the grid's height) in the plume at density 18",
                           [("lamp_in_volume", dict(energy=200.0, radius=0.15, height=0.3)),
                            ("volume", dict(density=18.0))]),
    "v_plume_area_dense": ("p_point_in_plume", "v_plume_area (a 0.4 m square area light, "
                           "150 W, facing down) in the plume at density 18",
                           [("hide_lights", dict(kind="POINT")),
                            ("add_light", dict(kind="AREA", energy=150.0, size=0.4,
                                               location=(0.0, 0.0, -0.6))),
                            ("volume", dict(density=18.0))]),
    "v_cloud_spot": ("cloud_vdb", "a spot (300 W, radius 0.3 m, 60 deg, blend 0.2) inside "
                     "the cloud at half its height, pointing down, beside the sun and sky",
                     [("add_light", dict(kind="SPOT", energy=300.0, radius=0.3, height=0.5,
                                         spot_size=math.radians(60), spot_blend=0.2))]),
    # the ninth set (2026-12-07, forty-eighth session): area lights inside uneven smoke
    "v_smoke_area": ("smoke_plume", "its point light replaced by a 0.3 m square area light "
                     "(100 W) inside the plume at 30 % of the grid's height, tilted",
                     [("hide_lights", dict(kind="POINT")),
                      ("add_light", dict(kind="AREA", energy=100.0, size=0.3, height=0.3,
                                         rotation=(0.9, 0.0, 0.6)))]),
    "v_cloud_area": ("cloud_vdb", "a 0.5 m square area light (300 W) inside the cloud at half "
                     "its height, facing down, beside the sun and sky",
                     [("add_light", dict(kind="AREA", energy=300.0, size=0.5, height=0.5))]),
    # the seventh set (2026-12-07, forty-sixth session): features met together that the
    # public scenes keep apart
    "v_chromatic_sun_sky": ("p_chromatic_box", "its spot replaced by a sun (3 W/m^2) under a "
                            "blue sky (0.3, 0.4, 0.6 x 0.5)",
                            [("hide_lights", dict(kind="SPOT")),
                             ("add_light", dict(kind="SUN", energy=3.0, radius=0.0,
                                                location=(0, 0, 5),
                                                rotation=(math.radians(45), 0.0,
                                                          math.radians(40)))),
                             ("world", dict(color=(0.3, 0.4, 0.6), strength=0.5))]),
    "v_plume_area": ("p_point_in_plume", "its point light replaced by a 0.4 m square area "
                     "light (150 W) in the same place, facing down",
                     [("hide_lights", dict(kind="POINT")),
                      ("add_light", dict(kind="AREA", energy=150.0, size=0.4,
                                         location=(0.0, 0.0, -0.6)))]),
    "v_backlit_vdb_dark": ("p_backlit_vdb", "albedo 0.7, g 0.6",
                           [("volume", dict(color=0.7, anisotropy=0.6))]),
    "v_slab_sun_sky": ("p_slab_over_ground", "its point light replaced by a sun (3 W/m^2) "
                       "under a blue sky (0.3, 0.4, 0.6)",
                       [("hide_lights", dict(kind="POINT")),
                        ("add_light", dict(kind="SUN", energy=3.0, radius=0.0, location=(0, 0, 5),
                                           rotation=(math.radians(40), 0.0, math.radians(30)))),
                        ("world", dict(color=(0.3, 0.4, 0.6), strength=1.0))]),
    "v_glow_slab": ("p_slab_over_ground", "its point light off; the slab (density 2) glows "
                    "orange (1, 0.5, 0.2) at strength 2",
                    [("hide_lights", dict(kind="POINT")), ("volume", dict(density=2.0)),
                     ("emission", dict(color=(1.0, 0.5, 0.2), strength=2.0))]),
    # v_plume_area without its sun and at g 0; v_slab_sun_sky's sun alone and sky alone
    "v_plume_area_nosun": ("p_point_in_plume", "v_plume_area without its sun",
                           [("hide_lights", dict(kind="POINT")),
                            ("add_light", dict(kind="AREA", energy=150.0, size=0.4,
                                               location=(0.0, 0.0, -0.6))),
                            ("hide_lights", dict(kind="SUN"))]),
    "v_plume_area_g0": ("p_point_in_plume", "v_plume_area with g 0",
                        [("hide_lights", dict(kind="POINT")),
                         ("add_light", dict(kind="AREA", energy=150.0, size=0.4,
                                            location=(0.0, 0.0, -0.6))),
                         ("volume", dict(anisotropy=0.0))]),
    "v_slab_sky_only": ("p_slab_over_ground", "v_slab_sun_sky without its sun",
                        [("hide_lights", dict(kind="POINT")),
                         ("world", dict(color=(0.3, 0.4, 0.6), strength=1.0))]),
    "v_slab_sun_only": ("p_slab_over_ground", "v_slab_sun_sky with the world black",
                        [("hide_lights", dict(kind="POINT")),
                         ("add_light", dict(kind="SUN", energy=3.0, radius=0.0, location=(0, 0, 5),
                                            rotation=(math.radians(40), 0.0, math.radians(30)))),
                         ("world", dict(color=(0.3, 0.4, 0.6), strength=0.0))]),
    # the sky over a ground alone, the ground black (no light off it): the sky's multiple
    # scattering where the ground hides part of it, in a thick slab and a thin haze
    "v_slab_sky_black": ("p_slab_over_ground", "v_slab_sky_only with the ground black",
                         [("hide_lights", dict(kind="POINT")),
                          ("world", dict(color=(0.3, 0.4, 0.6), strength=1.0)),
                          ("ground", dict(color=(0.0, 0.0, 0.0)))]),
    "v_haze_sky_black": ("p_haze_sun_ground", "its sun off, the haze lifted 5 cm off a black "
                         "ground, under its sky at strength 2",
                         [("hide_lights", dict(kind="SUN")), ("lift", dict(dz=0.05)),
                          ("world", dict(color=(0.2, 0.25, 0.35), strength=2.0)),
                          ("ground", dict(color=(0.0, 0.0, 0.0)))]),
    "v_haze_sky_matte": ("p_haze_sun_ground", "v_haze_sky_black with the ground's specular "
                         "layer off (Specular IOR Level 0)",
                         [("hide_lights", dict(kind="SUN")), ("lift", dict(dz=0.05)),
                          ("world", dict(color=(0.2, 0.25, 0.35), strength=2.0)),
                          ("ground", dict(color=(0.0, 0.0, 0.0), specular=0.0))]),
    "v_slab_sky_g9": ("p_slab_over_ground", "v_slab_sky_only at g 0.9",
                      [("hide_lights", dict(kind="POINT")),
                       ("world", dict(color=(0.3, 0.4, 0.6), strength=1.0)),
                       ("volume", dict(anisotropy=0.9))]),
    # v_glow_dense taken apart: its anisotropy alone, and its density and albedo at g 0
    "v_glow_g6": ("p_glowing_smoke", "g 0.6", [("volume", dict(anisotropy=0.6))]),
    "v_glow_dense_g0": ("p_glowing_smoke", "density 12, albedo 0.95, g 0",
                        [("volume", dict(density=12.0, color=0.95, anisotropy=0.0))]),
}


def _principled(material):
    return next(n for n in material.node_tree.nodes if n.bl_idname == "ShaderNodeVolumePrincipled")


def _set(node, density=None, color=None, anisotropy=None):
    if density is not None:
        node.inputs["Density"].default_value = density
    if color is not None:
        node.inputs["Color"].default_value = (color, color, color, 1.0)
    if anisotropy is not None:
        node.inputs["Anisotropy"].default_value = anisotropy


def _volume_objects(sc):
    return [o for o in sc.objects if o.type == "VOLUME" or
            (o.type == "MESH" and o.active_material is not None and
             o.active_material.node_tree is not None and
             any(n.bl_idname == "ShaderNodeVolumePrincipled" for n in o.active_material.node_tree.nodes))]


def _volume_box(sc):
    """(lo, hi): the world box of the scene's first Volume object, or else of its first
    volume mesh (its bound box's corners, transformed)."""
    import mathutils
    vol = next((o for o in sc.objects if o.type == "VOLUME"), None) or _volume_objects(sc)[0]
    cs = [vol.matrix_world @ mathutils.Vector(c) for c in vol.bound_box]
    return ([min(c[i] for c in cs) for i in range(3)], [max(c[i] for c in cs) for i in range(3)])


def apply(sc, step: str, kw: dict) -> None:
    """One recipe step on the open scene ``sc``."""
    import bpy
    if step == "volume":
        for o in _volume_objects(sc):
            _set(_principled(o.active_material), **kw)
    elif step == "world_fog":
        node = next(n for n in sc.world.node_tree.nodes
                    if n.bl_idname in ("ShaderNodeVolumePrincipled", "ShaderNodeVolumeScatter"))
        node.inputs["Density"].default_value = kw["density"]
        node.inputs["Anisotropy"].default_value = kw["anisotropy"]
    elif step == "lamp":
        ob = next(o for o in sc.objects if o.type == "LIGHT" and o.data.type == "POINT")
        ob.data.energy = kw.get("energy", ob.data.energy)
        ob.data.shadow_soft_size = kw.get("radius", ob.data.shadow_soft_size)
        if "location" in kw:
            ob.location = kw["location"]
    elif step == "lamp_in_volume":
        lo, hi = _volume_box(sc)
        ob = next(o for o in sc.objects if o.type == "LIGHT" and o.data.type == "POINT")
        ob.data.energy, ob.data.shadow_soft_size = kw["energy"], kw["radius"]
        ob.location = (0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]),
                       lo[2] + kw["height"] * (hi[2] - lo[2]))
    elif step == "hide_lights":   # every light of a kind
        for o in sc.objects:
            if o.type == "LIGHT" and o.data.type == kw["kind"]:
                o.hide_render = True
    elif step == "add_light":
        data = bpy.data.lights.new("added_" + kw["kind"].lower(), kw["kind"])
        data.energy = kw["energy"]
        if kw["kind"] == "AREA":
            data.size = kw["size"]
        elif kw["kind"] == "SUN":
            data.angle = kw.get("angle", data.angle)
        else:
            data.shadow_soft_size = kw["radius"]
        if kw["kind"] == "SPOT":
            data.spot_size, data.spot_blend = kw["spot_size"], kw["spot_blend"]
        ob = bpy.data.objects.new(data.name, data)
        sc.collection.objects.link(ob)
        if "location" in kw:
            ob.location = kw["location"]
        else:   # over the first volume's box: its middle, at `height` of it, `above` higher
            lo, hi = _volume_box(sc)
            ob.location = (0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]),
                           lo[2] + kw["height"] * (hi[2] - lo[2]) + kw.get("above", 0.0))
        ob.rotation_euler = kw.get("rotation", (0.0, 0.0, 0.0))
    elif step == "noise_density":   # the shader texture's multiplier (families.noise_density)
        for o in _volume_objects(sc):
            for n in o.active_material.node_tree.nodes:
                if n.bl_idname == "ShaderNodeMath" and n.operation == "MULTIPLY":
                    n.inputs[1].default_value = kw["density"]
    elif step == "world":   # the background's colour and strength
        bg = next(n for n in sc.world.node_tree.nodes if n.bl_idname == "ShaderNodeBackground")
        bg.inputs["Color"].default_value = (*kw["color"], 1.0)
        bg.inputs["Strength"].default_value = kw["strength"]
    elif step == "emission":   # a constant emission on every volume's Principled Volume
        for o in _volume_objects(sc):
            node = _principled(o.active_material)
            node.inputs["Emission Color"].default_value = (*kw["color"], 1.0)
            node.inputs["Emission Strength"].default_value = kw["strength"]
    elif step == "ground":   # the base colour of the surfaces' materials named ground*
        for mat in bpy.data.materials:
            if mat.name.startswith("ground") and mat.node_tree is not None:
                bsdf = mat.node_tree.nodes.get("Principled BSDF")
                bsdf.inputs["Base Color"].default_value = (*kw["color"], 1.0)
                if "specular" in kw:   # 'Specular IOR Level' (0.5: F0 0.04 at IOR 1.5)
                    bsdf.inputs["Specular IOR Level"].default_value = kw["specular"]
    elif step == "sun":
        for o in sc.objects:
            if o.type == "LIGHT" and o.data.type == "SUN":
                o.rotation_euler = kw["rotation"]
    elif step == "camera":
        sc.camera.location = kw["location"]
        if "rotation" in kw:
            sc.camera.rotation_euler = kw["rotation"]
    elif step == "lift":
        for o in _volume_objects(sc):
            o.location.z += kw["dz"]
    elif step == "sun_to_spot":
        for o in sc.objects:
            if o.type == "LIGHT" and o.data.type == "SUN":
                o.hide_render = True
        data = bpy.data.lights.new("wide_spot", "SPOT")
        data.energy, data.spot_size, data.spot_blend = 4000.0, math.radians(100), 0.3
        data.shadow_soft_size = 0.2
        ob = bpy.data.objects.new("wide_spot", data)
        sc.collection.objects.link(ob)
        ob.location = (1.0, 1.0, 5.0)
    else:
        raise ValueError(step)


def build(name: str, work: str) -> str:
    """The variant's folder (scene.blend with absolute paths to its grids)."""
    import bpy
    src, _, recipe = VARIANTS[name]
    bpy.ops.wm.open_mainfile(filepath=os.path.join(SCENES, src, "scene.blend"))
    sc = bpy.context.scene
    for step, kw in recipe:
        apply(sc, step, kw)
    bpy.ops.file.make_paths_absolute()
    d = os.path.join(work, name)
    os.makedirs(d, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(d, "scene.blend"))
    return d


def cycles_refs(d: str, spp: int) -> float:
    """Cycles' ref_s1/2 and ss_s1/2 in ``d``; their seconds."""
    import bpy
    from mpp_render.blender import batch
    t = time.perf_counter()
    for multiple, stem in ((True, "ref"), (False, "ss")):
        for seed in (1, 2):
            bpy.ops.wm.open_mainfile(filepath=os.path.join(d, "scene.blend"))
            sc = bpy.context.scene
            batch.set_cycles_reference(sc, spp, multiple=multiple, seed=seed)
            batch.set_multilayer_exr(sc)
            bpy.ops.render.render()
            bpy.data.images["Render Result"].save_render(
                filepath=os.path.join(d, f"{stem}_s{seed}.exr"), scene=sc)
    return time.perf_counter() - t


def ours(d: str) -> dict:
    """Our full render (the scene's own settings) and single scattering (16 spp) scored."""
    import bpy
    from mpp_render import metrics
    from mpp_render.blender import batch
    from mpp_render.exr import read_passes
    out = {}
    for key, single in (("full", False), ("single", True)):
        refs = [read_passes(p)["Combined"][..., :3] for p in metrics.reference_paths(d, single)]
        bpy.ops.wm.open_mainfile(filepath=os.path.join(d, "scene.blend"))
        sc = bpy.context.scene
        if single:
            batch.set_mpp(sc, 16, multiple=False)
        else:
            sc.render.engine = "MPP_RENDER"
        t = time.perf_counter()
        rec = batch.render_current(sc, os.path.join(d, f"ours_{key}.exr"))
        m = metrics.compare(rec["_passes"]["Combined"][..., :3], refs)
        out[key] = {k: round(float(m[k]), 4) for k in ("rel_rmse_4", "floor_4", "bias")}
        out[key]["seconds"] = round(time.perf_counter() - t, 2)
    return out


def report(rows, out_dir: str, spp: int) -> None:
    lines = ["# Hold-out scenes", "",
             f"Generated by `benchmarks/holdout.py` on {time.strftime('%Y-%m-%d')} (Cycles "
             f"{spp} spp x 2 seeds per reference). Variants of public scenes that no constant "
             "was fitted on; ours at each scene's own settings (full) and at 16 spp with "
             "multiple scattering off (single), scored as the suite is (rel_rmse_4, floor_4 "
             "and bias of `shared/reference/metrics.md`).", "",
             "| variant | from | what changes | full | single |", "|---|---|---|---|---|"]
    for r in rows:
        f, s = r["full"], r["single"]
        lines.append(f"| {r['variant']} | {r['from']} | {r['change']} | {f['rel_rmse_4']:.4f} "
                     f"(floor {f['floor_4']:.4f}, bias {f['bias']:+.4f}) | {s['rel_rmse_4']:.4f} "
                     f"(floor {s['floor_4']:.4f}, bias {s['bias']:+.4f}) |")
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, "holdout.md"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    with open(os.path.join(out_dir, "holdout.json"), "w") as fh:
        json.dump({"generated": time.strftime("%Y-%m-%d"), "cycles_spp": spp, "rows": rows},
                  fh, indent=1)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="")
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--work", default="")
    ap.add_argument("--out", default="")
    ap.add_argument("--keep", action="store_true", help="reuse references already in --work")
    args = ap.parse_args(argv)
    from mpp_render.blender import batch
    batch.register()
    names = [n for n in args.only.split(",") if n] or list(VARIANTS)
    work = args.work or tempfile.mkdtemp(prefix="mpp_holdout_")
    rows = []
    for name in names:
        d = os.path.join(work, name)
        have = all(os.path.exists(os.path.join(d, f"{s}_s{k}.exr")) for s in ("ref", "ss") for k in (1, 2))
        cyc = None
        if not (args.keep and have):
            build(name, work)
            cyc = round(cycles_refs(d, args.spp), 1)
        src, change, _ = VARIANTS[name]
        row = {"variant": name, "from": src, "change": change, "cycles_seconds": cyc, **ours(d)}
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.out:
        report(rows, args.out, args.spp)


if __name__ == "__main__":
    main()
