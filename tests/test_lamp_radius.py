"""A point or spot light with a radius is Cycles' soft-falloff lamp: a disc of radius r facing
the shading point, of radiance I / (pi r^2) (lights.py).  Its irradiance has a closed form,
the sampled directions fill the disc's cone uniformly in solid angle, and the distance to
the disc the march scales the optical depth by is the disc's solid-angle-weighted mean."""
import math

import numpy as np
import pytest

from mpp_render import lights
from mpp_render.lights import pack_light
from mpp_render.scene import Light


def lamp(radius, strength=100.0):
    m = np.eye(4)
    return Light("POINT", "p", np.full(3, strength), position=np.zeros(3), matrix=m, radius=radius)


def disc_integral(d0, r, f, n=4000):
    """Integral over the disc of radius r facing a point at distance d0 of f(t) cos / t^2 dA
    (midpoint rule in the disc's radius), t the distance to the disc point."""
    rho = (np.arange(n) + 0.5) / n * r
    t = np.sqrt(d0 * d0 + rho * rho)
    return float(np.sum(f(t) * d0 / t ** 3 * 2 * np.pi * rho) * (r / n))


@pytest.mark.parametrize("d0", [0.02, 0.1, 0.25, 0.5, 2.0])
def test_irradiance_is_the_disc_integral(d0):
    r, P = 0.3, 100.0
    rec = pack_light(lamp(r, P))
    u = np.random.default_rng(1).random((64, 2))
    x = np.tile([0.0, 0.0, d0], (len(u), 1))
    d, e, wc, dc, ds = lights.light_sample(rec, x, u[:, 0], u[:, 1])
    I = P / (4 * np.pi)
    closed = 2 * I * (1 - d0 / math.hypot(d0, r)) / r ** 2
    assert np.allclose(e, closed, rtol=1e-12)                    # every sample: the whole disc
    assert closed == pytest.approx(I / (np.pi * r * r) * disc_integral(d0, r, lambda t: 1.0), rel=1e-5)
    if d0 > 5 * r:
        assert closed == pytest.approx(I / d0 ** 2, rel=0.05)     # far away: a point


def test_directions_fill_the_cone_and_distance_is_the_disc_mean():
    r, d0 = 0.3, 0.2
    rec = pack_light(lamp(r))
    k = 128  # a stratified grid over (u1, u2)
    g = (np.stack(np.meshgrid(np.arange(k), np.arange(k), indexing="ij"), -1).reshape(-1, 2) + 0.5) / k
    x = np.tile([0.0, 0.0, d0], (len(g), 1))
    d, e, wc, dc, ds = lights.light_sample(rec, x, g[:, 0], g[:, 1])
    cos = -np.einsum("ij,ij->i", d, wc)         # propagation direction against the way to the centre
    cos_max = d0 / math.hypot(d0, r)
    assert cos.min() >= cos_max - 1e-12 and cos.max() <= 1.0 + 1e-12
    # uniform in solid angle: cos is uniform on [cos_max, 1]
    assert np.mean(cos) == pytest.approx(0.5 * (1 + cos_max), rel=2e-3)
    assert np.allclose(ds, d0 / cos)
    # the mean distance over the disc's solid angle
    want = disc_integral(d0, r, lambda t: t) / disc_integral(d0, r, lambda t: 1.0)
    assert np.mean(ds) == pytest.approx(want, rel=2e-3)


def test_radius_zero_stays_a_point():
    rec = pack_light(lamp(0.0, 4 * np.pi))
    x = np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 0.0]])
    d, e, wc, dc, ds = lights.light_sample(rec, x, np.full(2, 0.3), np.full(2, 0.7))
    assert np.allclose(e[:, 0], 1.0 / np.array([4.0, 1.0]))
    assert np.array_equal(ds, dc)               # no stretch of the optical depth


def test_path_stretch_is_exact_in_a_homogeneous_medium():
    sigma, voxel = 3.0, 0.01
    dc = np.array([0.05, 0.2, 1.0])
    ds = np.array([0.3, 0.25, 1.01])
    tau_centre = sigma * dc
    assert np.allclose(tau_centre * lights.path_stretch(ds, dc, voxel), sigma * ds)
    # next to the centre the field's depth stands for half a voxel's path
    assert lights.path_stretch(np.array([0.1]), np.array([0.001]), voxel)[0] == pytest.approx(0.1 / 0.005)


def test_first_scattering_power_round_a_lamp_inside_a_medium():
    """The multiple-scattering source round a lamp with a radius inside a medium carries the
    power the medium takes from the lamp: each lattice point the integral of
    sigma_s E <exp(-sigma_t r / cos theta)> (the disc's E and its points' paths) under its tent,
    as the lattice shares every voxel's power (source.restricted_source), summed in shells
    round the lamp within 10 %.  (The cells next to the lamp once multiplied the disc's finite
    E by R^2 / r^2, as for a lamp without radius: 4x the power within 0.1 m of a 0.1 m lamp,
    and p_point_in_cube's multiple scattering 22 % too bright; then they took the plain mean
    of the voxels beside the point, half a voxel off the lamp at even strides.)"""
    from mpp_render.media import prepare
    from mpp_render.precompute.source import source_and_density
    from mpp_render.scene import Medium
    n, size, st, alb, radius = 96, 2.0, 2.0, 0.9, 0.1
    vox = size / n
    i2w = np.eye(4)
    i2w[:3, :3] *= vox
    i2w[:3, 3] = -size / 2 + vox / 2
    pm = prepare(Medium("m", np.ones((n, n, n), np.float32), i2w, np.full(3, alb * st),
                        np.full(3, (1 - alb) * st), 0.3))
    where = np.array([-0.2, 0.1, -0.3])
    light = Light("POINT", "p", np.full(3, 60.0), position=where, matrix=np.eye(4), radius=radius)
    f = np.zeros(pm.grid.shape + (4,), np.float32)
    f[..., 0] = pm.grid
    idx = np.stack(np.meshgrid(*[np.arange(s) for s in pm.grid.shape], indexing="ij"), -1)
    r_vox = np.linalg.norm(pm.to_world(idx.reshape(-1, 3).astype(np.float64)) - where, axis=1)
    f[..., 1:4] = (st * r_vox).reshape(pm.grid.shape)[..., None]   # the optical depth to it
    intensity = 60.0 / (4 * np.pi)
    # the source per volume against the distance to the lamp (W/m^3)
    rr = np.linspace(0.0, 1.0, 20001)
    hyp = np.sqrt(rr * rr + radius * radius)
    e = 2 * intensity * (1 - rr / hyp) / radius ** 2
    s2 = (np.arange(400) + 0.5) / 400      # the disc's squared radius, uniform (light_sample)
    cos = 1 - s2[None, :] * (radius * radius / (hyp * (hyp + rr)))[:, None]
    q_of_r = alb * st * e * np.exp(-st * rr[:, None] / cos).mean(axis=1)
    for stride in (2, 3):
        base, _, pts = source_and_density(pm, f, light, 1, stride)
        h = vox * stride
        power = base[:, 0] * h ** 3
        r = np.linalg.norm(pts - where, axis=1)
        near = np.flatnonzero(r < 0.5 + 2 * h)
        # each point's tent (1 - |u| / h per axis) integrated at 16 midpoints an axis
        t = ((np.arange(16) + 0.5) / 16 * 2 - 1) * h
        u = np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3)
        w = np.prod(1 - np.abs(u) / h, axis=1) * (2 * h / 16) ** 3
        exact = np.array([np.dot(w, np.interp(np.linalg.norm(pts[k] + u - where, axis=1), rr,
                                              q_of_r)) for k in near])
        for lo, hi in ((0.0, 0.1), (0.1, 0.2), (0.2, 0.5)):
            here = (r[near] >= lo) & (r[near] < hi)
            got = power[near][here].sum()
            assert got == pytest.approx(exact[here].sum(), rel=0.10), (stride, lo, hi, got,
                                                                      exact[here].sum())


def test_the_disc_transmittance_is_what_the_marchs_disc_points_average_to():
    """lights.disc_transmittance (the first-scattering source's) equals the mean over the
    march's random disc points (light_sample with path_stretch) within 0.3 %."""
    from mpp_render.lights import disc_transmittance, light_sample, pack_light, path_stretch
    light = Light("POINT", "p", np.full(3, 60.0), position=np.zeros(3), matrix=np.eye(4),
                  radius=0.3)
    x = np.array([[0.05, 0.0, 0.0], [0.3, 0.1, 0.0], [0.0, 0.0, 0.7], [2.0, 0.0, 0.0]])
    tau = np.array([[0.2, 0.5, 1.0], [1.0, 2.0, 3.0], [0.5, 0.5, 0.5], [4.0, 4.0, 4.0]])
    rng = np.random.default_rng(2)
    n = 200000
    got = disc_transmittance(light, x, tau, 0.02)
    for i in range(len(x)):
        xi = np.repeat(x[i:i + 1], n, axis=0)
        _, e, _, dc, ds = light_sample(pack_light(light), xi, rng.random(n), rng.random(n))
        mc = np.exp(-tau[i][None, :] * path_stretch(ds, dc, 0.02)[:, None]).mean(axis=0)
        assert np.allclose(got[i], mc, rtol=3e-3), (i, got[i], mc)
    assert np.all(got[:3] < np.exp(-tau[:3]))   # longer paths than to the centre


def test_the_disc_points_own_depth_near_a_lamp_in_an_uneven_medium():
    """Where the medium is not the same across the lamp's disc the stretched centre's depth
    is wrong: a point just inside a dense half-space (y > 0) whose disc points' paths partly
    run through the empty half.  With the depth marched per disc point (``depth``, within
    ``reach`` radii) the mean over many points equals a Monte Carlo over the march's random
    disc points with their exact depths within 1 %; the stretched depth alone misses by far
    more, and beyond ``reach`` nothing changes."""
    from mpp_render.lights import disc_transmittance, light_sample
    sigma = 4.0
    light = Light("POINT", "p", np.full(3, 60.0), position=np.zeros(3), matrix=np.eye(4),
                  radius=0.3)

    def depth(p, d, t):   # exact: sigma times the length of the segment with y > 0
        y0, y1 = p[:, 1], p[:, 1] + d[:, 1] * t
        lo, hi = np.minimum(y0, y1), np.maximum(y0, y1)
        frac = np.where(hi > lo, np.clip(hi, 0, None) - np.clip(lo, 0, None), (y0 > 0) * 1.0)
        frac = np.where(hi > lo, frac / np.maximum(hi - lo, 1e-300), frac)
        return np.repeat((sigma * t * frac)[:, None], 3, axis=1)

    x0 = np.array([[0.5, 0.04, 0.2]])
    n = 4000
    # the same point to a micrometre, each copy its own turn of the disc's nodes
    # (lights.point_jitter hashes the coordinates)
    xs = np.repeat(x0, n, axis=0) + np.random.default_rng(5).uniform(-1e-6, 1e-6, (n, 3))
    wc = -x0 / np.linalg.norm(x0)
    tau_c = depth(x0, wc, np.linalg.norm(x0)[None])
    taus = np.repeat(tau_c, n, axis=0)
    each = disc_transmittance(light, xs, taus, 0.01, depth=depth, reach=4.0)
    got = each.mean(axis=0)
    # a point's value does not depend on the call it comes in
    assert np.array_equal(disc_transmittance(light, xs[7:9], taus[7:9], 0.01, depth=depth,
                                             reach=4.0), each[7:9])
    rng = np.random.default_rng(3)
    m = 200000
    wi, _, _, _, ds = light_sample(pack_light(light), np.repeat(x0, m, axis=0), rng.random(m),
                                   rng.random(m))
    exact = np.exp(-depth(np.repeat(x0, m, axis=0), -wi, ds)).mean(axis=0)
    stretched = disc_transmittance(light, x0, tau_c, 0.01)[0]
    assert np.allclose(got, exact, rtol=0.01), (got, exact)
    assert abs(stretched[0] / exact[0] - 1.0) > 0.1, (stretched, exact)
    far = disc_transmittance(light, x0, tau_c, 0.01, depth=depth, reach=1.0)[0]
    assert np.array_equal(far, stretched)


def test_the_disc_points_are_marched_only_where_the_media_round_the_lamp_are_uneven():
    """media.disc_reaches: Tuning.disc_exact radii round a lamp with a radius whose
    surroundings hold uneven density; 0 in a homogeneous medium (the stretch is exact
    there), far from every medium, for a lamp without radius and for other lights."""
    from mpp_render.media import disc_reaches, prepare
    from mpp_render.scene import Medium
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.05
    i2w[:3, 3] = -1.0
    flat = prepare(Medium("flat", np.ones((40, 40, 40), np.float32), i2w, np.ones(3),
                          np.zeros(3), 0.0))
    rough = np.ones((40, 40, 40), np.float32)
    rough[20:, :, :] = 3.0
    lumpy = prepare(Medium("lumpy", rough, i2w, np.ones(3), np.zeros(3), 0.0))

    def lamp_at(p, radius=0.1, kind="POINT"):
        return Light(kind, "l", np.full(3, 10.0), position=np.array(p, float), matrix=np.eye(4),
                     radius=radius, direction=np.array([0.0, 0.0, -1.0]))
    inside = lamp_at([-0.5, 0.0, 0.0])       # 0.5 m from the density step at x = 0
    near_step = lamp_at([0.05, 0.0, 0.0])
    assert disc_reaches([flat], [inside, near_step], 2.0) == [0.0, 0.0]
    assert disc_reaches([lumpy], [inside, near_step], 2.0) == [0.0, pytest.approx(0.2)]
    assert disc_reaches([lumpy], [lamp_at([0.05, 0.0, 0.0], radius=0.0)], 2.0) == [0.0]
    assert disc_reaches([lumpy], [lamp_at([5.0, 5.0, 5.0])], 2.0) == [0.0]
    # the box's own edge is uneven too: a lamp by its face
    assert disc_reaches([flat], [lamp_at([0.95, 0.0, 0.0])], 2.0) == [pytest.approx(0.2)]
    # at least disc_voxels of the finest voxel (0.05 m here): a small lamp reaches as far
    # as a large one would, and a reach that now takes in the step at x = 0 is uneven
    assert disc_reaches([lumpy], [near_step], 2.0, 16.0) == [pytest.approx(0.8)]
    assert disc_reaches([lumpy], [lamp_at([0.05, 0.0, 0.0], radius=0.5)], 2.0, 16.0) == \
        [pytest.approx(1.0)]
    assert disc_reaches([lumpy], [inside], 2.0) == [0.0]
    assert disc_reaches([lumpy], [inside], 2.0, 16.0) == [pytest.approx(0.8)]
    assert disc_reaches([lumpy], [lamp_at([0.05, 0.0, 0.0], radius=0.0)], 2.0, 16.0) == [0.0]


def test_a_spots_irradiance_without_jitter_carries_the_marchs_flux():
    """lights.incident without a jitter (what the precompute's sources read) gives a spot
    with a radius the flux of the march's jittered samples through a plane across its beam
    near the lamp, within 1 %: a jitter per point (lights.point_jitter).  One fixed jitter
    for every point is off there (fog_beam's spot; the paths' source with it): it counted the
    penumbra 10 % high while the disc lattice was read by the concentric map, 8 % low since
    it is read in polar coordinates (its squared radii i / 8 at the fixed jitter).  The same
    point gets the same jitter in any call."""
    from mpp_render.lights import incident, light_sample, point_jitter
    m = np.eye(4)
    m[:3, :3] = np.array([[0, 0, -1.0], [0, 1, 0], [1, 0, 0]])   # local -Z along +x
    m[:3, 3] = [-4.5, 0.0, 0.0]
    spot = Light("SPOT", "s", np.full(3, 2000.0), position=m[:3, 3].copy(), matrix=m,
                 direction=np.array([1.0, 0.0, 0.0]), spot_size=np.radians(8.0),
                 spot_blend=0.1, radius=0.1)
    g = np.linspace(-0.6, 0.6, 241)
    Y, Z = np.meshgrid(g, g, indexing="ij")
    P = np.stack([np.full(Y.size, -2.9), Y.ravel(), Z.ravel()], 1)
    dA = (g[1] - g[0]) ** 2
    rng = np.random.default_rng(4)
    n = len(P)
    marched = np.mean([light_sample(pack_light(spot), P, rng.random(n), rng.random(n))[1][:, 0]
                       for _ in range(32)], axis=0).sum() * dA
    got = incident(spot, P)[1][:, 0].sum() * dA
    fixed = light_sample(pack_light(spot), P, np.full(n, 0.5), np.full(n, 0.5))[1][:, 0].sum() * dA
    assert got == pytest.approx(marched, rel=0.01), (got, marched)
    assert abs(fixed / marched - 1.0) > 0.05
    assert np.array_equal(point_jitter(P[::-1])[::-1], point_jitter(P))
