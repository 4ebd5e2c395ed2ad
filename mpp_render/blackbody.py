"""Blackbody emission of Principled Volume, in Cycles' units and colours.

Cycles (``svm_node_principled_volume`` in intern/cycles/kernel/svm/closure.h) gives a
Principled Volume with Blackbody Intensity b > 0 the emission

    L_e = Tint * sigma_SB / pi * 1e-6 * ((1 - b) + b T^4) * colour(T)     [W/(m^3 sr)]

with T = Temperature x max(attribute, 0) where the grid named by Temperature Attribute
exists (else T = Temperature), in kelvin, sigma_SB = 5.670373e-8 W/(m^2 K^4) the
Stefan-Boltzmann constant, and colour(T) the linear Rec.709 colour of a blackbody at T
scaled to unit luminance (Y = 0.2126 R + 0.7152 G + 0.0722 B = 1), T clamped to
[800, 12000] K.  The emission is not scaled by density (as Emission Strength x Emission
Color is not).

``colour`` here is computed from first principles, not from Cycles' fit: Planck's law
integrated against the CIE 1931 2-degree colour-matching functions (CIE 15:2004 tables,
5 nm steps from 360 to 830 nm), converted from XYZ to linear Rec.709 (D65) and divided by
Y.  Against Cycles renders of blackbody cubes (tests/blender/test_blackbody.py) it agrees to
0.1 % at 1000, 3000 and 6500 K.  Below about 1900 K the blue channel of the Rec.709 colour
is negative (the colour lies outside the Rec.709 gamut); Cycles keeps it negative inside a
Principled Volume, ``colour`` clamps it to 0 (at 1000 K: blue -0.0014 against red 0.072,
2 % of red).
"""
from __future__ import annotations

import numpy as np

T_MIN, T_MAX = 800.0, 12000.0  # kelvin: the range colour() covers (clamped outside)
STEFAN_BOLTZMANN = 5.670373e-8  # W/(m^2 K^4)
C2 = 1.4387769e-2  # second radiation constant h c / k_B, m K

# CIE 1931 2-degree standard observer x, y, z at 360, 365, ..., 830 nm.
_CMF_X = (
    0.0001299, 0.0002321, 0.0004149, 0.0007416, 0.001368, 0.002236, 0.004243, 0.00765, 0.01431,
    0.02319, 0.04351, 0.07763, 0.13438, 0.21477, 0.2839, 0.3285, 0.34828, 0.34806, 0.3362,
    0.3187, 0.2908, 0.2511, 0.19536, 0.1421, 0.09564, 0.05795, 0.03201, 0.0147, 0.0049, 0.0024,
    0.0093, 0.0291, 0.06327, 0.1096, 0.1655, 0.22575, 0.2904, 0.3597, 0.43345, 0.51205, 0.5945,
    0.6784, 0.7621, 0.8425, 0.9163, 0.9786, 1.0263, 1.0567, 1.0622, 1.0456, 1.0026, 0.9384,
    0.85445, 0.7514, 0.6424, 0.5419, 0.4479, 0.3608, 0.2835, 0.2187, 0.1649, 0.1212, 0.0874,
    0.0636, 0.04677, 0.0329, 0.0227, 0.01584, 0.0113592, 0.00811092, 0.00579035, 0.00410946,
    0.00289933, 0.00204919, 0.00143997, 0.000999949, 0.000690079, 0.000476021, 0.000332301,
    0.000234826, 0.000166151, 0.000117413, 8.30753e-05, 5.87065e-05, 4.15099e-05, 2.93533e-05,
    2.06738e-05, 1.45598e-05, 1.0254e-05, 7.22146e-06, 5.08587e-06, 3.58165e-06, 2.52253e-06,
    1.77651e-06, 1.25114e-06,
)

_CMF_Y = (
    3.917e-06, 6.965e-06, 1.239e-05, 2.202e-05, 3.9e-05, 6.4e-05, 0.00012, 0.000217, 0.000396,
    0.00064, 0.00121, 0.00218, 0.004, 0.0073, 0.0116, 0.01684, 0.023, 0.0298, 0.038, 0.048,
    0.06, 0.0739, 0.09098, 0.1126, 0.13902, 0.1693, 0.20802, 0.2586, 0.323, 0.4073, 0.503,
    0.6082, 0.71, 0.7932, 0.862, 0.91485, 0.954, 0.9803, 0.99495, 1, 0.995, 0.9786, 0.952,
    0.9154, 0.87, 0.8163, 0.757, 0.6949, 0.631, 0.5668, 0.503, 0.4412, 0.381, 0.321, 0.265,
    0.217, 0.175, 0.1382, 0.107, 0.0816, 0.061, 0.04458, 0.032, 0.0232, 0.017, 0.01192,
    0.00821, 0.005723, 0.004102, 0.002929, 0.002091, 0.001484, 0.001047, 0.00074, 0.00052,
    0.0003611, 0.0002492, 0.0001719, 0.00012, 8.48e-05, 6e-05, 4.24e-05, 3e-05, 2.12e-05,
    1.499e-05, 1.06e-05, 7.4657e-06, 5.2578e-06, 3.7029e-06, 2.6078e-06, 1.8366e-06,
    1.2934e-06, 9.1093e-07, 6.4153e-07, 4.5181e-07,
)

_CMF_Z = (
    0.0006061, 0.001086, 0.001946, 0.003486, 0.00645, 0.01055, 0.02005, 0.03621, 0.06785,
    0.1102, 0.2074, 0.3713, 0.6456, 1.03905, 1.3856, 1.62296, 1.74706, 1.7826, 1.77211, 1.7441,
    1.6692, 1.5281, 1.28764, 1.0419, 0.81295, 0.6162, 0.46518, 0.3533, 0.272, 0.2123, 0.1582,
    0.1117, 0.07825, 0.05725, 0.04216, 0.02984, 0.0203, 0.0134, 0.00875, 0.00575, 0.0039,
    0.00275, 0.0021, 0.0018, 0.00165, 0.0014, 0.0011, 0.001, 0.0008, 0.0006, 0.00034, 0.00024,
    0.00019, 0.0001, 5e-05, 3e-05, 2e-05, 1e-05, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
    0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
)

WAVELENGTHS_NM = np.arange(360.0, 831.0, 5.0)
CMF = np.stack([np.array(_CMF_X), np.array(_CMF_Y), np.array(_CMF_Z)], axis=1)  # (95, 3)

# XYZ -> linear Rec.709 / sRGB primaries, D65 white (IEC 61966-2-1).
XYZ_TO_REC709 = np.array([[3.2404542, -1.5371385, -0.4985314],
                          [-0.9692660, 1.8760108, 0.0415560],
                          [0.0556434, -0.2040259, 1.0572252]])

TABLE_STEP_K = 10.0  # colour() interpolates a table of the exact colour every 10 K
_TABLE_T = np.arange(T_MIN, T_MAX + TABLE_STEP_K / 2, TABLE_STEP_K)


def colour_exact(temperature) -> np.ndarray:
    """Linear Rec.709 colour of a blackbody at ``temperature`` (kelvin, any shape), unit
    luminance, *not* clamped to >= 0: (..., 3).  T is clamped to [T_MIN, T_MAX]."""
    t = np.clip(np.asarray(temperature, np.float64), T_MIN, T_MAX)
    lam = WAVELENGTHS_NM * 1e-9
    # Planck's spectral radiance up to a constant factor (it cancels in the normalisation)
    planck = 1.0 / (lam ** 5 * np.expm1(C2 / (lam * t[..., None])))
    xyz = planck @ CMF
    return (xyz / xyz[..., 1:2]) @ XYZ_TO_REC709.T


_TABLE = colour_exact(_TABLE_T)


def colour(temperature) -> np.ndarray:
    """Linear Rec.709 colour of a blackbody at ``temperature`` (kelvin, any shape; NaN and
    values below 800 K count as 800 K, above 12000 K as 12000 K), unit luminance, negative
    components clamped to 0: (..., 3) float64.  Linear interpolation of a 10 K table of
    ``colour_exact`` (within 1e-4 of it, relative to the largest channel)."""
    t = np.asarray(temperature, np.float64)
    t = np.clip(np.where(np.isfinite(t), t, T_MIN), T_MIN, T_MAX)
    f = (t - T_MIN) / TABLE_STEP_K
    i = np.minimum(np.floor(f).astype(np.int64), len(_TABLE_T) - 2)
    w = (f - i)[..., None]
    return np.maximum(_TABLE[i] * (1.0 - w) + _TABLE[i + 1] * w, 0.0)


def emission(temperature, intensity: float, tint=(1.0, 1.0, 1.0)) -> np.ndarray:
    """Principled Volume's blackbody emission (..., 3), W/(m^3 sr), at ``temperature``
    (kelvin, any shape; negative and non-finite values count as 0 K, as Cycles' max(T, 0))
    for Blackbody Intensity ``intensity`` (0: none) and Blackbody Tint ``tint`` (RGB)."""
    b = float(intensity)
    t = np.asarray(temperature, np.float64)
    t = np.where(np.isfinite(t), np.maximum(t, 0.0), 0.0)
    if not b > 0.0:
        return np.zeros(t.shape + (3,))
    power = STEFAN_BOLTZMANN * 1e-6 / np.pi * ((1.0 - b) + b * t ** 4)
    out = np.maximum(power, 0.0)[..., None] * colour(t) * np.asarray(tint, np.float64).reshape(3)
    return out
