"""The most-probable-path (MPP) multiple-scattering closed forms: order fractions, beam
moments, spreads, lobes.

The renderer's model of multiple scattering, the walk of the light pyramid's levels, is
``walk.py``; it was derived from these terms, and tests/test_mpp.py holds the two together
(and these terms to a Monte Carlo pencil beam, tests/pencil_beam.py).  No kernel, no bpy.

Pure numpy, no bpy.  The model and every formula here are derived in ``docs/method.md``;
this module only evaluates them, stably, over arrays.  Units: lengths in metres (m),
coefficients in 1/m, angles in radians, solid angle in steradians (sr).

Conventions (the same as :mod:`mpp_render.phase`):

* ``g`` is the Henyey-Greenstein anisotropy, g > 0 forward; cosines are taken between
  *propagation* directions.
* ``s`` is the path length along the (straightened) MPP from the light, in m.  Everything
  that depends on the medium only through optical depths accepts ``s = 1`` together with
  optical depths in place of coefficients (inhomogeneous media: ``tau_s = integral sigma_s``).
* A spatial width ``w`` is the *per-axis* standard deviation of an isotropic 2-D Gaussian
  in the plane perpendicular to the MPP: kernel ``exp(-r^2 / (2 w^2)) / (2 pi w^2)`` (1/m^2),
  so ``E[r^2] = 2 w^2``.
* ``min_order`` selects the photon population by the number N of scattering events it has
  undergone along the path (N is Poisson with mean ``sigma_s * s``): 0 = the whole beam,
  1 = light scattered at least once (what a view-ray marcher needs when it applies the last
  scattering, sigma_s(x) p, itself), 2 = light scattered at least twice.

Sources: Premoze, Ashikhmin, Ramamoorthi, Nayar, EGSR 2004 and the report CUCS-017-04 (the
MPP idea, w(s) ~ <theta^2> s^3 / 24 l); Fermi-Eyges small-angle transport (the s^3/24 law);
the closed forms for the exact second moments of the Henyey-Greenstein random walk, the
HG convolution identity HG(g1) * HG(g2) = HG(g1 g2) and the vMF inverse-Langevin mapping are
derived in docs/method.md.
"""
from __future__ import annotations

import functools
import math

import numpy as np

from .phase import clamp_g

KAPPA_MAX = 1.0e6          # vMF concentration cap: lobe half-width ~ 1/sqrt(KAPPA_MAX) = 1 mrad
G_MAX = 0.999              # |g| cap, as in phase.G_LIMIT
THETA2_LIMIT_COEFF = 8.0 * 0.915965594177219015 - math.pi ** 2 / 2  # lim <theta^2>/(1-g), g->1

_SMALL_X = 0.05            # below this scattering optical depth the finite-order sums are used
_NTERMS_SMALL = 8          # orders summed in that regime (truncation ~ x^8 / 8!)


# ----------------------------------------------------------------------------------------
# stable elementary helpers
# ----------------------------------------------------------------------------------------

def _arr(x):
    return np.asarray(x, dtype=np.float64)


def _phi1(z):
    """(1 - exp(-z)) / z, = 1 at z = 0; any real z (rel. accuracy ~1e-16)."""
    z = _arr(z)
    out = np.ones_like(z)
    nz = z != 0.0
    zz = z[nz]
    out[nz] = -np.expm1(-zz) / zz
    return out


def _divdiff_exp(p, q):
    """(exp(-q) - exp(-p)) / (p - q) for p, q >= 0, without cancellation when p ~ q."""
    m = np.minimum(p, q)
    return np.exp(-m) * _phi1(np.abs(p - q))


def _poisson_tail(x, k):
    """P(N >= k) for N ~ Poisson(x), k in {0, 1, 2}; exact to ~1e-16 relative for all x >= 0."""
    x = _arr(x)
    if k <= 0:
        return np.ones_like(x)
    if k == 1:
        return -np.expm1(-x)
    if k == 2:
        out = np.empty_like(x)
        small = x < 1.0
        xs = x[small]
        term = xs * xs / 2.0
        acc = term.copy()
        for j in range(3, 24):                 # e^-x sum_{j>=2} x^j/j!: positive terms only
            term = term * xs / j
            acc += term
        out[small] = np.exp(-xs) * acc
        xl = x[~small]
        out[~small] = -np.expm1(-xl) - xl * np.exp(-xl)
        return out
    raise ValueError("min_order must be 0, 1 or 2")


def _expm1_minus(y, k):
    """sum_{j>=k} y^j / j! for k in {0, 1, 2} (exp(y), expm1(y), expm1(y) - y), any real y."""
    y = _arr(y)
    if k <= 0:
        return np.exp(y)
    if k == 1:
        return np.expm1(y)
    out = np.empty_like(y)
    small = np.abs(y) < 0.5
    ys = y[small]
    term = ys * ys / 2.0
    acc = term.copy()
    for j in range(3, 24):
        term = term * ys / j
        acc += term
    out[small] = acc
    yl = y[~small]
    out[~small] = np.expm1(yl) - yl
    return out


# ----------------------------------------------------------------------------------------
# 1. the phase function's mean squared angle
# ----------------------------------------------------------------------------------------

_GL_X, _GL_W = np.polynomial.legendre.leggauss(32)


def _hg_theta_moments(g: float):
    """(normalisation, <theta^2>) of HG by composite 32-point Gauss-Legendre in theta on
    panels graded geometrically towards the peak (theta = 0 for g > 0, pi for g < 0)."""
    a = abs(g)
    h = max((1.0 - a) / 4.0, 1e-9)
    edges = [0.0]
    while edges[-1] + h < math.pi:
        edges.append(edges[-1] + h)
        h = min(2.0 * h, 0.25)
    edges.append(math.pi)
    e = np.array(edges)
    if g < 0:                                    # grade towards theta = pi instead
        e = np.sort(math.pi - e)
    lo, hi = e[:-1], e[1:]
    th = 0.5 * (lo + hi)[:, None] + 0.5 * (hi - lo)[:, None] * _GL_X[None, :]
    wq = 0.5 * (hi - lo)[:, None] * _GL_W[None, :]
    d = (1.0 - g) ** 2 + 4.0 * g * np.sin(0.5 * th) ** 2      # 1 + g^2 - 2 g cos, no cancellation
    f = (1.0 - g * g) / (2.0 * d * np.sqrt(d)) * np.sin(th) * wq   # 2 pi p(theta) sin(theta)
    return float(f.sum()), float((f * th * th).sum())


@functools.lru_cache(maxsize=4096)
def _mean_sq_angle_cached(g: float) -> float:
    norm, m2 = _hg_theta_moments(g)
    return m2 / norm


def mean_sq_angle(g):
    """<theta^2> = 2 pi int_0^pi theta^2 p_HG(theta) sin(theta) dtheta, in rad^2.

    The 2-D mean squared deflection angle of one Henyey-Greenstein scattering, for any g in
    (-1, 1) (scalar or array).  Composite Gauss-Legendre quadrature (accurate to ~1e-12),
    cached on g rounded to 1e-9.  Values: pi^2/2 - 2 at g = 0; -> pi^2 as g -> -1;
    (8 G - pi^2/2) (1 - g) ~ 2.393 (1 - g) as g -> 1 (G = Catalan's constant): HG's heavy
    tail makes it 20 % larger than the small-angle 2 (1 - g) = <2 (1 - cos theta)>.
    """
    ga = _arr(g)
    if np.any(np.abs(ga) >= 1.0):
        raise ValueError("mean_sq_angle needs -1 < g < 1")
    flat = ga.ravel()
    out = np.array([_mean_sq_angle_cached(round(float(v), 9)) for v in flat])
    return out.reshape(ga.shape) if ga.ndim else float(out[0])


def transport_rates(g):
    """Per-scattering decorrelation (b1, b2) = (1 - <P1(cos)>, 1 - <P2(cos)>) = (1 - g, 1 - g^2)
    of Henyey-Greenstein (dimensionless).  sigma_s * b1 is the inverse transport mean free
    path (1/m); sigma_s * b2 sets the growth of the transverse direction (E[u_x^2])."""
    g = np.clip(_arr(g), -G_MAX, G_MAX)
    return 1.0 - g, 1.0 - g * g


def small_angle_rates(theta2):
    """(b1, b2) of a narrow phase function with 2-D mean squared angle ``theta2`` (rad^2):
    1 - cos ~ theta^2/2 and 1 - P2(cos) ~ 3 theta^2/2 (Brownian motion on the sphere).
    Clamped to <= 1 (an isotropic scattering decorrelates completely)."""
    t = np.maximum(_arr(theta2), 0.0)
    return np.minimum(0.5 * t, 1.0), np.minimum(1.5 * t, 1.0)


# ----------------------------------------------------------------------------------------
# 2. scattering-order fractions (the weights that keep single and multiple apart)
# ----------------------------------------------------------------------------------------

def order_fractions_tau(tau_s, tau_a):
    """(f0, f1, f2plus): fractions of the power launched along a path that is still travelling
    after optical depths ``tau_s`` (scattering) and ``tau_a`` (absorption), split by the number
    of scattering events N ~ Poisson(tau_s):  f0 = e^-tau_a e^-tau_s (unscattered = light
    transmittance), f1 = e^-tau_a tau_s e^-tau_s, f2plus = e^-tau_a P(N >= 2).
    Dimensionless; f0 + f1 + f2plus = e^-tau_a (no loss at albedo 1)."""
    ts = np.maximum(_arr(tau_s), 0.0)
    surv = np.exp(-np.maximum(_arr(tau_a), 0.0))
    e = np.exp(-ts)
    return surv * e, surv * ts * e, surv * _poisson_tail(ts, 2)


def order_fractions(s, sigma_s, sigma_a):
    """:func:`order_fractions_tau` for a homogeneous path of length ``s`` (m)."""
    s = np.maximum(_arr(s), 0.0)
    return order_fractions_tau(_arr(sigma_s) * s, _arr(sigma_a) * s)


def scattered_fraction(s, sigma_s, sigma_a):
    """e^{-sigma_a s} (1 - e^{-sigma_s s}): fraction of the launched power that arrives at path
    length s (m) having scattered at least once (dimensionless).  This is the weight of the
    incident light that a view-ray marcher scatters once more (sigma_s(x) p) into the eye:
    the result is exactly the radiance of orders >= 2, disjoint from single scattering, which
    uses the unscattered e^{-(sigma_s + sigma_a) s}."""
    s = np.maximum(_arr(s), 0.0)
    return np.exp(-_arr(sigma_a) * s) * _poisson_tail(_arr(sigma_s) * s, 1)


def multiple_fraction(s, sigma_s, sigma_a, min_order: int = 2):
    """e^{-sigma_a s} P(N >= min_order), N ~ Poisson(sigma_s s): the fraction of the launched
    power that, at path length s (m), has scattered at least ``min_order`` times.

    Default 2: e^{-sigma_a s} (1 - e^{-sigma_s s} - sigma_s s e^{-sigma_s s}) -- the
    multiply-scattered part of the beam itself (~ (sigma_s s)^2 / 2 for small s).  Use it when
    the path ends at the eye; with a final scattering applied at the view sample use
    :func:`scattered_fraction` (min_order=1).  Stable for sigma_s -> 0, s -> 0, s -> inf."""
    s = np.maximum(_arr(s), 0.0)
    return np.exp(-_arr(sigma_a) * s) * _poisson_tail(_arr(sigma_s) * s, int(min_order))


def mean_order(s, sigma_s, min_order: int = 0):
    """E[N | N >= min_order], the mean number of scattering events of that population."""
    x = np.maximum(_arr(sigma_s) * _arr(s), 0.0)
    k = int(min_order)
    if k == 0:
        return x
    # E[N 1{N>=k}] = x P(N >= k-1)
    num = x * _poisson_tail(x, k - 1)
    den = _poisson_tail(x, k)
    limit = np.full_like(x, float(k))
    ok = den > 1e-280
    return np.where(ok, num / np.where(ok, den, 1.0), limit)


# ----------------------------------------------------------------------------------------
# 3. spatial spread w(s)
# ----------------------------------------------------------------------------------------

def _fixed_order_moments(n: int, s, g1, g2):
    """Per-axis (E[x^2], E[x u_x], E[u_x^2]) of a photon that scattered exactly n >= 1 times on
    [0, s] (scattering points uniform), given per-scattering <P1> = g1 and <P2> = g2."""
    c = [(1.0 - g2 ** i) / 3.0 for i in range(n + 1)]          # E[u_x^2] after i scatterings
    denom = (n + 1.0) * (n + 2.0)
    exx = 0.0
    for i in range(1, n + 1):
        for j in range(1, n + 1):
            lij = (2.0 if i == j else 1.0) / denom
            exx = exx + lij * g1 ** abs(i - j) * c[min(i, j)]
    exu = 0.0
    for i in range(1, n + 1):
        exu = exu + g1 ** (n - i) * c[i]
    exu = exu / (n + 1.0)
    return exx * s * s, exu * s, c[n] + 0.0 * s


def _beam_moments_all(s, x, b1, b2):
    """Per-axis second moments of the whole beam (all orders, N=0 included) at path s."""
    p = b1 * x
    q = b2 * x
    U = -np.expm1(-q) / 3.0
    ser = np.maximum(p, q) < 0.1
    C = np.empty_like(x)
    V = np.empty_like(x)
    ps, qs, ss = p[ser], q[ser], s[ser]
    # B = sum_{m>=2} (-1)^m/(m+1)! sum_{a+b=m; a,b>=1} q^a p^b  (V = 2 s^2 B / (3 p))
    # C = s/3 sum_{m>=1} (-1)^(m+1)/(m+1)! sum_{a+b=m; a>=1} q^a p^b
    bsum = np.zeros_like(ps)        # B / (p q)
    csum = np.zeros_like(ps)        # C / (s q / 3)
    for m in range(1, 11):
        hom_c = np.zeros_like(ps)   # sum_{a=1..m} q^(a-1) p^(m-a)
        for a in range(1, m + 1):
            hom_c += qs ** (a - 1) * ps ** (m - a)
        csum += (-1.0) ** (m + 1) / math.factorial(m + 1) * hom_c
        if m >= 2:
            hom_b = np.zeros_like(ps)   # sum_{a=1..m-1} q^(a-1) p^(m-a-1)
            for a in range(1, m):
                hom_b += qs ** (a - 1) * ps ** (m - a - 1)
            bsum += (-1.0) ** m / math.factorial(m + 1) * hom_b
    C[ser] = ss * qs / 3.0 * csum
    V[ser] = 2.0 * ss * ss * qs / 3.0 * bsum
    pl, ql, sl = p[~ser], q[~ser], s[~ser]
    D = _divdiff_exp(pl, ql)
    C[~ser] = sl / 3.0 * (_phi1(pl) - D)
    B = 1.0 - _phi1(pl) - _phi1(ql) + D
    V[~ser] = 2.0 * sl * sl / (3.0 * pl) * B
    return V, C, U


def beam_moments(s, sigma_s, b1, b2, min_order: int = 0):
    """Exact per-axis second moments (E[x^2] m^2, E[x u_x] m, E[u_x^2]) of a pencil beam's
    photons at path length s (m), restricted to N >= min_order scatterings and normalised to
    that population.  x: lateral offset along one transverse axis, u_x: that component of the
    unit direction.  b1, b2: :func:`transport_rates` or :func:`small_angle_rates`.
    Exact for any phase function with <P1> = 1 - b1, <P2> = 1 - b2 (no small-angle step)."""
    s, sigma_s, b1, b2 = np.broadcast_arrays(np.maximum(_arr(s), 0.0), _arr(sigma_s),
                                             _arr(b1), _arr(b2))
    shape = s.shape
    s, sigma_s, b1, b2 = (a.ravel().astype(np.float64) for a in (s, sigma_s, b1, b2))
    x = np.maximum(sigma_s * s, 0.0)
    k = int(min_order)
    if k not in (0, 1, 2):
        raise ValueError("min_order must be 0, 1 or 2")
    V = np.zeros_like(x)
    C = np.zeros_like(x)
    U = np.zeros_like(x)
    g1, g2 = 1.0 - b1, 1.0 - b2
    small = x < _SMALL_X
    if np.any(small):
        xs, ss, g1s, g2s = x[small], s[small], g1[small], g2[small]
        # weights P(N=n | N>=k) for n = k..k+7, as x^(n-k) k!/n! normalised
        kk = max(k, 1) if k > 0 else 0
        terms = []
        wsum = np.zeros_like(xs)
        for n in range(kk, kk + _NTERMS_SMALL):
            w = xs ** (n - kk) * (math.factorial(kk) / math.factorial(n))
            wsum += w
            terms.append((n, w))
        Vs = np.zeros_like(xs)
        Cs = np.zeros_like(xs)
        Us = np.zeros_like(xs)
        for n, w in terms:
            if n == 0:
                continue
            exx, exu, euu = _fixed_order_moments(n, ss, g1s, g2s)
            Vs += w * exx
            Cs += w * exu
            Us += w * euu
        V[small], C[small], U[small] = Vs / wsum, Cs / wsum, Us / wsum
    big = ~small
    if np.any(big):
        xb, sb, b1b, b2b = x[big], s[big], b1[big], b2[big]
        Vb, Cb, Ub = _beam_moments_all(sb, xb, b1b, b2b)
        if k == 2:                                  # remove the exactly-once-scattered photons
            p1 = xb * np.exp(-xb)
            exx, exu, euu = _fixed_order_moments(1, sb, 1.0 - b1b, 1.0 - b2b)
            Vb, Cb, Ub = Vb - p1 * exx, Cb - p1 * exu, Ub - p1 * euu
        pk = _poisson_tail(xb, k)
        V[big], C[big], U[big] = Vb / pk, Cb / pk, Ub / pk
    return V.reshape(shape), C.reshape(shape), U.reshape(shape)


def _absorption_narrowing(s, sigma_s, sigma_a, b1):
    """Gaussian small-angle factor f(y) = 3 (1 - tanh(y)/y) / y^2 on w^2 (see method.md),
    y = sqrt(sigma_a a1) min(s, 1/a1) / 2, a1 = sigma_s b1; f(0) = 1, f ~ 1 - 2 y^2 / 5."""
    a1 = np.maximum(_arr(sigma_s) * _arr(b1), 0.0)
    sa = np.maximum(_arr(sigma_a), 0.0)
    s = np.maximum(_arr(s), 0.0)
    # min(s, 1/a1) * sqrt(sa a1) without dividing by a1
    y = 0.5 * np.minimum(s * np.sqrt(sa * a1), np.sqrt(sa / np.where(a1 > 0, a1, 1.0)))
    y = np.where(a1 > 0, y, 0.0)
    y = np.broadcast_to(y, np.broadcast(s, a1, sa).shape).astype(np.float64)
    f = np.ones_like(y)
    lo = (y > 0) & (y < 0.1)
    yl = y[lo] ** 2
    f[lo] = 1.0 - 0.4 * yl + 17.0 / 105.0 * yl * yl - 62.0 / 945.0 * yl ** 3
    hi = y >= 0.1
    yh = y[hi]
    f[hi] = 3.0 * (1.0 - np.tanh(yh) / yh) / (yh * yh)
    return f


def spread_width_sq(s, sigma_s, sigma_a, theta2=None, g=None, min_order: int = 1):
    """w(s)^2 in m^2: per-axis variance of the lateral offset, from the MPP, of the light that
    arrives after path length s (m) travelling in a given direction (conditioned on the final
    direction, as in the paper: Var(x) - Cov(x, u_x)^2 / Var(u_x)).

    * ``g`` given (recommended): exact second moments of the Henyey-Greenstein random walk
      (b1 = 1 - g, b2 = 1 - g^2); ``theta2`` is ignored.  Matches a pencil-beam Monte Carlo to
      its noise for all s (tests/test_mpp.py).
    * ``g`` None: the paper's small-angle law driven by ``theta2`` (rad^2, e.g.
      :func:`mean_sq_angle`) through b1 = theta2/2, b2 = 3 theta2/2; for small s this is
      exactly sigma_s theta2 s^3 / 24 (min_order 0).  With HG's <theta^2> it is ~1.8x the
      Monte-Carlo value at 1-3 mean free paths (heavy tail, see docs/method.md).

    Saturation: both forms grow like s^3 while the beam is collimated and like
    (2/3) s / (sigma_s b1) (transverse diffusion, transport mean free path 1/(sigma_s b1))
    once directions have decorrelated -- no clamp is needed.  ``sigma_a`` narrows the spread
    by the small-angle factor of docs/method.md (absorption favours straighter paths when s is
    the straight length of the MPP), frozen beyond one transport mean free path.
    ``min_order``: population (0 all, 1 scattered >= once (default), 2 >= twice).
    Safe for sigma_s = 0, sigma_a = 0, s = 0 and optical depths of 1e4 and beyond.
    """
    if g is not None:
        b1, b2 = transport_rates(g)
    elif theta2 is not None:
        b1, b2 = small_angle_rates(theta2)
    else:
        raise ValueError("spread_width_sq needs theta2 or g")
    V, C, U = beam_moments(s, sigma_s, b1, b2, min_order)
    safe = U > 0
    w2 = np.where(safe, V - C * C / np.where(safe, U, 1.0), 0.0)
    w2 = np.maximum(w2, 0.0) * _absorption_narrowing(s, sigma_s, sigma_a, b1)
    return w2 if np.ndim(w2) else float(w2)


def spread_width_sq_paper(s, sigma_s, sigma_a, theta2):
    """The dimensionally consistent reading of the slide's formula, for reference only:
    theta2 sigma_s s^3 / (24 (1 + sigma_a sigma_s theta2 s^2 / 12)), in m^2 (unsaturated)."""
    s = _arr(s)
    t = _arr(theta2) * _arr(sigma_s)
    return t * s ** 3 / (24.0 * (1.0 + _arr(sigma_a) * t * s * s / 12.0))


# ----------------------------------------------------------------------------------------
# 4. angular spread
# ----------------------------------------------------------------------------------------

def mean_cosine(s, sigma_s, g, min_order: int = 1, extra_orders: int = 0):
    """Exact mean cosine (between the light's propagation direction and the photon direction)
    of the population N >= min_order at path length s, for Henyey-Greenstein:
    E[g^(N + extra_orders) | N >= min_order] with N ~ Poisson(sigma_s s).
    ``extra_orders`` = 1 includes a last scattering at the view sample.  Dimensionless.
    min_order 0: exp(-sigma_s (1 - g) s); 1: expm1(g x) / expm1(x); 2: (expm1(gx) - gx) /
    (expm1(x) - x), evaluated without overflow for large x."""
    g = np.clip(_arr(g), -G_MAX, G_MAX)
    x = np.maximum(_arr(sigma_s) * _arr(s), 0.0)
    x, g = np.broadcast_arrays(x, g)
    k = int(min_order)
    if k not in (0, 1, 2):
        raise ValueError("min_order must be 0, 1 or 2")
    out = np.empty(x.shape)
    mid = x <= 30.0
    xm, gm = x[mid], g[mid]
    den = _expm1_minus(xm, k)
    num = _expm1_minus(gm * xm, k)
    lim = gm ** k                                   # x -> 0 limit
    okd = den > 0
    out[mid] = np.where(okd, num / np.where(okd, den, 1.0), lim)
    xl, gl = x[~mid], g[~mid]                       # e^-x sums are negligible or tiny here
    # E[g^N 1{N>=k}] / P(N>=k) = (e^{-x(1-g)} - e^{-x} sum_{j<k} (gx)^j/j!) / P(N>=k)
    corr = np.zeros_like(xl)
    for j in range(k):
        corr = corr + np.exp(-xl + j * np.log(xl) - math.lgamma(j + 1)) * gl ** j
    out[~mid] = (np.exp(-xl * (1.0 - gl)) - corr) / _poisson_tail(xl, k)
    out = out * g ** int(extra_orders)
    return out if out.ndim else float(out)


def langevin(kappa):
    """Mean cosine of a vMF lobe, A(kappa) = coth(kappa) - 1/kappa (series near 0)."""
    k = np.abs(_arr(kappa))
    out = np.empty_like(k)
    sm = k < 1e-3
    out[sm] = k[sm] / 3.0 - k[sm] ** 3 / 45.0
    md = (~sm) & (k < 20.0)
    out[md] = 1.0 / np.tanh(k[md]) - 1.0 / k[md]
    lg = k >= 20.0
    out[lg] = 1.0 - 1.0 / k[lg]
    return np.sign(_arr(kappa)) * out


def kappa_from_mean_cosine(mu):
    """vMF concentration kappa >= 0 whose mean cosine is ``mu`` (inverse Langevin): Banerjee
    et al.'s start kappa = mu (3 - mu^2) / (1 - mu^2) and four Newton steps; kappa = 0
    (isotropic) for mu <= 0 (a vMF lobe cannot peak backwards here), <= KAPPA_MAX."""
    mu = np.clip(_arr(mu), 0.0, 1.0 - 1.0 / KAPPA_MAX)
    k = mu * (3.0 - mu * mu) / (1.0 - mu * mu)
    for _ in range(4):
        A = langevin(k)
        sm = k < 1e-3
        dA = np.where(sm, 1.0 / 3.0 - k * k / 15.0,
                      np.where(k < 20.0,
                               1.0 / np.maximum(k, 1e-3) ** 2
                               - 1.0 / np.sinh(np.minimum(np.maximum(k, 1e-3), 20.0)) ** 2,
                               1.0 / np.maximum(k, 1.0) ** 2))
        k = np.maximum(k - (A - mu) / dA, 0.0)
    k = np.where(mu >= 1.0 - 20.0 / KAPPA_MAX, 1.0 / (1.0 - mu), k)   # A = 1 - 1/k exactly
    out = np.clip(k, 0.0, KAPPA_MAX)
    return out if out.ndim else float(out)


def angular_spread(s, sigma_s, theta2=None, g=None, min_order: int = 1, extra_orders: int = 0):
    """vMF concentration kappa (dimensionless, in [0, KAPPA_MAX]) of the angular spread of the
    light after path length s (m).

    * ``g`` given (recommended): kappa matches the exact mean cosine :func:`mean_cosine`.
    * ``g`` None: small-angle spread Theta^2 = theta2 E[N | N >= min_order] (rad^2; for the
      whole beam sigma_s theta2 s), mapped onto the sphere as mean cosine exp(-Theta^2 / 2)
      (Brownian motion on the sphere), i.e. kappa ~ 2 / Theta^2 while Theta^2 << 1 and -> 0
      (isotropic) as Theta^2 grows.
    """
    if g is not None:
        mu = mean_cosine(s, sigma_s, g, min_order, extra_orders)
    elif theta2 is not None:
        n = mean_order(s, sigma_s, min_order) + int(extra_orders)
        mu = np.exp(-0.5 * _arr(theta2) * n)
    else:
        raise ValueError("angular_spread needs theta2 or g")
    return kappa_from_mean_cosine(mu)


def vmf_lobe(cos, kappa):
    """von Mises-Fisher lobe on the sphere, kappa exp(kappa (cos - 1)) / (2 pi (1 - e^-2kappa)),
    in 1/sr; normalised over the sphere for every kappa >= 0; 1/(4 pi) at kappa = 0, finite up
    to kappa = 1e6 and beyond (no exp(kappa) is ever formed)."""
    c = np.clip(_arr(cos), -1.0, 1.0)
    k = np.maximum(_arr(kappa), 0.0)
    k_safe = np.where(k > 1e-12, k, 1.0)
    norm = np.where(k > 1e-12, k_safe / (-np.expm1(-2.0 * k_safe)), 0.5 + 0.5 * k)
    out = norm * np.exp(k * (c - 1.0)) / (2.0 * np.pi)
    return out if out.ndim else float(out)


def _lgamma1p(n):
    """log Gamma(n + 1) for real arrays n >= 0 (Stirling series after an 8-step shift;
    ~1e-13 absolute)."""
    z = _arr(n) + 1.0
    shift = np.zeros_like(z)
    for i in range(8):
        shift += np.log(z + i)
    zz = z + 8.0
    st = ((zz - 0.5) * np.log(zz) - zz + 0.5 * math.log(2.0 * math.pi) + 1.0 / (12.0 * zz)
          - 1.0 / (360.0 * zz ** 3) + 1.0 / (1260.0 * zz ** 5))
    return st - shift


def lobe_hg_mixture(cos, s, sigma_s, g, min_order: int = 1, extra_orders: int = 0,
                    max_terms: int = 32):
    """Exact angular distribution (1/sr) of the population N >= min_order at path length s:
    sum_n P(N = n | N >= min_order) HG(cos; g^(n + extra_orders)), using the identity that
    n successive HG(g) scatterings compose to HG(g^n) (Legendre coefficients multiply).
    ``extra_orders`` = 1 adds the last scattering at the view sample (incident light of
    order >= 1 scattered towards the eye: the lobe of orders >= 2).  Orders are summed
    over a Poisson window [x - 7 sqrt(x) - 4, x + 7 sqrt(x) + 6] (x = sigma_s s): its first
    max_terms/2 orders one by one, the rest with a stride (midpoint rule on the smooth
    Poisson weights; even and odd orders separately when g < 0).  Normalised over the sphere for any g.  This is what the vMF lobe only
    approximates (comparison in docs/method.md).  ``cos`` and ``s`` broadcast."""
    g = float(clamp_g(float(g)))
    c = _arr(cos)
    x = np.maximum(_arr(sigma_s) * _arr(s), 0.0)
    c, x = np.broadcast_arrays(c, x)
    shape = c.shape
    c, x = c.ravel(), x.ravel()
    k = int(min_order)
    e = int(extra_orders)
    if k + e < 1:
        raise ValueError("the unscattered beam (order 0) is a delta, not a lobe: "
                         "min_order + extra_orders must be >= 1")
    sd = np.sqrt(x)
    n_lo = np.maximum(k, np.floor(x - 7.0 * sd - 4.0))
    n_hi = np.maximum(n_lo, np.ceil(x + 7.0 * sd + 6.0))
    # the first orders one by one (the forward peak of HG(g^n) is steep in n there) ...
    n_exact = max(max_terms // 2, 1)
    j = np.arange(n_exact, dtype=np.float64)[None, :]
    n_first = n_lo[:, None] + j
    w_first = np.ones_like(n_first)
    # ... the rest of the window sampled with a stride (midpoint rule on smooth weights)
    rest_lo = n_lo + n_exact
    span = np.maximum(n_hi - rest_lo + 1.0, 0.0)
    m_rest = max(max_terms - n_exact, 2)
    sign_first = np.where(np.mod(n_first + e, 2.0) == 1.0, math.copysign(1.0, g), 1.0)
    if g >= 0.0:
        h = np.maximum(np.ceil(span / m_rest), 1.0)[:, None]
        j = np.arange(m_rest, dtype=np.float64)[None, :]
        n_rest = rest_lo[:, None] + j * h + (h - 1.0) / 2.0        # group centres
        w_rest = np.broadcast_to(h, n_rest.shape)
        sign_rest = np.ones_like(n_rest)
    else:                                   # g^n alternates: keep the parities apart
        half = max(m_rest // 2, 1)
        H = 2.0 * np.maximum(np.ceil(span / (2.0 * half)), 1.0)[:, None]
        j = np.arange(half, dtype=np.float64)[None, :]
        nodes, signs = [], []
        for par in (0.0, 1.0):
            start = rest_lo[:, None] + np.mod(par - rest_lo[:, None], 2.0)
            nodes.append(start + j * H + (H / 2.0 - 1.0))             # centre of H/2 members
            signs.append(np.where(np.mod(start + e, 2.0) == 1.0, -1.0, 1.0) + 0.0 * j)
        n_rest = np.concatenate(nodes, axis=1)
        sign_rest = np.concatenate(signs, axis=1)
        w_rest = np.broadcast_to(H / 2.0, n_rest.shape)
    sign = np.concatenate([sign_first, sign_rest], axis=1)
    n = np.concatenate([n_first, n_rest], axis=1)
    wgt = np.concatenate([w_first, w_rest], axis=1)
    valid = n <= n_hi[:, None]
    n = np.where(valid, n, n_lo[:, None])
    xs = np.maximum(x, 1e-300)[:, None]
    logw = n * np.log(xs) - _lgamma1p(n) + np.log(wgt)
    logw = np.where(valid, logw, -np.inf)
    logw -= logw.max(axis=1, keepdims=True)
    w = np.exp(logw)
    w /= w.sum(axis=1, keepdims=True)
    m = n + e
    if g == 0.0:
        gn = np.where(m == 0, 1.0, 0.0)
    else:
        gn = sign * np.exp(m * math.log(abs(g)))
    d = np.maximum(1.0 + gn * gn - 2.0 * gn * c[:, None], 1e-12)
    lobes = (1.0 - gn * gn) / (4.0 * np.pi * d * np.sqrt(d))
    out = (w * lobes).sum(axis=1).reshape(shape)
    return out if out.ndim else float(out)
