"""The world: constant background radiance from the world's Surface shader, and its Volume
shader as a homogeneous fog filling all space (rendered by mpp_render.worldfog).

The fog is homogeneous, so an input a node tree drives (a field, materials.py) cannot vary
in it: each field is taken at one point, the camera's position (object and generated
coordinates are the world position there, as for Cycles' background shader; grids read 0),
with a warning naming the input and the value used.
"""
from __future__ import annotations

from typing import List, Optional

import numpy as np

from ...scene import Medium, World
from .convert import fmt, matrix, rgb
from .materials import (ClosureInputs, has_fields, is_linked, merge, output_closures, realise,
                        volume_shading)
from .nodes import describe
from .shadergraph import point_sampler


def world_from_scene(scene, warnings: List[str]) -> World:
    """``World.color`` = sum of the Background (and Emission) closures' Color x Strength
    reaching the world output's Surface, in W/(m^2 sr).  ``World.volume``: the closures
    reaching its Volume (Principled Volume, Volume Scatter / Absorption / Coefficients,
    Emission, through Mix / Add Shader and groups, as for materials) merged into one
    homogeneous medium; the world has no grids, so density attributes count as 1 and
    blackbody emission uses the constant Temperature.  No world: black, no fog."""
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
    return World(color=color, volume=world_volume(world, where, warnings,
                                                  camera_position(scene)))


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
