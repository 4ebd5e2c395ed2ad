"""Translate Blender's evaluated depsgraph into the bpy-free :class:`SceneDescription`.

Everything is copied into numpy arrays and dataclasses, because the evaluated objects are
freed when ``RenderEngine.render`` returns.  Scene content that cannot be rendered (an
unsupported node, light type or camera, a missing .vdb, bad voxel values, ...) never raises:
it is skipped or approximated and explained by a message in ``SceneDescription.warnings``.

Modules: ``camera`` (view plane, camera matrix), ``lights``, ``materials`` (volume and surface
shaders to constant coefficients, built on ``nodes``), ``meshes`` (volume meshes voxelised by
``voxelise``, opaque meshes as surfaces), ``vdb`` (Volume objects), ``fluid`` (Mantaflow smoke
domains), ``world``.

Work that does not change from frame to frame is kept in ``mpp_render.cache``: voxelised
mesh interiors under a hash of the mesh's vertices and triangles (kind 'voxels'), grids of
unchanged .vdb files ('vdb') and fluid cache frames ('fluid').
"""
from __future__ import annotations

import dataclasses
from typing import Optional, Set

import numpy as np

from ...cache import CACHE, digest
from ...lights import is_dark
from ...scene import Camera, SceneDescription, Settings
from .camera import camera_from_object, default_camera, render_size
from .convert import matrix
from .fluid import FluidTranslator, fluid_domain
from .lights import light_from_object
from .materials import is_linked
from .meshes import MeshTranslator, mesh_arrays, slot_materials
from .vdb import VolumeTranslator
from .world import FIELD_SOURCE, textured_fog, world_from_scene

__all__ = ["scene_from_depsgraph", "retranslate"]

# Object types Cycles renders as geometry but this engine does not (yet).
UNSUPPORTED_GEOMETRY = {"CURVES": "hair curves", "POINTCLOUD": "point clouds"}
# Object types whose evaluated geometry is a mesh reached through ``to_mesh``.
MESH_LIKE = ("CURVE", "SURFACE", "META", "FONT")


def scene_from_depsgraph(depsgraph, settings: Settings, camera_override=None,
                         width: Optional[int] = None, height: Optional[int] = None,
                         camera: Optional[Camera] = None) -> SceneDescription:
    """The :class:`~mpp_render.scene.SceneDescription` of one frame of ``depsgraph``'s view
    layer.

    ``settings``: already filled by the caller (``voxel_resolution`` is used here).
    ``camera_override``: the evaluated camera object to render from (the RenderEngine's), else
    ``depsgraph.scene_eval.camera``.  ``width``/``height``: image size in pixels, by default
    the scene's render resolution x percentage.  ``camera``: a camera already made (the
    viewport's view, blender/viewport.py), used as it is instead of a camera object."""
    scene = depsgraph.scene_eval
    warnings = []
    if width is None or height is None:
        w, h = render_size(scene)
        width, height = width or w, height or h
    cam_ob = camera_override if camera_override is not None else scene.camera
    if camera is None and cam_ob is None:
        warnings.append("the scene has no camera; rendering from the origin looking down -Z")
        camera = default_camera(width, height)
    elif camera is None:
        camera = camera_from_object(cam_ob, scene, width, height, warnings)
    desc = SceneDescription(camera=camera, settings=settings, warnings=warnings)
    if getattr(scene.render, "use_motion_blur", False):
        warnings.append("motion blur is not supported yet; the frame is rendered without it")
    try:
        desc.world = world_from_scene(scene, warnings, textured=True)
    except Exception as e:  # safety net, as for objects
        warnings.append(f"the world could not be translated ({type(e).__name__}: {e}); "
                        "using black")
    _objects(depsgraph, desc, settings)
    desc.media = desc.media + _world_fog(scene, camera, settings, warnings)
    unlit = _unlit_message(desc)
    if unlit:
        desc.warnings.append(unlit)
    desc.warnings = list(dict.fromkeys(warnings))  # instances repeat the same message
    return desc


def retranslate(depsgraph, settings: Settings, previous: Optional[SceneDescription],
                parts: Set[str], camera: Camera) -> SceneDescription:
    """``previous`` with the ``parts`` ('lights', 'geometry': media and surfaces, 'world',
    or 'all': the scene's settings, a new frame) translated again from
    ``depsgraph`` and ``camera`` and ``settings`` put in; the rest is kept as it was (the same
    objects, so the precompute's cache keys match).  No ``previous`` or 'all' translates the
    whole scene.  The warnings of the parts translated again are added to the earlier ones."""
    if previous is None or "all" in parts:
        return scene_from_depsgraph(depsgraph, settings, camera=camera)
    desc = dataclasses.replace(previous, camera=camera, settings=settings,
                               warnings=list(previous.warnings))
    if "world" in parts:
        desc.world = world_from_scene(depsgraph.scene_eval, desc.warnings, textured=True)
    objects = {"lights", "geometry"} & set(parts)
    if objects:
        fresh = SceneDescription(camera=camera, settings=settings, warnings=desc.warnings)
        _objects(depsgraph, fresh, settings, only=None if len(objects) == 2 else objects.pop())
        if "lights" in parts:
            desc.lights = fresh.lights
        if "geometry" in parts:
            desc.media, desc.surfaces = fresh.media, fresh.surfaces
    # a world fog that varies in space lies on a grid over the view: again with the world or
    # a new camera, else the one made before (the same objects, for the cache's keys)
    fog = [m for m in previous.media if m.source == FIELD_SOURCE]
    if "world" in parts or not _same_view(camera, previous.camera):
        fog = _world_fog(depsgraph.scene_eval, camera, settings, desc.warnings)
    desc.media = [m for m in desc.media if m.source != FIELD_SOURCE] + fog
    desc.warnings = list(dict.fromkeys(desc.warnings))
    return desc


def _same_view(a: Camera, b: Camera) -> bool:
    """Whether cameras ``a`` and ``b`` are the same in every field."""
    return all(np.array_equal(np.asarray(x), np.asarray(y))
               for x, y in zip(dataclasses.astuple(a), dataclasses.astuple(b)))


def _world_fog(scene, camera: Camera, settings: Settings, warnings) -> list:
    """The world's fog as media on a grid over the view where a node tree varies it in
    space (world.textured_fog), else none."""
    try:
        return textured_fog(scene, camera, settings.voxel_resolution, warnings) or []
    except Exception as e:  # safety net, as for objects
        warnings.append(f"the world's fog could not be translated ({type(e).__name__}: {e}); "
                        "it is left out")
        return []


def _objects(depsgraph, desc: SceneDescription, settings: Settings,
             only: Optional[str] = None) -> None:
    """Lights, media and surfaces of every render-visible object instance (``only``
    'lights': the lights alone; 'geometry': all but the lights).  An instance that fails to
    translate is skipped with a warning naming it, so one bad object never costs the whole
    frame."""
    meshes = MeshTranslator(settings.voxel_resolution, desc.warnings)
    meshes._cache = CACHE.store("voxels")  # keyed by mesh content (_mesh_key): kept across frames
    volumes = VolumeTranslator(desc.warnings)
    fluids = FluidTranslator(desc.warnings, depsgraph.scene_eval.frame_current)
    for inst in depsgraph.object_instances:
        if not getattr(inst, "show_self", True):
            continue
        ob = inst.object
        if only is not None and (ob.type == "LIGHT") != (only == "lights"):
            continue
        try:
            _instance(ob, matrix(inst.matrix_world), meshes, volumes, fluids, desc)
        except Exception as e:  # safety net: report, keep the rest of the scene
            desc.warnings.append(f"object '{ob.name}' could not be translated "
                                 f"({type(e).__name__}: {e}); skipped")


def _instance(ob, world_matrix, meshes: MeshTranslator, volumes: VolumeTranslator,
              fluids: FluidTranslator, desc: SceneDescription) -> None:
    """Translate one evaluated object placed by ``world_matrix`` into ``desc``."""
    kind = ob.type
    if kind == "LIGHT":
        light = light_from_object(ob, world_matrix, desc.warnings)
        if light is not None:
            if np.any(np.asarray(light.strength) < 0):
                desc.warnings.append(f"light '{ob.name}': negative power is not supported; "
                                     "the light emits nothing")
            desc.lights.append(light)
    elif kind == "MESH":
        domain = fluid_domain(ob)
        if domain is not None:  # a smoke domain renders its grids, not its mesh (as Cycles)
            desc.media.extend(fluids.translate(ob, domain, world_matrix))
            return
        media, surfaces = meshes.translate(ob, ob.data, world_matrix,
                                           cache_key=_mesh_key(ob, ob.data))
        desc.media.extend(media)
        desc.surfaces.extend(surfaces)
    elif kind in MESH_LIKE:
        _mesh_like(ob, world_matrix, meshes, desc)
    elif kind == "VOLUME":
        desc.media.extend(volumes.translate(ob, world_matrix))
    elif kind in UNSUPPORTED_GEOMETRY:
        desc.warnings.append(f"object '{ob.name}': {UNSUPPORTED_GEOMETRY[kind]} are not "
                             "supported; skipped")


def _unlit_message(desc: SceneDescription) -> Optional[str]:
    """A warning when volumes are in the frame but nothing lights them (no light with
    positive power, a black world, no emission): the frame would be black without a word."""
    if not desc.media or any(not is_dark(light) for light in desc.lights):
        return None
    if np.any(np.asarray(desc.world.color) > 0):
        return None
    if any(np.any(np.asarray(m.emission) > 0) or m.emission_grid is not None
           for m in desc.media):
        return None
    if desc.world.volume is not None and np.any(np.asarray(desc.world.volume.emission) > 0):
        return None
    what = ("the scene has no lights" if not desc.lights else
            "no light of the scene has positive power")
    return f"{what} and the world is black: the volumes receive no light and render black"


def _mesh_like(ob, world_matrix, meshes: MeshTranslator, desc: SceneDescription) -> None:
    """Curves, surfaces, metaballs and text through their evaluated mesh."""
    try:
        mesh = ob.to_mesh()
    except RuntimeError:
        mesh = None
    if mesh is None:
        return
    try:
        media, surfaces = meshes.translate(ob, mesh, world_matrix, cache_key=_mesh_key(ob, mesh))
        desc.media.extend(media)
        desc.surfaces.extend(surfaces)
    finally:
        ob.to_mesh_clear()


def _mesh_key(ob, mesh):
    """The voxelisation key of a mesh with a volume material: a hash of its vertices and
    triangles, so an unchanged mesh is voxelised once across frames; None for other meshes
    (they are not voxelised)."""
    if not any(m is not None and is_linked(getattr(m, "node_tree", None), "Volume")
               for m in slot_materials(ob, mesh)
               if getattr(m, "node_tree", None) is not None):
        return None
    verts, tris, _ = mesh_arrays(mesh)
    return digest(verts, tris)
