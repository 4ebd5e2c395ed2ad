"""The directions through which a surface point gathers the light around it (no bpy).

``surfaces.shade`` reflects the sky, the other surfaces and the light the media scatter
towards a point through ``k`` directions per camera sample.  Cosine-weighted directions
(density cos(theta) / pi per steradian) suit the sky and a medium's smooth light.  Round a
lamp inside a medium they do not: a homogeneous medium's once-scattered light seen from a
point at distance D from the lamp, along a direction at angle gamma from the lamp's, is

    L(gamma) = sigma_s I p (pi - gamma) / (D sin gamma)                     [W/(m^2 sr)]

(an isotropic phase function p and no extinction: the integral of 1 / r^2 along the ray,
int_0^inf ds / (D^2 + s^2 - 2 D s cos gamma); Sun, Ramamoorthi, Narasimhan and Nayar,
SIGGRAPH 2005, give it with extinction), peaked as 1 / gamma towards the lamp: cosine-weighted directions see it through
a few rare directions that pass near the lamp, a heavy tail of noise (a ground under a lamp
in fog kept 7-16 samples per pixel under adaptive sampling).

So where the gather reads the media's light and a lamp (a point, spot or area light) sits
inside a medium (``Guides``: its centre within a grid's box, or anywhere in the world's fog),
or a medium emits (a fire: its emission and its glow in the smoke round it reach a point
through the directions towards it; ``Guides.of_emitters``, at the emission's centroid), a
share of the ``k`` directions (``Tuning.guided_gathers``, half) is drawn about a lamp
instead: the lamp chosen with probability P_i proportional to its power over its distance
(the scale of L above), then gamma in [0, pi] about the direction to its centre with density
2 (pi - gamma) / pi^2 and the azimuth uniform, a density per steradian of

    p_i(w) = (pi - gamma_i(w)) / (pi^3 sin gamma_i(w)),

which follows L's (pi - gamma) / sin gamma: a gathered direction's L / p is nearly constant
where the lamp's glow dominates.  Every direction, of either kind, weighs by the balance
heuristic of the multi-sample model (Veach 1997, section 9.2.2):

    weight(w) = (cos / pi) / (k_c cos / pi + k_l sum_i P_i p_i(w)),

with k_c and k_l the directions of each kind, so the gathered light stays unbiased (a test
holds the weights' integral over the hemisphere to 1), and a direction below the surface
weighs nothing (it is not traced).  Without guides all k are cosine-weighted and each weighs
1 / k.

Directions are stratified as ``surfaces.shade`` asks: each kind's first random number in
equal bands (of 1 - cos^2 theta for the cosine-weighted ones, of gamma's distribution for the
guided ones).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .phase import orthonormal_basis


@dataclass
class Guides:
    """Lamps that gathers aim at: ``position`` (G,3) m, the centres of the lamps; ``power``
    (G,) > 0 W, their mean power over the channels."""

    position: np.ndarray
    power: np.ndarray

    @classmethod
    def of_lights(cls, lights, inside=None) -> "Guides | None":
        """The point, spot and area lights that emit and whose centre ``inside(centre)``
        finds in a medium (all of them without ``inside``), or None when there is none (a
        sun's light is not peaked about a point, nor, much, a lamp's outside the media)."""
        pos, power = [], []
        for light in lights:
            if light.kind == "SUN":
                continue
            p = float(np.mean(np.asarray(light.strength, np.float64)))
            if not p > 0.0:
                continue
            centre = np.asarray(light.matrix, np.float64)[:3, 3] if light.kind == "AREA" \
                else np.asarray(light.position, np.float64)
            if inside is not None and not inside(centre):
                continue
            pos.append(centre)
            power.append(p)
        if not pos:
            return None
        return cls(np.asarray(pos, np.float64).reshape(-1, 3), np.asarray(power, np.float64))

    @classmethod
    def of_emitters(cls, media) -> "Guides | None":
        """The media that emit (PreparedMedium.emits; not the world's fog, whose glow is
        everywhere), each as a guide at the centroid of its emission with the power it
        gives off, 4 pi sum(e V) W (the mean over the channels): a fire's light on the
        ground round it comes through the few directions that meet it, and its glow in the
        smoke round it peaks towards it as a lamp's does; None when none emits."""
        pos, power = [], []
        for pm in media:
            if pm.endless or not pm.emits:
                continue
            e = pm.emitted()
            if e is None:
                continue
            lum = e.mean(axis=-1)
            flat = np.flatnonzero(lum > 0.0)
            if not flat.size:
                continue
            vol = float(abs(np.linalg.det(np.asarray(pm.i2w[:3, :3], np.float64))))
            wts = lum.reshape(-1)[flat]
            ijk = np.stack(np.unravel_index(flat, lum.shape), axis=1).astype(np.float64)
            pos.append(np.average(pm.to_world(ijk), axis=0, weights=wts))
            power.append(4.0 * np.pi * vol * float(wts.sum()))
        if not pos:
            return None
        return cls(np.asarray(pos, np.float64).reshape(-1, 3), np.asarray(power, np.float64))

    @staticmethod
    def joined(*guides) -> "Guides | None":
        """The guides of every one of ``guides`` that is not None, or None."""
        got = [g for g in guides if g is not None]
        if not got:
            return None
        return Guides(np.concatenate([g.position for g in got]),
                      np.concatenate([g.power for g in got]))

    def choice(self, points) -> tuple:
        """(unit directions (N,G,3) from ``points`` to each lamp, probabilities (N,G) of
        choosing each: power over distance, normalised)."""
        v = self.position[None, :, :] - np.asarray(points, np.float64)[:, None, :]
        dist = np.maximum(np.linalg.norm(v, axis=2), 1e-9)
        score = self.power[None, :] / dist
        return v / dist[..., None], score / score.sum(axis=1, keepdims=True)


def guided_density(axes, prob, w) -> np.ndarray:
    """sum_i P_i p_i(w) (N,) per steradian: ``axes`` (N,G,3) unit directions to the lamps,
    ``prob`` (N,G) their probabilities, ``w`` (N,3) unit directions."""
    cross = np.cross(axes, w[:, None, :])
    sin = np.linalg.norm(cross, axis=2)
    with np.errstate(divide="ignore"):
        gamma = np.arctan2(sin, np.einsum("ngj,nj->ng", axes, w))
        return np.sum(prob * (np.pi - gamma) / (np.pi ** 3 * sin), axis=1)


def directions(nrm, points, u, k: int, guides: "Guides | None" = None, choose=None,
               guided: float = 0.5):
    """The ``k`` gathering directions of each point and their weights.

    ``nrm`` (N,3) unit normals (towards the viewer), ``points`` (N,3) m, ``u`` (N,k,2)
    random numbers in [0,1) (their stratification across a pixel's samples already
    applied), ``choose`` (N,k) in [0,1), the guided directions' choice of lamp (needed with
    ``guides``), ``guided`` the share of the k drawn about the lamps (rounded down).  Returns (w (N,k,3) unit directions, weight (N,k)): the gathered radiance
    along w times weight times the surface's directional albedo is the estimate of the
    reflected light, summed over the k."""
    n = len(nrm)
    k_l = min(int(k * guided), k - 1) if guides is not None else 0
    k_c = k - k_l
    w = np.empty((n, k, 3))
    # the cosine-weighted ones, stratified in r^2 = 1 - cos^2
    uc = u[:, :k_c]
    r = np.sqrt((np.arange(k_c)[None, :] + uc[..., 0]) / k_c)
    phi = 2.0 * np.pi * uc[..., 1]
    t1, t2 = orthonormal_basis(nrm)
    w[:, :k_c] = (t1[:, None] * (r * np.cos(phi))[..., None] + t2[:, None] * (r * np.sin(phi))[..., None]
                  + nrm[:, None] * np.sqrt(np.maximum(0.0, 1.0 - r * r))[..., None])
    if k_l == 0:
        return w, np.full((n, k), 1.0 / k)
    axes, prob = guides.choice(points)
    # the guided ones: a lamp by its probability
    cdf = np.cumsum(prob, axis=1)
    pick = np.minimum((np.asarray(choose)[:, k_c:, None] >= cdf[:, None, :]).sum(axis=2),
                      prob.shape[1] - 1)
    a = np.take_along_axis(axes, pick[..., None], axis=1)          # (N,k_l,3)
    ul = u[:, k_c:]
    # gamma by the inverse of its distribution, 1 - (1 - gamma / pi)^2
    gamma = np.pi * (1.0 - np.sqrt(1.0 - (np.arange(k_l)[None, :] + ul[..., 0]) / k_l))
    phi = 2.0 * np.pi * ul[..., 1]
    b1, b2 = orthonormal_basis(a.reshape(-1, 3))
    sg, cg = np.sin(gamma).reshape(-1, 1), np.cos(gamma).reshape(-1, 1)
    wl = a.reshape(-1, 3) * cg + sg * (b1 * np.cos(phi).reshape(-1, 1) + b2 * np.sin(phi).reshape(-1, 1))
    w[:, k_c:] = wl.reshape(n, k_l, 3)
    # the balance heuristic over both kinds
    cos = np.einsum("nkj,nj->nk", w, nrm)
    pc = np.maximum(cos, 0.0) / np.pi
    pl = guided_density(np.repeat(axes, k, axis=0), np.repeat(prob, k, axis=0),
                        w.reshape(-1, 3)).reshape(n, k)
    with np.errstate(invalid="ignore", divide="ignore"):
        weight = np.where(cos > 0.0, pc / (k_c * pc + k_l * pl), 0.0)
    return w, np.nan_to_num(weight, nan=0.0, posinf=0.0)
