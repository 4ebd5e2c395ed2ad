"""Socket types of shader nodes and the conversions Blender makes at a link (no bpy).

Values are VALUE (N,), VECTOR (N, 3) or RGBA (N, 3: alpha has its own outputs) float64.  A
link converts as Blender does (Cycles' ``svm_node_convert``, Geometry Nodes' implicit
conversions): RGBA -> VALUE is the Rec.709 luminance 0.2126 R + 0.7152 G + 0.0722 B (the
weights of Blender's default colour management; Geometry Nodes give exactly these),
VECTOR -> VALUE the mean of x, y, z, VALUE -> VECTOR / RGBA broadcasts, VECTOR <-> RGBA
passes the three components.
"""
from __future__ import annotations

from typing import Tuple

import numpy as np

VALUE, VECTOR, RGBA = "VALUE", "VECTOR", "RGBA"
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def type_of(constant) -> str:
    """The socket type a constant belongs to: float VALUE, 3-tuple VECTOR, 4-tuple RGBA."""
    if np.ndim(constant) == 0:
        return VALUE
    return RGBA if len(constant) == 4 else VECTOR


def convert(values: np.ndarray, source: str, target: str) -> np.ndarray:
    """``values`` of socket type ``source`` as ``target`` (see the module docstring)."""
    if target == VALUE:
        if source == VALUE:
            return values
        return values @ LUMINANCE if source == RGBA else values.mean(axis=-1)
    if source == VALUE:
        return np.repeat(np.asarray(values)[..., None], 3, axis=-1)
    return values


def constant_array(constant, n: int) -> Tuple[np.ndarray, str]:
    kind = type_of(constant)
    if kind == VALUE:
        return np.full(n, float(constant)), kind
    return np.tile(np.asarray(constant, np.float64)[:3], (n, 1)), kind
