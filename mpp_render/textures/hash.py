"""Bob Jenkins' lookup3 hashes as Blender uses them, vectorised with numpy.

Follows ``source/blender/blenlib/intern/noise.cc`` (namespace ``blender::noise``) and
``intern/cycles/util/hash.h`` (the two are kept identical): the integer hashes
``hash_uint{,2,3,4}`` are lookup3's ``final`` (and, for four keys, one ``mix``) with the
initial value ``0xdeadbeef + (n << 2) + 13``; the float hashes hash the float32 *bit
pattern* of their arguments and map the 32-bit result to [0, 1] as
``float32(h) / float32(0xFFFFFFFF)`` (i.e. ``float32(h) * 2**-32``, computed in float32).

Conventions: integer inputs are anything castable to uint32 (wrapping like C); float
inputs are cast to float32 first; a float2/3/4 argument is an array with a trailing axis
of length 2/3/4.  Outputs are uint32 arrays (integer hashes) or float32 arrays (float
hashes; the ``_to_float{2,3,4}`` variants add a trailing axis).
"""
import numpy as np

_U32 = np.uint32
_INV_MAX = np.float32(1.0) / np.float32(0xFFFFFFFF)  # float(0xFFFFFFFF) == 2**32 in float32


def _u32(x):
    """Array cast to uint32 with C wrap-around (signed ints taken modulo 2**32)."""
    a = np.asarray(x)
    if a.dtype == np.uint32:
        return a
    if a.dtype.kind in "iu":
        return a.astype(np.int64).astype(np.uint32)
    if a.dtype.kind == "b":
        return a.astype(np.uint32)
    return np.asarray(a, dtype=np.int64).astype(np.uint32)


def _rot(x, k):
    return (x << _U32(k)) | (x >> _U32(32 - k))


def _final(a, b, c):
    c = c ^ b
    c = c - _rot(b, 14)
    a = a ^ c
    a = a - _rot(c, 11)
    b = b ^ a
    b = b - _rot(a, 25)
    c = c ^ b
    c = c - _rot(b, 16)
    a = a ^ c
    a = a - _rot(c, 4)
    b = b ^ a
    b = b - _rot(a, 14)
    c = c ^ b
    c = c - _rot(b, 24)
    return c


def _mix(a, b, c):
    a = a - c
    a = a ^ _rot(c, 4)
    c = c + b
    b = b - a
    b = b ^ _rot(a, 6)
    a = a + c
    c = c - b
    c = c ^ _rot(b, 8)
    b = b + a
    a = a - c
    a = a ^ _rot(c, 16)
    c = c + b
    b = b - a
    b = b ^ _rot(a, 19)
    a = a + c
    c = c - b
    c = c ^ _rot(b, 4)
    b = b + a
    return a, b, c


def _init(n):
    return _U32((0xDEADBEEF + (n << 2) + 13) & 0xFFFFFFFF)


def hash_uint(kx):
    """lookup3 hash of one uint32 key (Blender ``hash(uint32_t)``)."""
    with np.errstate(over="ignore"):
        kx = _u32(kx)
        a = b = c = np.broadcast_to(_init(1), kx.shape).copy()
        a = a + kx
        return np.asarray(_final(a, b, c), dtype=np.uint32)


def hash_uint2(kx, ky):
    """lookup3 hash of two uint32 keys."""
    with np.errstate(over="ignore"):
        kx, ky = np.broadcast_arrays(_u32(kx), _u32(ky))
        a = np.full(kx.shape, _init(2), np.uint32)
        b = a + ky
        c = a.copy()
        a = a + kx
        return np.asarray(_final(a, b, c), dtype=np.uint32)


def hash_uint3(kx, ky, kz):
    """lookup3 hash of three uint32 keys."""
    with np.errstate(over="ignore"):
        kx, ky, kz = np.broadcast_arrays(_u32(kx), _u32(ky), _u32(kz))
        init = np.full(kx.shape, _init(3), np.uint32)
        c = init + kz
        b = init + ky
        a = init + kx
        return np.asarray(_final(a, b, c), dtype=np.uint32)


def hash_uint4(kx, ky, kz, kw):
    """lookup3 hash of four uint32 keys (one ``mix`` then ``final``)."""
    with np.errstate(over="ignore"):
        kx, ky, kz, kw = np.broadcast_arrays(_u32(kx), _u32(ky), _u32(kz), _u32(kw))
        init = np.full(kx.shape, _init(4), np.uint32)
        a = init + kx
        b = init + ky
        c = init + kz
        a, b, c = _mix(a, b, c)
        a = a + kw
        return np.asarray(_final(a, b, c), dtype=np.uint32)


def uint_to_float(h):
    """[0, 2**32) -> [0, 1] as Blender: ``float(h) / float(0xFFFFFFFF)`` in float32."""
    return np.asarray(h, dtype=np.uint32).astype(np.float32) * _INV_MAX


def float_as_uint(x):
    """The float32 bit pattern of ``x`` as uint32."""
    return np.asarray(x, dtype=np.float32).view(np.uint32)


def _split(k, n):
    k = np.asarray(k, dtype=np.float32)
    if k.shape[-1] != n:
        raise ValueError(f"expected a trailing axis of length {n}, got shape {k.shape}")
    return tuple(k[..., i] for i in range(n))


def _cst(x, v):
    return np.full(np.shape(x), v, dtype=np.float32)


# ---- float(s) -> float --------------------------------------------------------------


def hash_uint_to_float(kx):
    return uint_to_float(hash_uint(kx))


def hash_uint2_to_float(kx, ky):
    return uint_to_float(hash_uint2(kx, ky))


def hash_uint3_to_float(kx, ky, kz):
    return uint_to_float(hash_uint3(kx, ky, kz))


def hash_uint4_to_float(kx, ky, kz, kw):
    return uint_to_float(hash_uint4(kx, ky, kz, kw))


def hash_float_to_float(k):
    """Hash of one float -> [0, 1]."""
    return uint_to_float(hash_uint(float_as_uint(k)))


def _h2(x, y):
    return uint_to_float(hash_uint2(float_as_uint(x), float_as_uint(y)))


def _h3(x, y, z):
    return uint_to_float(hash_uint3(float_as_uint(x), float_as_uint(y), float_as_uint(z)))


def _h4(x, y, z, w):
    return uint_to_float(
        hash_uint4(float_as_uint(x), float_as_uint(y), float_as_uint(z), float_as_uint(w)))


def hash_float2_to_float(k):
    """Hash of a float2 (trailing axis 2) -> [0, 1]."""
    return _h2(*_split(k, 2))


def hash_float3_to_float(k):
    """Hash of a float3 (trailing axis 3) -> [0, 1]."""
    return _h3(*_split(k, 3))


def hash_float4_to_float(k):
    """Hash of a float4 (trailing axis 4) -> [0, 1]."""
    return _h4(*_split(k, 4))


# ---- -> float2 / float3 / float4 ----------------------------------------------------



def hash_float_to_float3(k):
    """float -> float3: (h(k), h(k, 1), h(k, 2))."""
    k = np.asarray(k, dtype=np.float32)
    return np.stack([hash_float_to_float(k), _h2(k, _cst(k, 1.0)), _h2(k, _cst(k, 2.0))],
                    axis=-1)



def hash_float2_to_float2(k):
    """float2 -> float2: (h(x, y), h(x, y, 1))."""
    x, y = _split(k, 2)
    return np.stack([_h2(x, y), _h3(x, y, _cst(x, 1.0))], axis=-1)


def hash_float2_to_float3(k):
    """float2 -> float3: (h(x, y), h(x, y, 1), h(x, y, 2))."""
    x, y = _split(k, 2)
    return np.stack([_h2(x, y), _h3(x, y, _cst(x, 1.0)), _h3(x, y, _cst(x, 2.0))], axis=-1)




def hash_float3_to_float3(k):
    """float3 -> float3: (h(x, y, z), h(x, y, z, 1), h(x, y, z, 2))."""
    x, y, z = _split(k, 3)
    return np.stack([_h3(x, y, z), _h4(x, y, z, _cst(x, 1.0)), _h4(x, y, z, _cst(x, 2.0))],
                    axis=-1)




def hash_float4_to_float3(k):
    """float4 -> float3: (h(x, y, z, w), h(z, x, w, y), h(w, z, y, x))."""
    x, y, z, w = _split(k, 4)
    return np.stack([_h4(x, y, z, w), _h4(z, x, w, y), _h4(w, z, y, x)], axis=-1)


def hash_float4_to_float4(k):
    """float4 -> float4: (h(x,y,z,w), h(w,x,y,z), h(z,w,x,y), h(y,z,w,x))."""
    x, y, z, w = _split(k, 4)
    return np.stack([_h4(x, y, z, w), _h4(w, x, y, z), _h4(z, w, x, y), _h4(y, z, w, x)],
                    axis=-1)
