"""Tests of the MPP model's per-sample terms (mpp_render.mpp) against closed forms, limits and
a pencil-beam Monte Carlo.  See docs/method.md for the derivations."""
import math

import numpy as np
import pytest

from mpp_render import mpp
from mpp_render.phase import hg

from pencil_beam import mc_width_sq, pencil_beam_mc

CATALAN = 0.915965594177219015

# mpp-math.md section 2 (400k-point trapezoid)
THETA2_TABLE = {-0.9: 8.18, -0.5: 5.16, 0.0: 2.93, 0.3: 1.91, 0.5: 1.31, 0.7: 0.756,
                0.8: 0.495, 0.85: 0.368, 0.9: 0.243, 0.95: 0.121, 0.99: 0.024}

MC_GS = (0.8, 0.9, 0.95)
MC_S = (1.0, 3.0, 10.0)          # mean free paths (sigma_s = 1/m)
MC_PHOTONS = 200_000
W_TOL = 0.04                     # measured worst |MC/exact - 1| over 6 seeds: 1.2 %


@pytest.fixture(scope="module")
def beams():
    """One pencil beam per g, recorded at 1, 3 and 10 mean free paths (fixed seeds)."""
    return {g: pencil_beam_mc(g, 1.0, 0.0, MC_S, MC_PHOTONS, np.random.default_rng(17 + i))
            for i, g in enumerate(MC_GS)}


def sphere_integral(f, backward=False):
    """Integral of f(cos) over the sphere (sr), panels graded towards cos = 1 and cos = -1 so
    that lobes as narrow as kappa = 1e6 or HG(+-0.999) are resolved."""
    x, w = np.polynomial.legendre.leggauss(40)
    e = np.concatenate([[0.0], np.geomspace(1e-10, 1.0, 70)])
    lo, hi = e[:-1], e[1:]
    u = 0.5 * (lo + hi)[:, None] + 0.5 * (hi - lo)[:, None] * x      # u = 1 - cos in [0, 1]
    wq = 0.5 * (hi - lo)[:, None] * w
    total = (f(1.0 - u) * wq).sum() + (f(-1.0 + u) * wq).sum()       # both hemispheres
    return 2.0 * math.pi * total


# --------------------------------------------------------------------------- <theta^2>

def test_mean_sq_angle_reproduces_table():
    for g, ref in THETA2_TABLE.items():
        val = mpp.mean_sq_angle(g)
        assert float(f"{val:.3g}") == pytest.approx(ref, rel=1e-9, abs=1e-12), (g, val, ref)


def test_mean_sq_angle_limits_and_vectorisation():
    assert mpp.mean_sq_angle(0.0) == pytest.approx(math.pi ** 2 / 2 - 2, rel=1e-12)
    assert mpp.mean_sq_angle(-0.99999) == pytest.approx(math.pi ** 2, rel=1e-3)
    # g -> 1: <theta^2> / (1 - g) -> 8 G - pi^2/2 = 2.3929 (20 % above the small-angle 2)
    lim = 8 * CATALAN - math.pi ** 2 / 2
    assert mpp.THETA2_LIMIT_COEFF == pytest.approx(lim, rel=1e-15)
    for g, tol in ((0.999, 2e-3), (0.9999, 3e-4), (0.99999, 3e-5)):
        assert mpp.mean_sq_angle(g) / (1 - g) == pytest.approx(lim, rel=tol)
    # the "2 (1 - g)" of the small-angle argument is <2 (1 - cos)>, exact for HG:
    mu = np.linspace(-1, 1, 400001)
    for g in (0.5, 0.9):
        assert 2 * math.pi * np.trapz(2 * (1 - mu) * hg(mu, g), mu) == pytest.approx(2 * (1 - g), rel=1e-4)
    # quadrature normalisation, arrays, monotonicity
    for g in (-0.999, -0.5, 0.0, 0.7, 0.999, 0.99999):
        norm, _ = mpp._hg_theta_moments(g)
        assert norm == pytest.approx(1.0, abs=1e-9)
    gs = np.linspace(-0.99, 0.99, 41)
    vals = mpp.mean_sq_angle(gs)
    assert vals.shape == gs.shape and np.all(np.diff(vals) < 0)
    with pytest.raises(ValueError):
        mpp.mean_sq_angle(1.0)


# --------------------------------------------------------------------------- lobes

@pytest.mark.parametrize("kappa", [0.0, 1e-8, 1.0, 100.0, 1e6])
def test_vmf_lobe_normalised_and_finite(kappa):
    assert sphere_integral(lambda c: mpp.vmf_lobe(c, kappa)) == pytest.approx(1.0, abs=1e-6)
    vals = mpp.vmf_lobe(np.array([-1.0, 0.0, 1.0]), kappa)
    assert np.all(np.isfinite(vals)) and np.all(vals >= 0)
    peak = kappa / (-math.expm1(-2 * kappa)) / (2 * math.pi) if kappa > 0 else 1 / (4 * math.pi)
    assert vals[2] == pytest.approx(peak, rel=1e-9)


def test_kappa_inverts_langevin_and_is_clamped():
    mu = np.array([0.0, 1e-9, 1e-4, 0.1, 0.5, 0.9, 0.999, 1 - 1e-5])
    k = mpp.kappa_from_mean_cosine(mu)
    assert np.allclose(mpp.langevin(k), mu, rtol=1e-10, atol=1e-14)
    assert mpp.kappa_from_mean_cosine(-0.3) == 0.0
    assert mpp.kappa_from_mean_cosine(1.0) == pytest.approx(mpp.KAPPA_MAX, rel=1e-9)
    # small-angle reading: kappa ~ 2 / Theta^2 for the whole beam
    th2, s = 0.01, 1.0
    assert mpp.angular_spread(s, 1.0, th2, min_order=0) == pytest.approx(2 / (th2 * s), rel=0.01)


@pytest.mark.parametrize("g", [0.999, 0.9, 0.3, 0.0, -0.5, -0.95])
def test_hg_mixture_lobe_normalised(g):
    for s in (0.0, 0.01, 1.0, 10.0, 1e3):
        for mo, ex in ((1, 0), (1, 1), (2, 0), (0, 1)):
            val = sphere_integral(lambda c: mpp.lobe_hg_mixture(c, s, 1.0, g, mo, ex))
            assert val == pytest.approx(1.0, abs=2e-5), (g, s, mo, ex, val)
    # a single order is HG itself, two orders compose to HG(g^2)
    c = np.linspace(-1, 1, 9)
    assert np.allclose(mpp.lobe_hg_mixture(c, 0.0, 1.0, g, 1, 0), hg(c, g), rtol=1e-9)
    assert np.allclose(mpp.lobe_hg_mixture(c, 0.0, 1.0, g, 1, 1), hg(c, g * g), rtol=1e-9)
    with pytest.raises(ValueError):
        mpp.lobe_hg_mixture(c, 1.0, 1.0, g, 0, 0)


# --------------------------------------------------------------------------- Monte Carlo

@pytest.mark.parametrize("g", MC_GS)
def test_spread_width_matches_pencil_beam_mc(beams, g):
    """w(s)^2 (conditioned on the final direction, per axis) against the Monte Carlo at 1, 3
    and 10 mean free paths, for the whole beam and for orders >= 1 and >= 2."""
    r = beams[g]
    for k, s in enumerate(r["s"]):
        for mo in (0, 1, 2):
            mc = mc_width_sq(r["position"][k], r["direction"][k], r["order"][k] >= mo)
            ex = mpp.spread_width_sq(s, 1.0, 0.0, g=g, min_order=mo)
            assert mc == pytest.approx(ex, rel=W_TOL), (g, s, mo, mc, ex)
        # the paper's small-angle width with HG's <theta^2> is far off (heavy tail): >= 1.5x
        paper = mpp.spread_width_sq_paper(s, 1.0, 0.0, mpp.mean_sq_angle(g))
        assert paper / mpp.spread_width_sq(s, 1.0, 0.0, g=g, min_order=0) > 1.5


@pytest.mark.parametrize("g", MC_GS)
def test_angular_spread_matches_pencil_beam_mc(beams, g):
    r = beams[g]
    edges = np.array([1.0, 0.999, 0.99, 0.95, 0.8, 0.5, 0.0, -1.0])
    for k, s in enumerate(r["s"]):
        for mo in (1, 2):
            sel = r["order"][k] >= mo
            cz = r["direction"][k][sel, 2]
            assert cz.mean() == pytest.approx(mpp.mean_cosine(s, 1.0, g, mo), abs=5e-3)
            # the exact HG-order mixture reproduces the histogram (per sr) bin by bin
            counts = np.array([((cz <= edges[i]) & (cz > edges[i + 1])).sum()
                               for i in range(len(edges) - 1)])
            for i in range(len(edges) - 1):
                cc = np.linspace(edges[i + 1], edges[i], 801)
                p = np.trapz(mpp.lobe_hg_mixture(cc, s, 1.0, g, mo), cc) * 2 * math.pi
                expect = p * sel.sum()
                assert abs(counts[i] - expect) < 5 * math.sqrt(expect) + 0.02 * expect, \
                    (g, s, mo, i, counts[i], expect)
        # whole beam: exp(-sigma_s (1 - g) s)
        assert r["direction"][k][:, 2].mean() == pytest.approx(math.exp(-(1 - g) * s), abs=5e-3)


def test_mc_without_scattering_is_a_straight_line():
    r = pencil_beam_mc(0.9, 0.0, 0.5, [0.0, 2.0], 100, np.random.default_rng(0))
    assert np.allclose(r["position"][1], [0.0, 0.0, 2.0])
    assert np.all(r["order"] == 0)
    assert np.allclose(r["weight"], np.exp(-0.5 * np.array([0.0, 2.0])))


# --------------------------------------------------------------------------- w(s) closed forms

def test_moment_closed_forms_equal_order_by_order_sums():
    """Two independent derivations: the closed forms (Markov direction process) and the sum
    over scattering orders of fixed-order moments (uniform scattering points)."""
    for g in (0.95, 0.3, 0.0, -0.7):
        b1, b2 = mpp.transport_rates(g)
        unit = {n: np.array([float(v) for v in mpp._fixed_order_moments(
            n, np.array(1.0), np.array(1 - b1), np.array(1 - b2))]) for n in range(1, 50)}
        for x in (0.0499, 0.0501, 0.4, 3.0, 15.0):
            scale = np.array([x * x, x, 1.0])            # E[x^2] ~ s^2, E[x u] ~ s
            for mo in (0, 1, 2):
                V, C, U = mpp.beam_moments(x, 1.0, b1, b2, mo)
                acc = np.zeros(3)
                tot = 0.0
                for n in range(mo, 50):
                    pn = math.exp(-x + n * math.log(x) - math.lgamma(n + 1))
                    tot += pn
                    if n:
                        acc += pn * unit[n] * scale
                assert np.allclose([V, C, U], acc / tot, rtol=1e-10), (g, x, mo)


def test_spread_width_small_s_saturation_and_absorption():
    th2 = 0.05
    # theta2 path reduces to the paper's Fermi-Eyges law sigma_s theta2 s^3 / 24 for small s
    for s in (1e-4, 1e-3, 1e-2):
        assert mpp.spread_width_sq(s, 2.0, 0.0, th2, min_order=0) == pytest.approx(
            float(mpp.spread_width_sq_paper(s, 2.0, 0.0, th2)), rel=1e-2)
    # exact HG: w^2 -> sigma_s (1 - g^2) s^3 / 36 (all), (1 - g^2) s^2 / 36 (orders >= 1)
    g = 0.9
    assert mpp.spread_width_sq(1e-4, 1.0, 0.0, g=g, min_order=0) == pytest.approx(
        (1 - g * g) * 1e-12 / 36, rel=1e-3)
    assert mpp.spread_width_sq(1e-4, 1.0, 0.0, g=g, min_order=1) == pytest.approx(
        (1 - g * g) * 1e-8 / 36, rel=1e-3)
    # saturation: transverse diffusion (2/3) s / (sigma_s (1 - g)) for s >> transport mfp
    for g in (-0.5, 0.0, 0.9, 0.999):
        s = 1e7
        assert mpp.spread_width_sq(s, 1.0, 0.0, g=g) == pytest.approx(2 / 3 * s / (1 - g), rel=1e-3)
    # monotone in s, with or without absorption; absorption only narrows
    s = np.geomspace(1e-6, 1e5, 2000)
    for g in (-0.95, 0.0, 0.9, 0.999):
        for sa in (0.0, 0.1, 10.0, 1e4):
            for mo in (0, 1, 2):
                w = mpp.spread_width_sq(s, 1.0, sa, g=g, min_order=mo)
                assert np.all(np.diff(w) >= -1e-12 * w[1:]), (g, sa, mo)
                assert np.all(w <= mpp.spread_width_sq(s, 1.0, 0.0, g=g, min_order=mo) * (1 + 1e-12))
    # first-order absorption term of the Gaussian small-angle theory: 1 / (1 + sa ss th2 s^2 / 20)
    ss, sa, s = 1.0, 0.02, 1.0
    ratio = mpp.spread_width_sq(s, ss, sa, th2) / mpp.spread_width_sq(s, ss, 0.0, th2)
    assert ratio == pytest.approx(1 - sa * ss * th2 * s * s / 20, abs=1e-6)


# --------------------------------------------------------------------------- weights

def test_order_fractions_limits():
    s = np.array([0.0, 1e-8, 1e-3, 0.5, 2.0, 50.0, 1e4])
    # sigma_s = 0: nothing scatters
    assert np.all(mpp.multiple_fraction(s, 0.0, 0.3) == 0.0)
    assert np.all(mpp.scattered_fraction(s, 0.0, 0.3) == 0.0)
    # small optical depth: (sigma_s s)^2 / 2 and sigma_s s
    for x in (1e-12, 1e-8, 1e-4):
        assert mpp.multiple_fraction(x, 1.0, 0.0) == pytest.approx(x * x / 2, rel=1e-3)
        assert mpp.scattered_fraction(x, 1.0, 0.0) == pytest.approx(x, rel=1e-3)
    # closed form away from 0
    for x in (0.3, 1.0, 5.0):
        assert mpp.multiple_fraction(x, 1.0, 0.0) == pytest.approx(
            1 - math.exp(-x) - x * math.exp(-x), rel=1e-12)
    for ss, sa in ((0.5, 0.0), (1.0, 0.2), (3.0, 7.0), (1e-9, 1.0)):
        f0, f1, f2 = mpp.order_fractions(s, ss, sa)
        scat = mpp.scattered_fraction(s, ss, sa)
        assert np.all(f1 + f2 <= scat * (1 + 1e-12) + 1e-300)
        assert np.allclose(f1 + f2, scat, rtol=1e-12, atol=1e-300)
        assert np.allclose(f2, mpp.multiple_fraction(s, ss, sa), rtol=1e-12, atol=0)
        assert np.allclose(f0 + f1 + f2, np.exp(-sa * s), rtol=1e-12)
        assert np.allclose(f0, np.exp(-(ss + sa) * s), rtol=1e-12)      # = light transmittance
    # albedo 1: no energy lost at any depth
    assert np.allclose(sum(mpp.order_fractions(s, 2.0, 0.0)), 1.0, rtol=1e-14)
    # population means
    assert mpp.mean_order(1e-9, 1.0, 2) == pytest.approx(2.0)
    assert mpp.mean_order(4.0, 1.0, 0) == pytest.approx(4.0)
    assert mpp.mean_order(4.0, 1.0, 1) == pytest.approx(4 / (1 - math.exp(-4)))


def test_scale_invariance():
    """Doubling all coefficients and halving all lengths changes nothing dimensionless."""
    s = np.array([0.01, 0.7, 3.0, 40.0])
    for g in (-0.5, 0.0, 0.9):
        th2 = mpp.mean_sq_angle(g)
        a = (s, 1.3, 0.4)
        b = (s / 2, 2.6, 0.8)
        for f in (mpp.multiple_fraction, mpp.scattered_fraction):
            assert np.allclose(f(*a), f(*b), rtol=1e-13)
        for mo in (0, 1, 2):
            assert np.allclose(mpp.spread_width_sq(*a, g=g, min_order=mo) / s ** 2,
                               mpp.spread_width_sq(*b, g=g, min_order=mo) / (s / 2) ** 2, rtol=1e-12)
            assert np.allclose(mpp.spread_width_sq(*a, th2, min_order=mo) / s ** 2,
                               mpp.spread_width_sq(*b, th2, min_order=mo) / (s / 2) ** 2, rtol=1e-12)
            assert np.allclose(mpp.angular_spread(s, 1.3, g=g, min_order=mo),
                               mpp.angular_spread(s / 2, 2.6, g=g, min_order=mo), rtol=1e-12)
            assert np.allclose(mpp.angular_spread(s, 1.3, th2, min_order=mo),
                               mpp.angular_spread(s / 2, 2.6, th2, min_order=mo), rtol=1e-12)
        c = np.linspace(-1, 1, 7)[:, None]
        assert np.allclose(mpp.lobe_hg_mixture(c, s, 1.3, g), mpp.lobe_hg_mixture(c, s / 2, 2.6, g),
                           rtol=1e-12)


def test_stiff_cases_finite():
    s = np.array([0.0, 1e-9, 1.0, 1e4])[:, None, None]
    ss = np.array([0.0, 1e-300, 1e-8, 1.0, 1e4])[None, :, None]
    sa = np.array([0.0, 1.0, 1e4])[None, None, :]
    for g in (-0.95, 0.0, 0.999):
        th2 = mpp.mean_sq_angle(g)
        for mo in (0, 1, 2):
            for w in (mpp.spread_width_sq(s, ss, sa, g=g, min_order=mo),
                      mpp.spread_width_sq(s, ss, sa, th2, min_order=mo)):
                assert np.all(np.isfinite(w)) and np.all(w >= 0)
            for k in (mpp.angular_spread(s, ss, g=g, min_order=mo) + 0 * sa,
                      mpp.angular_spread(s, ss, th2, min_order=mo) + 0 * sa):
                assert np.all(np.isfinite(k)) and np.all((k >= 0) & (k <= mpp.KAPPA_MAX))
                lobe = mpp.vmf_lobe(np.array([-1.0, 1.0])[:, None, None, None], k)
                assert np.all(np.isfinite(lobe)) and np.all(lobe >= 0)
            mu = mpp.mean_cosine(s, ss, g, mo)
            assert np.all(np.isfinite(mu)) and np.all(np.abs(mu) <= 1)
        lobe = mpp.lobe_hg_mixture(np.array([-1.0, 0.0, 1.0])[:, None], np.array([0, 1e-9, 1.0, 1e4]),
                                   1e4, g)
        assert np.all(np.isfinite(lobe)) and np.all(lobe >= 0)
        for f in mpp.order_fractions(s, ss, sa) + (mpp.scattered_fraction(s, ss, sa),
                                                   mpp.multiple_fraction(s, ss, sa)):
            assert np.all(np.isfinite(f)) and np.all((f >= 0) & (f <= 1))
    # isotropic and backward media: the lobe of the multiply scattered light is (near) isotropic
    assert mpp.angular_spread(5.0, 1.0, g=0.0) == 0.0
    assert mpp.angular_spread(5.0, 1.0, g=-0.95, min_order=1) == 0.0
