"""The forward peak of a forward-scattering medium (docs/method.md, "The forward peak"): the
delta-Eddington split, the beam of unscattered and forward-scattered light the precompute
sweeps through the delta-scaled media, and the light of that beam the march adds to the
multiply scattered light."""
import numpy as np
import pytest

from mpp_render import kernels, kernels_np
from mpp_render.media import delta_scaled, prepare
from mpp_render.phase import delta_fraction, delta_g, hg
from mpp_render.precompute import precompute
from mpp_render.march import pack_lights
from mpp_render.scene import Camera, Light, Medium, World


def test_the_split_keeps_the_transport_coefficient():
    for g in (0.05, 0.3, 0.6, 0.85, 0.99):
        f, gs = delta_fraction(g), delta_g(g)
        assert f == pytest.approx(g * g) and gs == pytest.approx(g / (1 + g))
        assert gs == pytest.approx((g - f) / (1 - f))
        assert (1 - f) * (1 - gs) == pytest.approx(1 - g, rel=1e-12)
    for g in (0.0, -0.4):   # nothing forward to split
        assert delta_fraction(g) == 0.0 and delta_g(g) == g


def cube(g, n=20):
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.1
    i2w[:3, 3] = -0.95
    return prepare(Medium("cube", np.ones((n, n, n), np.float32), i2w, np.full(3, 2.0),
                          np.array([0.2, 0.3, 0.4]), g))


def test_delta_scaled_medium():
    pm = cube(0.7)
    d = delta_scaled(pm)
    np.testing.assert_allclose(d.sigma_s, pm.sigma_s * (1 - 0.49))
    np.testing.assert_allclose(d.sigma_t, d.sigma_s + pm.sigma_a)
    assert d.g == pytest.approx(0.7 / 1.7) and d.grid is pm.grid
    iso = cube(0.0)
    assert delta_scaled(iso) is iso and delta_scaled(cube(-0.3)).g == pytest.approx(-0.3)


SUN = Light("SUN", "sun", np.full(3, 2.0), direction=np.array([0.0, 0.0, -1.0]))
CAM = Camera("PERSP", np.eye(4), 4, 4, (-1, 1, -1, 1))


def test_the_beam_is_swept_through_the_delta_scaled_medium():
    """Multiple scattering on and a forward peak: each lit light gets a beam channel whose
    optical depth is the light's through sigma_t* = sigma_t - g^2 sigma_s; none with multiple
    scattering off or without a forward peak (g <= 0)."""
    pm = cube(0.7)
    pre = precompute([pm], [SUN], World(), CAM, multiple=True)
    c, b = pre.layout.light_channels[0], pre.layout.beam_channels[0]
    f = pre.fields[0][2:-2, 2:-2, 2:-2]   # away from the sides' half-voxel ramps
    tau, beam = f[..., c:c + 3].astype(np.float64), f[..., b:b + 3].astype(np.float64)
    deep = tau[..., 0] > 0.5
    ratio = beam[deep] / tau[deep] / (delta_scaled(pm).sigma_t / pm.sigma_t)[None, :]
    assert deep.sum() > 1000 and np.abs(ratio - 1.0).max() < 1e-4
    assert precompute([pm], [SUN], World(), CAM, multiple=False).layout.beam_channels is None
    assert precompute([cube(0.0)], [SUN], World(), CAM, multiple=True).layout.beam_channels is None
    assert precompute([cube(-0.5)], [SUN], World(), CAM, multiple=True).layout.beam_channels is None


@pytest.mark.parametrize("backend", ["numpy", "c"])
def test_the_forward_peak_light_scattered_towards_the_camera(backend):
    """A horizontal ray through a cube lit from straight above, with the pyramid left out:
    the march's multiply scattered light is the beam's light beyond the unscattered light,
    scattered by the medium's own HG at 90 degrees and attenuated along the ray:
    sigma_s HG(0; g) E (e^-tau* - e^-tau) (1 - e^(-sigma_t L)) / sigma_t, with tau and tau* read
    from the fields at the ray's depth (constant along it)."""
    if backend == "c" and kernels._c is None:
        pytest.skip("compiled kernels not built")
    march = kernels_np.march if backend == "numpy" else kernels.c_march
    g = 0.7
    pm = cube(g)
    pre = precompute([pm], [SUN], World(), CAM, multiple=True)
    c, b = pre.layout.light_channels[0], pre.layout.beam_channels[0]
    z, L = 0.35, 1.6
    x_mid = np.array([0.0, 0.05, z])   # on a lattice of voxel centres in y and z
    idx = (x_mid @ pm.w2i[:, :3].T + pm.w2i[:, 3])
    i, j, k = np.round(idx).astype(int)
    tau = pre.fields[0][i, j, k, c:c + 3].astype(np.float64)
    tau_b = pre.fields[0][i, j, k, b:b + 3].astype(np.float64)
    n = 64
    o = np.tile([-3.0, 0.05, z], (n, 1))
    d = np.tile([1.0, 0.0, 0.0], (n, 1))
    t0, t1 = np.full(n, 2.2), np.full(n, 2.2 + L)
    table = np.zeros((1, len(kernels_np.RHO_TABLE), 6))
    out = march(o, d, t0, t1, np.ones(n), np.arange(n, dtype=np.uint32), pre.fields, [pm.w2i],
                [pm.sigma_s], [pm.sigma_t], [pm.g], [pm.threshold], [pm.voxel_size],
                pack_lights([SUN], pre.layout), -1, 0.02, 0.01, 1e10, (-1, [[None]], [table]))
    single, multi = out[0], out[3]
    st = pm.sigma_t
    along = (1 - np.exp(-st * L)) / st
    want_ms = pm.sigma_s * hg(0.0, g) * 2.0 * (np.exp(-tau_b) - np.exp(-tau)) * along
    want_ss = pm.sigma_s * hg(0.0, g) * 2.0 * np.exp(-tau) * along
    print("tau", tau, "beam", tau_b, "multiple", multi.mean(0), "want", want_ms)
    assert np.all(tau_b < 0.7 * tau)
    np.testing.assert_allclose(multi.mean(0), want_ms, rtol=0.01)
    np.testing.assert_allclose(single.mean(0), want_ss, rtol=0.01)
    # without the beam's channel (multiple scattering off) nothing of it is added
    off = march(o, d, t0, t1, np.ones(n), np.arange(n, dtype=np.uint32), pre.fields, [pm.w2i],
                [pm.sigma_s], [pm.sigma_t], [pm.g], [pm.threshold], [pm.voxel_size],
                pack_lights([SUN], pre.layout), -1, 0.02, 0.01, 1e10, None)
    assert np.all(off[3] == 0.0)
    np.testing.assert_allclose(off[0], single)
