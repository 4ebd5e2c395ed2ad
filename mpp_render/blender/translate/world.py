"""The world: constant background radiance from the world's Surface shader, and its Volume
shader as a fog filling all space (rendered by mpp_render.worldfog).

A fog whose inputs no node tree varies in space is homogeneous and endless (``World.volume``,
worldfog.py).  One whose inputs a node tree varies in space (a height fog from a Gradient of
the position, a Noise fog; object and generated coordinates are the world position, as for
Cycles' background shader; grids read 0) is evaluated on a grid over the view instead
(``textured_fog``): the camera-aligned box round the view frustum (worldfog.frustum_box) to
the depth its own extinction needs (worldfog.field_depth), at the Voxel Resolution, as one
medium per group of closures that share their fields ('WORLD_FIELD', interpolated like a
grid).  What lies beyond that box (behind the camera, outside the frustum, past the depth) is
left out: its shadows on the lights and its light.
"""
from __future__ import annotations

from typing import List, Optional

import numpy as np

from ... import worldfog
from ...cache import CACHE
from ...scene import Camera, Medium, World
from .convert import fmt, matrix, rgb
from .materials import (ClosureInputs, has_fields, is_linked, merge, output_closures, realise,
                        volume_shading)
from .nodes import describe
from .shadergraph import FieldContext, point_sampler, points_sampler

FIELD_SOURCE = "WORLD_FIELD"  # a world fog that varies in space, on its grid (module docstring)


def world_from_scene(scene, warnings: List[str], textured: bool = False) -> World:
    """``World.color`` = sum of the Background (and Emission) closures' Color x Strength
    reaching the world output's Surface, in W/(m^2 sr).  ``World.volume``: the closures
    reaching its Volume (Principled Volume, Volume Scatter / Absorption / Coefficients,
    Emission, through Mix / Add Shader and groups, as for materials) merged into one
    homogeneous medium; the world has no grids, so density attributes count as 1 and
    blackbody emission uses the constant Temperature.  With ``textured``, a fog that a node
    tree varies in space is left to ``textured_fog`` (``World.volume`` None); without it, its
    inputs are taken at the camera, with a warning.  No world: black, no fog."""
    world = scene.world
    if world is None:
        return World()
    where = f"world '{world.name}'"
    tree = world.node_tree
    if tree is None:
        return World(color=rgb(world.color))
    color = np.zeros(3)
    for c in output_closures(tree, "Surface", where, warnings):
        kind = c.node.bl_idname
        inp = ClosureInputs(c, where, warnings)
        if kind in ("ShaderNodeBackground", "ShaderNodeEmission"):
            color += c.weight * inp.color("Color") * inp.number("Strength")
        else:
            warnings.append(f"{where}: shader {describe(c.node)} is not supported; ignored")
    if textured and varies_in_space(world, where):
        return World(color=color)
    return World(color=color, volume=world_volume(world, where, warnings,
                                                  camera_position(scene)))


def varies_in_space(world, where: str) -> bool:
    """Whether a node tree varies the inputs of ``world``'s Volume shader in space."""
    if world.node_tree is None or not is_linked(world.node_tree, "Volume"):
        return False
    return any(has_fields(co) and _varies(co) for co in volume_shading(world, where, []))


def camera_position(scene) -> Optional[np.ndarray]:
    """World position (m) of the scene's camera, or None without one."""
    cam = getattr(scene, "camera", None)
    if cam is None:
        return None
    return matrix(cam.matrix_world)[:3, 3]


def world_volume(world, where: str, warnings: List[str], at=None):
    """The world's Volume shader as a 'WORLD' Medium (coefficients in 1/m, emission in
    W/(m^3 sr)), or None when nothing is linked into it or it neither attenuates nor emits.
    Fields are taken at the point ``at`` (the camera position; None: the origin)."""
    if not is_linked(world.node_tree, "Volume"):
        return None
    groups = volume_shading(world, where, warnings)
    if not groups:
        return None
    at = np.zeros(3) if at is None else np.asarray(at, np.float64)
    sample = point_sampler(at, lambda f: warnings.append(
        f"{where}: {f.describe()} varies in space, but the world's fog is homogeneous; the MPP "
        f"engine uses its value at the camera {fmt(tuple(at))}"))
    groups = [_folded(co, sample, where, warnings) for co in groups]
    co = merge(groups)
    sigma_s = np.maximum(np.asarray(co.sigma_s, np.float64), 0.0)
    sigma_a = np.maximum(np.asarray(co.sigma_a, np.float64), 0.0)
    emission = np.maximum(np.asarray(co.emission, np.float64), 0.0)
    if not (np.any(sigma_s + sigma_a > 0) or np.any(emission > 0)):
        return None
    return Medium(name=f"world '{world.name}'", density=np.ones((1, 1, 1), np.float32),
                  index_to_world=np.eye(4), sigma_s=sigma_s, sigma_a=sigma_a, g=float(co.g),
                  emission=emission, source="WORLD")


def _folded(co, sample, where, warnings):
    """Closures ``co`` with their fields taken at one point (``sample``) and folded into the
    constant coefficients and emission."""
    if not has_fields(co):
        return co
    density, out, grid = realise(co, np.ones(1, np.float32), sample, lambda name: None,
                                 where, warnings, per_point=False)[:3]   # one point: one colour
    d = float(density[0])
    out.sigma_s = out.sigma_s * d
    out.sigma_a = out.sigma_a * d
    if grid is not None:
        out.emission = out.emission + np.asarray(grid[0], np.float64)
    return out


def _varies(co) -> bool:
    """Whether any field of closures ``co`` varies in space."""
    seen = []
    realise(co, np.ones(1, np.float32), point_sampler(np.zeros(3), seen.append),
            lambda name: None, "", [], per_point=False)
    return bool(seen)


def textured_fog(scene, camera: Camera, resolution: int,
                 warnings: List[str]) -> Optional[List[Medium]]:
    """The world's fog as media on a grid over the view of ``camera`` (module docstring),
    ``resolution`` voxels along the box's longest side; None where no node tree varies the
    fog's inputs in space (the homogeneous endless fog of ``world_volume`` serves) or the
    world has no Volume."""
    world = scene.world
    if world is None or world.node_tree is None or not is_linked(world.node_tree, "Volume"):
        return None
    where = f"world '{world.name}'"
    if not varies_in_space(world, where):
        return None
    groups = volume_shading(world, where, warnings)

    def realised(co, sample, n):
        if not has_fields(co):
            return np.ones(n, np.float32), co, None, None, None
        return realise(co, np.ones(n, np.float32), sample, lambda name: None, where, [])

    def extinction_at(points):
        sample = points_sampler(points)
        total = np.zeros(len(points))
        for co in groups:
            density, out, _, _, ext = realised(co, sample, len(points))
            st = np.asarray(out.sigma_s, np.float64) + np.asarray(out.sigma_a, np.float64)
            per = np.asarray(density, np.float64)[:, None] * st[None, :]
            if ext is not None:
                per = per * np.asarray(ext, np.float64).reshape(-1, 3)
            total += per.max(axis=1)
        return total

    depth = worldfog.field_depth(camera, extinction_at)
    near = max(float(camera.clip_start), 0.0)
    shape, i2w, voxel = worldfog.frustum_box(camera, near, depth, resolution)
    fields = FieldContext(None, float(scene.frame_current), CACHE.store("voxels"))
    sampler = fields.sampler(shape, i2w, np.eye(4))
    media = []
    for i, co in enumerate(groups):
        if has_fields(co):
            density, out, grid, scatter, ext = realise(co, np.ones(shape, np.float32), sampler,
                                                       lambda name: None, where, warnings)
        else:
            density, out, grid, scatter, ext = np.ones(shape, np.float32), co, None, None, None
        if grid is not None and not np.any(grid > 0):
            grid = None
        if not np.any(density > 0) and grid is None and not np.any(out.emission > 0):
            continue
        media.append(Medium(name=where if len(groups) == 1 else f"{where}:{i}",
                            density=np.asarray(density, np.float32).reshape(shape),
                            index_to_world=i2w, sigma_s=np.maximum(out.sigma_s, 0.0),
                            sigma_a=np.maximum(out.sigma_a, 0.0), g=float(out.g),
                            emission=np.maximum(out.emission, 0.0), source=FIELD_SOURCE,
                            emission_grid=grid, scatter_grid=scatter, extinction_grid=ext))
    warnings.append(f"{where}: its fog varies in space; the MPP engine renders it on a grid "
                    f"over the view, {depth:.3g} m deep ({voxel:.3g} m voxels), and leaves "
                    "out the fog beyond it")
    return media
