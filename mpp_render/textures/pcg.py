"""The PCG integer hashes Blender's Voronoi texture uses for its 2D-4D cells, in numpy.

Blender hashes a 2D/3D/4D Voronoi cell by its integer corner with the PCG hashes of Jarzynski
and Olano, "Hash Functions for GPU Rendering" (JCGT 9(3), 2020), in the signed-integer form
Blender uses so that OSL can share it: ``hash_pcg2d_i``, ``hash_pcg3d_i``, ``hash_pcg4d_i``
and ``hash_int{2,3,4}_to_float{2,3,4}`` of ``intern/cycles/util/hash.h`` (the same functions
are in BLI and in EEVEE's ``gpu_shader_common_hash.glsl``).  1D Voronoi keeps the lookup3
float hashes of ``.hash``.

Conventions: int32 arithmetic wraps (two's complement), ``>>`` is the arithmetic shift of a
signed int, results are masked to 31 bits and mapped to [0, 1] as
``float32(h) * (1 / float32(0x7FFFFFFF))`` (float32(0x7FFFFFFF) is 2**31).  Inputs are int
arrays with a trailing axis of 2, 3 or 4; outputs are float32 arrays of the same shape
(``hash_int2_to_float3`` / ``hash_int4_to_float3``: trailing axis 3).

``.hash`` holds the lookup3 family; these are the PCG one.
"""
import numpy as np

_I32 = np.int32
_MUL = _I32(1664525)
_ADD = _I32(1013904223)
_MASK = _I32(0x7FFFFFFF)
_TO_FLOAT = np.float32(1.0) / np.float32(0x7FFFFFFF)


def _i32(k):
    k = np.asarray(k)
    if k.dtype == np.int32:
        return k
    return k.astype(np.int64).astype(np.int32)


def _start(k):
    v = _i32(k) * _MUL + _ADD
    return [v[..., i] for i in range(v.shape[-1])]


def _finish(parts):
    return np.stack(parts, axis=-1) & _MASK


def hash_pcg2d_i(k):
    """PCG 2D of int2 (trailing axis 2) -> non-negative int32 (..., 2)."""
    x, y = _start(k)
    x = x + y * _MUL
    y = y + x * _MUL
    x = x ^ (x >> 16)
    y = y ^ (y >> 16)
    x = x + y * _MUL
    y = y + x * _MUL
    return _finish([x, y])


def hash_pcg3d_i(k):
    """PCG 3D of int3 -> non-negative int32 (..., 3)."""
    x, y, z = _start(k)
    x = x + y * z
    y = y + z * x
    z = z + x * y
    x = x ^ (x >> 16)
    y = y ^ (y >> 16)
    z = z ^ (z >> 16)
    x = x + y * z
    y = y + z * x
    z = z + x * y
    return _finish([x, y, z])


def hash_pcg4d_i(k):
    """PCG 4D of int4 -> non-negative int32 (..., 4)."""
    x, y, z, w = _start(k)
    x = x + y * w
    y = y + z * x
    z = z + x * y
    w = w + y * z
    x = x ^ (x >> 16)
    y = y ^ (y >> 16)
    z = z ^ (z >> 16)
    w = w ^ (w >> 16)
    x = x + y * w
    y = y + z * x
    z = z + x * y
    w = w + y * z
    return _finish([x, y, z, w])


def _to_float(h):
    return h.astype(np.float32) * _TO_FLOAT


def hash_int2_to_float2(k):
    return _to_float(hash_pcg2d_i(k))


def hash_int3_to_float3(k):
    return _to_float(hash_pcg3d_i(k))


def hash_int4_to_float4(k):
    return _to_float(hash_pcg4d_i(k))


def hash_int2_to_float3(k):
    """int2 -> float3: the 3D hash of (x, y, 0)."""
    k = _i32(k)
    return hash_int3_to_float3(np.concatenate([k, np.zeros_like(k[..., :1])], axis=-1))


def hash_int4_to_float3(k):
    """int4 -> float3: the first three components of the 4D hash."""
    return hash_int4_to_float4(k)[..., :3]
