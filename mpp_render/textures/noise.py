"""Blender's Noise Texture (Perlin noise and its fractal variants), vectorised with numpy.

Follows Blender 4.1-5.0 ``source/blender/blenlib/intern/noise.cc`` (``blender::noise``:
``perlin_noise``, ``perlin_signed``, ``perlin_fbm``, ``perlin_multi_fractal``,
``perlin_hetero_terrain``, ``perlin_hybrid_multi_fractal``,
``perlin_ridged_multi_fractal``, ``perlin_distortion``, ``random_float*_offset``,
``perlin_float3_fractal_distorted``) and the Geometry Nodes multi-function of
``source/blender/nodes/shader/nodes/node_shader_tex_noise.cc``, which Cycles
(``intern/cycles/kernel/svm/noise.h``, ``fractal_noise.h``, ``noisetex.h``) mirrors.

Conventions
-----------
* Positions are texture-space coordinates (already multiplied by the node's Scale); they
  are float32 like Blender's, and every operation that moves a position (scale, octave
  lacunarity, ``fmod(p, 100000)``, random offsets, distortion) is done in float32 in
  Blender's order, because at large coordinates the noise depends on the exact rounding.
* Inside one lattice cell the gradient/fade/interpolation arithmetic follows BLI's own
  mix of float32 and float64 operations, so noise values are bit-identical to Blender's
  in almost all points (one ulp matters: see the note above ``_fade``).
* ``perlin_signed`` is in about [-1, 1]; ``perlin`` = ``perlin_signed / 2 + 0.5``.
* Per-point parameters: any numeric argument may be a scalar or an (N,) array.  Octave
  loops run to the largest detail and mask points that are done.
"""
import numpy as np

from . import hash as _h

F32 = np.float32
_PERIOD = F32(100000.0)
_SIGNED_SCALE = {1: F32(0.2500), 2: F32(0.6616), 3: F32(0.9820), 4: F32(0.8344)}
_NOISE_TYPES = ("MULTIFRACTAL", "FBM", "HYBRID_MULTIFRACTAL", "RIDGED_MULTIFRACTAL",
                "HETERO_TERRAIN")
_DIMENSIONS = {"1D": 1, "2D": 2, "3D": 3, "4D": 4}


# ---- single-octave Perlin noise ----------------------------------------------------------
#
# The arithmetic below reproduces BLI's float32 / float64 mix operation by operation so
# that the result is bit-identical to Blender's in the vast majority of points: at large
# coordinates (and through Distortion) one ulp of difference in a noise value can move a
# position by one float32 ulp, which later octaves magnify.

def _fade(t):
    """BLI ``fade``: ``t*t*t`` in float32 times a double polynomial, rounded to float32."""
    t3 = (t * t * t).astype(np.float64)
    t64 = t.astype(np.float64)
    return (t3 * (t64 * (t64 * 6.0 - 15.0) + 10.0)).astype(F32)


def _negate_if_bit(v, h, bit):
    """``-v`` where bit ``bit`` of ``h`` is set, else ``v`` (float32; flips the sign bit,
    exactly like negation)."""
    flip = ((h >> np.uint32(bit)) & np.uint32(1)) << np.uint32(31)
    return (np.ascontiguousarray(v, F32).view(np.uint32) ^ flip).view(F32)


def _grad(h, f):
    """Blender's ``noise_grad`` for d = len(f) (h: uint32 (k,), f: list of float32 (k,))."""
    d = len(f)
    if d == 1:
        h = h & np.uint32(15)
        g = (np.uint32(1) + (h & np.uint32(7))).astype(F32)
        return _negate_if_bit(g, h, 3) * f[0]
    if d == 2:
        x, y = f
        h = h & np.uint32(7)
        lo = h < 4
        u = np.where(lo, x, y)
        v = F32(2.0) * np.where(lo, y, x)
        return _negate_if_bit(u, h, 0) + _negate_if_bit(v, h, 1)
    if d == 3:
        x, y, z = f
        h = h & np.uint32(15)
        u = np.where(h < 8, x, y)
        vt = np.where((h == 12) | (h == 14), x, z)
        v = np.where(h < 4, y, vt)
        return _negate_if_bit(u, h, 0) + _negate_if_bit(v, h, 1)
    x, y, z, w = f
    h = h & np.uint32(31)
    u = np.where(h < 24, x, y)
    v = np.where(h < 16, y, z)
    s = np.where(h < 8, z, w)
    return (_negate_if_bit(u, h, 0) + _negate_if_bit(v, h, 1)) + _negate_if_bit(s, h, 2)


_HASH = {1: _h.hash_uint, 2: _h.hash_uint2, 3: _h.hash_uint3, 4: _h.hash_uint4}


def perlin_noise(p):
    """Raw Perlin gradient noise at float32 positions ``p`` (k, d), d in 1..4 (BLI
    ``perlin_noise``: lookup3-hashed gradients, quintic fade, multilinear mix).  Returns
    float32 (k,).  No period wrap and no output scaling (see :func:`perlin_signed`)."""
    p = np.asarray(p, F32)
    d = p.shape[-1]
    one = F32(1.0)
    # floor_fraction(): i = int(x) - (x < 0); f = x - i  (f == 1 at negative integers)
    # (non-finite positions: lattice cell 0, and the NaN propagates to the result)
    ip = np.trunc(np.where(np.isfinite(p), p, F32(0.0))).astype(np.int64) - (p < 0)
    fx = p - ip.astype(F32)
    ip32 = ip.astype(np.uint32)  # two's complement wrap as C's int -> uint32
    f0 = [fx[:, a] for a in range(d)]
    f1 = [fx[:, a] - one for a in range(d)]
    fade = _fade(fx)
    hash_fn = _HASH[d]
    # gradient values at the 2**d corners; corner bit a set = +1 along axis a (x lowest)
    v = []
    for corner in range(1 << d):
        off = [(corner >> a) & 1 for a in range(d)]
        h = hash_fn(*[ip32[:, a] + np.uint32(off[a]) for a in range(d)])
        v.append(_grad(h, [f1[a] if off[a] else f0[a] for a in range(d)]))
    if d == 1:
        u = fade[:, 0]
        return (one - u) * v[0] + u * v[1]
    u, vv = fade[:, 0], fade[:, 1]
    x1 = one - u
    if d == 2:
        # (1.0 - y) is a double in BLI: exact product, then a double sum rounded once
        a = (v[0] * x1 + v[1] * u).astype(np.float64)
        b = vv * (v[2] * x1 + v[3] * u)
        return ((1.0 - vv.astype(np.float64)) * a + b.astype(np.float64)).astype(F32)

    t = fade[:, 2]
    y1, z1 = one - vv, one - t

    def tri(c):  # BLI trilinear mix, all float32
        return (z1 * (y1 * (c[0] * x1 + c[1] * u) + vv * (c[2] * x1 + c[3] * u)) +
                t * (y1 * (c[4] * x1 + c[5] * u) + vv * (c[6] * x1 + c[7] * u)))

    if d == 3:
        return tri(v)
    s = fade[:, 3]
    return (one - s) * tri(v[:8]) + s * tri(v[8:])


_BIG = F32(1000000.0)


def perlin_signed(p):
    """Signed Perlin noise in about [-1, 1] at float32 positions (k, d).  As Blender, each
    coordinate is wrapped with ``fmod(x, 100000)`` against float precision loss, plus 0.5
    where ``|x| >= 1e6`` (there float32 positions are whole numbers, where Perlin noise is
    0; this correction is in Blender 5.0's BLI ``perlin_signed``, checked against bpy
    5.0.1, though not in the 4.1 sources); the raw noise is scaled by 0.2500 / 0.6616 /
    0.9820 / 0.8344 for d = 1 / 2 / 3 / 4."""
    p = np.asarray(p, F32)
    corr = np.where(np.abs(p) >= _BIG, F32(0.5), F32(0.0))
    with np.errstate(invalid="ignore"):  # fmod(inf) = nan, as in C
        q = np.fmod(p, _PERIOD) + corr
    return perlin_noise(q) * _SIGNED_SCALE[p.shape[-1]]


def perlin(p):
    """Unsigned Perlin noise in about [0, 1]: ``perlin_signed(p) / 2 + 0.5``."""
    return perlin_signed(p) / F32(2.0) + F32(0.5)


# ---- fractal variants (per-point parameters, octave loop over the largest detail) --------

def _eval_on(mask, p):
    """perlin_signed on the rows of p where mask is true; zeros elsewhere (float32)."""
    out = np.zeros(p.shape[0], F32)
    if mask.all():
        return perlin_signed(p)
    idx = np.nonzero(mask)[0]
    if idx.size:
        out[idx] = perlin_signed(p[idx])
    return out


def _octaves(detail):
    n = np.trunc(detail).astype(np.int64)          # C int(detail)
    rmd = (detail - np.floor(detail)).astype(F32)  # detail - floor(detail)
    return n, rmd


def _mix(a, b, t):
    return (F32(1.0) - t) * a + t * b


def fbm(p, detail, roughness, lacunarity, normalize):
    """fBm (BLI ``perlin_fbm``): sum of octaves ``perlin_signed(fscale * p) * amp``; with
    ``normalize`` remapped to [0, 1] by ``0.5 * sum / maxamp + 0.5``; a fractional detail
    blends in one more octave."""
    p = np.asarray(p, F32)
    k = p.shape[0]
    detail, roughness, lacunarity = (_per_point(x, k) for x in (detail, roughness, lacunarity))
    n, rmd = _octaves(detail)
    fscale = np.ones(k, F32)
    amp = np.ones(k, F32)
    maxamp = np.zeros(k, F32)
    total = np.zeros(k, F32)
    sum2 = np.zeros(k, F32)
    nmax = int(n.max()) if k else 0
    for i in range(nmax + 2):
        main = i <= n
        extra = (i == n + 1) & (rmd != 0)
        need = main | extra
        if not need.any():
            break
        t = _eval_on(need, fscale[:, None] * p)
        total = np.where(main, total + t * amp, total)
        sum2 = np.where(extra, total + t * amp, sum2)
        maxamp = np.where(main, maxamp + amp, maxamp)
        amp = np.where(main, amp * roughness, amp)
        fscale = np.where(main, fscale * lacunarity, fscale)
    has_rmd = rmd != 0
    with np.errstate(divide="ignore", invalid="ignore"):
        if normalize:
            a = F32(0.5) * total / maxamp + F32(0.5)
            b = F32(0.5) * sum2 / (maxamp + amp) + F32(0.5)
        else:
            a, b = total, sum2
    return np.where(has_rmd, _mix(a, b, rmd), a).astype(F32)


def multi_fractal(p, detail, roughness, lacunarity):
    """Multifractal (BLI ``perlin_multi_fractal``): product of ``pwr * noise + 1``."""
    p = np.asarray(p, F32)
    k = p.shape[0]
    detail, roughness, lacunarity = (_per_point(x, k) for x in (detail, roughness, lacunarity))
    n, rmd = _octaves(detail)
    value = np.ones(k, F32)
    pwr = np.ones(k, F32)
    for i in range(int(n.max()) + 2 if k else 0):
        main = i <= n
        extra = (i == n + 1) & (rmd != 0)
        need = main | extra
        if not need.any():
            break
        t = _eval_on(need, p)
        value = np.where(main, value * (pwr * t + F32(1.0)), value)
        value = np.where(extra, value * (rmd * pwr * t + F32(1.0)), value)
        pwr = np.where(main, pwr * roughness, pwr)
        p = np.where(main[:, None], p * lacunarity[:, None], p)
    return value


def hetero_terrain(p, detail, roughness, lacunarity, offset):
    """Heterogeneous terrain (BLI ``perlin_hetero_terrain``)."""
    p = np.asarray(p, F32)
    k = p.shape[0]
    detail, roughness, lacunarity, offset = (
        _per_point(x, k) for x in (detail, roughness, lacunarity, offset))
    n, rmd = _octaves(detail)
    pwr = roughness.astype(F32).copy()
    value = offset + perlin_signed(p)
    p = p * lacunarity[:, None]
    for i in range(1, int(n.max()) + 2 if k else 1):
        main = i <= n
        extra = (i == n + 1) & (rmd != 0)
        need = main | extra
        if not need.any():
            break
        t = _eval_on(need, p)
        increment = (t + offset) * pwr * value
        value = np.where(main, value + increment, value)
        value = np.where(extra, value + rmd * increment, value)
        pwr = np.where(main, pwr * roughness, pwr)
        p = np.where(main[:, None], p * lacunarity[:, None], p)
    return value


def hybrid_multi_fractal(p, detail, roughness, lacunarity, offset, gain):
    """Hybrid additive/multiplicative multifractal (BLI ``perlin_hybrid_multi_fractal``);
    a point's octave loop stops once its weight drops to 0.001 or below."""
    p = np.asarray(p, F32)
    k = p.shape[0]
    detail, roughness, lacunarity, offset, gain = (
        _per_point(x, k) for x in (detail, roughness, lacunarity, offset, gain))
    n, rmd = _octaves(detail)
    pwr = np.ones(k, F32)
    value = np.zeros(k, F32)
    weight = np.ones(k, F32)
    thr = F32(0.001)
    i = 0
    while True:
        main = (weight > thr) & (i <= n)
        extra = (weight > thr) & (i == n + 1) & (rmd != 0)
        need = main | extra
        if not need.any():
            break
        weight = np.where(need, np.minimum(weight, F32(1.0)), weight)
        t = _eval_on(need, p)
        signal = (t + offset) * pwr
        value = np.where(main, value + weight * signal, value)
        value = np.where(extra, value + rmd * weight * signal, value)
        pwr = np.where(main, pwr * roughness, pwr)
        weight = np.where(main, weight * (gain * signal), weight)
        p = np.where(main[:, None], p * lacunarity[:, None], p)
        # points that only took the remainder octave are finished
        weight = np.where(extra, F32(0.0), weight)
        i += 1
    return value


def ridged_multi_fractal(p, detail, roughness, lacunarity, offset, gain):
    """Ridged multifractal (BLI ``perlin_ridged_multi_fractal``); as in Blender the
    fractional part of the detail is ignored."""
    p = np.asarray(p, F32)
    k = p.shape[0]
    detail, roughness, lacunarity, offset, gain = (
        _per_point(x, k) for x in (detail, roughness, lacunarity, offset, gain))
    n, _ = _octaves(detail)
    pwr = roughness.astype(F32).copy()
    signal = offset - np.abs(perlin_signed(p))
    signal = signal * signal
    value = signal.copy()
    for i in range(1, int(n.max()) + 1 if k else 1):
        main = i <= n
        p = np.where(main[:, None], p * lacunarity[:, None], p)
        weight = np.clip(signal * gain, F32(0.0), F32(1.0))
        t = _eval_on(main, p)
        s = offset - np.abs(t)
        s = s * s
        s = s * weight
        signal = np.where(main, s, signal)
        value = np.where(main, value + s * pwr, value)
        pwr = np.where(main, pwr * roughness, pwr)
    return value


def perlin_select(p, detail, roughness, lacunarity, offset, gain, noise_type, normalize):
    """Dispatch on Blender's ``noise_type`` enum identifier (BLI ``perlin_select``)."""
    if noise_type == "FBM":
        return fbm(p, detail, roughness, lacunarity, normalize)
    if noise_type == "MULTIFRACTAL":
        return multi_fractal(p, detail, roughness, lacunarity)
    if noise_type == "HYBRID_MULTIFRACTAL":
        return hybrid_multi_fractal(p, detail, roughness, lacunarity, offset, gain)
    if noise_type == "RIDGED_MULTIFRACTAL":
        return ridged_multi_fractal(p, detail, roughness, lacunarity, offset, gain)
    if noise_type == "HETERO_TERRAIN":
        return hetero_terrain(p, detail, roughness, lacunarity, offset)
    raise ValueError(f"unknown noise_type {noise_type!r}; expected one of {_NOISE_TYPES}")


# ---- seeds, distortion, the node ---------------------------------------------------------

def random_offset(seed, d):
    """Blender's ``random_float{,2,3,4}_offset(seed)``: components in [100, 200] (float32
    (d,)); 1D hashes the seed alone, 2-4D hash (seed, component index)."""
    seed = F32(seed)
    if d == 1:
        h = _h.hash_float_to_float(np.array([seed], F32))
    else:
        k = np.stack([np.full(d, seed, F32), np.arange(d, dtype=F32)], axis=-1)
        h = _h.hash_float2_to_float(k)
    return (F32(100.0) + h * F32(100.0)).astype(F32)


def perlin_distortion(p, strength):
    """Per-axis displacement ``perlin_signed(p + random_offset(axis)) * strength`` (p: (k, d)
    float32, strength: scalar or (k,))."""
    d = p.shape[-1]
    strength = _per_point(strength, p.shape[0])
    cols = [perlin_signed(p + random_offset(float(a), d)) * strength for a in range(d)]
    return np.stack(cols, axis=-1).astype(F32)


_COLOR_SEEDS = {1: (1.0, 2.0), 2: (2.0, 3.0), 3: (3.0, 4.0), 4: (4.0, 5.0)}


def _per_point(x, n):
    a = np.asarray(x, F32)
    if a.ndim == 0:
        return np.full(n, a, F32)
    if a.shape != (n,):
        raise ValueError(f"expected a scalar or shape ({n},), got {a.shape}")
    return a


def noise_texture(vector, w=0.0, dimensions="3D", scale=5.0, detail=2.0, roughness=0.5,
                  lacunarity=2.0, offset=0.0, gain=1.0, distortion=0.0, noise_type="FBM",
                  normalize=True, color=True):
    """Blender's Noise Texture node at N points.

    ``vector``: (N, 3) texture coordinates (ignored in 1D, where only ``w`` is used; 2D uses
    x, y; 3D x, y, z; 4D x, y, z, w).  ``dimensions``: '1D'..'4D'; ``noise_type``: 'FBM',
    'MULTIFRACTAL', 'HYBRID_MULTIFRACTAL', 'RIDGED_MULTIFRACTAL', 'HETERO_TERRAIN'
    (``normalize`` only affects FBM).  Every numeric input is a scalar or an (N,) array.
    Detail is clamped to [0, 15] and roughness to >= 0 as the node does.

    Returns ``(fac, color)``: fac (N,) float32; color (N, 3) float32 (``fac`` and two more
    evaluations at Blender's random offsets) or None when ``color`` is false.
    """
    if dimensions not in _DIMENSIONS:
        raise ValueError(f"unknown dimensions {dimensions!r}")
    d = _DIMENSIONS[dimensions]
    if vector is None:
        n = np.shape(np.asarray(w))[0]
        vec = np.zeros((n, 3), F32)
    else:
        vec = np.asarray(vector, F32).reshape(-1, 3)
        n = vec.shape[0]
    sc = _per_point(scale, n)
    ww = _per_point(w, n)
    det = np.clip(_per_point(detail, n), F32(0.0), F32(15.0))
    rough = np.maximum(_per_point(roughness, n), F32(0.0))
    lac = _per_point(lacunarity, n)
    off = _per_point(offset, n)
    gn = _per_point(gain, n)
    dist = _per_point(distortion, n)

    if d == 1:
        p = (ww * sc)[:, None]
    else:
        pv = vec * sc[:, None]
        p = pv[:, :2] if d == 2 else pv if d == 3 else np.concatenate(
            [pv, (ww * sc)[:, None]], axis=1)
    p = np.ascontiguousarray(p, F32)
    p = p + perlin_distortion(p, dist)

    args = (det, rough, lac, off, gn, noise_type, bool(normalize))
    fac = perlin_select(p, *args).astype(F32)
    if not color:
        return fac, None
    s1, s2 = _COLOR_SEEDS[d]
    g = perlin_select(p + random_offset(s1, d), *args)
    b = perlin_select(p + random_offset(s2, d), *args)
    return fac, np.stack([fac, g, b], axis=-1).astype(F32)
