"""Rectangular area lights sampled in the solid angle they subtend (lights.light_sample,
csrc/light.h): the same light as points uniform over the area, without their noise."""
import numpy as np
import pytest

from mpp_render.lightrecord import L_AX, L_AY, L_NORMAL, L_POS
from mpp_render.lights import light_sample, pack_light, rect_solid_angle_sample
from mpp_render.scene import Light


def rect_light(tilt=0.3, shape="RECTANGLE"):
    c, s = np.cos(tilt), np.sin(tilt)
    m = np.array([[c, 0, s, 0.1], [0, 1, 0, 0.0], [-s, 0, c, 0.8], [0, 0, 0, 1.0]])
    return pack_light(Light("AREA", "rect", np.full(3, 300.0), matrix=m, shape=shape,
                            size_x=0.6, size_y=0.4))


def by_area(rec, x, u1, u2):
    """The irradiance estimate of points uniform over the rectangle: L cos A / r^2."""
    a, b = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
    src = rec[L_POS:L_POS + 3] + rec[L_AX:L_AX + 3] * a[:, None] + rec[L_AY:L_AY + 3] * b[:, None]
    v = x - src
    r2 = np.einsum("ij,ij->i", v, v)
    cos = np.maximum((v / np.sqrt(r2)[:, None]) @ rec[L_NORMAL:L_NORMAL + 3], 0.0)
    area = 4.0 * np.linalg.norm(rec[L_AX:L_AX + 3]) * np.linalg.norm(rec[L_AY:L_AY + 3])
    radiance = 300.0 / np.pi / area
    return radiance * cos * area / r2, v / np.sqrt(r2)[:, None]


@pytest.mark.parametrize("point", [(0.0, 0.0, 0.7), (0.5, 0.3, 0.2), (0.35, 0.15, 0.6),
                                   (3.0, 2.0, -1.0), (0.1, 0.0, 0.79)])
def test_solid_angle_samples_carry_the_light_of_area_samples_without_their_noise(point):
    rec = rect_light()
    rng = np.random.default_rng(1)
    n = 200_000
    x = np.tile(np.asarray(point, np.float64), (n, 1))
    u1, u2 = rng.random(n), rng.random(n)
    d, e, _, _, ds = light_sample(rec, x, u1, u2)
    ea, da = by_area(rec, x, u1, u2)
    assert ea.mean() > 0.0                   # the point is in front of the light
    # every sample is the light's radiance times its solid angle: no noise at all
    assert np.ptp(e[:, 0]) <= 1e-9 * e[0, 0]
    assert e[0, 0] == pytest.approx(ea.mean(), rel=6 * ea.std() / np.sqrt(n) / ea.mean() + 1e-3)
    # the directions are those of the light's points, weighted as area samples weigh them
    mean_dir = (e[:, :1] * d).mean(axis=0)
    want = (ea[:, None] * da).mean(axis=0)
    assert mean_dir == pytest.approx(want, abs=8 * ea.std() / np.sqrt(n) + 1e-3 * ea.mean())
    # and every sampled point lies on the rectangle
    src = x - d * ds[:, None]
    local = src - rec[L_POS:L_POS + 3]
    ax, ay = rec[L_AX:L_AX + 3], rec[L_AY:L_AY + 3]
    assert np.all(np.abs(local @ ax / (ax @ ax)) <= 1 + 1e-9)
    assert np.all(np.abs(local @ ay / (ay @ ay)) <= 1 + 1e-9)
    assert np.abs(local @ np.cross(ax, ay)).max() <= 1e-9


def test_behind_in_the_plane_far_or_round_falls_back():
    rec = rect_light()
    u = np.full(3, 0.4)
    x = np.array([[0.1, 0.0, 0.9], [0.1, 0.0, 0.8], [0.1, 0.0, -100.0]])
    omega, _ = rect_solid_angle_sample(rec, x, np.linalg.norm(x - rec[L_POS:L_POS + 3], axis=1),
                                       u, u)
    assert np.all(omega[:2] < 0.0)          # behind it; in its plane (at its centre)
    assert omega[2] < 0.0                    # 100 m: over 64 diagonals away, by area
    e = light_sample(rec, x, u, u)[1]
    assert np.all(e[0] == 0.0) and np.all(e[2] > 0.0)
    disc = rect_light(shape="DISK")
    got = light_sample(disc, np.array([[0.0, 0.0, 0.7]]), np.array([0.3]), np.array([0.6]))[1]
    assert got[0, 0] > 0.0


@pytest.mark.parametrize("point,normal", [((0.0, 0.0, 0.2), (0.0, 0.0, 1.0)),
                                          ((0.5, 0.3, 0.2), (0.6, 0.0, 0.8)),
                                          ((0.35, 0.15, 0.6), (-1.0, 0.0, 0.0)),
                                          ((3.0, 2.0, -1.0), (-0.6, -0.48, 0.64))])
def test_a_surface_draws_the_light_towards_its_normal_unbiased_and_with_less_noise(point, normal):
    """With the surface's normal (lights.cosine_warp) the irradiance E cos at a surface point
    keeps its mean (that of the plain solid-angle draw) within the noise, and its spread per
    sample falls where the cosine varies across the light (measured: 1.9x for a light 0.6 m
    above a floor, whose cosine the corners' bilinear blend follows less well; 2.2x for a
    wall the light half faces; 5.7-8x for tilted surfaces further off), never rising."""
    rec = rect_light()
    rng = np.random.default_rng(4)
    n = 200_000
    x = np.tile(np.asarray(point, np.float64), (n, 1))
    nrm = np.tile(np.asarray(normal, np.float64) / np.linalg.norm(normal), (n, 1))
    u1, u2 = rng.random(n), rng.random(n)
    est = []
    for given in (None, nrm):
        d, e = light_sample(rec, x, u1, u2, normal=given)[:2]
        est.append(e[:, 0] * np.maximum(-np.einsum("ij,ij->i", d, nrm), 0.0))
    plain, warped = est
    assert plain.mean() > 0.0 and np.all(np.isfinite(warped)) and np.all(warped >= 0.0)
    se = np.hypot(plain.std(), warped.std()) / np.sqrt(n)
    assert abs(warped.mean() - plain.mean()) < 5 * se, (warped.mean(), plain.mean(), se)
    print(point, normal, "spread plain / warped", plain.std() / warped.std())
    assert warped.std() <= 1.02 * plain.std()
    if np.ptp(plain) > 0.2 * plain.mean():    # the cosine varies across the light
        assert warped.std() < plain.std() / 1.5


def test_the_warp_density_integrates_to_one_and_maps_the_square_onto_itself():
    """cosine_warp's density over the unit square integrates to 1, and its points stay in
    [0, 1)^2: it is a change of variables, whatever the corners' cosines."""
    from mpp_render.lights import cosine_warp
    rec = rect_light()
    rng = np.random.default_rng(5)
    n = 400_000
    x = np.tile([0.5, 0.3, 0.2], (n, 1))
    nrm = np.tile([0.6, 0.0, 0.8], (n, 1))
    u, v = rng.random(n), rng.random(n)
    up, vp, pdf = cosine_warp(rec, x, nrm, u, v)
    assert np.all((up >= 0) & (up < 1) & (vp >= 0) & (vp < 1)) and np.all(pdf > 0)
    # E[1 / pdf(u', v')] over the warped points is the square's area, 1
    inv = 1.0 / pdf
    assert inv.mean() == pytest.approx(1.0, abs=5 * inv.std() / np.sqrt(n))


def test_light_varies_weighs_a_rectangle_by_its_exact_irradiance():
    """kernels_np.varies_value (light_varies' measure, the twin of march.c's) reads a
    rectangle's irradiance as lights.area_incident integrates it over the emitter (Van
    Oosterom and Strackee on its two triangles), seen from its centre, and 0 behind it; the
    solid angle of a point 1 mm above a large square is nearly a hemisphere's."""
    from mpp_render import kernels_np
    from mpp_render.lights import area_incident
    from mpp_render.phase import hg
    c_, s_ = np.cos(0.3), np.sin(0.3)
    m = np.array([[c_, 0, s_, 0.1], [0, 1, 0, 0.0], [-s_, 0, c_, 0.8], [0, 0, 0, 1.0]])
    light = Light("AREA", "rect", np.array([300.0, 200.0, 100.0]), matrix=m,
                  shape="RECTANGLE", size_x=0.6, size_y=0.4)
    rec = pack_light(light)
    rng = np.random.default_rng(3)
    c, n = rec[L_POS:L_POS + 3], rec[L_NORMAL:L_NORMAL + 3]
    pts = c + rng.normal(size=(200, 3)) * 0.8
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    _, e = area_incident(light, pts, direction=False)
    omega = kernels_np.area_omega(rec, pts)
    front = (pts - c) @ n > 0.0
    assert front.any() and (~front).any()
    assert np.all(omega[~front] == 0.0) and np.all(omega[front] > 0.0)
    radiance = e[front].sum(axis=1) / omega[front]
    assert np.allclose(radiance, radiance[0], rtol=1e-9)      # e = L_e Omega, one L_e
    wi = (pts - c) / np.linalg.norm(pts - c, axis=1, keepdims=True)
    for g in (0.0, 0.7):
        want = e.sum(axis=1) * hg(-np.einsum("ij,ij->i", wi, dirs), g)
        assert np.allclose(kernels_np.varies_value(rec, pts, dirs, g), want, rtol=1e-9, atol=0)
    big = pack_light(Light("AREA", "big", np.full(3, 10.0), matrix=np.eye(4),
                           shape="SQUARE", size_x=4.0, size_y=4.0))
    above = np.array([[0.1, -0.2, -1e-3]]) if big[L_NORMAL + 2] < 0 else np.array([[0.1, -0.2, 1e-3]])
    assert kernels_np.area_omega(big, above)[0] == pytest.approx(2.0 * np.pi, rel=2e-3)


def rect(tilt=0.3, shape="RECTANGLE"):
    c, s = np.cos(tilt), np.sin(tilt)
    m = np.array([[c, 0, s, 0.1], [0, 1, 0, 0.0], [-s, 0, c, 0.8], [0, 0, 0, 1.0]])
    return Light("AREA", "rect", np.full(3, 300.0), matrix=m, shape=shape, size_x=0.6,
                 size_y=0.4)


@pytest.mark.parametrize("shape", ["RECTANGLE", "ELLIPSE"])
@pytest.mark.parametrize("point", [(0.0, 0.0, 0.7), (0.5, 0.3, 0.2), (0.35, 0.15, 0.6),
                                   (1.5, 1.0, -0.4), (0.4, 0.0, 0.655)])
def test_the_sources_area_transmittance_is_what_the_marchs_emitter_points_average_to(shape,
                                                                                      point):
    """lights.area_transmittance (the paths' first scatterings, precompute/source.py) against
    the march's own estimate: emitter points drawn by light_sample, each with the centre's
    optical depth stretched to its distance (path_stretch), weighed by their light, in a
    homogeneous medium of 2 /m and 4 /m -- within 0.5 %; the centre's exp(-tau) alone misses
    by more beside the emitter."""
    from mpp_render.lights import area_transmittance, path_stretch
    light = rect(shape=shape)
    rec = pack_light(light)
    rng = np.random.default_rng(7)
    n = 400_000
    x = np.tile(np.asarray(point, np.float64), (n, 1))
    _, e, _, _, ds = light_sample(rec, x, rng.random(n), rng.random(n))
    assert e[:, 0].mean() > 0.0
    dc = float(np.linalg.norm(np.asarray(point) - rec[L_POS:L_POS + 3]))
    missed = 0.0
    for sigma in (2.0, 4.0):
        tau = np.full((1, 3), sigma * dc)
        want = np.sum(e[:, 0] * np.exp(-tau[0, 0] * path_stretch(ds, dc, 0.02))) / e[:, 0].sum()
        got = area_transmittance(light, np.asarray([point], float), tau, 0.02)[0]
        np.testing.assert_allclose(got, want, rtol=0.005)
        missed = max(missed, abs(np.exp(-tau[0, 0]) / want - 1.0))
    if point == (0.4, 0.0, 0.655):   # beside the emitter's edge, 5 cm in front of its plane
        assert missed > 0.05


def test_area_transmittance_behind_the_emitter_is_the_centres():
    """Behind the emitter no light comes: exp(-tau) there, bit for bit."""
    from mpp_render.lights import area_transmittance
    light = rect(tilt=0.0)
    tau = np.array([[0.7, 1.1, 2.0], [0.7, 1.1, 2.0]])
    x = np.array([[0.1, 0.0, 1.3], [0.3, 0.2, 3.0]])   # it emits downwards
    np.testing.assert_array_equal(area_transmittance(light, x, tau, 0.02), np.exp(-tau))
