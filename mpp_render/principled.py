"""Cycles' Principled BSDF on opaque surfaces (no bpy; the surfaces' shading, surfaces.py).

f is Cycles' Principled BSDF (Blender 4.x/5.0, ``intern/cycles/kernel/svm/closure.h``), built
top-down as Cycles layers its closures, each layer taking the weight w it leaves below:

* coat (``coat_weight`` > 0): GGX (alpha = coat_roughness^2) with the exact dielectric
  Fresnel of ``coat_ior``, energy-compensated; below it w *= 1 - coat_weight x its albedo, and
  the coat tint absorbs along the refracted view path, tint^(1 / cos theta_t).  The emission
  is seen through the coat.
* metal (``metallic`` > 0): GGX with the F82-tint conductor Fresnel (F0 = base colour, edge
  tint = specular tint; Kutz et al., "Novel aspects of the Adobe Standard Material"), weight
  metallic x w; below it w *= 1 - metallic.
* dielectric specular (``specular`` = F0 > 0): GGX (alpha = roughness^2) whose Fresnel is the
  exact dielectric curve of the IOR with that F0, remapped from F0..1 to F0 x tint..1; below
  it w *= 1 - max over RGB of its albedo estimate (Cycles' ``closure_layering_weight``).
* diffuse: base colour x w, Lambert, or Oren-Nayar (Fujii's improved model with the OpenPBR
  energy-preserving multiple-scattering term) when ``diffuse_roughness`` > 0.

GGX lobes use the height-correlated Smith term.  With 'Multiscatter GGX' each GGX lobe is
scaled by 1 + F_ms (1 - E) / E (Kulla & Conty, "Revisiting Physically Based Shading at
Imageworks": E the lobe's directional albedo at the view angle, E_avg its cosine-weighted
mean, F_ms = F_ss E_avg / (1 - F_ss (1 - E_avg)), F_ss the hemispherical mean Fresnel).  The
albedos that drive the layering come from tables laid out as Cycles' ``ggx_E``,
``ggx_Eavg`` and ``ggx_gen_schlick_ior_s`` (``intern/cycles/app/cycles_precompute.cpp``:
32 x 32 / 32 and 16 x 16 x 16 grids over roughness, view cosine and sqrt of the IOR's F0,
read with linear interpolation), but computed here by deterministic quadrature over the
distribution of visible normals instead of Monte Carlo (``_vndf_nodes``).  The layering
depends on the view direction, so like Cycles' the BSDF is not reciprocal; the single GGX
lobes are.  Glossy lobes with alpha^2 <= 2e-10 are mirrors: they reflect the sky (through
their albedo) but no light, as Cycles gives delta lobes no light sampling.
"""
from __future__ import annotations

import threading
from typing import Dict

import numpy as np

WEIGHT_CUTOFF = 1e-5        # Cycles' CLOSURE_WEIGHT_CUTOFF: lighter closures are left out
SINGULAR_ALPHA2 = 2e-10     # Cycles' BSDF_ROUGHNESS_SQ_THRESH: alpha^2 at or below is a mirror


# -- the Principled BSDF --------------------------------------------------------------------

def _ms_factor(fss, e, e_avg):
    """Kulla-Conty energy compensation 1 + F_ms (1 - E) / E of a GGX lobe with directional
    albedo ``e`` (N,) and mean albedo ``e_avg`` (N,) whose mean Fresnel is ``fss``
    ((N,) or (N,3))."""
    e = np.maximum(e, 1e-6)
    if np.ndim(fss) == 2:
        e, e_avg = e[:, None], e_avg[:, None]
    fms = fss * e_avg / (1.0 - fss * (1.0 - e_avg))
    return 1.0 + fms * (1.0 - e) / e


class Principled:
    """Cycles' Principled BSDF at N surface points, set up for one view direction each.

    ``prm``: per-point shading inputs (``SurfaceSet.params`` rows); ``n`` (N,3): unit normals
    on the viewer's side; ``wv`` (N,3): unit directions towards the viewer.  The setup does
    what Cycles does once per shading point: the lobe weights, the layering of the lower
    layers under the albedo of the upper ones, and the energy compensation, all of which
    depend on the view direction only.  ``eval`` then gives f cos(theta_l) (1/sr, RGB) for
    light directions, ``albedo`` the directional albedo (RGB) that reflects a uniform sky, and
    ``emission`` the emitted radiance seen through the coat (W/(m^2 sr))."""

    def __init__(self, prm: Dict[str, np.ndarray], n, wv):
        self.n = np.asarray(n, np.float64)
        self.wv = np.asarray(wv, np.float64)
        cv = np.clip(np.einsum("ij,ij->i", self.n, self.wv), 1e-7, 1.0)
        self.cv = cv
        npts = len(cv)
        ms = prm["multiscatter"] > 0.5
        w = np.repeat(prm["weight"][:, None], 3, axis=1)
        w0 = w.copy()
        zero3 = np.zeros((npts, 3))

        # coat: dielectric Fresnel, always energy-compensated (Cycles' dielectric setup)
        cw = prm["coat_weight"]
        cior = prm["coat_ior"]
        self.coat_alpha = np.square(prm["coat_roughness"])
        self.coat_ior = cior
        self.coat = (cw > WEIGHT_CUTOFF) & (cior > 1.0 + 1e-6)
        self.coat_w, self.coat_alb = zero3, zero3
        if self.coat.any():
            rc = prm["coat_roughness"]
            e, e_avg = ggx_albedo(rc, cv), ggx_avg_albedo(rc)
            k = _ms_factor(fresnel_dielectric_avg(cior), e, e_avg)
            est = f0_from_ior(cior) + (1.0 - f0_from_ior(cior)) * fresnel_s(rc, cv, cior)
            on = self.coat[:, None]
            self.coat_w = np.where(on, (cw * k)[:, None] * w, 0.0)
            self.coat_alb = self.coat_w * (e * est)[:, None]
            w = np.where(on, w * np.clip(1.0 - cw * k * e * est, 0.0, 1.0)[:, None], w)
            tint = prm["coat_tint"]
            tinted = on & np.any(tint != 1.0, axis=1, keepdims=True)
            if tinted.any():
                cos_t = np.sqrt(np.maximum(1.0 - (1.0 - cv * cv) / (cior * cior), 1e-12))
                with np.errstate(divide="ignore"):
                    through = np.where(tint > 0, tint ** (1.0 / cos_t)[:, None], 0.0)
                w = np.where(tinted, w * (1.0 + cw[:, None] * (through - 1.0)), w)
        with np.errstate(divide="ignore", invalid="ignore"):
            self.emission = prm["emission"] * np.where(w0 > 0, w / w0, 1.0)

        rough = prm["roughness"]
        e = ggx_albedo(rough, cv)
        e_avg = ggx_avg_albedo(rough)
        self.alpha = rough * rough

        # metal: F82-tint conductor Fresnel
        m = prm["metallic"]
        self.metal = m > WEIGHT_CUTOFF
        self.metal_w, self.metal_alb = zero3, zero3
        if self.metal.any():
            self.f0m = np.clip(prm["base_color"], 0.0, 1.0)
            self.b82 = f82_tint_b(self.f0m, np.minimum(prm["specular_tint"], 1.0))
            k = np.where(ms[:, None],
                         _ms_factor(fresnel_f82_avg(self.f0m, self.b82), e, e_avg), 1.0)
            on = self.metal[:, None]
            self.metal_w = np.where(on, m[:, None] * w * k, 0.0)
            a5, b6 = schlick_s(rough, cv)
            self.metal_alb = self.metal_w * np.clip(
                self.f0m * e[:, None] + (1.0 - self.f0m) * a5[:, None] - self.b82 * b6[:, None],
                0.0, None)
            w = np.where(on, w * (1.0 - m)[:, None], w)

        # dielectric specular: the IOR's exact Fresnel remapped to F0 x tint .. 1
        f0 = prm["specular"]
        self.spec = f0 > 1e-12
        self.spec_w, self.spec_alb = zero3, zero3
        if self.spec.any():
            self.eta = ior_from_f0(f0)
            self.f0r = f0_from_ior(self.eta)
            self.f0t = np.clip(f0[:, None] * prm["specular_tint"], 0.0, 1.0)
            s_avg = np.clip((fresnel_dielectric_avg(self.eta) - self.f0r) / (1.0 - self.f0r),
                            0.0, 1.0)
            fss = self.f0t + (1.0 - self.f0t) * s_avg[:, None]
            k = np.where(ms[:, None], _ms_factor(fss, e, e_avg), 1.0)
            est = self.f0t + (1.0 - self.f0t) * fresnel_s(rough, cv, self.eta)[:, None]
            on = self.spec[:, None]
            self.spec_w = np.where(on, w * k, 0.0)
            # the layering divides Cycles' albedo estimate by the closure weight: E k est
            # with Multiscatter GGX (its weight carries E k), est alone with plain GGX
            ratio = np.where(ms[:, None], e[:, None] * k, 1.0) * est
            ratio = np.where(w > 0, ratio, 0.0)
            self.spec_alb = self.spec_w * e[:, None] * est
            w = np.where(on, w * np.clip(1.0 - ratio.max(axis=1), 0.0, 1.0)[:, None], w)

        # diffuse: Lambert, or Oren-Nayar where Diffuse Roughness > 0
        self.diff_w = w * prm["base_color"]
        sigma = prm["diffuse_roughness"]
        self.on = sigma >= WEIGHT_CUTOFF
        self.on_a = np.where(self.on, 1.0 / (np.pi + sigma * (np.pi / 2 - 2.0 / 3.0)), 1 / np.pi)
        self.on_b = np.where(self.on, sigma * self.on_a, 0.0)
        self.on_ms = zero3
        diff_alb = np.ones(npts)
        if self.on.any():
            e_avg_on = self.on_a * np.pi + self.on_b * OREN_NAYAR_G_AVG
            rho = np.clip(prm["base_color"], 0.0, 1.0)
            ea = np.minimum(e_avg_on, 1.0 - 1e-9)[:, None]
            ems = rho * rho * (ea / (1.0 - ea)) / (np.pi * (1.0 - rho * (1.0 - ea)))
            ev = self.on_a * np.pi + self.on_b * oren_nayar_g(cv)
            self.on_ms = np.where(self.on[:, None], ems * (1.0 - ev)[:, None], 0.0)
            diff_alb = np.where(self.on, ev, 1.0)
            self.diff_alb_ms = self.on_ms * (np.pi * (1.0 - e_avg_on))[:, None]
        else:
            self.diff_alb_ms = zero3
        self.diff_alb = self.diff_w * (diff_alb[:, None] + self.diff_alb_ms)

    def albedo(self, idx=slice(None)):
        """Directional albedo (RGB) at the view direction: the fraction of a uniform sky's
        radiance the surface reflects (from the albedo tables, the dielectric layers as Cycles
        estimates them)."""
        return (self.coat_alb + self.metal_alb + self.spec_alb + self.diff_alb)[idx]

    def eval(self, wl, idx=None):
        """f(w_v, w_l) cos(theta_l) (1/sr, RGB (K,3)) for unit directions ``wl`` (K,3) towards
        the lights, at the points ``idx`` (default: all, K = N)."""
        if idx is None:
            idx = np.arange(len(self.cv))
        n, wv, cv = self.n[idx], self.wv[idx], self.cv[idx]
        wl = np.asarray(wl, np.float64)
        cl = np.einsum("ij,ij->i", n, wl)
        up = cl > 0
        cl = np.clip(cl, 1e-7, 1.0)
        h = wl + wv
        h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-300)
        ch = np.einsum("ij,ij->i", n, h)
        cvh = np.clip(np.einsum("ij,ij->i", wv, h), 0.0, 1.0)

        # diffuse
        a, b = self.on_a[idx], self.on_b[idx]
        t = np.einsum("ij,ij->i", wl, wv) - cl * cv
        t = np.where(t > 0, t / np.maximum(np.maximum(cl, cv), 1e-300), t)
        el = a * np.pi + b * oren_nayar_g(cl)
        f = self.diff_w[idx] * (cl * (a + b * t))[:, None]
        f += self.diff_w[idx] * self.on_ms[idx] * (cl * (1.0 - el))[:, None]

        if self.coat.any():
            sel = self.coat[idx]
            if sel.any():
                lobe = ggx_reflection(self.coat_alpha[idx], cv, cl, ch)
                fr = fresnel_dielectric(cvh, self.coat_ior[idx])
                f += self.coat_w[idx] * (lobe * fr)[:, None]
        alpha = self.alpha[idx]
        if self.metal.any() or self.spec.any():
            lobe = ggx_reflection(alpha, cv, cl, ch)
            if self.metal.any():
                f += self.metal_w[idx] * lobe[:, None] * fresnel_f82(
                    cvh[:, None], self.f0m[idx], self.b82[idx])
            if self.spec.any():
                eta, f0r = self.eta[idx], self.f0r[idx]
                s = np.clip((fresnel_dielectric(cvh, eta) - f0r) / (1.0 - f0r), 0.0, 1.0)
                f0t = self.f0t[idx]
                f += self.spec_w[idx] * lobe[:, None] * (f0t + (1.0 - f0t) * s[:, None])
        return np.where(up[:, None], f, 0.0)


# -- Fresnel --------------------------------------------------------------------------------

def f0_from_ior(eta):
    """Reflectance at normal incidence ((eta - 1) / (eta + 1))^2 of a dielectric interface."""
    eta = np.asarray(eta, np.float64)
    return ((eta - 1.0) / (eta + 1.0)) ** 2


def ior_from_f0(f0):
    """The relative IOR (>= 1) whose normal-incidence reflectance is ``f0``, clamped to 0.99
    as Cycles does (an IOR of 399 at most)."""
    r = np.sqrt(np.clip(np.asarray(f0, np.float64), 0.0, 0.99))
    return (1.0 + r) / (1.0 - r)


def fresnel_dielectric(cos_i, eta):
    """Unpolarised Fresnel reflectance of light arriving at cosine ``cos_i`` (>= 0) on an
    interface of relative IOR ``eta`` (1 for total internal reflection)."""
    c = np.abs(np.asarray(cos_i, np.float64))
    eta = np.asarray(eta, np.float64)
    g2 = eta * eta - 1.0 + c * c
    g = np.sqrt(np.maximum(g2, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (g - c) / (g + c)
        b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
        f = 0.5 * a * a * (1.0 + b * b)
    return np.where(g2 > 0.0, np.nan_to_num(f, nan=1.0), 1.0)


def fresnel_dielectric_avg(eta):
    """Hemispherical mean 2 int_0^1 F(mu, eta) mu dmu of the dielectric Fresnel for eta >= 1,
    by Kulla & Conty's rational fit (the one Cycles uses, ``fresnel_dielectric_Fss``)."""
    eta = np.asarray(eta, np.float64)
    return (eta - 1.0) / (4.08567 + 1.00071 * eta)


_F82_MU = 1.0 / 7.0     # the F82 model pins the Fresnel curve at cos = 1/7 (about 82 deg)


def f82_tint_b(f0, tint):
    """The F82-tint model's b so that F(1/7) = tint x Schlick(1/7): b = Schlick(1/7) (1 -
    tint) / (mu (1 - mu)^6) at mu = 1/7 (Kutz et al.); 0 for a white tint."""
    mu = _F82_MU
    schlick = f0 + (1.0 - f0) * (1.0 - mu) ** 5
    return schlick * (1.0 - tint) / (mu * (1.0 - mu) ** 6)


def fresnel_f82(cos_i, f0, b):
    """F82-tint conductor Fresnel: Schlick(f0) - b cos (1 - cos)^6, clamped to [0, 1]."""
    s = np.clip(1.0 - cos_i, 0.0, 1.0)
    return np.clip(f0 + (1.0 - f0) * s ** 5 - b * cos_i * s ** 6, 0.0, 1.0)


def fresnel_f82_avg(f0, b):
    """Hemispherical mean of :func:`fresnel_f82` (unclamped): 2 int mu F dmu =
    f0 + (1 - f0) / 21 - b / 126."""
    return f0 + (1.0 - f0) / 21.0 - b / 126.0


# -- GGX ------------------------------------------------------------------------------------

def ggx_lambda(alpha2, cos):
    """Smith's Lambda of GGX for a direction at cosine ``cos`` to the normal."""
    c2 = np.clip(np.asarray(cos, np.float64), 1e-7, 1.0) ** 2
    return 0.5 * (np.sqrt(1.0 + alpha2 * (1.0 / c2 - 1.0)) - 1.0)


def ggx_ndf(alpha2, cos_h):
    """GGX normal distribution D (1/sr) of microfacet normals at cosine ``cos_h``."""
    c2 = np.minimum(np.square(cos_h), 1.0)
    return alpha2 / (np.pi * np.square(1.0 - c2 + alpha2 * c2))


def ggx_reflection(alpha, cos_v, cos_l, cos_h):
    """Single-scattering GGX reflection without Fresnel, times cos(theta_l):
    D G2 / (4 cos_v), with the height-correlated G2 = 1 / (1 + Lambda_v + Lambda_l).  Zero for
    mirror-like alpha (alpha^2 <= SINGULAR_ALPHA2) and for directions below the surface."""
    a2 = np.square(alpha)
    g2 = 1.0 / (1.0 + ggx_lambda(a2, cos_v) + ggx_lambda(a2, cos_l))
    with np.errstate(divide="ignore", invalid="ignore"):   # alpha = 0: masked below
        f = ggx_ndf(a2, cos_h) * g2 / (4.0 * np.maximum(cos_v, 1e-7))
    return np.where((a2 > SINGULAR_ALPHA2) & (cos_l > 0) & (cos_h > 0), f, 0.0)


# -- Oren-Nayar -----------------------------------------------------------------------------

def oren_nayar_g(cos):
    """int t(l, v) cos(theta_v) dw_v of Fujii's improved Oren-Nayar model (t = l.v -
    cos_l cos_v, divided by max(cos_l, cos_v) where positive) as a function of cos_l, so that
    its directional albedo is a pi + b G; integrated in closed form, checked by quadrature in
    the tests."""
    c = np.clip(np.asarray(cos, np.float64), 0.0, 1.0)
    s = np.sqrt(1.0 - c * c)
    th = np.arccos(c)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = s * (th - 2.0 / 3.0 - s * c) + 2.0 / 3.0 * (s / c) * (1.0 - s ** 3)
    return np.where(c < 1e-6, np.pi / 2 - 2.0 / 3.0 - c, g)


def _oren_nayar_g_avg() -> float:
    """2 int_0^1 G(mu) mu dmu (Gauss-Legendre)."""
    x, w = np.polynomial.legendre.leggauss(64)
    mu = 0.5 * (x + 1.0)
    return float(np.sum(w * 0.5 * 2.0 * mu * oren_nayar_g(mu)))


OREN_NAYAR_G_AVG = _oren_nayar_g_avg()


# -- albedo tables --------------------------------------------------------------------------

QUAD_N = 256    # quadrature nodes per axis over the visible normals; with 256^2 per table
                # entry the tables agree with Cycles' own to about 1e-4


def _vndf_nodes(rough: float, mu, n: int = QUAD_N):
    """Quadrature nodes over the GGX distribution of visible normals seen from directions at
    cosines ``mu`` (K,): returns ``w`` (K,P), the node weights with the visible-normal density
    included and zero where the reflected direction falls below the surface (as Cycles'
    tables count such samples as 0), ``c`` (K,P) the cosine between that direction and the
    normal h, and ``g`` (K,P) the height-correlated shadowing of the reflection over the
    masking of the view, G2 / G1 = (1 + L_v) / (1 + L_v + L_o).

    The integral of a function q(h) against the visible normals is sum(w q).  Normals are
    parameterised by their slope: the GGX slope radius r has CDF r^2 / (alpha^2 + r^2) = t,
    with t = 1 - (1 - u)^2 (which removes the 1 / sqrt(1 - t) edge of grazing views) and u, and
    the azimuth (over half a turn by symmetry), on midpoint grids.  Exact for alpha -> 0."""
    alpha = max(float(rough), 1e-4) ** 2
    a2 = alpha * alpha
    mu = np.clip(np.atleast_1d(np.asarray(mu, np.float64)), 1e-4, 1.0)[:, None, None]
    u = (np.arange(n) + 0.5) / n
    t = 1.0 - (1.0 - u) ** 2
    wt = 2.0 * (1.0 - u) / (n * n)
    phi = (np.arange(n) + 0.5) / n * np.pi
    r = alpha * np.sqrt(t / (1.0 - t))
    hz = 1.0 / np.sqrt(1.0 + r * r)                         # (n,)
    hx = -r[:, None] * np.cos(phi)[None, :] * hz[:, None]  # (n, n)
    sv = np.sqrt(1.0 - mu * mu)
    c = sv * hx[None] + mu * hz[None, :, None]             # cos(view, h)
    lam_v = ggx_lambda(a2, mu)
    dens = np.maximum(c, 0.0) / ((1.0 + lam_v) * mu * hz[None, :, None])
    wo_z = 2.0 * c * hz[None, :, None] - mu
    w = np.where(wo_z > 0.0, wt[None, :, None] * dens, 0.0)
    g = (1.0 + lam_v) / (1.0 + lam_v + ggx_lambda(a2, wo_z))
    k = len(mu)
    return w.reshape(k, -1), np.clip(c, 0.0, 1.0).reshape(k, -1), g.reshape(k, -1)


class _Table:
    """A lookup table laid out as one of Cycles' (value axes, then the view cosine), filled
    one column (all view cosines at fixed other coordinates) at a time on first use and kept
    for the process; ``fill(key)`` returns the column (n_mu,) for an index tuple ``key``."""

    def __init__(self, shape, fill):
        self.data = np.full(shape, np.nan)
        self.fill = fill
        self.lock = threading.Lock()

    def ensure(self, keys):
        for key in {tuple(int(i) for i in k) for k in keys}:
            if np.isnan(self.data[key][0]):
                col = self.fill(key)
                with self.lock:
                    self.data[key] = col


def _grid(v, size):
    """Cycles' lookup_table_read axis: (lower index, upper index, fraction) of ``v`` in [0, 1]
    on ``size`` points."""
    x = np.clip(np.asarray(v, np.float64), 0.0, 1.0) * (size - 1)
    i0 = np.minimum(np.floor(x).astype(np.int64), size - 1)
    return i0, np.minimum(i0 + 1, size - 1), x - i0


def _axis_value(i, size, hi=1.0):
    """The coordinate of grid point ``i`` (Cycles clamps it to [1e-4, hi])."""
    return min(max(i / (size - 1), 1e-4), hi)


E_SIZE, S_SIZE = 32, 16


def _vndf_mean(rough: float, mu, q):
    """sum(w q(c, g)) of :func:`_vndf_nodes` for each view cosine in ``mu``, a few at a time
    to bound the memory."""
    mu = np.atleast_1d(np.asarray(mu, np.float64))
    out = []
    for k in range(0, len(mu), 4):
        w, c, g = _vndf_nodes(rough, mu[k:k + 4])
        out.append(np.sum(w * q(c, g), axis=1))
    return np.clip(np.concatenate(out), 0.0, 1.0)


def _mu_axis(size):
    return [_axis_value(j, size) for j in range(size)]


def _e_column(key):
    return _vndf_mean(_axis_value(key[0], E_SIZE), _mu_axis(E_SIZE), lambda c, g: g)


def _e_avg(key):
    x, wq = np.polynomial.legendre.leggauss(24)
    mu = 0.5 * (x + 1.0)
    e = _vndf_mean(_axis_value(key[0], E_SIZE), mu, lambda c, g: g)
    return np.array([np.clip(np.sum(wq * mu * e), 0.0, 1.0)])


def _s_column(key):
    iz, ix = key
    eta = float(ior_from_f0(_axis_value(iz, S_SIZE, 0.99) ** 4))
    f0 = float(f0_from_ior(eta))
    return _vndf_mean(_axis_value(ix, S_SIZE), _mu_axis(S_SIZE),
                      lambda c, g: np.clip((fresnel_dielectric(c, eta) - f0) / (1.0 - f0), 0, 1))


def _schlick_column(key):
    ix, which = key
    return _vndf_mean(_axis_value(ix, S_SIZE), _mu_axis(S_SIZE),
                      (lambda c, g: g * (1.0 - c) ** 5) if which == 0 else
                      (lambda c, g: g * c * (1.0 - c) ** 6))


_E = _Table((E_SIZE, E_SIZE), _e_column)               # [rough, mu]
_E_AVG = _Table((E_SIZE, 1), _e_avg)                   # [rough, -]
_S = _Table((S_SIZE, S_SIZE, S_SIZE), _s_column)       # [z, rough, mu]
_SCHLICK = _Table((S_SIZE, 2, S_SIZE), _schlick_column)  # [rough, (s5, b6), mu]


def ggx_albedo(rough, mu):
    """Directional albedo E of the single-scattering GGX lobe without Fresnel (Cycles'
    ``ggx_E``: 32 x 32 over roughness and view cosine, bilinear)."""
    x0, x1, tx = _grid(rough, E_SIZE)
    y0, y1, ty = _grid(mu, E_SIZE)
    _E.ensure([(i,) for i in np.unique(np.concatenate([x0, x1]))])
    d = _E.data
    lo = d[x0, y0] + ty * (d[x0, y1] - d[x0, y0])
    hi = d[x1, y0] + ty * (d[x1, y1] - d[x1, y0])
    return lo + tx * (hi - lo)


def ggx_avg_albedo(rough):
    """Cosine-weighted mean E_avg = 2 int E(mu) mu dmu of :func:`ggx_albedo` (Cycles'
    ``ggx_Eavg``: 32 roughness values, linear)."""
    x0, x1, tx = _grid(rough, E_SIZE)
    _E_AVG.ensure([(i,) for i in np.unique(np.concatenate([x0, x1]))])
    d = _E_AVG.data[:, 0]
    return d[x0] + tx * (d[x1] - d[x0])


def fresnel_s(rough, mu, eta):
    """Mean over the visible normals seen at view cosine ``mu`` of the remapped dielectric
    Fresnel s = (F(cos, eta) - F0) / (1 - F0), reflections below the surface counting 0, so
    that F0' + (1 - F0') s estimates the Fresnel-weighted albedo over E of a lobe whose Fresnel
    runs from F0' to 1 (Cycles' ``ggx_gen_schlick_ior_s``: 16^3 over roughness, view cosine
    and z = sqrt((eta - 1) / (eta + 1)), trilinear)."""
    eta = np.asarray(eta, np.float64)
    z = np.sqrt(np.abs((eta - 1.0) / (eta + 1.0)))
    x0, x1, tx = _grid(rough, S_SIZE)
    y0, y1, ty = _grid(mu, S_SIZE)
    z0, z1, tz = _grid(z, S_SIZE)
    _S.ensure({(zz, xx) for zz in np.unique(np.concatenate([z0, z1]))
               for xx in np.unique(np.concatenate([x0, x1]))})
    d = _S.data

    def bilinear(zi):
        lo = d[zi, x0, y0] + ty * (d[zi, x0, y1] - d[zi, x0, y0])
        hi = d[zi, x1, y0] + ty * (d[zi, x1, y1] - d[zi, x1, y0])
        return lo + tx * (hi - lo)

    a = bilinear(z0)
    return a + tz * (bilinear(z1) - a)


def schlick_s(rough, mu):
    """(a5, b6): the single-scattering GGX albedo at view cosine ``mu`` weighted by (1 - c)^5
    and by c (1 - c)^6, c the cosine between the view and the microfacet normal (16 x 16 over
    roughness and view cosine, bilinear), so that f0 E + (1 - f0) a5 - b b6 is the albedo of
    a GGX lobe with the F82-tint Fresnel (before its clamp to [0, 1])."""
    x0, x1, tx = _grid(rough, S_SIZE)
    y0, y1, ty = _grid(mu, S_SIZE)
    _SCHLICK.ensure([(i, k) for i in np.unique(np.concatenate([x0, x1])) for k in (0, 1)])
    out = []
    for k in (0, 1):
        d = _SCHLICK.data[:, k, :]
        lo = d[x0, y0] + ty * (d[x0, y1] - d[x0, y0])
        hi = d[x1, y0] + ty * (d[x1, y1] - d[x1, y0])
        out.append(lo + tx * (hi - lo))
    return out[0], out[1]
