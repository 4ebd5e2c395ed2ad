"""The world: constant background radiance from the world's Surface shader."""
from __future__ import annotations

from typing import List

import numpy as np

from ...scene import World
from .convert import rgb
from .materials import ClosureInputs, output_closures, is_linked
from .nodes import describe


def world_from_scene(scene, warnings: List[str]) -> World:
    """``World.color`` = sum of the Background (and Emission) closures' Color x Strength
    reaching the world output's Surface, in W/(m^2 sr).  A world Volume is not supported yet
    (warned).  No world: black."""
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
    if is_linked(tree, "Volume"):
        warnings.append(f"{where}: world volume not supported yet; ignored")
    return World(color=color)
