"""A mesh volume's light pyramids summed once over levels and lights, towards the camera
(the walk's multiple scattering, Preview): a medium of one density wherever it has any reads
the same weights and anisotropies of its level table at every march sample, and the
direction from a sample to the camera is that of the camera ray through it, so its levels
are summed with those weights and the phase function towards the camera at each lattice
point into one level, which the march reads through march.FLAT_TABLE (weight 4 pi,
anisotropy 0: the factor 1).  Camera-dependent, so it is part of the precompute and its
cache (the camera's position is in the cache's key with multiple scattering on).  Where
Tuning.flatten says so (precompute.lightpyramid.flattens).  Radiance in W/(m^2 sr)."""
from __future__ import annotations

from typing import List, Optional

import numpy as np

from ..lights import pack_light
from ..media import PreparedMedium
from ..scene import Camera, Light, Tuning


def flattened(pm: PreparedMedium, mfs, lights: List[Light], camera: Camera,
              tuning: Tuning = Tuning()) -> list:
    """``mfs`` (one MultipleField or None a light, ``flat`` set by the precompute) as one
    MultipleField holding the flattened level (``flatten_levels``) and None for the other
    lights: what the march reads."""
    from ..walk import level_table
    from .lightpyramid import MultipleField
    ref = next(m for m in mfs if m is not None)
    table = level_table(pm.g, pm.sigma_s, pm.sigma_a, ref.h, len(ref.levels))
    after = None
    if any(m is not None and m.first is not None for m in mfs):
        after = level_table(pm.g, pm.sigma_s, pm.sigma_a, ref.h, len(ref.levels),
                            exact_flights=tuning.exact_flights)
    flat = flatten_levels(pm, mfs, lights, table, camera, after)
    stride = flat_stride(mfs)
    return [MultipleField(stride, ref.h * stride / ref.stride, [flat], flat=True)] + \
        [None] * (len(mfs) - 1)


def flat_stride(mfs) -> int:
    """The stride (voxels) of a medium's flattened level: the finest of its light pyramids'
    lattice and its exact first flights' (precompute.source.fine_stride divides the
    pyramid's stride)."""
    ref = next(m for m in mfs if m is not None)
    return min([ref.stride] + [m.first.stride for m in mfs
                               if m is not None and m.first is not None and m.first.stride])


def flatten_levels(pm: PreparedMedium, mfs, lights: List[Light], table: np.ndarray,
                   camera: Camera, table_after: Optional[np.ndarray] = None) -> np.ndarray:
    """One level (X,Y,Z,3) float32 on the lattice ``flat_stride(mfs)`` voxels apart: at
    each point y, sum over lights l and levels k of the level read at y times the level's
    weight and HG(cos_l(y); g_k) at density 1 (``table``: walk.level_table), cos_l(y)
    the cosine between the light's propagation at y and the direction from y to the
    ``camera``: what kernels_np.multiple_source computes at a march sample of a density-1
    medium, with the phase factor interpolated between lattice points instead of taken at
    the sample (it varies over metres, the lattice is centimetres).  An area light's
    direction is its centre's (the march jitters it over the area).

    A light whose MultipleField carries exact first flights (``first``, firstflight.py)
    adds, by their weight w per channel, those flights plus the levels read through
    ``table_after`` (level_table(..., exact_flights=2): the paths that scattered twice more),
    and 1 - w of the levels through ``table``."""
    from ..camera import towards_camera
    from ..kernels_np import hg, upsample
    from ..lights import light_sample
    from ..walk import table_lookup
    from .lattice import lattice_points, lattice_shape
    ref = next(m for m in mfs if m is not None)
    stride = flat_stride(mfs)
    shape = lattice_shape(pm.grid.shape, stride)
    _, x = lattice_points(pm, shape, stride)
    v = towards_camera(camera, x)
    tab = table_lookup(table, np.ones(1))[:, 0, :]   # (levels, 6) at density 1
    tab_after = None if table_after is None else table_lookup(table_after, np.ones(1))[:, 0, :]
    out = np.zeros(tuple(shape) + (3,), np.float64)
    for light, msf in zip(lights, mfs):
        if msf is None:
            continue
        half = np.full(len(x), 0.5)
        wi = light_sample(pack_light(light), x, half, half)[0]
        cos = np.einsum("ij,ij->i", wi, v)   # the kernels' -(wi . d): d = -v
        first = msf.first if tab_after is not None else None
        w = None if first is None else np.asarray(first.weight, np.float64)
        # each level upsampled once, read through ``table`` by 1 - w, ``table_after`` by w
        for k, lev in enumerate(msf.levels[:len(tab)]):
            up = upsample(lev, 2 ** k * msf.stride // stride, shape).reshape(-1, 3)

            def read(t):
                return (up * (t[k, :3] * hg(cos[:, None], t[k, 3:]))).reshape(out.shape)

            if w is None:
                out += read(tab)
                continue
            if np.any(w < 1.0):
                out += (1.0 - w) * read(tab)
            out += w * read(tab_after)
        if first is not None:
            fstride = first.stride or msf.stride
            out += w * upsample(first.field, fstride // stride, shape)
    return np.ascontiguousarray(out, np.float32)
