"""Colour operations of Blender's shader nodes, vectorised with numpy (no bpy).

* HSV and HSL conversions as Cycles' ``intern/cycles/util/color.h`` (``rgb_to_hsv``,
  ``hsv_to_rgb``, ``rgb_to_hsl``, ``hsl_to_rgb``): hue, saturation, value/lightness in
  [0, 1] for colours in [0, 1]; a grey has hue and saturation 0.
* The Mix node's blend modes (``BLEND``, keyed by ``blend_type``) as Cycles'
  ``kernel/svm/color_util.h`` (``svm_mix_*``), which Geometry Nodes' ``ramp_blend``
  (``blenkernel/intern/material.cc``) matches.
* The Color Ramp (``color_ramp``) as ``BKE_colorband_evaluate``
  (``blenkernel/intern/colorband.cc``) with ``key_curve_position_weights``
  (``blenkernel/intern/key.cc``) for B-spline and cardinal interpolation.  Geometry Nodes
  evaluate the band exactly like this; Cycles bakes it into a 256-entry table and
  interpolates that linearly (a difference below 1e-4 for smooth ramps, up to half a table
  step in position at CONSTANT steps).

Colours are linear RGB float64 arrays (..., 3); alpha is handled separately where a node has
an Alpha output.  Factors ``t`` broadcast against the colours' leading axes.
"""
from __future__ import annotations

from typing import Callable, Dict, Sequence, Tuple

import numpy as np


def rgb_to_hsv(rgb):
    rgb = np.asarray(rgb, np.float64)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    cmax = np.maximum(r, np.maximum(g, b))
    cmin = np.minimum(r, np.minimum(g, b))
    delta = cmax - cmin
    with np.errstate(all="ignore"):
        s = np.where(cmax != 0.0, delta / np.where(cmax != 0.0, cmax, 1.0), 0.0)
        safe = np.where(delta != 0.0, delta, 1.0)
        cr, cg, cb = (cmax - r) / safe, (cmax - g) / safe, (cmax - b) / safe
    h = np.where(r == cmax, cb - cg, np.where(g == cmax, 2.0 + cr - cb, 4.0 + cg - cr)) / 6.0
    h = np.where(h < 0.0, h + 1.0, h)
    h = np.where(s != 0.0, h, 0.0)
    return np.stack([h, s, cmax], axis=-1)


def hsv_to_rgb(hsv):
    hsv = np.asarray(hsv, np.float64)
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    h6 = np.where(h == 1.0, 0.0, h) * 6.0
    i = np.floor(h6)
    f = h6 - i
    p = v * (1.0 - s)
    q = v * (1.0 - s * f)
    t = v * (1.0 - s * (1.0 - f))
    sectors = [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v)]
    out = np.stack([v, p, q], axis=-1)          # i >= 5 (and below 0)
    for k in range(4, -1, -1):
        out = np.where((i == k)[..., None], np.stack(sectors[k], axis=-1), out)
    grey = np.stack([v, v, v], axis=-1)
    return np.where((s != 0.0)[..., None], out, grey)


def rgb_to_hsl(rgb):
    rgb = np.asarray(rgb, np.float64)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    cmax = np.maximum(r, np.maximum(g, b))
    cmin = np.minimum(r, np.minimum(g, b))
    lum = np.minimum(1.0, (cmax + cmin) / 2.0)
    d = cmax - cmin
    with np.errstate(all="ignore"):
        safe = np.where(d != 0.0, d, 1.0)
        s = np.where(lum > 0.5, d / (2.0 - cmax - cmin), d / (cmax + cmin))
        h = np.where(cmax == r, (g - b) / safe + np.where(g < b, 6.0, 0.0),
                     np.where(cmax == g, (b - r) / safe + 2.0, (r - g) / safe + 4.0))
    grey = cmax == cmin
    return np.stack([np.where(grey, 0.0, h) / 6.0, np.where(grey, 0.0, s), lum], axis=-1)


def _hue_weights(h):
    """Cycles' and BLI's piecewise-linear hue to RGB weights in [0, 1]."""
    nr = np.clip(np.abs(h * 6.0 - 3.0) - 1.0, 0.0, 1.0)
    ng = np.clip(2.0 - np.abs(h * 6.0 - 2.0), 0.0, 1.0)
    nb = np.clip(2.0 - np.abs(h * 6.0 - 4.0), 0.0, 1.0)
    return nr, ng, nb


def hsl_to_rgb(hsl):
    hsl = np.asarray(hsl, np.float64)
    h, s, lum = hsl[..., 0], hsl[..., 1], hsl[..., 2]
    nr, ng, nb = _hue_weights(h)
    chroma = (1.0 - np.abs(2.0 * lum - 1.0)) * s
    return np.stack([(nr - 0.5) * chroma + lum, (ng - 0.5) * chroma + lum,
                     (nb - 0.5) * chroma + lum], axis=-1)


# -- the Mix node's blend modes --------------------------------------------------------------

def _lerp(a, b, t):
    return a + t * (b - a)


def _overlay(t, c1, c2):
    tm = 1.0 - t
    low = c1 * (tm + 2.0 * t * c2)
    high = 1.0 - (tm + 2.0 * t * (1.0 - c2)) * (1.0 - c1)
    return np.where(c1 < 0.5, low, high)


def _divide(t, c1, c2):
    with np.errstate(all="ignore"):
        q = (1.0 - t) * c1 + t * c1 / np.where(c2 != 0.0, c2, 1.0)
    return np.where(c2 != 0.0, q, c1)


def _dodge(t, c1, c2):
    tmp = 1.0 - t * c2
    with np.errstate(all="ignore"):
        q = np.minimum(c1 / np.where(tmp > 0.0, tmp, 1.0), 1.0)
    return np.where(c1 != 0.0, np.where(tmp <= 0.0, 1.0, q), c1)


def _burn(t, c1, c2):
    tmp = (1.0 - t) + t * c2
    with np.errstate(all="ignore"):
        q = np.clip(1.0 - (1.0 - c1) / np.where(tmp > 0.0, tmp, 1.0), 0.0, 1.0)
    return np.where(tmp <= 0.0, 0.0, q)


def _hue(t, c1, c2):
    hsv2 = rgb_to_hsv(c2)
    hsv = rgb_to_hsv(c1)
    hsv[..., 0] = hsv2[..., 0]
    return np.where((hsv2[..., 1] != 0.0)[..., None], _lerp(c1, hsv_to_rgb(hsv), t), c1)


def _saturation(t, c1, c2):
    hsv = rgb_to_hsv(c1)
    hsv2 = rgb_to_hsv(c2)
    tt = np.broadcast_to(t, hsv.shape)[..., 0]
    mixed = hsv.copy()
    mixed[..., 1] = (1.0 - tt) * hsv[..., 1] + tt * hsv2[..., 1]
    return np.where((hsv[..., 1] != 0.0)[..., None], hsv_to_rgb(mixed), c1)


def _value(t, c1, c2):
    hsv = rgb_to_hsv(c1)
    hsv2 = rgb_to_hsv(c2)
    tt = np.broadcast_to(t, hsv.shape)[..., 0]
    hsv[..., 2] = (1.0 - tt) * hsv[..., 2] + tt * hsv2[..., 2]
    return hsv_to_rgb(hsv)


def _colour(t, c1, c2):
    hsv2 = rgb_to_hsv(c2)
    hsv = rgb_to_hsv(c1)
    hsv[..., 0] = hsv2[..., 0]
    hsv[..., 1] = hsv2[..., 1]
    return np.where((hsv2[..., 1] != 0.0)[..., None], _lerp(c1, hsv_to_rgb(hsv), t), c1)


def _soft_light(t, c1, c2):
    scr = 1.0 - (1.0 - c2) * (1.0 - c1)
    return (1.0 - t) * c1 + t * ((1.0 - c1) * c2 * c1 + c1 * scr)


# blend_type -> f(t (..., 1), c1 (..., 3), c2 (..., 3)) -> (..., 3)
BLEND: Dict[str, Callable] = {
    "MIX": lambda t, c1, c2: _lerp(c1, c2, t),
    "DARKEN": lambda t, c1, c2: _lerp(c1, np.minimum(c1, c2), t),
    "MULTIPLY": lambda t, c1, c2: _lerp(c1, c1 * c2, t),
    "BURN": _burn,
    "LIGHTEN": lambda t, c1, c2: _lerp(c1, np.maximum(c1, c2), t),
    "SCREEN": lambda t, c1, c2: 1.0 - ((1.0 - t) + t * (1.0 - c2)) * (1.0 - c1),
    "DODGE": _dodge,
    "ADD": lambda t, c1, c2: _lerp(c1, c1 + c2, t),
    "OVERLAY": _overlay,
    "SOFT_LIGHT": _soft_light,
    "LINEAR_LIGHT": lambda t, c1, c2: c1 + t * (2.0 * c2 - 1.0),
    "DIFFERENCE": lambda t, c1, c2: _lerp(c1, np.abs(c1 - c2), t),
    "EXCLUSION": lambda t, c1, c2: np.maximum(_lerp(c1, c1 + c2 - 2.0 * c1 * c2, t), 0.0),
    "SUBTRACT": lambda t, c1, c2: _lerp(c1, c1 - c2, t),
    "DIVIDE": _divide,
    "HUE": _hue,
    "SATURATION": _saturation,
    "COLOR": _colour,
    "VALUE": _value,
}


# -- the Color Ramp --------------------------------------------------------------------------

def _spline_weights(f, interpolation):
    """``key_curve_position_weights`` for KEY_BSPLINE / KEY_CARDINAL: (4, N) weights."""
    f2, f3 = f * f, f * f * f
    if interpolation == "CARDINAL":
        fc = 0.71
        return np.stack([-fc * f3 + 2.0 * fc * f2 - fc * f,
                         (2.0 - fc) * f3 + (fc - 3.0) * f2 + 1.0,
                         (fc - 2.0) * f3 + (3.0 - 2.0 * fc) * f2 + fc * f,
                         fc * f3 - fc * f2])
    sixth = 0.16666666
    return np.stack([-sixth * f3 + 0.5 * f2 - 0.5 * f + sixth,
                     0.5 * f3 - f2 + 0.66666666,
                     -0.5 * f3 + 0.5 * f2 + 0.5 * f + sixth,
                     sixth * f3])


def _hue_interp(mode, mfac, fac, h1, h2):
    """``colorband_hue_interp``: the hue between h1 (weight mfac) and h2 (weight fac) the
    ramp's hue interpolation ('NEAR', 'FAR', 'CW', 'CCW') goes by."""
    h1 = np.where(h1 < 1.0, h1, h1 - 1.0)
    h2 = np.where(h2 < 1.0, h2, h2 - 1.0)
    if mode == "FAR":
        up = (h1 == h2) | ((h1 < h2) & (h2 - h1 < 0.5))
        down = ~up & (h1 > h2) & (h2 - h1 > -0.5)
    elif mode == "CCW":
        up, down = np.zeros_like(h1, bool), h1 > h2
    elif mode == "CW":
        up, down = h1 < h2, np.zeros_like(h1, bool)
    else:  # NEAR
        up = (h1 < h2) & (h2 - h1 > 0.5)
        down = (h1 > h2) & (h2 - h1 < -0.5)
    h = np.where(up, mfac * (h1 + 1.0) + fac * h2,
                 np.where(down, mfac * h1 + fac * (h2 + 1.0), mfac * h1 + fac * h2))
    return np.where(up | down, np.where(h < 1.0, h, h - 1.0), h)


def color_ramp(x, positions: Sequence[float], colours: Sequence[Sequence[float]],
               interpolation: str = "LINEAR", color_mode: str = "RGB",
               hue_interpolation: str = "NEAR") -> Tuple[np.ndarray, np.ndarray]:
    """The Color Ramp at factors ``x`` (N,): ``(colour (N, 3), alpha (N,))``.

    ``positions`` (sorted ascending, as Blender keeps them) and ``colours`` (RGBA) are the
    ramp's elements; ``interpolation``: 'LINEAR', 'EASE', 'CONSTANT', 'B_SPLINE' or
    'CARDINAL' (used in the RGB colour mode; 'HSV' and 'HSL' interpolate linearly in that
    space with ``hue_interpolation`` 'NEAR', 'FAR', 'CW' or 'CCW').  Before the first and
    after the last element the colour is that element's, except for the splines, which run
    on to positions 0 and 1."""
    x = np.asarray(x, np.float64)
    pos = np.asarray(positions, np.float64)
    col = np.asarray(colours, np.float64).reshape(-1, 4)
    n = len(pos)
    if n == 0:
        return np.zeros(x.shape + (3,)), np.zeros(x.shape)
    if n == 1:
        out = np.broadcast_to(col[0], x.shape + (4,))
        return out[..., :3].copy(), out[..., 3].copy()
    ipo = interpolation if color_mode == "RGB" else "LINEAR"
    a = np.searchsorted(pos, x, side="right")       # first element with position > x
    # the elements either side: "right" (cbd1) at a, "left" (cbd2) at a - 1; past the ends a
    # copy of the end element at position 1 (right) or 0 (left)
    right_i = np.minimum(a, n - 1)
    left_i = np.maximum(a - 1, 0)
    right_pos = np.where(a == n, 1.0, pos[right_i])
    left_pos = np.where(a == 0, 0.0, pos[left_i])
    right_c, left_c = col[right_i], col[left_i]
    with np.errstate(all="ignore"):
        fac = np.where(left_pos != right_pos, (x - right_pos) / (left_pos - right_pos),
                       np.where(a != n, 0.0, 1.0))
    if ipo in ("B_SPLINE", "CARDINAL"):
        far_right = col[np.where(a >= n - 1, right_i, np.minimum(a + 1, n - 1))]
        far_left = col[np.where(a < 2, left_i, np.maximum(a - 2, 0))]
        t = _spline_weights(np.clip(fac, 0.0, 1.0), ipo)
        out = (t[3][..., None] * far_left + t[2][..., None] * left_c
               + t[1][..., None] * right_c + t[0][..., None] * far_right)
        out = np.clip(out, 0.0, 1.0)
        return out[..., :3], out[..., 3]
    if ipo == "CONSTANT":
        out = left_c
    else:
        if ipo == "EASE":
            fac = 3.0 * fac * fac - 2.0 * fac * fac * fac
        mfac = 1.0 - fac
        if color_mode in ("HSV", "HSL"):
            to, back = (rgb_to_hsv, hsv_to_rgb) if color_mode == "HSV" else (rgb_to_hsl, hsl_to_rgb)
            c1, c2 = to(right_c[..., :3]), to(left_c[..., :3])
            mixed = np.stack([_hue_interp(hue_interpolation, mfac, fac, c1[..., 0], c2[..., 0]),
                              mfac * c1[..., 1] + fac * c2[..., 1],
                              mfac * c1[..., 2] + fac * c2[..., 2]], axis=-1)
            alpha = mfac * right_c[..., 3] + fac * left_c[..., 3]
            out = np.concatenate([back(mixed), alpha[..., None]], axis=-1)
        else:
            out = mfac[..., None] * right_c + fac[..., None] * left_c
    # before the first and after the last element: that element's colour
    out = np.where((a == n)[..., None], col[n - 1], out)
    out = np.where((x <= pos[0])[..., None], col[0], out)
    return out[..., :3], out[..., 3]
