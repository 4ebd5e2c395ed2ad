"""The drift of the light pyramid along the light (docs/method.md, "Drift along the light"):
the walk's mean displacement and its regression on the direction towards the camera against a
photon walk, and the levels moved by it."""
import numpy as np
import pytest

from mpp_render import pyramid
from mpp_render.precompute import lattice, lightpyramid, source
from mpp_render.walk import level_paths, walk_displacement
from mpp_render.media import PreparedMedium, trilinear
from mpp_render.phase import sample_hg
from mpp_render.scene import Camera, Light


def test_walk_displacement_limits():
    g = 0.8
    u = np.array([1e-6, 1e-3])
    drift, beta = walk_displacement(u, g)
    np.testing.assert_allclose(drift, g * u, rtol=1e-3)
    np.testing.assert_allclose(beta, g * u / (1 + g * g), rtol=1e-2)
    drift, beta = walk_displacement(np.array([50.0, 1e4]), g)
    np.testing.assert_allclose(drift, g, rtol=1e-9)
    np.testing.assert_allclose(beta, g, rtol=1e-9)
    drift, beta = walk_displacement(np.logspace(-4, 3, 50), 0.0)
    assert np.all(drift == 0) and np.all(beta == 0)
    d, b = walk_displacement(np.logspace(-4, 3, 50), 0.95)
    assert np.all(np.diff(d) >= 0) and np.all(np.diff(b) >= 0) and np.all(np.isfinite(b))
    d, b = walk_displacement(np.logspace(-4, 1, 50), 0.95)
    assert np.all(np.diff(d) > 0) and np.all(np.diff(b) > 0)


def walk(g, length, n, rng, g_last=None):
    """Photons after a first scattering at the origin of light travelling along +z: HG
    flights at rate 1/m for ``length`` m, then scattered once more (towards v) by HG of
    ``g_last`` (g when None).  Returns the positions (n,3) and the final directions v (n,3)."""
    z = np.tile([0.0, 0.0, 1.0], (n, 1))
    d = sample_hg(rng.random(n), rng.random(n), g, z)
    x = np.zeros((n, 3))
    left = np.full(n, float(length))
    while True:
        live = np.flatnonzero(left > 0)
        if not live.size:
            break
        step = np.minimum(rng.exponential(1.0, live.size), left[live])
        x[live] += step[:, None] * d[live]
        left[live] -= step
        turn = live[left[live] > 0]
        d[turn] = sample_hg(rng.random(turn.size), rng.random(turn.size), g, d[turn])
    v = sample_hg(rng.random(n), rng.random(n), g if g_last is None else g_last, d)
    return x, v


@pytest.mark.parametrize("g, length, g_last", [(0.5, 0.7, None), (0.85, 0.7, None),
                                               (0.85, 3.0, None), (0.3, 4.0, None),
                                               (0.85 / 1.85, 0.7, 0.85), (0.85 / 1.85, 3.0, 0.85)])
def test_walk_displacement_matches_a_photon_walk(g, length, g_last):
    """sigma_s = 1/m: l_tr = 1/(1 - g).  The mean progress along the light and the regression
    Cov(x, v) / Var(v) (traces over the axes) within 3 % of a 200 000-photon walk, also for a
    last scattering of another anisotropy than the walk's (the delta-scaled walk of a g = 0.85
    medium, g* = g / (1 + g), seen through the medium's own HG: docs/method.md, "The forward
    peak"; with the walk's g* in its place beta came out about half as large)."""
    rng = np.random.default_rng(7)
    x, v = walk(g, length, 200_000, rng, g_last)
    l_tr = 1.0 / (1.0 - g)
    drift, beta = walk_displacement(length / l_tr, g, g_last)
    mx, mv = x.mean(0), v.mean(0)
    cov = np.mean(np.sum(x * v, 1)) - mx @ mv
    var = np.mean(np.sum(v * v, 1)) - mv @ mv
    assert abs(mx[2] / (drift * l_tr) - 1) < 0.03, (mx[2], drift * l_tr)
    assert abs(cov / var / (beta * l_tr) - 1) < 0.03, (cov / var, beta * l_tr)


def blob_pyramid(n=33):
    base = np.zeros((n, n, n, 3), np.float32)
    base[16, 16, 16] = 1.0
    return pyramid.build(base, max_levels=4)


class _Medium:
    """What drift_levels reads of a prepared medium: g and the index <-> world maps (its
    methods PreparedMedium's)."""

    def __init__(self, g, spacing=0.1):
        self.g = g
        self.i2w = np.eye(4)
        self.i2w[:3, :3] *= spacing
        self.i2w[:3, 3] = -16 * spacing
        self.w2i = np.linalg.inv(self.i2w)[:3, :]

    to_world = PreparedMedium.to_world
    to_index = PreparedMedium.to_index


def centroid(level, k, med, c=0):
    w = level[..., c].astype(np.float64)
    idx = np.stack(np.meshgrid(*[np.arange(s) for s in w.shape], indexing="ij"), -1) * 2.0 ** k
    i = np.tensordot(w, idx, axes=3) / w.sum()
    return i @ med.i2w[:3, :3].T + med.i2w[:3, 3]


def test_levels_move_along_the_sun_and_towards_the_camera():
    """A point source blurred: each level's centroid moves by E[x_k | v] of its paths (an
    orthographic camera, so v is the same everywhere), and not at all for g = 0."""
    sun = Light("SUN", "sun", np.ones(3), direction=np.array([0.0, 0.0, -1.0]))
    c2w = np.eye(4)
    c2w[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # looks along +y: v = (0, -1, 0)
    cam = Camera("ORTHO", c2w, 8, 8, (-1, 1, -1, 1))
    sigma_s, h = 4.0, 0.1
    for g in (0.0, 0.7):
        med = _Medium(g, h)
        levels = blob_pyramid()
        before = [centroid(lv, k, med) for k, lv in enumerate(levels)]
        lightpyramid.drift_levels(levels, med, sun, cam, 1, h, sigma_s)
        after = [centroid(lv, k, med) for k, lv in enumerate(levels)]
        if g == 0.0:
            for a, b in zip(before, after):
                np.testing.assert_allclose(a, b, atol=1e-9)
            continue
        l_tr = 1.0 / (sigma_s * (1 - g))
        for k, (_, _, l_k) in enumerate(level_paths(h, len(levels), l_tr, g)):
            u = float(l_k) / l_tr
            drift, beta = walk_displacement(u, g)
            d, v = np.array([0, 0, -1.0]), np.array([0, -1.0, 0])
            want = l_tr * (drift * d + beta * (v - g * g * np.exp(-u) * d))
            assert np.linalg.norm(want) > 0.02
            np.testing.assert_allclose(after[k] - before[k], want, atol=0.1 * h * 2 ** k + 0.01)


@pytest.mark.parametrize("side", [True, False])
def test_point_light_levels_move_away_from_the_light(side):
    """Radial drift: a source beside a point light moves away from it and, seen from the
    side, towards the camera.  Seen from the light (v = -d; a sun, so that d is the same
    everywhere) nothing moves: the light that turns back towards the light has, on average,
    not gone anywhere."""
    med = _Medium(0.8, 0.1)
    light = Light("POINT", "pt", np.ones(3), position=np.array([-3.0, 0.0, 0.0])) if side else \
        Light("SUN", "sun", np.ones(3), direction=np.array([1.0, 0.0, 0.0]))
    c2w = np.eye(4)
    if side:
        c2w[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # v = (0, -1, 0)
    else:
        c2w[:3, :3] = [[0, 0, -1], [0, 1, 0], [1, 0, 0]]  # v = (-1, 0, 0), towards the light
    cam = Camera("ORTHO", c2w, 8, 8, (-1, 1, -1, 1))
    levels = blob_pyramid()
    before = [centroid(lv, k, med) for k, lv in enumerate(levels)]
    lightpyramid.drift_levels(levels, med, light, cam, 1, 0.1, 3.0)
    moved = [centroid(lv, k, med) - b for k, (lv, b) in enumerate(zip(levels, before))]
    assert all(abs(m[2]) < 1e-3 for m in moved)
    if side:
        assert moved[1][0] > 0.02 and moved[1][1] < -0.02
    else:
        assert all(np.linalg.norm(m) < 1e-5 for m in moved), moved


def source_pyramid(base, light, med, levels=4):
    """A light pyramid with the power-weighted light directions of its sources, as
    multiple_field builds it: (levels, directions)."""
    shape = base.shape[:3]
    _, pts = lattice.lattice_points(med, shape, 1)
    return lightpyramid.source_pyramid(base.reshape(-1, 3).astype(np.float64), light, pts, shape,
                                     float(med.g), levels)


def test_a_spot_beam_drifts_along_the_beam_not_from_the_light():
    """A beam along a spot light's axis, seen from the side: every level moves along the
    axis, also beside the beam and close to the light, where the direction from the light
    to the point itself is far from the axis (what the levels read before the sources'
    directions were carried: that spread the beam's glow into a cone)."""
    med = _Medium(0.85, 0.1)
    spot = Light("SPOT", "spot", np.ones(3), position=np.array([-1.8, 0.0, 0.0]),
                 direction=np.array([1.0, 0.0, 0.0]))
    base = np.zeros((33, 33, 33, 3), np.float32)
    base[:, 16, 16] = np.exp(-0.1 * np.arange(33))[:, None]
    c2w = np.eye(4)
    c2w[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # looks along +y: v = (0, -1, 0)
    cam = Camera("ORTHO", c2w, 8, 8, (-1, 1, -1, 1))
    sigma_s, h, g = 2.0, 0.1, med.g
    l_tr = 1.0 / (sigma_s * (1 - g))
    levels, directions = source_pyramid(base, spot, med)
    before = [lv.copy() for lv in levels]
    radial = [lv.copy() for lv in levels]
    lightpyramid.drift_levels(levels, med, spot, cam, 1, h, sigma_s, directions)
    lightpyramid.drift_levels(radial, med, spot, cam, 1, h, sigma_s)
    d, v = np.array([1.0, 0, 0]), np.array([0, -1.0, 0])
    for k, (_, _, l_k) in enumerate(level_paths(h, len(levels), l_tr, g)):
        u = float(l_k) / l_tr
        drift, beta = walk_displacement(u, g)
        shift = l_tr * (drift * d + beta * (v - g * g * np.exp(-u) * d)) / (h * 2 ** k)
        idx = lattice.lattice_index(before[k].shape[:3])
        padded = np.pad(before[k], ((1, 1), (1, 1), (1, 1), (0, 0)))
        want = trilinear(padded, idx - shift + 1.0).reshape(before[k].shape)
        top = float(before[k].max())
        np.testing.assert_allclose(levels[k], want, atol=1e-4 * top)
        if k >= 1:
            assert np.abs(radial[k] - want).max() > 0.05 * top, k


def test_mean_source_directions_round_a_point_light():
    """Round a point light inside the medium its sources' directions cancel (the mean is short
    on coarse levels and radial far from it), and a level without power nearby takes the
    coarser level's mean: a blob lit from the side lends its direction to the empty space."""
    med = _Medium(0.8, 0.1)
    light = Light("POINT", "pt", np.ones(3), position=np.zeros(3))
    _, pts = lattice.lattice_points(med, (33, 33, 33), 1)
    r2 = np.maximum(np.sum(pts * pts, 1), 0.01)
    base = np.repeat((1.0 / r2)[:, None], 3, 1).reshape(33, 33, 33, 3)
    _, directions = source_pyramid(base, light, med)
    mean = lightpyramid.mean_source_directions(directions, light, med, 1)
    assert np.linalg.norm(mean[3][2, 2, 2]) < 0.5  # level 3, at the light (level-0 index 16)
    assert mean[1][16, 8, 8] @ np.array([1.0, 0, 0]) > 0.9  # 1.6 m out along +x: radial
    far = Light("POINT", "pt", np.ones(3), position=np.array([-1.6, 1.5, 0.0]))
    blob = np.zeros((33, 33, 33, 3), np.float32)
    blob[14:19, 14:19, 14:19] = 1.0
    _, directions = source_pyramid(blob, far, med)
    mean = lightpyramid.mean_source_directions(directions, far, med, 1)
    to_blob = -far.position / np.linalg.norm(far.position)
    point = np.array([16.0, 30.0, 16.0])  # empty on level 0, 1.4 m beside the blob
    assert directions[0][16, 30, 16, 3] == 0.0
    own = source.light_direction(far, point @ med.i2w[:3, :3].T + med.i2w[:3, 3])[0]
    assert own @ to_blob < 0.8
    got = mean[0][16, 30, 16]
    assert got @ to_blob / np.linalg.norm(got) > 0.95


def test_each_colour_channel_drifts_by_its_own_transport_length():
    """A chromatic medium: each channel's levels move as a grey medium of that channel's
    sigma_s would move them (the channel that scatters more drifts less)."""
    sun = Light("SUN", "sun", np.ones(3), direction=np.array([0.0, 0.0, -1.0]))
    c2w = np.eye(4)
    c2w[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    cam = Camera("ORTHO", c2w, 8, 8, (-1, 1, -1, 1))
    med, h = _Medium(0.7, 0.1), 0.1
    sigma = np.array([2.0, 4.0, 8.0])
    levels = blob_pyramid()
    lightpyramid.drift_levels(levels, med, sun, cam, 1, h, sigma)
    for c, s_c in enumerate(sigma):
        grey = blob_pyramid()
        lightpyramid.drift_levels(grey, med, sun, cam, 1, h, s_c)
        for k in range(len(levels)):
            np.testing.assert_allclose(levels[k][..., c], grey[k][..., c], rtol=1e-6, atol=1e-9)
    moved = [np.linalg.norm(centroid(levels[2], 2, med, c) - centroid(blob_pyramid()[2], 2, med, c))
             for c in range(3)]
    assert moved[0] > moved[1] > moved[2] > 0.0, moved
