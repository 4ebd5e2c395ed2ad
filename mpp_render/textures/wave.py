"""Blender's Wave Texture node, vectorised with numpy.

Follows the Geometry Nodes multi-function of Blender 4.1-5.0
``source/blender/nodes/shader/nodes/node_shader_tex_wave.cc`` (``WaveFunction``), the
same algorithm as Cycles ``intern/cycles/kernel/svm/wave.h``:

* ``p = (vector * scale + 1e-6) * 0.999999`` (float32, "prevent precision issues on unit
  coordinates");
* Bands: ``n = 20 * p.x`` (or y, z) or ``10 * (p.x + p.y + p.z)`` for Diagonal; Rings:
  ``n = 20 * |p|`` with the ring axis' component zeroed (Spherical keeps all three);
* ``n += phase_offset``; with distortion ``!= 0``:
  ``n += distortion * (2 * fbm(p * detail_scale, detail, detail_roughness, 2, normalize) - 1)``
  (:func:`mpp_render.textures.noise.fbm`, 3D, detail not clamped, as the node);
* profile: Sine ``0.5 + 0.5 sin(n - pi/2)``; Saw ``frac(n / 2pi)``; Triangle
  ``2 |n/2pi - floor(n/2pi + 0.5)|``.

Float32 like Blender, with the few double-precision steps (``n - M_PI_2``,
``n / (M_PI * 2)``) done in float64 and rounded to float32 as C does.
Returns ``(fac (N,), color (N, 3))`` with color = fac in every channel.
"""
import numpy as np

from .noise import F32, _per_point, fbm

_BANDS = ("X", "Y", "Z", "DIAGONAL")
_RINGS = ("X", "Y", "Z", "SPHERICAL")
_PROFILES = ("SIN", "SAW", "TRI")


def wave_texture(vector, wave_type="BANDS", bands_direction="X", rings_direction="X",
                 wave_profile="SIN", scale=5.0, distortion=0.0, detail=2.0, detail_scale=1.0,
                 detail_roughness=0.5, phase_offset=0.0):
    """Blender's Wave Texture at N points (``vector`` (N, 3); numeric inputs scalars or
    (N,) arrays; enums as Blender's identifiers: ``wave_type`` 'BANDS' / 'RINGS',
    ``bands_direction`` 'X' 'Y' 'Z' 'DIAGONAL', ``rings_direction`` 'X' 'Y' 'Z'
    'SPHERICAL', ``wave_profile`` 'SIN' 'SAW' 'TRI').  Returns (fac, color) float32."""
    vec = np.asarray(vector, F32).reshape(-1, 3)
    n_pts = vec.shape[0]
    sc = _per_point(scale, n_pts)
    dist = _per_point(distortion, n_pts)
    det = _per_point(detail, n_pts)
    dsc = _per_point(detail_scale, n_pts)
    drough = _per_point(detail_roughness, n_pts)
    phase = _per_point(phase_offset, n_pts)

    p = vec * sc[:, None]
    p = (p + F32(0.000001)) * F32(0.999999)

    if wave_type == "BANDS":
        if bands_direction not in _BANDS:
            raise ValueError(f"unknown bands_direction {bands_direction!r}")
        if bands_direction == "DIAGONAL":
            n = (p[:, 0] + p[:, 1] + p[:, 2]) * F32(10.0)
        else:
            n = p[:, _BANDS.index(bands_direction)] * F32(20.0)
    elif wave_type == "RINGS":
        if rings_direction not in _RINGS:
            raise ValueError(f"unknown rings_direction {rings_direction!r}")
        rp = p.copy()
        if rings_direction != "SPHERICAL":
            rp[:, _RINGS.index(rings_direction)] *= F32(0.0)
        n = np.sqrt(rp[:, 0] * rp[:, 0] + rp[:, 1] * rp[:, 1] + rp[:, 2] * rp[:, 2]) * F32(20.0)
    else:
        raise ValueError(f"unknown wave_type {wave_type!r}")

    n = (n + phase).astype(F32)
    on = dist != 0
    if on.any():
        idx = np.nonzero(on)[0]
        q = p[idx] * dsc[idx, None]
        noise = fbm(q, det[idx], drough[idx], F32(2.0), True)
        n[idx] = n[idx] + dist[idx] * (noise * F32(2.0) - F32(1.0))

    if wave_profile == "SIN":
        arg = (n.astype(np.float64) - np.pi / 2).astype(F32)
        val = F32(0.5) + F32(0.5) * np.sin(arg.astype(np.float64)).astype(F32)
    elif wave_profile in ("SAW", "TRI"):
        n = (n.astype(np.float64) / (np.pi * 2.0)).astype(F32)
        if wave_profile == "SAW":
            val = n - np.floor(n)
        else:
            val = np.abs(n - np.floor(n + F32(0.5))) * F32(2.0)
    else:
        raise ValueError(f"unknown wave_profile {wave_profile!r}")
    val = val.astype(F32)
    return val, np.repeat(val[:, None], 3, axis=1)
