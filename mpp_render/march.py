"""The camera-ray march: transmittance, single scattering and depth along each ray.

Along a ray x(t) = o + t d the march cuts [t0, t1] (the union of the media's boxes, clipped
to the camera's clip range) into segments of length h and reads every medium's field at one
jittered point per segment.  Within a segment extinction sigma_t and in-scattered radiance S
are taken as constant, so the segment adds T * S * (1 - exp(-sigma_t h)) / sigma_t and
multiplies T by exp(-sigma_t h): exact for homogeneous media and stable at any optical depth.

In-scattered radiance at x, per medium m with density rho_m(x):
  S = sum_m rho_m sigma_s,m [ sum_lights p_m(w_l . -d) E_l(x) exp(-tau_l,m(x)) + A_m(x) ]
with E_l the light's irradiance (lights.py), tau the precomputed optical depth to the light
and A the precomputed world light (precompute.py).  Rays stop when T < ``T_MIN``.

Mesh volumes have a sharp surface (media.density_from).  There the optical depth to a light
jumps from 0 outside to sigma_t * distance inside, a kink that trilinear interpolation of
the voxel values smears over a voxel and that darkens the lit surface; so where a sample's
interpolation stencil straddles the surface, the first voxels towards the light are
integrated exactly (``REFINE_STEPS`` half-voxel steps, until the stencil is wholly inside or
outside) and the precomputed optical depth is read only from there on.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List

import numpy as np

from .lights import incident
from .media import PreparedMedium, density_from, to_index, trilinear
from .passes import DEPTH_MISS, DEPTH_OPACITY
from .phase import hg
from .precompute import FieldLayout
from .scene import Light

T_MIN = 1e-6
REFINE_STEPS = 8


@dataclass
class MarchContext:
    media: List[PreparedMedium]
    fields: List[np.ndarray]
    layout: FieldLayout
    lights: List[Light]
    step: float


def _towards_light(light: Light, x):
    """Unit directions from points x (N,3) to the light's centre and the distance (m)."""
    if light.kind == "SUN":
        w = -np.asarray(light.direction, np.float64)
        w = w / np.linalg.norm(w)
        return np.broadcast_to(w, x.shape), np.full(len(x), np.inf)
    pos = np.asarray(light.matrix, np.float64)[:3, 3] if light.kind == "AREA" else \
        np.asarray(light.position, np.float64)
    v = pos - x
    dist = np.linalg.norm(v, axis=1)
    return v / np.maximum(dist, 1e-30)[:, None], dist


def refined_optical_depth(ctx: MarchContext, mi: int, light_index: int, x):
    """Optical depth (N,3) from points x near medium mi's sharp surface to a light: exact
    over the first voxels, then the precomputed field (see the module docstring)."""
    pm, fld = ctx.media[mi], ctx.fields[mi]
    c = ctx.layout.light_channels[light_index]
    w, dist = _towards_light(ctx.lights[light_index], x)
    delta = 0.5 * pm.voxel_size
    tau = np.zeros((len(x), 3))
    end = x.copy()
    done = np.zeros(len(x), bool)
    for k in range(1, REFINE_STEPS + 1):
        todo = ~done
        if not todo.any():
            break
        seg = np.clip(dist[todo] - (k - 1) * delta, 0.0, delta)
        mid = x[todo] + w[todo] * ((k - 1) * delta + 0.5 * seg)[:, None]
        for om, ofl in zip(ctx.media, ctx.fields):
            rho = density_from(trilinear(om.grid, to_index(om, mid)), om.threshold)
            tau[todo] += (rho * seg)[:, None] * om.sigma_t
        pk = x[todo] + w[todo] * ((k - 1) * delta + seg)[:, None]
        occ = trilinear(pm.grid, to_index(pm, pk))
        end[todo] = pk
        fin = (occ <= 0.0) | (occ >= 1.0) | (seg < delta)
        idx = np.flatnonzero(todo)
        done[idx[fin]] = True
    return tau + trilinear(fld[..., c:c + 3], to_index(pm, end))


def march_rays(ctx: MarchContext, origins, dirs, t0, t1, axial, rng):
    """March rays; returns dict of per-ray arrays: 'single' (N,3), 'T' (N,3), 'depth' (N,)."""
    n = len(origins)
    single = np.zeros((n, 3))
    trans = np.ones((n, 3))
    depth = np.full(n, DEPTH_MISS)
    h = ctx.step
    t = t0 + rng.random(n) * h  # jittered sample position in the first segment
    seg_start = t0.copy()
    alive = np.flatnonzero(seg_start < t1)
    lights = [(li, L) for li, L in enumerate(ctx.lights) if ctx.layout.light_channels[li] is not None]
    while alive.size:
        o = origins[alive]
        d = dirs[alive]
        hl = np.minimum(h, t1[alive] - seg_start[alive])
        ts = np.minimum(t[alive], seg_start[alive] + hl)
        x = o + d * ts[:, None]
        m = len(alive)
        sig_t = np.zeros((m, 3))
        src = np.zeros((m, 3))
        emit = [(li, L, *incident(L, x, rng.random((m, 2)))) for li, L in lights]
        for mi, (pm, fld) in enumerate(zip(ctx.media, ctx.fields)):
            v = trilinear(fld, to_index(pm, x))
            rho = density_from(v[:, 0], pm.threshold)
            if not np.any(rho > 0):
                continue
            sig_t += rho[:, None] * pm.sigma_t
            edge = np.flatnonzero((v[:, 0] > 0.0) & (v[:, 0] < 1.0) & (rho > 0)) if pm.sharp else []
            inc = np.zeros((m, 3))
            for li, L, wi, e in emit:
                c = ctx.layout.light_channels[li]
                tau = v[:, c:c + 3]
                if len(edge):
                    tau = tau.copy()
                    tau[edge] = refined_optical_depth(ctx, mi, li, x[edge])
                cos = -np.einsum("ij,ij->i", wi, d)
                inc += (hg(cos, pm.g)[:, None] * e) * np.exp(-tau)
            if ctx.layout.ambient_channel is not None:
                a = ctx.layout.ambient_channel
                inc += v[:, a:a + 3]
            src += rho[:, None] * pm.sigma_s * inc
        x_t = sig_t * hl[:, None]
        # (1 - exp(-x)) / x without cancellation; -> 1 as x -> 0
        frac = np.where(x_t > 1e-7, -np.expm1(-x_t) / np.maximum(x_t, 1e-300), 1.0 - 0.5 * x_t)
        T_before = trans[alive]
        single[alive] += T_before * src * (frac * hl[:, None])
        T_after = T_before * np.exp(-x_t)
        trans[alive] = T_after
        # depth: first segment where the opacity 1 - mean(T) reaches DEPTH_OPACITY
        tb, ta = T_before.mean(axis=1), T_after.mean(axis=1)
        thr = 1.0 - DEPTH_OPACITY
        hit = (depth[alive] >= DEPTH_MISS) & (ta <= thr) & (tb > thr)
        if hit.any():
            with np.errstate(divide="ignore", invalid="ignore"):
                f = np.clip(np.log(tb[hit] / thr) / np.log(tb[hit] / np.maximum(ta[hit], 1e-300)), 0, 1)
            depth[alive[hit]] = (seg_start[alive[hit]] + f * hl[hit]) * axial[alive[hit]]
        seg_start[alive] += hl
        t[alive] = seg_start[alive] + rng.random(m) * h
        keep = (seg_start[alive] < t1[alive]) & (T_after.max(axis=1) > T_MIN)
        alive = alive[keep]
    return {"single": single, "T": trans, "depth": depth}
