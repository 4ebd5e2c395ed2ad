"""Light emission as seen from points in the media, in Cycles' units.

``incident(light, points, u)`` returns, for world points (N,3), the propagation direction of
the arriving light (unit, from the light towards the point) and the RGB irradiance E (W/m^2)
it brings on a plane facing it, *before* attenuation by the media.  Single scattering at a
point is then sigma_s * p(cos) * E * T_light.

* POINT / SPOT: radiant intensity I = P / (4 pi) W/sr (Cycles' point and spot convention), so
  E = I / d^2.  A light with a radius r is Cycles' default "soft falloff" lamp
  (kernel/light/point.h, the branch ``is_sphere = !use_soft_falloff`` takes by default): a
  disc of radius r facing the shading point with radiance I / (pi r^2).  It subtends the cone
  of half-angle atan(r / d) about the centre, so E = I / (pi r^2) * 2 pi (1 - cos theta_max)
  = 2 I (1 - d / sqrt(d^2 + r^2)) / r^2 (I / d^2 far away, 2 I / r^2 at the centre) whatever
  point of the disc is sampled; the jitter picks the direction uniformly in that solid
  angle (the phase function and a spot's cone see it), and the distance to the disc along it,
  d / cos(theta), scales the optical depth to the centre (``path_stretch``): the disc's
  light crosses more medium than the centre's path.  A spot with a radius averages its
  cone over 8 such directions (a lattice shifted by the jitter: the same mean as one
  direction, far less noise in the penumbra) and reports the irradiance-weighted direction.
* SPOT cone: smoothstep((cos(theta) - cos(size/2)) / ((1 - cos(size/2)) * blend)), theta
  measured in the light's local frame (non-uniform scale included); no normalisation by the
  cone's solid angle.
* SUN: ``strength`` is already the irradiance; a directional light along ``direction``.
* AREA: one point per call is picked on the emitter from ``u``; the estimate is
  L_e cos(theta_l) A / d^2 with L_e = P / (pi A) (``normalize``) or P / pi; only the front
  (local -Z) side emits.  Averaging calls with stratified ``u`` converges to the integral.
  The optical depth to the centre is scaled to the sampled point's distance, as for a disc.
"""
from __future__ import annotations

import numpy as np

from .lightrecord import (KIND_AREA, KIND_POINT, KIND_SPOT, KIND_SUN, L_ANGLES, L_AREA, L_AX, L_AY,
                          L_BEAM, L_BLEND, L_CHANNEL, L_COND, L_COSHALF, L_DIR, L_DISC, L_INDIRECT,
                          L_INV, L_KIND, L_NORMAL, L_NORMALIZE, L_POS, L_RADIUS, L_ROUND, L_STRENGTH,
                          LIGHT_FIELDS)
from .phase import orthonormal_basis
from .rng import hash32
from .scene import Light


# The light as the march kernel samples it (the C twin: csrc/light.h).
SPOT_DISC_POINTS = 8    # points of a sphere spot's disc its cone is averaged over (C twin)
SPOT_DISC_PHI = 0.6180339887498949  # the lattice's second coordinate steps by the golden ratio
SPOT_GATE_MARGIN = 1.05  # widens the disc's angular radius in the one-point test
# cos and sin of 2 pi frac(i SPOT_DISC_PHI): the turn of the disc lattice's i-th azimuth from
# its first (the C twin's table; tests/test_light_samples.py holds both to this formula)
LAMP_DISC_TURN = np.array([[1.0, 0.0],
                           [-0.7373688780783199, -0.6754902942615236],
                           [0.08742572471695967, 0.9961710408648278],
                           [0.6084388609788622, -0.7936007512916963],
                           [-0.9847134853154288, 0.17418195037931125],
                           [0.8437552948123968, 0.5367280526263234],
                           [-0.2596043049014893, -0.9657150743757781],
                           [-0.4609070247133709, 0.8874484292452537]])


def disc_turn(i: int):
    """(cos, sin) of 2 pi frac(i SPOT_DISC_PHI): LAMP_DISC_TURN's row, or beyond its rows
    the formula."""
    if i < len(LAMP_DISC_TURN):
        return LAMP_DISC_TURN[i]
    f = i * SPOT_DISC_PHI
    f -= np.floor(f)
    return np.cos(2.0 * np.pi * f), np.sin(2.0 * np.pi * f)


def _disc(a, b, round_shape):
    """Square [-1,1]^2 (identity) or concentric map to the unit disc."""
    if not round_shape:
        return a, b
    big = np.abs(a) > np.abs(b)
    r = np.where(big, a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(big, (np.pi / 4) * b / np.where(a == 0, 1, a),
                       np.pi / 2 - (np.pi / 4) * a / np.where(b == 0, 1, b))
    phi = np.where((a == 0) & (b == 0), 0.0, phi)
    return r * np.cos(phi), r * np.sin(phi)


def _spot_cos(rec, v):
    """(N,) cosines between the spot's axis and propagation directions ``v`` (N,3), measured
    in the light's local frame (its inverse matrix: non-uniform scale included)."""
    loc = v @ rec[L_INV:L_INV + 9].reshape(3, 3).T
    return -loc[:, 2] / np.maximum(np.sqrt(np.einsum("ij,ij->i", loc, loc)), 1e-30)


def straddles(rec, wc, dc):
    """(N,) whether the cone of a spot with a radius differs over its disc as seen from points
    at unit directions ``wc`` (N,3) and distances ``dc`` (N,) from its centre: their angle to
    the axis within the disc's angular radius (times SPOT_GATE_MARGIN and L_COND) of the
    cone's edge or blend, or the point inside the lamp (light_sample's one-point test, the C
    twin's)."""
    th = np.arccos(np.clip(_spot_cos(rec, -wc), -1.0, 1.0))
    inside = rec[L_RADIUS] < dc
    spread = SPOT_GATE_MARGIN * rec[L_COND] * np.arcsin(
        np.where(inside, rec[L_RADIUS] / np.where(inside, dc, 1.0), 1.0))
    return ~(inside & ((th - spread > rec[L_ANGLES]) | (th + spread < rec[L_ANGLES + 1])))


def light_sample(rec, x, u1, u2, disc_points: int = SPOT_DISC_POINTS, normal=None):
    """(propagation direction (N,3), irradiance (N,3), unit direction to the light centre
    (N,3), distance to the centre (N,), distance to the emitting point(s) sampled (N,): their
    irradiance-weighted mean; the centre's for a point without radius) of packed light
    ``rec`` (lightrecord.py) at points ``x`` (N,3, m), jitter ``u1``, ``u2`` (N,) in [0, 1).
    ``disc_points``: the directions a spot with a radius averages its cone over (the C
    twin's SPOT_DISC_POINTS).  ``normal``: None, or unit normals (N,3) of surfaces at
    ``x`` (surfaces.shade; the march has none, and its C twin no such argument): a
    rectangle light's points are then drawn in its solid angle warped towards the corners
    the surface faces most (``cosine_warp``), the irradiance divided by the warp's
    density."""
    kind = int(rec[L_KIND])
    s = rec[L_STRENGTH:L_STRENGTH + 3]
    n = len(x)
    if kind == KIND_SUN:
        d = np.broadcast_to(rec[L_DIR:L_DIR + 3], (n, 3)).copy()
        return d, np.broadcast_to(s, (n, 3)).copy(), -d, np.full(n, np.inf), np.full(n, np.inf)
    centre = rec[L_POS:L_POS + 3]
    vc = centre - x
    dc = np.sqrt(np.einsum("ij,ij->i", vc, vc))
    wc = vc / np.maximum(dc, 1e-30)[:, None]
    if kind in (KIND_POINT, KIND_SPOT):
        radius = rec[L_RADIUS]
        t1 = t2 = np.zeros((n, 3))
        if radius > 0.0:
            t1, t2 = orthonormal_basis(-wc)
        # 1 - cos(theta_max) of the cone the facing disc subtends, without cancellation
        hyp = np.sqrt(dc * dc + radius * radius)
        omc_max = radius * radius / (hyp * (hyp + dc)) if radius > 0.0 else np.zeros(n)
        e_disc = 2.0 * omc_max / (radius * radius) if radius > 0.0 else np.zeros(n)

        def emitted(s2, ca, sa):
            """(direction, irradiance per unit intensity, distance) of the disc point of
            squared radius s2 on the unit disc whose azimuth's cosine and sine are ca, sa."""
            if radius > 0.0:
                # Cycles' soft-falloff lamp (C twin): a disc facing x of radiance I/(pi r^2);
                # the disc point maps to a direction uniform in the disc's solid angle,
                # 1 - cos theta = s2 (1 - cos theta_max)
                omc = s2 * omc_max
                cos_t = 1.0 - omc
                sin_t = np.sqrt(np.maximum(omc * (2.0 - omc), 0.0))
                di = -(wc * cos_t[:, None] + (t1 * ca[:, None] + t2 * sa[:, None]) * sin_t[:, None])
                r2 = 1.0 / e_disc
                dist = dc / np.maximum(cos_t, 1e-12)  # to the disc along di
            else:
                v = x - centre
                dist = np.sqrt(np.einsum("ij,ij->i", v, v))
                di = v / np.maximum(dist, 1e-30)[:, None]
                r2 = np.maximum(dist * dist, 1e-4 ** 2)
            att = 1.0
            if kind == KIND_SPOT:
                cos_t = _spot_cos(rec, di)
                ch, bl = rec[L_COSHALF], rec[L_BLEND]
                if bl <= 0.0:
                    att = (cos_t > ch).astype(np.float64)
                else:
                    q = np.clip((cos_t - ch) / ((1.0 - ch) * bl), 0.0, 1.0)
                    att = q * q * (3.0 - 2.0 * q)
            return di, np.broadcast_to(att / r2, (n,)), np.broadcast_to(dist, (n,))

        # one disc point (C twin): (u1, u2) by the concentric map, (0.5, 0.5) the centre
        a, b = _disc(2.0 * u1 - 1.0, 2.0 * u2 - 1.0, True)
        s2 = a * a + b * b
        rs = np.where(s2 > 0.0, 1.0 / np.sqrt(np.where(s2 > 0.0, s2, 1.0)), 0.0)
        d, esum, ds = emitted(s2, a * rs, b * rs)
        if radius > 0.0:
            ds = np.where(esum > 0.0, ds, dc)
        else:
            ds = dc
        # a spot with a radius averages its cone over disc_points points of the disc where
        # it straddles the cone (C twin): the lattice (1/2 + i / disc_points, frac(i
        # SPOT_DISC_PHI)) shifted by (u1, u2) modulo 1 in polar coordinates on the unit disc
        # (the squared radius and the azimuth over 2 pi), the azimuths one cos and sin
        # turned by LAMP_DISC_TURN
        many = straddles(rec, wc, dc) if (kind == KIND_SPOT and radius > 0.0 and disc_points > 1) \
            else np.zeros(n, bool)
        if many.any():
            m = np.flatnonzero(many)
            c0, s0 = np.cos(2.0 * np.pi * u2), np.sin(2.0 * np.pi * u2)
            ew = np.zeros(n)
            lsum = np.zeros(n)
            dsum = np.zeros((n, 3))
            for i in range(disc_points):
                s2 = np.broadcast_to(u1 + 0.5 + i / disc_points, (n,))
                s2 = np.where(s2 >= 1.0, s2 - 1.0, s2)
                s2 = np.where(s2 >= 1.0, s2 - 1.0, s2)
                ct, st = disc_turn(i)
                di, w, dist = emitted(s2, c0 * ct - s0 * st, s0 * ct + c0 * st)
                if i == 0:
                    d0 = di   # the direction where no point of the lattice lights x
                ew = ew + w
                lsum = lsum + w * dist
                dsum = dsum + w[:, None] * di
            # the irradiance-weighted mean direction and distance, as the phase function and
            # the optical depth see them
            dn = np.sqrt(np.einsum("ij,ij->i", dsum, dsum))
            d = d.copy()
            d[m] = np.where((dn[m] > 0.0)[:, None], dsum[m] / np.where(dn[m] > 0.0, dn[m], 1.0)[:, None], d0[m])
            ds = np.array(ds, np.float64, copy=True)
            ds[m] = np.where(ew[m] > 0.0, lsum[m] / np.where(ew[m] > 0.0, ew[m], 1.0), dc[m])
            esum = np.array(esum, np.float64, copy=True)
            esum[m] = ew[m] / disc_points
        e = s[None, :] / (4.0 * np.pi) * np.asarray(esum)[:, None]
        return d, e, wc, dc, np.asarray(ds, np.float64)
    # AREA
    a, b = _disc(2.0 * u1 - 1.0, 2.0 * u2 - 1.0, rec[L_ROUND] > 0)
    omega = np.full(n, -1.0)
    src = centre + rec[L_AX:L_AX + 3] * a[:, None] + rec[L_AY:L_AY + 3] * b[:, None]
    if not rec[L_ROUND] > 0:
        pdf = 1.0
        if normal is not None:
            u1, u2, pdf = cosine_warp(rec, x, normal, u1, u2)
        omega, rect = rect_solid_angle_sample(rec, x, dc, u1, u2)
        omega = np.where(omega >= 0.0, omega / pdf, -1.0)
        src = np.where((omega >= 0.0)[:, None], rect, src)
    v = x - src
    dist2 = np.maximum(np.einsum("ij,ij->i", v, v), 1e-8)
    d = v / np.sqrt(dist2)[:, None]
    cos_l = np.maximum(d @ rec[L_NORMAL:L_NORMAL + 3], 0.0)
    area = rec[L_AREA]
    radiance = s / np.pi / (area if (rec[L_NORMALIZE] > 0 and area > 0) else 1.0)
    # the radiance times the solid angle per sample: omega (pdf 1 / omega) or cos A / r^2
    w = np.where(omega >= 0.0, np.where(cos_l > 0.0, omega, 0.0), cos_l * area / dist2)
    return d, radiance[None, :] * w[:, None], wc, dc, np.sqrt(dist2)


RECT_FAR = 64.0   # beyond this many diagonals a rectangle light is sampled by area (C twin)
COSINE_FLOOR = 0.01   # the least corner weight of cosine_warp (as pbrt-v4's): no zero density


def cosine_warp(rec, x, normal, u, v):
    """(u', v', density (N,)): ``u``, ``v`` (N,) in [0, 1) warped by the bilinear density whose
    corners are the cosines between ``normal`` (N,3) and the directions from ``x`` (N,3) to
    the rectangle light's corners (at least COSINE_FLOOR), the corners of
    rect_solid_angle_sample's square: u from the light's -x edge to its +x edge, v from -y
    to +y.  rect_solid_angle_sample of (u', v') then draws points in the solid angle with
    density about proportional to the cosine at the surface, the factor that made a
    ground's direct light from a large area light noisy (p_fog_area: 5 % per sample);
    dividing by the density keeps the estimate unbiased.  The bilinear sampling is pbrt-v4's
    (Pharr, Jakob and Humphreys 2023, "SampleBilinear"; Hart et al. 2020, "Practical
    product sampling by fitting and composing warps")."""
    centre = rec[L_POS:L_POS + 3]
    ax, ay = rec[L_AX:L_AX + 3], rec[L_AY:L_AY + 3]
    w = []
    for sx, sy in ((-1, -1), (1, -1), (-1, 1), (1, 1)):
        c = (centre + sx * ax + sy * ay)[None, :] - x
        cn = np.einsum("ij,ij->i", c, normal) / np.maximum(np.linalg.norm(c, axis=1), 1e-30)
        w.append(np.maximum(cn, COSINE_FLOOR))
    w00, w10, w01, w11 = w
    up = _sample_linear(u, w00 + w01, w10 + w11)
    vp = _sample_linear(v, (1.0 - up) * w00 + up * w10, (1.0 - up) * w01 + up * w11)
    bil = ((1.0 - up) * (1.0 - vp) * w00 + up * (1.0 - vp) * w10 + (1.0 - up) * vp * w01
           + up * vp * w11)
    return up, vp, 4.0 * bil / (w00 + w10 + w01 + w11)


def _sample_linear(u, a, b):
    """x in [0, 1) with density proportional to (1 - x) a + x b (a, b > 0), from u in [0, 1)."""
    x = u * (a + b) / (a + np.sqrt((1.0 - u) * a * a + u * b * b))
    return np.minimum(x, 1.0 - 1e-12)


def rect_solid_angle_sample(rec, x, dc, u, v):
    """(solid angle (N,) sr, points (N,3) m): points of the rectangular area light ``rec``
    uniform in the solid angle it subtends at ``x`` (Urena, Fajardo and King 2013, "An
    Area-Preserving Parametrization for Spherical Rectangles"), from ``u``, ``v`` in [0, 1);
    the solid angle is -1 (sample by area instead) where the rectangle is skewed, x lies in
    its plane or behind it, or farther (``dc``) than RECT_FAR diagonals.  The twin of
    csrc/light.h's rect_solid_angle_sample: the same steps in the same order."""
    n = len(x)
    ax, ay = rec[L_AX:L_AX + 3], rec[L_AY:L_AY + 3]
    la, lb = float(np.sqrt(ax @ ax)), float(np.sqrt(ay @ ay))
    out = np.full(n, -1.0), np.zeros((n, 3))
    if not (la > 0.0 and lb > 0.0):
        return out
    ex, ey = ax / la, ay / lb
    if abs(float(ex @ ey)) > 1e-6:
        return out
    ez = np.array([ex[1] * ey[2] - ex[2] * ey[1], ex[2] * ey[0] - ex[0] * ey[2],
                   ex[0] * ey[1] - ex[1] * ey[0]])
    centre = rec[L_POS:L_POS + 3]
    front = (x - centre) @ rec[L_NORMAL:L_NORMAL + 3]
    dd = (centre - ax - ay)[None, :] - x
    x0, y0, z0 = dd @ ex, dd @ ey, dd @ ez
    ok = (dc <= RECT_FAR * 2.0 * np.sqrt(la * la + lb * lb)) & (front > 1e-9 * (la + lb)) \
        & (np.abs(z0) > 1e-9 * (la + lb))
    flip = z0 > 0.0
    z0 = np.where(flip, -z0, z0)
    ezs = np.where(flip[:, None], -ez, ez)
    x1, y1, z2 = x0 + 2.0 * la, y0 + 2.0 * lb, z0 * z0
    n0z, n1z = -y0 / np.sqrt(z2 + y0 * y0), x1 / np.sqrt(z2 + x1 * x1)
    n2z, n3z = y1 / np.sqrt(z2 + y1 * y1), -x0 / np.sqrt(z2 + x0 * x0)
    g0 = np.arccos(np.clip(-n0z * n1z, -1.0, 1.0))
    g1 = np.arccos(np.clip(-n1z * n2z, -1.0, 1.0))
    g2 = np.arccos(np.clip(-n2z * n3z, -1.0, 1.0))
    g3 = np.arccos(np.clip(-n3z * n0z, -1.0, 1.0))
    k = 2.0 * np.pi - g2 - g3
    S = g0 + g1 - k
    ok &= S > 0.0
    au = u * S + k
    sa = np.sin(au)
    fu = (np.cos(au) * n0z - n2z) / np.where(np.abs(sa) > 1e-300, sa, 1e-300)
    cu = np.clip(np.where(fu > 0.0, 1.0, -1.0) / np.sqrt(fu * fu + n0z * n0z), -1.0, 1.0)
    xu = np.clip(-(cu * z0) / np.sqrt(np.maximum(1.0 - cu * cu, 1e-300)), x0, x1)
    dist = np.sqrt(xu * xu + z2)
    h0, h1 = y0 / np.sqrt(dist * dist + y0 * y0), y1 / np.sqrt(dist * dist + y1 * y1)
    hv = h0 + v * (h1 - h0)
    hv2 = hv * hv
    yv = np.where(hv2 < 1.0 - 1e-12, hv * dist / np.sqrt(np.maximum(1.0 - hv2, 1e-300)), y1)
    yv = np.clip(yv, y0, y1)
    pts = x + xu[:, None] * ex + yv[:, None] * ey + z0[:, None] * ezs
    return np.where(ok, S, -1.0), np.where(ok[:, None], pts, 0.0)


def path_stretch(ds, dc, voxel):
    """(N,) factor from the field's optical depth to the light's centre (distance ``dc``, m) to
    that to the emitting point sampled (``ds``): the centre path's mean extinction times the
    point's path length, ds / dc (exact in a homogeneous medium); dc at least half a voxel,
    the path the field's trilinear depth stands for next to the centre (C twin)."""
    return ds / np.maximum(dc, 0.5 * voxel)

DISC_NODES = 8   # Gauss-Legendre points of disc_transmittance over a lamp's disc


def disc_transmittance(light: Light, x, tau, voxel: float, nodes: int = DISC_NODES,
                       depth=None, reach: float = 0.0, change=None, transmit=None):
    """The transmittance (N,3) a lamp's light reaches points ``x`` (N,3, m) with, from the
    optical depth ``tau`` (N,3) to its centre: for a POINT or SPOT light with a radius the
    mean over its soft-falloff disc (light_sample: every disc point carries the same
    irradiance, and its squared radius s^2 is uniform in [0, 1]) of
    exp(-tau path_stretch(d / cos theta, d, voxel)), cos theta = 1 - s^2 (1 - cos theta_max),
    by ``nodes``-point Gauss-Legendre quadrature in s^2 -- what the march's random disc
    points average to; for an AREA light ``area_transmittance``; exp(-tau) for the sun and
    lamps without a radius.  Round a lamp inside a dense medium the
    centre's depth alone made its first scattering too bright (the plume's second order 27 %
    over Cycles' with a 0.3 m lamp).

    ``depth`` (callable (points, unit dirs, lengths) -> (N,3) optical depth through the
    media) and ``reach`` (lamp radii, Tuning.disc_exact): within ``reach`` radii of the lamp
    each node's disc point gets the march's correction (kernels_np.disc_correction: its own
    path's depth minus the stretched centre's, both through ``depth``), at an angle about
    the centre's direction turned by the golden angle from node to node and by a fixed
    pseudo-random offset per point: the stretched depth is exact only where the medium is
    the same across the disc.  ``change`` (N,3) or None: beyond that, the disc's depth
    change (precompute/discdepth.py, the field's disc channels) added to every node's
    stretched depth, as the march adds it.  ``transmit``: area_transmittance's.  For an AREA
    light ``reach`` counts half-diagonals (extent_radius) and ``nodes`` the corrected
    emitter points, about sqrt(nodes) per axis and at least AREA_EXACT_NODES
    (area_transmittance)."""
    tau = np.asarray(tau, np.float64)
    if light.kind == "AREA":
        return area_transmittance(light, x, tau, voxel, transmit=transmit, depth=depth,
                                  reach=reach, change=change,
                                  exact_nodes=max(AREA_EXACT_NODES, int(round(np.sqrt(nodes)))))
    if not has_disc(light):
        return np.exp(-tau)
    radius = float(light.radius)
    x = np.asarray(x, np.float64).reshape(-1, 3)
    centre = np.asarray(light.position, np.float64)
    dc = np.linalg.norm(x - centre, axis=1)
    hyp = np.sqrt(dc * dc + radius * radius)
    omc_max = radius * radius / (hyp * (hyp + dc))
    k, kw = np.polynomial.legendre.leggauss(nodes)
    s2, w = 0.5 * (k + 1.0), 0.5 * kw
    cos_t = 1.0 - s2[None, :] * omc_max[:, None]
    stretch = path_stretch(dc[:, None] / cos_t, dc[:, None], voxel)          # (N,K)
    out = np.einsum("k,nkc->nc", w, np.exp(-tau[:, None, :] * stretch[..., None]))
    if change is not None:
        out *= np.exp(-np.maximum(np.asarray(change, np.float64), -tau))
    near = np.flatnonzero((dc < reach * radius) & (dc > 0.0)) if depth is not None else []
    if len(near):
        xs, dn = x[near], dc[near]
        wc = (centre - xs) / dn[:, None]
        t1, t2 = orthonormal_basis(wc)
        tau_c = depth(xs, wc, dn)
        turn = point_jitter(xs)[:, 0]   # the same point, the same turn, whatever the call
        acc = np.zeros((len(near), 3))
        for j in range(nodes):
            c = cos_t[near, j]
            sn = np.sqrt(np.maximum(0.0, 1.0 - c * c))
            phi = 2.0 * np.pi * ((j * GOLDEN + turn) % 1.0)
            wd = c[:, None] * wc + (sn * np.cos(phi))[:, None] * t1 + (sn * np.sin(phi))[:, None] * t2
            st = stretch[near, j][:, None]
            tj = tau[near] * st + depth(xs, wd, dn / c) - st * tau_c
            acc += w[j] * np.exp(-np.maximum(tj, 0.0))
        out[near] = acc
    return out


GOLDEN = 0.6180339887498949   # the golden ratio's fraction: disc_transmittance's turn per node


def area_geometry(light: Light):
    """World-space centre, local X and Y half-axes (scaled) and the emitter area (m^2)."""
    m = np.asarray(light.matrix, np.float64)
    sx = light.size_x
    sy = light.size_y if light.shape in ("RECTANGLE", "ELLIPSE") else light.size_x
    ax = m[:3, 0] * 0.5 * sx
    ay = m[:3, 1] * 0.5 * sy
    area = 4.0 * np.linalg.norm(ax) * np.linalg.norm(ay)
    if light.shape in ("DISK", "ELLIPSE"):
        area *= np.pi / 4.0
    return m[:3, 3], ax, ay, area


_KINDS = {"POINT": KIND_POINT, "SPOT": KIND_SPOT, "SUN": KIND_SUN, "AREA": KIND_AREA}


def spot_angles(coshalf: float, blend: float):
    """(half angle, inner angle) in radians of a spot whose half angle has cosine ``coshalf``
    and whose blend is ``blend``: the inner angle is where its smoothstep begins, cosine
    coshalf + (1 - coshalf) blend (the half angle itself without a blend)."""
    th_out = float(np.arccos(np.clip(coshalf, -1.0, 1.0)))
    if not blend > 0.0:
        return th_out, th_out
    return th_out, float(np.arccos(min(coshalf + (1.0 - coshalf) * blend, 1.0)))


def pack_light(light: Light, channel: int = -1, beam: int = -1, disc: int = -1) -> np.ndarray:
    """The light as one float64 record of ``LIGHT_FIELDS`` (layout: lightrecord), the form
    the kernels read; ``channel`` is its optical-depth channel in the media fields or -1,
    ``beam`` that of its forward peak's light (precompute.FieldLayout.beam_channels) or -1,
    ``disc`` that of its disc's depth change (FieldLayout.disc_channels) or -1."""
    if light.kind not in _KINDS:
        raise ValueError(f"unsupported light type {light.kind!r}")
    r = np.zeros(LIGHT_FIELDS)
    r[L_KIND] = _KINDS[light.kind]
    r[L_STRENGTH:L_STRENGTH + 3] = np.asarray(light.strength, np.float64).reshape(3)
    d = np.asarray(light.direction, np.float64)
    r[L_DIR:L_DIR + 3] = d / max(np.linalg.norm(d), 1e-30)
    m = np.asarray(light.matrix, np.float64)
    r[L_POS:L_POS + 3] = m[:3, 3] if light.kind == "AREA" else np.asarray(light.position, np.float64)
    try:
        r[L_INV:L_INV + 9] = np.linalg.inv(m[:3, :3]).ravel()
    except np.linalg.LinAlgError:  # a zero-scaled light: its cone is measured unscaled
        r[L_INV:L_INV + 9] = np.eye(3).ravel()
    sv = np.linalg.svd(r[L_INV:L_INV + 9].reshape(3, 3), compute_uv=False)
    r[L_COND] = sv[0] / sv[-1] if sv[-1] > 0.0 and np.isfinite(sv[0] / sv[-1]) else 1e30
    r[L_COSHALF] = np.cos(0.5 * light.spot_size)
    r[L_BLEND] = max(light.spot_blend, 0.0)
    r[L_ANGLES:L_ANGLES + 2] = spot_angles(r[L_COSHALF], r[L_BLEND])
    r[L_RADIUS] = max(light.radius, 0.0)
    if light.kind == "AREA":
        _, ax, ay, area = area_geometry(light)
        r[L_AX:L_AX + 3], r[L_AY:L_AY + 3], r[L_AREA] = ax, ay, area
        nrm = -m[:3, 2]
        r[L_NORMAL:L_NORMAL + 3] = nrm / max(np.linalg.norm(nrm), 1e-30)
        r[L_NORMALIZE] = 1.0 if light.normalize else 0.0
        r[L_ROUND] = 1.0 if light.shape in ("DISK", "ELLIPSE") else 0.0
    r[L_CHANNEL] = channel
    r[L_BEAM] = beam
    r[L_DISC] = disc
    r[L_INDIRECT] = 1.0 if light.indirect else 0.0
    return r


def incident(light: Light, points, u=None, sample=None):
    """(direction (N,3), irradiance RGB (N,3)) of ``light`` at world ``points`` (N,3).

    ``u`` (N,2) in [0,1): jitter for lights with an extent (sphere radius, area emitters).
    ``sample``: light_sample or its compiled twin (kernels.light_sample, which the layers
    above pass in), what a point light or spot is sampled with (a spot with a radius through
    ``spot_incident``); None: light_sample."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if u is None:
        if light.kind == "AREA":
            return area_incident(light, points)
        if light.kind == "SPOT" and (light.radius or 0.0) > 0.0:
            return spot_incident(light, points, sample)
        u = np.full((len(points), 2), 0.5)
    d, e = (sample or light_sample)(pack_light(light), points, u[:, 0], u[:, 1])[:2]
    return d, e


SPOT_SHIFTS = 8        # spot_incident's shifts of the disc lattice per axis near the lamp
SPOT_NEAR = 8.0        # where the disc straddles the cone within this many radii of the lamp
SPOT_SHIFT_ROWS = 1 << 20   # the rows sampled at once


def spot_incident(light: Light, points, sample=None):
    """(direction (N,3), irradiance RGB (N,3)) of a spot with a radius at ``points``, sampled
    by ``sample`` (light_sample or its compiled twin): the disc lattice shifted by each
    point's own jitter (point_jitter), and where the disc straddles the cone's edge or blend
    (``straddles``) within SPOT_NEAR radii of the lamp the mean over SPOT_SHIFTS x
    SPOT_SHIFTS shifts stratified about that jitter (SPOT_SHIFTS^2 SPOT_DISC_POINTS disc
    points), the direction their irradiance-weighted mean.  With one shift a point near the
    lamp, where the disc spans a wide angle across the cone, was off by up to tens of per
    cent, the same for every seed; farther out the disc is narrow and each lattice point of
    the paths sums many voxels (docs/method.md §6, *A spot's disc*)."""
    sample = sample or light_sample
    rec = pack_light(light)
    u = point_jitter(points)
    d, e, wc, dc, _ = sample(rec, points, u[:, 0], u[:, 1])
    vary = np.flatnonzero((dc < SPOT_NEAR * rec[L_RADIUS]) & straddles(rec, wc, dc))
    if len(vary) == 0:
        return d, e
    # the lattice repeats its first coordinate every 1 / SPOT_DISC_POINTS: the shifts
    # stratify that cell along it, and the whole unit along the second
    k = SPOT_SHIFTS * SPOT_SHIFTS
    i, j = np.divmod(np.arange(k), SPOT_SHIFTS)
    grid = np.stack([i / SPOT_DISC_POINTS, j], axis=1) / SPOT_SHIFTS      # (k,2)
    d, e = d.copy(), e.copy()
    per = max(1, SPOT_SHIFT_ROWS // k)
    for a in range(0, len(vary), per):
        idx = vary[a:a + per]
        u0 = u[idx] / SPOT_SHIFTS
        u0[:, 0] /= SPOT_DISC_POINTS
        w = (u0[:, None, :] + grid[None, :, :]).reshape(-1, 2)
        di, ei = sample(rec, np.repeat(points[idx], k, axis=0), w[:, 0], w[:, 1])[:2]
        ei = ei.reshape(len(idx), k, 3)
        dsum = np.einsum("nkc,nk->nc", di.reshape(len(idx), k, 3), ei.sum(axis=2))
        n = np.sqrt(np.einsum("ij,ij->i", dsum, dsum))
        e[idx] = ei.mean(axis=1)
        d[idx] = np.where((n > 0.0)[:, None], dsum / np.where(n > 0.0, n, 1.0)[:, None], d[idx])
    return d, e


AREA_NODES = 6   # Gauss-Legendre points per axis of area_transmittance over an emitter
AREA_EXACT_NODES = 4   # emitter points per axis whose own paths area_depth_change marches,
# at least (disc_transmittance)
# within AREA_NEAR emitter half-diagonals of its centre the weight cos / d^2 peaks where the
# emitter is nearest: AREA_NEAR_NODES per axis there; beyond AREA_MID the weight is smooth
# and the transmittance varies across the emitter as exp(-sigma a s) (sigma the extinction,
# a the half-diagonal, s in [-1, 1]), which AREA_FAR_NODES per axis hold within 0.5 % for
# sigma a up to about 2
AREA_NEAR = 1.5
AREA_NEAR_NODES = 16
AREA_MID = 4.0
AREA_FAR_NODES = 4


def _emitter_nodes(light: Light, nodes: int):
    """(points (K,3) m, weights (K,) summing to 1) of a Gauss-Legendre rule with ``nodes``
    per axis over an AREA light's emitter: the rectangle, or the disc or ellipse in its
    squared radius (equal areas; ``nodes`` points) and angle (twice as many, evenly)."""
    c, ax, ay, _ = area_geometry(light)
    k, kw = np.polynomial.legendre.leggauss(int(nodes))
    if light.shape in ("DISK", "ELLIPSE"):
        r = np.sqrt(0.5 * (k + 1.0))
        m = 2 * int(nodes)                                 # angles: the rim is 2 pi long
        t = 2.0 * np.pi * (np.arange(m) + 0.5) / m
        a_ = (r[:, None] * np.cos(t)[None, :]).reshape(-1)
        b_ = (r[:, None] * np.sin(t)[None, :]).reshape(-1)
        wa = np.repeat(0.5 * kw, m) / m
    else:
        a_, b_ = np.repeat(k, nodes), np.tile(k, nodes)
        wa = np.repeat(kw, nodes) * np.tile(kw, nodes) / 4.0
    return c + a_[:, None] * ax + b_[:, None] * ay, wa


def emitter_transmittance(x, tau, dc, nodes, weights, normal, voxel: float) -> np.ndarray:
    """(N,3) the transmittance an emitter's light reaches points ``x`` (N,3, m) with, from
    their optical depth ``tau`` (N,3) to its centre at distances ``dc`` (N,, m): the mean over
    its quadrature ``nodes`` (K,3, m) with ``weights`` (K,), each weighed by the solid angle
    it subtends from its emitting side (unit ``normal`` (3,)), w_k max(v . n, 0) / d^3 with
    v = x - node and d = |v|, of exp(-tau path_stretch(d, dc, voxel)); exp(-tau) where no
    node faces the point.  The numpy twin of the compiled kernel (csrc/emitter.c,
    kernels.emitter_transmittance)."""
    x = np.asarray(x, np.float64).reshape(-1, 3)
    tau = np.asarray(tau, np.float64).reshape(len(x), 3)
    dc = np.asarray(dc, np.float64).reshape(len(x))
    pts = np.asarray(nodes, np.float64).reshape(-1, 3)
    wa = np.asarray(weights, np.float64).reshape(len(pts))
    normal = np.asarray(normal, np.float64).reshape(3)
    out = np.exp(-tau)
    grey = tau[:, 0] == tau[:, 1]
    grey &= tau[:, 1] == tau[:, 2]
    for a0 in range(0, len(x), 4096):
        idx = np.arange(a0, min(a0 + 4096, len(x)))
        v = x[idx, None, :] - pts[None, :, :]                       # emitter -> point
        d = np.maximum(np.sqrt(np.einsum("nkc,nkc->nk", v, v)), 1e-9)
        w = wa[None, :] * np.maximum(v @ normal, 0.0) / (d * d * d)
        st = path_stretch(d, dc[idx, None], voxel)                   # (n,K)
        num = np.empty((len(idx), 3))
        g = grey[idx]
        if g.any():   # a grey depth takes its transmittance once for the three channels
            num[g] = np.einsum("nk,nk->n", w[g], np.exp(-tau[idx[g], 0, None] * st[g]))[:, None]
        if not g.all():
            c = ~g
            num[c] = np.einsum("nk,nkc->nc", w[c],
                               np.exp(-tau[idx[c], None, :] * st[c][..., None]))
        den = w.sum(axis=1)
        ok = den > 0.0
        out[idx[ok]] = num[ok] / den[ok, None]
    return out


def emitter_normal(light: Light) -> np.ndarray:
    """(3,) the unit normal of an AREA light's emitter plane (its half axes' cross product),
    on its emitting side (the packed record's L_NORMAL)."""
    _, ax, ay, _ = area_geometry(light)
    normal = np.cross(ax, ay)
    normal /= max(float(np.linalg.norm(normal)), 1e-300)
    if np.dot(normal, pack_light(light)[L_NORMAL:L_NORMAL + 3]) < 0.0:
        normal = -normal
    return normal


def area_transmittance(light: Light, x, tau, voxel: float, nodes: int = AREA_NODES,
                       transmit=None, depth=None, reach: float = 0.0, change=None,
                       exact_nodes: int = AREA_EXACT_NODES):
    """The transmittance (N,3) an AREA light's light reaches points ``x`` (N,3, m) with,
    from the optical depth ``tau`` (N,3) to its centre: the mean over its emitter, weighed by
    the solid angle each part subtends (cos theta_l dA / d^2, the front side only), of
    exp(-tau path_stretch(d, d_c, voxel)) -- what the march's emitter points, drawn by
    their solid angle with that stretch (csrc/light.h), average to, by Gauss-Legendre
    points over the emitter (``_emitter_nodes``): ``AREA_NEAR_NODES`` per axis within
    ``AREA_NEAR`` half-diagonals of its centre, ``nodes`` to ``AREA_MID``,
    ``AREA_FAR_NODES`` beyond.  Not 1 far away: in a medium the emitter's near and far
    parts differ in depth by about sigma a wherever the point is.
    The centre's depth alone read the light that reaches a point beside a large emitter
    from its near parts as if it came the longer way from its centre (p_area_in_box's
    multiple scattering 0.967 of Cycles').  ``transmit``: ``emitter_transmittance`` (None)
    or its compiled twin (kernels.emitter_transmittance, which the layers above pass in).

    The stretch is exact only where the medium is the same across the emitter.  ``depth``
    (callable (points, unit dirs, lengths) -> (N,3) optical depth through the media) and
    ``reach`` (half-diagonals, Tuning.disc_exact): within ``reach`` of the centre the
    transmittance is multiplied by exp(-D), D the change ``area_depth_change`` finds on
    ``exact_nodes`` per axis with each node's own path marched through ``depth`` (the
    march marches each sampled point's own path there, kernels_np.disc_correction).
    ``change`` (N,3) or None: beyond, that change as the field's disc channels hold it
    (precompute/discdepth.py), as the march adds it."""
    transmit = transmit or emitter_transmittance
    x = np.asarray(x, np.float64).reshape(-1, 3)
    tau = np.asarray(tau, np.float64).reshape(len(x), -1)
    c, ax, ay, _ = area_geometry(light)
    half = float(np.sqrt(np.dot(ax, ax) + np.dot(ay, ay)))
    normal = emitter_normal(light)
    dc = np.linalg.norm(x - c, axis=1)
    out = np.exp(-tau)
    for n, lo, hi in ((AREA_NEAR_NODES, 0.0, AREA_NEAR), (int(nodes), AREA_NEAR, AREA_MID),
                      (AREA_FAR_NODES, AREA_MID, np.inf)):
        sel = np.flatnonzero((dc >= lo * half) & (dc < hi * half))
        if len(sel):
            pts, wa = _emitter_nodes(light, n)
            out[sel] = transmit(x[sel], tau[sel], dc[sel], pts, wa, normal, voxel)
    d = None if change is None else np.array(change, np.float64).reshape(len(x), 3)
    near = np.flatnonzero((dc < reach * half) & (dc > 0.0)) if depth is not None else []
    if len(near):
        d = np.zeros((len(x), 3)) if d is None else d
        d[near] = area_depth_change(light, x[near], tau[near], voxel, depth, exact_nodes)
    if d is not None:
        out *= np.exp(-np.maximum(d, -tau))
    return out


def area_depth_change(light: Light, x, tau, voxel: float, depth, nodes: int) -> np.ndarray:
    """(N,3) the change D in the optical depth to an AREA light that makes the stretched
    centre's depth ``tau`` (N,3) at points ``x`` (N,3, m) give the emitter's mean
    transmittance: D = log(sum_k w_k exp(-s_k tau)) - log(sum_k w_k exp(-tau_k)) over a
    ``nodes`` x ``nodes`` Gauss-Legendre rule on the emitter, w_k each node's solid angle
    (emitter_transmittance's weights), s_k its path_stretch and tau_k its own path's depth,
    the field's stretched depth plus what ``depth`` (callable (points, unit dirs, lengths)
    -> (N,3)) finds along its path less the stretched centre's, as the march corrects it
    (kernels_np.disc_correction).  0 where no node faces the point."""
    x = np.asarray(x, np.float64).reshape(-1, 3)
    tau = np.asarray(tau, np.float64).reshape(len(x), 3)
    centre = np.asarray(light.position, np.float64)
    normal = emitter_normal(light)
    pts, wa = _emitter_nodes(light, nodes)
    dc = np.linalg.norm(x - centre, axis=1)
    ok = dc > 0.0
    wc = (centre - x) / np.where(ok, dc, 1.0)[:, None]
    tau_c = depth(x, wc, dc)
    num_s = np.zeros((len(x), 3))
    num_e = np.zeros((len(x), 3))
    for p, a in zip(pts, wa):
        v = x - p                                             # emitter -> point
        dn = np.maximum(np.linalg.norm(v, axis=1), 1e-9)
        w = a * np.maximum(v @ normal, 0.0) / (dn * dn * dn)
        st = path_stretch(dn, dc, voxel)[:, None]
        tk = tau * st + depth(x, -v / dn[:, None], dn) - st * tau_c
        num_s += w[:, None] * np.exp(-tau * st)
        num_e += w[:, None] * np.exp(-np.maximum(tk, 0.0))
    good = ok[:, None] & (num_s > 0.0) & (num_e > 0.0)
    return np.where(good, np.log(np.where(good, num_s, 1.0)) - np.log(np.where(good, num_e, 1.0)),
                    0.0)


def point_jitter(points) -> np.ndarray:
    """(N,2) jitter in [0, 1) drawn per point from a hash of its coordinates' bits: the same
    for the same point whatever the call.  A spot with a radius averages its cone over
    SPOT_DISC_POINTS disc points, a lattice the jitter shifts; one fixed shift for every
    point is off in the penumbra, and the paths' source with it.  While the lattice was read
    by the concentric map it counted the penumbra high (fog_beam's flux into the box at 1.6 m
    from its 0.1 m lamp: 2.555 W at u = (0.5, 0.5), 2.310 with a jitter per point, 2.316
    without the radius; fog_beam's multiple scattering 8 % over Cycles'); read in polar
    coordinates, it counts it 8 % low (tests/test_lamp_radius.py)."""
    bits = np.ascontiguousarray(np.asarray(points, np.float64).reshape(-1, 3)).view(np.uint32)
    h = np.full(len(bits), 0x9E3779B9, np.uint32)
    for c in range(bits.shape[1]):
        h = hash32(h ^ bits[:, c])
    u1 = hash32(h ^ np.uint32(0x68E31DA4))
    u2 = hash32(h ^ np.uint32(0xB5297A4D))
    return np.stack([u1, u2], axis=1).astype(np.float64) / 4294967296.0


def irradiance(light: Light, points, sample=None) -> np.ndarray:
    """The irradiance RGB (N,3, W/m^2) of ``incident(light, points, sample=sample)`` without
    its direction (an area light's emitter integral then skips Lambert's vector, half its
    cost)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if light.kind == "AREA":
        return area_incident(light, points, direction=False)[1]
    return incident(light, points, sample=sample)[1]


POLYGON_SIDES = 24  # sides of the polygon that stands for a disc or ellipse emitter
PLANE_EPS = 1e-9    # a point this close to an area light's plane (times its side) lies on it


def emitter_polygon(light: Light) -> np.ndarray:
    """Corners (V,3, world m, in order round the edge) of an AREA light's emitter: the
    rectangle's four, or for a disc or ellipse a ``POLYGON_SIDES``-gon of the same area."""
    c, ax, ay, _ = area_geometry(light)
    if light.shape in ("DISK", "ELLIPSE"):
        n = POLYGON_SIDES
        t = 2.0 * np.pi * np.arange(n) / n
        grow = np.sqrt(2.0 * np.pi / (n * np.sin(2.0 * np.pi / n)))  # polygon area = ellipse's
        return c + grow * (np.cos(t)[:, None] * ax + np.sin(t)[:, None] * ay)
    return c + np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float64) @ np.stack([ax, ay])


def polygon_solid_angle(polygon, points):
    """(r, |r|, Omega): the vectors r (N,V,3) from the ``points`` (N,3) to the convex planar
    ``polygon``'s corners (V,3, in order), their lengths (N,V), and the solid angle Omega
    (N,, sr) the polygon subtends at each point, from either side: Van Oosterom and
    Strackee's formula on the fan of triangles from its first corner."""
    r = np.asarray(polygon, np.float64)[None, :, :] - np.asarray(points, np.float64)[:, None, :]
    ln = np.maximum(np.linalg.norm(r, axis=2), 1e-300)
    omega = np.zeros(len(r))
    a, la = r[:, 0], ln[:, 0]
    for i in range(1, r.shape[1] - 1):
        b, c2, lb, lc = r[:, i], r[:, i + 1], ln[:, i], ln[:, i + 1]
        num = np.abs(np.einsum("ij,ij->i", a, np.cross(b, c2)))
        den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc
               + np.einsum("ij,ij->i", a, c2) * lb + np.einsum("ij,ij->i", b, c2) * la)
        omega += 2.0 * np.arctan2(num, den)
    return r, ln, omega


def area_incident(light: Light, points, direction: bool = True):
    """(direction (N,3), irradiance RGB (N,3)) of an AREA light integrated over its emitter:
    a Lambertian emitter of radiance L (W/(m^2 sr)) brings sum of L cos(theta_l) dA / d^2 =
    L Omega, Omega the solid angle (sr) the emitter subtends at the point (Van Oosterom and
    Strackee's formula on a fan of triangles), on the emitting side only; the direction is
    that of the light's mean propagation, minus Lambert's vector irradiance of the polygon
    (the sum over its edges of the angle each subtends times its unit normal, halved).  Exact
    also next to a large emitter, where one point of it read alone (1 / d^2) is not: a point
    1 mm above a 4 m square reads 2 pi L.  ``direction=False``: None for the direction."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    rec = pack_light(light)
    c = np.asarray(light.matrix, np.float64)[:3, 3]
    normal = rec[L_NORMAL:L_NORMAL + 3]
    area = rec[L_AREA]
    radiance = np.asarray(light.strength, np.float64).reshape(3) / np.pi / \
        (area if (light.normalize and area > 0.0) else 1.0)
    # a point on the emitter's plane itself (to rounding) takes half its front side's light,
    # the mean of the two sides' limits: a quadrature point that falls on the plane counts
    # the step there by halves
    side = (points - c) @ normal
    eps = PLANE_EPS * np.sqrt(max(float(area), 1e-300))
    on = np.abs(side) <= eps
    if np.any(on):
        points = points + np.where(on, eps - side, 0.0)[:, None] * normal[None, :]
    r, ln, omega = polygon_solid_angle(emitter_polygon(light), points)
    front = ((points - c) @ normal > 0.0) | on
    e = (np.where(front, omega, 0.0) * np.where(on, 0.5, 1.0))[:, None] * radiance[None, :]
    if not direction:
        return None, e
    u = r / ln[..., None]
    un = np.roll(u, -1, axis=1)
    cr = np.cross(u, un)
    gamma = np.arccos(np.clip(np.einsum("nvk,nvk->nv", u, un), -1.0, 1.0))
    vec = 0.5 * np.einsum("nv,nvk->nk", gamma / np.maximum(np.linalg.norm(cr, axis=2), 1e-300), cr)
    towards = c - points
    vec *= np.where(np.einsum("ij,ij->i", vec, towards) < 0.0, -1.0, 1.0)[:, None]
    nv = np.linalg.norm(vec, axis=1)
    far = np.linalg.norm(towards, axis=1)
    d = np.where((nv > 1e-12)[:, None], -vec / np.maximum(nv, 1e-300)[:, None],
                 -towards / np.maximum(far, 1e-300)[:, None])
    return d, e


def spot_attenuation(light: Light, from_light):
    """Cone factor (N,) for propagation directions ``from_light`` (N,3) of a SPOT light."""
    pts = np.asarray(light.position, np.float64) + np.asarray(from_light, np.float64)
    unit = Light("SPOT", light.name, np.full(3, 4.0 * np.pi), position=light.position,
                 direction=light.direction, matrix=light.matrix, spot_size=light.spot_size,
                 spot_blend=light.spot_blend)
    _, e = incident(unit, pts)
    dist2 = np.einsum("ij,ij->i", pts - unit.position, pts - unit.position)
    return e[:, 0] * np.maximum(dist2, 1e-8)


def outside_spot(light: Light, points, reach: float) -> np.ndarray:
    """(N,) bool: the ``points`` (N,3, m) round which a ball of radius ``reach`` (m) lies
    wholly outside a SPOT light's cone, with its emitter's radius and the cone measured in
    the light's local frame as ``incident`` does (its irradiance there is 0); all False for
    the other kinds and for points within reach + radius of the light."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if light.kind != "SPOT":
        return np.zeros(len(points), bool)
    rec = pack_light(light)
    v = points - rec[L_POS:L_POS + 3]
    dist = np.sqrt(np.einsum("ij,ij->i", v, v))
    near = dist <= reach + max(float(rec[L_RADIUS]), 0.0)
    safe = np.where(near, 1.0, dist)
    loc = v @ rec[L_INV:L_INV + 9].reshape(3, 3).T
    cos = -loc[:, 2] / np.maximum(np.sqrt(np.einsum("ij,ij->i", loc, loc)), 1e-30)
    theta = np.arccos(np.clip(cos, -1.0, 1.0))
    ball = np.arcsin(np.clip((reach + max(float(rec[L_RADIUS]), 0.0)) / safe, 0.0, 1.0))
    spread = SPOT_GATE_MARGIN * min(float(rec[L_COND]), 1e6) * ball
    return ~near & (theta - spread > np.arccos(np.clip(rec[L_COSHALF], -1.0, 1.0)))


def towards_light(light: Light, points):
    """(unit directions (N,3) from ``points`` to the light's centre, distances (N,) in m;
    inf and the reversed propagation direction for the sun)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if light.kind == "SUN":
        d = -np.asarray(light.direction, np.float64)
        return np.broadcast_to(d / np.linalg.norm(d), points.shape).copy(), np.full(len(points), np.inf)
    pos = np.asarray(light.matrix, np.float64)[:3, 3] if light.kind == "AREA" else \
        np.asarray(light.position, np.float64)
    v = pos - points
    dist = np.linalg.norm(v, axis=1)
    return v / np.maximum(dist, 1e-30)[:, None], dist


def has_disc(light: Light) -> bool:
    """Whether ``light`` shines from a disc facing the lit point: a point or spot light with
    a radius (light_sample, disc_transmittance; media.disc_reaches, precompute/discdepth.py)."""
    return light.kind in ("POINT", "SPOT") and float(getattr(light, "radius", 0.0) or 0.0) > 0.0


def has_extent(light: Light) -> bool:
    """Whether ``light`` shines from points off its centre: a lamp with a disc (has_disc) or
    an area light."""
    return has_disc(light) or (light.kind == "AREA" and extent_radius(light) > 0.0)


def extent_radius(light: Light) -> float:
    """The distance (m) from a lamp's centre to the farthest point it shines from: a point or
    spot light's radius, half an area light's diagonal (half its longer axis for a disc or
    ellipse); 0 for a sun."""
    if light.kind == "AREA":
        sx = float(light.size_x)
        sy = float(light.size_y) if light.shape in ("RECTANGLE", "ELLIPSE") else sx
        if light.shape in ("DISK", "ELLIPSE"):
            return 0.5 * max(sx, sy)
        return 0.5 * float(np.hypot(sx, sy))
    return float(getattr(light, "radius", 0.0) or 0.0) if light.kind in ("POINT", "SPOT") else 0.0


def distance_spread(light: Light, pts) -> np.ndarray:
    """(N,) an upper bound (m) on how far the distances from ``pts`` (N,3) to the points a
    lamp's disc or an area light's emitter shines from differ: sqrt(d^2 + r^2) - d for a
    disc of radius r facing a point at d from its centre (light_sample), the
    farthest corner's distance less the emitter's rectangle's own for an area light (its
    bounding rectangle for a disc or ellipse)."""
    pts = np.asarray(pts, np.float64).reshape(-1, 3)
    if light.kind != "AREA":
        r = extent_radius(light)
        d = np.linalg.norm(pts - np.asarray(light.position, np.float64), axis=1)
        return np.sqrt(d * d + r * r) - d
    c, ax, ay, _ = area_geometry(light)
    rel = pts - c
    far = np.max([np.linalg.norm(rel - sx * ax - sy * ay, axis=1)
                  for sx in (-1.0, 1.0) for sy in (-1.0, 1.0)], axis=0)
    near = rel.copy()
    for a in (ax, ay):   # the nearest point of the rectangle: clamp along each half axis
        la2 = float(np.dot(a, a))
        if la2 > 0.0:
            t = rel @ a / la2
            near -= np.clip(t, -1.0, 1.0)[:, None] * a
    return far - np.linalg.norm(near, axis=1)


def is_dark(light: Light) -> bool:
    """True when the light emits nothing (zero or negative strength)."""
    return not np.any(np.asarray(light.strength, np.float64) > 0.0)
