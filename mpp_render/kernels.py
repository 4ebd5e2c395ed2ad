"""Kernel dispatch: the compiled twin when it is built, otherwise the numpy twin.

``MPP_KERNELS=numpy`` in the environment forces the numpy path (tests use it to hold the
two twins to each other).  ``backend()`` says which one runs.  The wrappers here hand the C
kernels contiguous arrays of the exact dtypes they check for, and turn results into numpy.
"""
from __future__ import annotations

import os

import numpy as np

from . import kernels_np
from .lightrecord import LIGHT_FIELDS
from .mpp import DLOG_RHO, LOG_RHO0
from .media import BRICK

try:  # pragma: no cover - depends on the build
    from . import _kernels as _c  # built in place (setup.py build_ext --inplace)
except ImportError:
    try:  # the installed extension: the wheel of ``python -m mpp_render package``
        from mpp_render_kernels import _kernels as _c
    except ImportError:  # the engine still renders, on numpy
        _c = None

_FORCE_NUMPY = os.environ.get("MPP_KERNELS", "").lower() == "numpy"


def backend() -> str:
    return "numpy" if (_c is None or _FORCE_NUMPY) else "c"


FALLBACK_MESSAGE = ("MPP: the compiled kernels are not installed; rendering on the numpy path, "
                    "which gives the same image several times slower")
_fallback_said = False


def fallback_notice():
    """``FALLBACK_MESSAGE`` the first time it is asked for in a process whose compiled kernels
    are missing (not when ``MPP_KERNELS=numpy`` chose numpy), None otherwise: said once."""
    global _fallback_said
    if _c is not None or _fallback_said:
        return None
    _fallback_said = True
    return FALLBACK_MESSAGE


def _f64(a):
    return np.ascontiguousarray(a, np.float64)


def _f32(a):
    return np.ascontiguousarray(a, np.float32)


def c_optical_depth(points, dirs, t_max, grids, w2is, sigma_ts, thresholds, step, offset=0.5,
                    bricks=None, clip=False):
    n = len(points)
    buf = _c.optical_depth(_f64(points).reshape(n, 3), _f64(dirs).reshape(n, 3),
                           _f64(t_max).reshape(n), [_f32(g) for g in grids],
                           [_f64(w) for w in w2is], [_f64(s).reshape(3) for s in sigma_ts],
                           [float(t) for t in thresholds], float(step), float(offset),
                           None if bricks is None else [_f32(b) for b in bricks], BRICK,
                           bool(clip))
    return np.frombuffer(buf, np.float64).reshape(n, 3)


def c_light_sweep(out, channel, a2w, axis, sign, i_first, i_last, coef, light_index, cone, init,
                  p_lo, p_hi, n_sub, grids, w2is, sigma_ts, thresholds):
    if not (isinstance(out, np.ndarray) and out.dtype == np.float32 and out.flags.c_contiguous
            and out.flags.writeable and out.ndim == 4):
        raise ValueError("light_sweep: out must be a writable C-contiguous (X,Y,Z,C) float32 array")
    init = _f64(init)
    _c.light_sweep(out, int(channel), _f64(a2w).reshape(3, 4), int(axis), int(sign), int(i_first),
                   int(i_last), _f64(coef).reshape(6), _f64(light_index).reshape(3), int(bool(cone)),
                   init, int(p_lo), int(p_hi), int(n_sub), [_f32(g) for g in grids],
                   [_f64(w) for w in w2is], [_f64(s).reshape(3) for s in sigma_ts],
                   [float(t) for t in thresholds])


def c_upsample_into(field, channel, lattice, stride, flat):
    if not (isinstance(field, np.ndarray) and field.dtype == np.float32 and field.flags.c_contiguous
            and field.flags.writeable and field.ndim == 4):
        raise ValueError("upsample_into: field must be a writable C-contiguous (X,Y,Z,C) float32 array")
    _c.upsample_into(field, int(channel), _f32(lattice), int(stride),
                     np.ascontiguousarray(flat, np.int64).reshape(-1))


def c_trilinear(grid, idx):
    """media.trilinear on the compiled path: (N,C) for a 4-D grid, (N,) for a 3-D one.  A grid
    that is not float32 is read by the numpy twin (the kernel would round it to float32)."""
    if np.asarray(grid).dtype != np.float32:
        return kernels_np.trilinear(grid, idx)
    g = np.ascontiguousarray(grid)
    flat = g.ndim == 3
    g4 = g.reshape(g.shape + (1,)) if flat else g
    idx = _f64(idx).reshape(-1, 3)
    out = np.frombuffer(_c.trilinear(g4, idx), np.float64).reshape(len(idx), g4.shape[3])
    return out[:, 0] if flat else out


def c_march(origins, dirs, t0, t1, axial, keys, fields, w2is, sigma_ss, sigma_ts, gs,
            thresholds, voxels, lights, ambient, step, depth_opacity, depth_miss, multiple=None,
            emissions=None, bricks=None, adapt_tau=0.0, emission_channels=None):
    n = len(origins)
    nl = len(np.asarray(lights).reshape(-1, LIGHT_FIELDS))
    packed = None
    if multiple is not None:
        amb_ms, per_medium, tables = multiple
        levels, table = [], np.zeros((len(fields), nl, 4))
        table[:, :, 0] = -1
        for m, mfs in enumerate(per_medium):
            for li, msf in enumerate(mfs or []):
                if msf is None:
                    continue
                lv, stride, h = msf
                table[m, li] = (len(levels), len(lv), stride, h)
                levels.extend(_f32(x) for x in lv)
        packed = (int(amb_ms), levels, table, [_f64(t) for t in tables],
                  LOG_RHO0, DLOG_RHO)
    s, t, d, m, k, e = _c.march(_f64(origins).reshape(n, 3), _f64(dirs).reshape(n, 3),
                       _f64(t0).reshape(n), _f64(t1).reshape(n), _f64(axial).reshape(n),
                       np.ascontiguousarray(keys, np.uint32).reshape(n), [_f32(f) for f in fields],
                       [_f64(w) for w in w2is], [_f64(x).reshape(3) for x in sigma_ss],
                       [_f64(x).reshape(3) for x in sigma_ts], [float(g) for g in gs],
                       [float(x) for x in thresholds], [float(v) for v in voxels],
                       _f64(lights).reshape(-1, LIGHT_FIELDS), int(ambient),
                       float(step), float(depth_opacity), float(depth_miss), packed,
                       None if emissions is None else [_f64(x).reshape(3) for x in emissions],
                       None if bricks is None else [_f32(b) for b in bricks], BRICK,
                       float(adapt_tau),
                       None if emission_channels is None else [int(c) for c in emission_channels])
    return (np.frombuffer(s, np.float64).reshape(n, 3), np.frombuffer(t, np.float64).reshape(n, 3),
            np.frombuffer(d, np.float64).reshape(n), np.frombuffer(m, np.float64).reshape(n, 3),
            np.frombuffer(k, np.float64).reshape(n), np.frombuffer(e, np.float64).reshape(n, 3))


_C_WRAPPERS = {"optical_depth": c_optical_depth, "march": c_march,
               "light_sweep": c_light_sweep, "upsample_into": c_upsample_into,
               "trilinear": c_trilinear}


def get(name: str):
    """The kernel ``name`` from the active backend."""
    if backend() == "c" and name in _C_WRAPPERS and hasattr(_c, name):
        return _C_WRAPPERS[name]
    return getattr(kernels_np, name)
