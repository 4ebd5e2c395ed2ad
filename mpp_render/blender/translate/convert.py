"""Small conversions from Blender values (mathutils, RNA arrays, node socket values) to numpy.

Nothing here keeps a reference to Blender data: every function returns fresh float64 arrays or
Python floats, so the results outlive the evaluated depsgraph.
"""
from __future__ import annotations

import numpy as np

# Rec.709 luminance weights: Blender converts a colour to a float socket with these.
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def matrix(m) -> np.ndarray:
    """4x4 float64 copy of a ``mathutils.Matrix`` (or any nested 4x4 sequence)."""
    return np.array([list(row) for row in m], dtype=np.float64).reshape(4, 4)


def rgb(value) -> np.ndarray:
    """RGB float64 (3,) from a socket value: a float is broadcast, RGBA drops alpha."""
    if isinstance(value, (int, float)):
        return np.full(3, float(value))
    a = np.array(list(value)[:3], dtype=np.float64)
    if a.size == 1:
        return np.full(3, float(a[0]))
    return a


def scalar(value) -> float:
    """A float from a socket value; a colour (or vector) maps to its Rec.709 luminance, as
    Blender's implicit colour -> float socket conversion does."""
    if isinstance(value, (int, float)):
        return float(value)
    return float(rgb(value) @ LUMINANCE)


def unit(v) -> np.ndarray:
    """``v`` normalised to length 1 (returned unchanged when it is zero)."""
    v = np.asarray(v, dtype=np.float64)
    n = float(np.linalg.norm(v))
    return v / n if n > 0.0 else v


def fmt(c) -> str:
    """Short human form of a colour or float for warnings."""
    if isinstance(c, (int, float)):
        return f"{float(c):g}"
    return "(" + ", ".join(f"{float(x):g}" for x in rgb(c)) + ")"
