"""The compiled light sample (csrc/lightsample.c, kernels.light_sample) against its numpy twin
(lights.light_sample): every kind of light, points near and inside a lamp's radius, a
rectangle's cosine warp left to numpy, and bad input refused with a message; the same for an
area light's transmittance over its emitter (csrc/emitter.c, lights.emitter_transmittance)."""
import numpy as np
import pytest

from mpp_render import kernels, lights
from mpp_render.lightrecord import L_KIND
from mpp_render.lights import pack_light
from test_kernels import all_lights, rect_light, unjittered_lights

needs_c = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")


def points(n=4000, seed=3):
    """Points round the test lights, a tenth of them within 0.15 m of the point light's
    centre (inside its 0.2 m radius), with their jitter."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-3.0, 4.0, (n, 3))
    x[: n // 10] = np.array([1.5, -1.0, 0.5]) + rng.uniform(-0.15, 0.15, (n // 10, 3))
    return x, rng.random(n), rng.random(n)


def agree(a, b):
    for p, q in zip(a, b):
        p, q = np.asarray(p, np.float64), np.asarray(q, np.float64)
        assert p.shape == q.shape
        fin = np.isfinite(p)
        assert np.array_equal(fin, np.isfinite(q))   # a sun's distances are inf in both
        if fin.any():
            np.testing.assert_allclose(q[fin], p[fin], rtol=1e-8,
                                       atol=1e-12 * np.abs(p[fin]).max())


@needs_c
@pytest.mark.parametrize("light", all_lights() + [rect_light()] + unjittered_lights(),
                         ids=lambda lt: f"{lt.kind}-{lt.name}-r{lt.radius or 0}")
def test_twins_agree_for_every_kind(light):
    x, u1, u2 = points()
    rec = pack_light(light)
    a = lights.light_sample(rec, x, u1, u2)
    b = kernels.light_sample(rec, x, u1, u2, backend="c")
    agree(a, b)
    assert np.isfinite(b[1]).all() and (b[1] >= 0.0).all()
    if np.any(light.strength > 0) and light.kind != "SUN":
        assert b[1].max() > 0.0                       # the light reached some points
    if (light.radius or 0.0) > 0.0:                   # the jitter moves a lamp's disc point
        c = kernels.light_sample(rec, x, 1.0 - u1, u2, backend="c")
        assert np.abs(c[0] - b[0]).max() > 1e-3


@needs_c
def test_a_surfaces_normal_warps_only_a_rectangle_and_only_numpy_does_it():
    x, u1, u2 = points()
    nrm = np.tile([0.0, 0.0, 1.0], (len(x), 1))
    rect = pack_light(rect_light())
    warped = kernels.light_sample(rect, x, u1, u2, normal=nrm)       # numpy's cosine warp
    agree(lights.light_sample(rect, x, u1, u2, normal=nrm), warped)
    assert np.abs(warped[0] - kernels.light_sample(rect, x, u1, u2)[0]).max() > 1e-3
    for light in all_lights():                       # no other kind reads the normal
        rec = pack_light(light)
        agree(lights.light_sample(rec, x, u1, u2, normal=nrm),
              kernels.light_sample(rec, x, u1, u2, normal=nrm, backend="c"))


@needs_c
def test_bad_input_is_refused():
    x, u1, u2 = points(10)
    rec = pack_light(all_lights()[1])
    with pytest.raises(ValueError, match="rec"):
        kernels._c.light_samples(rec[:-1].copy(), x, u1, u2)
    bad = rec.copy()
    bad[L_KIND] = 7.0
    with pytest.raises(ValueError, match="unknown kind"):
        kernels._c.light_samples(bad, x, u1, u2)
    with pytest.raises(ValueError, match="u1"):
        kernels._c.light_samples(rec, x, u1[:5].copy(), u2)
    with pytest.raises(ValueError, match="x"):
        kernels._c.light_samples(rec, x.astype(np.float32), u1, u2)
    empty = kernels.light_sample(rec, np.zeros((0, 3)), np.zeros(0), np.zeros(0), backend="c")
    assert [a.shape[0] for a in empty] == [0] * 5


def emitter_case(n=3000, seed=11, shape="RECTANGLE"):
    """An area light's 16 x 16 nodes (lights._emitter_nodes) and points on both sides of its
    plane, some a hair from a node, with depths grey and chromatic, some 0."""
    light = rect_light()
    light.shape = shape
    pts, wa = lights._emitter_nodes(light, 16)
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.0, 2.0, (n, 3))
    x[:20] = pts[:20] + 1e-12                     # on a node: d held at 1e-9
    tau = rng.uniform(0.0, 6.0, (n, 3))
    tau[::3] = tau[::3, :1]                       # a third grey
    tau[::7] = 0.0
    normal = lights.emitter_normal(light)
    dc = np.linalg.norm(x - lights.area_geometry(light)[0], axis=1)
    dc[5:10] = 0.0                                # within half a voxel of the centre
    return x, tau, dc, pts, wa, normal


@needs_c
@pytest.mark.parametrize("shape", ["RECTANGLE", "DISK"])
def test_the_emitter_transmittance_twins_agree(shape):
    """csrc/emitter.c against lights.emitter_transmittance: the same per point to rounding,
    points behind the emitter at exp(-tau), every value in (0, 1]."""
    x, tau, dc, pts, wa, normal = emitter_case(shape=shape)
    want = lights.emitter_transmittance(x, tau, dc, pts, wa, normal, 0.05)
    got = kernels.emitter_transmittance(x, tau, dc, pts, wa, normal, 0.05, backend="c")
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-300)
    behind = (x - pts.mean(axis=0)) @ normal < -0.01
    assert behind.sum() > 100
    np.testing.assert_allclose(got[behind], np.exp(-tau[behind]), rtol=1e-15)  # libm's exp
    assert np.all((got > 0.0) & (got <= 1.0))
    front = ~behind & (tau[:, 0] > 0.5)
    assert np.abs(got[front] - np.exp(-tau[front])).max() > 1e-3   # the emitter's spread


@needs_c
def test_emitter_transmittance_refuses_bad_input():
    x, tau, dc, pts, wa, normal = emitter_case(50)
    c = kernels._c.emitter_transmittance
    with pytest.raises(ValueError, match="voxel"):
        c(x, tau, dc, pts, wa, normal, 0.0)
    with pytest.raises(ValueError, match="voxel"):
        c(x, tau, dc, pts, wa, normal, float("nan"))
    with pytest.raises(ValueError, match="tau"):
        c(x, tau[:10].copy(), dc, pts, wa, normal, 0.05)
    with pytest.raises(ValueError, match="weights"):
        c(x, tau, dc, pts, wa[:-1].copy(), normal, 0.05)
    with pytest.raises(ValueError, match="normal"):
        c(x, tau, dc, pts, wa, normal[:2].copy(), 0.05)
    with pytest.raises(ValueError, match="x"):
        c(x.astype(np.float32), tau, dc, pts, wa, normal, 0.05)
    none = kernels.emitter_transmittance(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), pts,
                                         wa, normal, 0.05, backend="c")
    assert none.shape == (0, 3)


def test_the_disc_lattice_turns_are_the_golden_ratio_steps():
    """LAMP_DISC_TURN (and the C twin's copy of it, which test_twins_agree_for_every_kind
    reads through a spot with a radius) is cos, sin of 2 pi frac(i SPOT_DISC_PHI)."""
    i = np.arange(len(lights.LAMP_DISC_TURN))
    f = i * lights.SPOT_DISC_PHI - np.floor(i * lights.SPOT_DISC_PHI)
    np.testing.assert_allclose(lights.LAMP_DISC_TURN, np.stack([np.cos(2 * np.pi * f),
                                                                np.sin(2 * np.pi * f)], 1),
                               rtol=0, atol=1e-15)
    assert len(lights.LAMP_DISC_TURN) == lights.SPOT_DISC_POINTS
    assert np.allclose(lights.disc_turn(11), [np.cos(2 * np.pi * (11 * lights.SPOT_DISC_PHI % 1)),
                                              np.sin(2 * np.pi * (11 * lights.SPOT_DISC_PHI % 1))])


@needs_c
def test_a_lamps_disc_points_are_uniform_in_its_solid_angle():
    """Over a grid of jitters the directions a lamp with a radius sends fill the cone its disc
    subtends evenly: 1 - cos of their angle to the centre uniform on [0, 1 - cos theta_max]
    (mean and second moment), the azimuth round it uniform (its mean cosine and sine 0)."""
    from test_kernels import all_lights
    lamp = next(lt for lt in all_lights() if lt.kind == "POINT" and (lt.radius or 0) > 0)
    rec = pack_light(lamp)
    k = 128
    u = (np.arange(k) + 0.5) / k
    u1, u2 = (a.ravel() for a in np.meshgrid(u, u))
    x = np.tile(lamp.position + np.array([0.0, 0.0, 0.7]), (len(u1), 1))
    d, _, wc, dc, _ = kernels.light_sample(rec, x, u1, u2, backend="c")
    r = lamp.radius
    hyp = np.hypot(dc[0], r)
    omc_max = r * r / (hyp * (hyp + dc[0]))
    q = (1.0 + np.einsum("ij,ij->i", d, wc)) / omc_max      # d points away from the lamp
    assert q.min() > -1e-6 and q.max() < 1.0 + 1e-6
    assert q.mean() == pytest.approx(0.5, abs=1e-3) and (q * q).mean() == pytest.approx(1 / 3, abs=1e-3)
    t1, t2 = lights.orthonormal_basis(-wc[:1])
    side = d - np.einsum("ij,ij->i", d, -wc)[:, None] * -wc
    ang = np.arctan2(side @ t2[0], side @ t1[0])
    assert abs(np.cos(ang).mean()) < 1e-3 and abs(np.sin(ang).mean()) < 1e-3


@needs_c
def test_the_unjittered_sample_of_a_lamp_with_a_radius_is_its_centre():
    """The callers' unjittered sample, (0.5, 0.5) (the march's test of how fast the light
    varies along a ray, the world fog's tail, a mesh volume's flattened levels), draws the
    centre of a lamp's disc in both twins: the propagation direction is the centre's."""
    from test_kernels import all_lights
    x, _, _ = points(500)
    half = np.full(len(x), 0.5)
    for lamp in (lt for lt in all_lights() if lt.kind == "POINT" and (lt.radius or 0) > 0):
        rec = pack_light(lamp)
        for d, _, wc, _, _ in (lights.light_sample(rec, x, half, half),
                               kernels.light_sample(rec, x, half, half, backend="c")):
            np.testing.assert_allclose(d, -wc, rtol=0, atol=1e-12)
