"""Lights in Cycles' units: power in W (POINT, SPOT, AREA), irradiance in W/m^2 (SUN)."""
from __future__ import annotations

from typing import List, Optional

import numpy as np

from ...scene import Light
from .convert import rgb, unit
from .materials import ClosureInputs, is_linked, output_closures
from .nodes import describe

KINDS = ("POINT", "SPOT", "SUN", "AREA")


def light_strength(light, where: str, warnings: List[str]) -> np.ndarray:
    """RGB strength as Cycles computes it: color x temperature colour (when
    ``use_temperature``) x energy x 2**exposure, times the emission of the light's node tree
    when it uses nodes."""
    s = rgb(light.color) * float(light.energy) * 2.0 ** float(light.exposure)
    if getattr(light, "use_temperature", False):
        s = s * rgb(light.temperature_color)
    if getattr(light, "use_nodes", False) and light.node_tree is not None:
        s = s * _node_emission(light.node_tree, where, warnings)
    return s


def _node_emission(tree, where, warnings) -> np.ndarray:
    """Colour x Strength of the Emission closures on a light's node tree output."""
    if not is_linked(tree, "Surface"):
        return np.ones(3)
    total = np.zeros(3)
    for c in output_closures(tree, "Surface", where, warnings):
        inp = ClosureInputs(c, where, warnings)
        if c.node.bl_idname == "ShaderNodeEmission":
            total += c.weight * inp.color("Color") * inp.number("Strength")
        else:
            warnings.append(f"{where}: shader {describe(c.node)} in the light's nodes is not "
                            "supported; ignored")
    return total


def light_from_object(ob, world_matrix: np.ndarray, warnings: List[str]) -> Optional[Light]:
    """A :class:`~mpp_render.scene.Light` for the evaluated light object ``ob`` placed by
    ``world_matrix`` (4x4); None (with a warning) for a light type that is not supported."""
    data = ob.data
    where = f"light '{ob.name}'"
    kind = data.type
    if kind not in KINDS:
        warnings.append(f"{where}: light type {kind} is not supported; skipped")
        return None
    m = np.array(world_matrix, dtype=np.float64)
    light = Light(kind=kind, name=ob.name, strength=light_strength(data, where, warnings),
                  position=m[:3, 3].copy(), direction=unit(-m[:3, 2]), matrix=m)
    if kind in ("POINT", "SPOT"):
        light.radius = float(data.shadow_soft_size)
    if kind == "SPOT":
        light.spot_size = float(data.spot_size)
        light.spot_blend = float(data.spot_blend)
        if getattr(data, "use_square", False):
            warnings.append(f"{where}: square spot cones are not supported; using a round cone")
    elif kind == "SUN":
        light.angle = float(data.angle)
    elif kind == "AREA":
        light.shape = data.shape
        light.size_x = float(data.size)
        light.size_y = float(data.size_y) if data.shape in ("RECTANGLE", "ELLIPSE") else float(data.size)
        light.normalize = bool(getattr(data, "normalize", True))
        if float(getattr(data, "spread", np.pi)) < np.pi - 1e-6:
            warnings.append(f"{where}: area light spread below 180 degrees is not supported; "
                            "using 180")
    if abs(float(getattr(data, "volume_factor", 1.0)) - 1.0) > 1e-9:
        warnings.append(f"{where}: a volume factor other than 1 is not supported; using 1")
    return light
