"""The world: constant background radiance from the world's Surface shader, and its Volume
shader as a homogeneous fog filling all space (rendered by mpp_render.worldfog)."""
from __future__ import annotations

from typing import List

import numpy as np

from ...scene import Medium, World
from .convert import rgb
from .materials import ClosureInputs, is_linked, merge, output_closures, volume_shading
from .nodes import describe


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
    return World(color=color, volume=world_volume(world, where, warnings))


def world_volume(world, where: str, warnings: List[str]):
    """The world's Volume shader as a 'WORLD' Medium (coefficients in 1/m, emission in
    W/(m^3 sr)), or None when nothing is linked into it or it neither attenuates nor emits."""
    if not is_linked(world.node_tree, "Volume"):
        return None
    groups = volume_shading(world, where, warnings)
    if not groups:
        return None
    co = merge(groups)
    sigma_s = np.maximum(np.asarray(co.sigma_s, np.float64), 0.0)
    sigma_a = np.maximum(np.asarray(co.sigma_a, np.float64), 0.0)
    emission = np.maximum(np.asarray(co.emission, np.float64), 0.0)
    if not (np.any(sigma_s + sigma_a > 0) or np.any(emission > 0)):
        return None
    return Medium(name=f"world '{world.name}'", density=np.ones((1, 1, 1), np.float32),
                  index_to_world=np.eye(4), sigma_s=sigma_s, sigma_a=sigma_a, g=float(co.g),
                  emission=emission, source="WORLD")
