"""The Math and Vector Math nodes' operations, vectorised with numpy (no bpy).

Each operation is one entry of a table keyed by Blender's enum identifier (the nodes'
``operation``).  They follow Cycles' ``intern/cycles/kernel/svm/math_util.h`` and Geometry
Nodes' ``source/blender/nodes/NOD_math_functions.hh`` (the two agree), with the *safe*
functions of ``source/blender/blenlib/intern/math_base_safe_inline.cc``:

* ``safe_divide(a, b)`` = a / b, 0 where b = 0; ``safe_modf`` = fmod(a, b), 0 where b = 0
  (Math 'MODULO', truncated); ``safe_floored_modf`` = a - floor(a / b) b, 0 where b = 0;
* ``safe_powf(a, b)`` = 0 for a negative base with a non-integer exponent, else pow(a, b)
  (0 ** -1 stays inf, as C's powf);
* ``safe_logf(a, base)`` = log(a) / log(base), 0 where a <= 0 or base <= 0 (or log(base) 0);
* ``safe_sqrtf(a)`` = sqrt(max(a, 0)); ``safe_inverse_sqrtf(a)`` = 1 / sqrt(a), 0 where a <= 0;
* ``safe_asinf`` / ``safe_acosf`` clamp their argument to [-1, 1];
* ``wrapf(v, max, min)`` = v - (max - min) floor((v - min) / (max - min)), ``min`` where the
  range is 0; ``pingpongf(v, s)`` = |fract((v - s) / 2s) 2s - s|, 0 where s = 0;
  ``smoothminf(a, b, k)`` = min(a, b) - h^3 k / 6 with h = max(k - |a - b|, 0) / k (plain
  min for k = 0); 'SMOOTH_MAX' is -smoothminf(-a, -b, k); 'COMPARE' is 1 where
  |a - b| <= max(c, FLT_EPSILON).

Inputs and outputs are float64 arrays that broadcast: scalars (N,) for Math; (N, 3) vectors
and (N,) scalars for Vector Math.
"""
from __future__ import annotations

from typing import Callable, Dict, Tuple

import numpy as np

FLT_EPSILON = float(np.finfo(np.float32).eps)


def _quiet(fn):
    """``fn`` with numpy's floating-point warnings off (the safe functions mask the cases)."""
    def run(*args):
        with np.errstate(all="ignore"):
            return fn(*args)
    run.__doc__ = fn.__doc__
    return run


@_quiet
def safe_divide(a, b):
    a, b = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64))
    return np.where(b != 0.0, a / np.where(b != 0.0, b, 1.0), 0.0)


@_quiet
def safe_modf(a, b):
    a, b = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64))
    return np.where(b != 0.0, np.fmod(a, np.where(b != 0.0, b, 1.0)), 0.0)


@_quiet
def safe_floored_modf(a, b):
    a, b = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64))
    safe_b = np.where(b != 0.0, b, 1.0)
    return np.where(b != 0.0, a - np.floor(a / safe_b) * b, 0.0)


@_quiet
def safe_powf(a, b):
    a, b = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(b, np.float64))
    bad = (a < 0.0) & (b != np.trunc(b))
    return np.where(bad, 0.0, np.power(a, b))


@_quiet
def safe_logf(a, base):
    a, base = np.broadcast_arrays(np.asarray(a, np.float64), np.asarray(base, np.float64))
    ok = (a > 0.0) & (base > 0.0)
    la = np.log(np.where(ok, a, 1.0))
    lb = np.log(np.where(ok, base, 1.0))
    return np.where(ok, safe_divide(la, lb), 0.0)


@_quiet
def safe_inverse_sqrtf(a):
    a = np.asarray(a, np.float64)
    return np.where(a > 0.0, 1.0 / np.sqrt(np.where(a > 0.0, a, 1.0)), 0.0)


def fract(a):
    return a - np.floor(a)


@_quiet
def wrapf(value, hi, lo):
    value, hi, lo = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in (value, hi, lo)))
    span = hi - lo
    safe = np.where(span != 0.0, span, 1.0)
    return np.where(span != 0.0, value - span * np.floor((value - lo) / safe), lo)


@_quiet
def pingpongf(value, scale):
    value, scale = np.broadcast_arrays(np.asarray(value, np.float64), np.asarray(scale, np.float64))
    safe = np.where(scale != 0.0, scale, 1.0)
    out = np.abs(fract((value - scale) / (safe * 2.0)) * scale * 2.0 - scale)
    return np.where(scale != 0.0, out, 0.0)


@_quiet
def smoothminf(a, b, k):
    a, b, k = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in (a, b, k)))
    safe = np.where(k != 0.0, k, 1.0)
    h = np.maximum(k - np.abs(a - b), 0.0) / safe
    return np.where(k != 0.0, np.minimum(a, b) - h * h * h * k / 6.0, np.minimum(a, b))


def _compare(a, b, c):
    return ((a == b) | (np.abs(a - b) <= np.maximum(c, FLT_EPSILON))).astype(np.float64)


# Math: operation -> f(a, b, c) for the inputs Value, Value_001, Value_002
MATH: Dict[str, Callable] = {
    "ADD": lambda a, b, c: a + b,
    "SUBTRACT": lambda a, b, c: a - b,
    "MULTIPLY": lambda a, b, c: a * b,
    "DIVIDE": lambda a, b, c: safe_divide(a, b),
    "MULTIPLY_ADD": lambda a, b, c: a * b + c,
    "POWER": lambda a, b, c: safe_powf(a, b),
    "LOGARITHM": lambda a, b, c: safe_logf(a, b),
    "SQRT": lambda a, b, c: np.sqrt(np.maximum(a, 0.0)),
    "INVERSE_SQRT": lambda a, b, c: safe_inverse_sqrtf(a),
    "ABSOLUTE": lambda a, b, c: np.abs(a),
    "EXPONENT": _quiet(lambda a, b, c: np.exp(a)),
    "MINIMUM": lambda a, b, c: np.minimum(a, b),
    "MAXIMUM": lambda a, b, c: np.maximum(a, b),
    "LESS_THAN": lambda a, b, c: (a < b).astype(np.float64),
    "GREATER_THAN": lambda a, b, c: (a > b).astype(np.float64),
    "SIGN": lambda a, b, c: np.sign(a),
    "COMPARE": _compare,
    "SMOOTH_MIN": lambda a, b, c: smoothminf(a, b, c),
    "SMOOTH_MAX": lambda a, b, c: -smoothminf(-a, -b, c),
    "ROUND": lambda a, b, c: np.floor(a + 0.5),
    "FLOOR": lambda a, b, c: np.floor(a),
    "CEIL": lambda a, b, c: np.ceil(a),
    "TRUNC": lambda a, b, c: np.trunc(a),
    "FRACT": lambda a, b, c: fract(a),
    "MODULO": lambda a, b, c: safe_modf(a, b),
    "FLOORED_MODULO": lambda a, b, c: safe_floored_modf(a, b),
    "WRAP": lambda a, b, c: wrapf(a, b, c),
    "SNAP": lambda a, b, c: np.floor(safe_divide(a, b)) * b,
    "PINGPONG": lambda a, b, c: pingpongf(a, b),
    "SINE": lambda a, b, c: np.sin(a),
    "COSINE": lambda a, b, c: np.cos(a),
    "TANGENT": _quiet(lambda a, b, c: np.tan(a)),
    "ARCSINE": lambda a, b, c: np.arcsin(np.clip(a, -1.0, 1.0)),
    "ARCCOSINE": lambda a, b, c: np.arccos(np.clip(a, -1.0, 1.0)),
    "ARCTANGENT": lambda a, b, c: np.arctan(a),
    "ARCTAN2": lambda a, b, c: np.arctan2(a, b),
    "SINH": _quiet(lambda a, b, c: np.sinh(a)),
    "COSH": _quiet(lambda a, b, c: np.cosh(a)),
    "TANH": lambda a, b, c: np.tanh(a),
    "RADIANS": lambda a, b, c: a * (np.pi / 180.0),
    "DEGREES": lambda a, b, c: a * (180.0 / np.pi),
}


def dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def length(a):
    return np.sqrt(dot(a, a))


@_quiet
def safe_normalize(a):
    """``a`` / |a|, 0 where |a| is 0 (BLI ``normalize``, Cycles ``safe_normalize``)."""
    n = length(a)[..., None]
    return np.where(n > 0.0, a / np.where(n > 0.0, n, 1.0), 0.0)


def project(a, b):
    """``a`` projected on ``b``; 0 where b = 0."""
    return safe_divide(dot(a, b), dot(b, b))[..., None] * b


def reflect(a, b):
    n = safe_normalize(b)
    return a - 2.0 * dot(a, n)[..., None] * n


def refract(a, b, eta):
    """Refraction of ``a`` at the normal ``b`` (normalised) with index ratio ``eta``; 0 at
    total internal reflection."""
    n = safe_normalize(b)
    eta = np.asarray(eta, np.float64)
    d = dot(n, a)
    k = 1.0 - eta * eta * (1.0 - d * d)
    out = (eta[..., None] * a if eta.ndim else eta * a) \
        - ((eta * d + np.sqrt(np.maximum(k, 0.0)))[..., None]) * n
    return np.where((k < 0.0)[..., None], 0.0, out)


def faceforward(a, b, c):
    """``a`` if dot(c, b) < 0, else -a (BLI ``faceforward(vector, incident, reference)``)."""
    return np.where((dot(c, b) < 0.0)[..., None], a, -a)


VECTOR = "VECTOR"
VALUE = "VALUE"

# Vector Math: operation -> (f(a, b, c, scale), which output it gives); a, b, c are the
# inputs Vector, Vector_001, Vector_002 ((N, 3)), scale the input Scale ((N,))
VECTOR_MATH: Dict[str, Tuple[Callable, str]] = {
    "ADD": (lambda a, b, c, s: a + b, VECTOR),
    "SUBTRACT": (lambda a, b, c, s: a - b, VECTOR),
    "MULTIPLY": (lambda a, b, c, s: a * b, VECTOR),
    "DIVIDE": (lambda a, b, c, s: safe_divide(a, b), VECTOR),
    "MULTIPLY_ADD": (lambda a, b, c, s: a * b + c, VECTOR),
    "CROSS_PRODUCT": (lambda a, b, c, s: np.cross(a, b), VECTOR),
    "PROJECT": (lambda a, b, c, s: project(a, b), VECTOR),
    "REFLECT": (lambda a, b, c, s: reflect(a, b), VECTOR),
    "REFRACT": (lambda a, b, c, s: refract(a, b, s), VECTOR),
    "FACEFORWARD": (lambda a, b, c, s: faceforward(a, b, c), VECTOR),
    "DOT_PRODUCT": (lambda a, b, c, s: dot(a, b), VALUE),
    "DISTANCE": (lambda a, b, c, s: length(a - b), VALUE),
    "LENGTH": (lambda a, b, c, s: length(a), VALUE),
    "SCALE": (lambda a, b, c, s: a * s[..., None], VECTOR),
    "NORMALIZE": (lambda a, b, c, s: safe_normalize(a), VECTOR),
    "ABSOLUTE": (lambda a, b, c, s: np.abs(a), VECTOR),
    "POWER": (lambda a, b, c, s: safe_powf(a, b), VECTOR),
    "SIGN": (lambda a, b, c, s: np.sign(a), VECTOR),
    "MINIMUM": (lambda a, b, c, s: np.minimum(a, b), VECTOR),
    "MAXIMUM": (lambda a, b, c, s: np.maximum(a, b), VECTOR),
    "FLOOR": (lambda a, b, c, s: np.floor(a), VECTOR),
    "CEIL": (lambda a, b, c, s: np.ceil(a), VECTOR),
    "FRACTION": (lambda a, b, c, s: fract(a), VECTOR),
    "MODULO": (lambda a, b, c, s: safe_modf(a, b), VECTOR),
    "WRAP": (lambda a, b, c, s: wrapf(a, b, c), VECTOR),
    "SNAP": (lambda a, b, c, s: np.floor(safe_divide(a, b)) * b, VECTOR),
    "SINE": (lambda a, b, c, s: np.sin(a), VECTOR),
    "COSINE": (lambda a, b, c, s: np.cos(a), VECTOR),
    "TANGENT": (_quiet(lambda a, b, c, s: np.tan(a)), VECTOR),
}
