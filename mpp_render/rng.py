"""Counter-based random numbers shared by the C kernels and their numpy twins:
u = hash(key, step, dim) in [0, 1), so that both trace the same samples.  ``lowbias32``
(C. Wellons' integer hash); all arithmetic wraps modulo 2^32."""
from __future__ import annotations

import numpy as np


_M32 = 0xFFFFFFFF


def hash32(x):
    """lowbias32 of uint32 array ``x`` (wrapping arithmetic)."""
    x = np.asarray(x, np.uint32).copy()
    x ^= x >> np.uint32(16)
    x *= np.uint32(0x7FEB352D)
    x ^= x >> np.uint32(15)
    x *= np.uint32(0x846CA68B)
    x ^= x >> np.uint32(16)
    return x


def uniform(keys, step: int, dim: int):
    """Uniform [0, 1) numbers for ray ``keys`` (uint32) at march step ``step`` and dimension
    ``dim``: 24 bits of hash(key ^ hash(step * 0x9E3779B1 + dim * 0x85EBCA77))."""
    salt = hash32(np.uint32(((step * 0x9E3779B1) + (dim * 0x85EBCA77)) & _M32))
    h = hash32(np.asarray(keys, np.uint32) ^ salt)
    return (h >> np.uint32(8)).astype(np.float64) * (1.0 / 16777216.0)
