"""The exact first flight (firstflight.py): its kernel's integrals, the convolution's
orientation, the escape fraction and blend, the walk's table without the first flight, and
how the march's flattened level takes it."""
import numpy as np
import pytest

from mpp_render import firstflight as ff
from mpp_render.walk import level_paths, level_table, table_lookup
from mpp_render.cancel import Cancelled
from mpp_render.precompute.flatten import flatten_levels
from mpp_render.phase import delta_fraction, delta_g, hg, outside_peak, peak_cone_cos


def rotation(a, b, c):
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return rz @ ry @ rx


@pytest.mark.parametrize("axes", [np.eye(3) * 0.1,
                                  rotation(0.3, -0.7, 1.1) @ np.diag([0.1, 0.12, 0.08])])
def test_the_bare_kernel_integrates_to_the_mean_free_path(axes):
    sigma = 2.0   # 1/m: the lattice spans 8 mean free paths either side, e^-8 beyond
    k = ff.flight_kernel(axes, (41, 41, 41), np.array([0.0, 0.6, 0.8]), (0.5, 1.0), sigma)
    assert np.all(np.isfinite(k)) and np.all(k >= 0.0)
    assert k.sum() * sigma == pytest.approx(1.0, abs=0.02)


@pytest.mark.parametrize("g", [-0.3, 0.85])
def test_the_camera_kernel_integrates_to_the_two_scatterings(g):
    """Over all space: (p1 composed with p2)(d . w) / sigma, p1 the first flight's direction
    (HG(g) outside its forward peak; for g <= 0 HG(g) itself, and then HG(g g2) exactly)."""
    sigma, g2 = 2.0, 0.6
    d = np.array([1.0, 0.0, 0.0])
    omega = ff.sphere_directions(400000)
    for cos in (0.8, 0.0, -0.7):
        w = np.array([cos, np.sqrt(1 - cos * cos), 0.0])
        k = ff.flight_kernel(np.eye(3) * 0.1, (41, 41, 41), d, (g, 1.0), sigma, w, g2)
        both = float(np.mean(ff.first_phase(omega @ d, g, 1.0) * hg(omega @ w, g2))) * 4 * np.pi
        if g <= 0:
            assert both == pytest.approx(float(hg(cos, g * g2)), rel=1e-3)
        assert k.sum() * sigma == pytest.approx(both, rel=0.03)


@pytest.mark.parametrize("g", [0.3, 0.5, 0.85, 0.95])
def test_the_first_flight_leaves_the_peak_to_the_beam(g):
    """HG(g)'s forward cone holds f = g^2 of its scattering (the beam channels' share); the
    first flight's directions are the rest, normalised, none inside the cone."""
    mu = np.linspace(-1.0, 1.0, 2000001)
    c = peak_cone_cos(g)
    cone = mu >= c
    in_cone = np.trapz(np.where(cone, hg(mu, g), 0.0), mu) * 2 * np.pi
    assert in_cone == pytest.approx(g * g, rel=1e-3)
    p = outside_peak(mu, g)
    assert np.trapz(p, mu) * 2 * np.pi == pytest.approx(1.0, rel=1e-3)
    assert not np.any(p[cone]) and np.all(p >= 0.0)
    assert peak_cone_cos(-0.4) == 1.0 and np.allclose(outside_peak(mu[::1000], -0.4),
                                                       hg(mu[::1000], -0.4))


def test_the_convolution_reads_the_flight_from_source_to_point():
    """F1(x) = sum_y Q(y) K(x - y): the FFT result equals the direct sum at a few points,
    with no wrap-around (a source in one corner lights the far corner by the kernel's far
    offset)."""
    rng = np.random.default_rng(3)
    shape = (9, 7, 6)
    axes = rotation(0.2, 0.1, -0.4) @ np.diag([0.2, 0.25, 0.15])
    d, w = np.array([0.0, 0.0, 1.0]), np.array([0.6, 0.0, 0.8])
    k = ff.flight_kernel(axes, shape, d, (0.6, 1.0), 1.3, w, 0.8)
    q = rng.random(shape)
    out = ff.convolve(ff.spectrum(q, shape), ff.spectrum(k, shape), shape)
    for x in [(0, 0, 0), (8, 6, 5), (4, 3, 2), (8, 0, 5)]:
        direct = sum(q[y] * k[tuple(np.array(x) - np.array(y) + np.array(shape) - 1)]
                     for y in np.ndindex(shape))
        assert out[x] == pytest.approx(direct, rel=1e-9)
    corner = np.zeros(shape)
    corner[0, 0, 0] = 1.0
    far = ff.convolve(ff.spectrum(corner, shape), ff.spectrum(k, shape), shape)
    assert far[8, 6, 5] == pytest.approx(k[16, 12, 10], rel=1e-9)


def beam_box(n=(24, 12, 12), h=0.1):
    """A box lattice with a beam along +x through its middle, scattering evenly from two
    lattice steps inside the box's faces: (q, inside, axes, dirs)."""
    q = np.zeros(n + (3,))
    q[2:n[0] - 2, n[1] // 2, n[2] // 2, :] = 1.0
    inside = np.ones(n, bool)
    dirs = np.tile([1.0, 0.0, 0.0], (int(np.prod(n)), 1))
    return q, inside, np.eye(3) * h, dirs


def test_the_escape_fraction_falls_with_the_optical_size():
    fractions = []
    for sigma in (0.05, 0.5, 2.0, 8.0, 50.0):
        q, inside, axes, dirs = beam_box()
        e = ff.escape_fraction(q, inside, axes, np.array([1.0, 0, 0]), (0.4, 1.0),
                               np.full(3, sigma))
        assert np.all((e >= 0.0) & (e <= 1.0)) and np.ptp(e) < 1e-12
        fractions.append(e[0])
    assert fractions[0] > 0.85 and fractions[-1] < 0.05
    assert np.all(np.diff(fractions) < 0.0)


def test_the_blend_weight_ramps_between_the_thresholds():
    e = np.array([0.0, ff.ESCAPE_LOW, 0.5 * (ff.ESCAPE_LOW + ff.ESCAPE_HIGH), ff.ESCAPE_HIGH, 1.0])
    assert ff.blend_weight(e).tolist() == pytest.approx([0.0, 0.0, 0.5, 1.0, 1.0])


def test_a_thin_box_takes_the_exact_flight_and_a_dense_one_the_walk():
    n = (24, 12, 12)
    v = np.tile([0.0, -1.0, 0.0], (int(np.prod(n)), 1))   # the camera far along -y
    q, inside, axes, dirs = beam_box(n)
    thin = ff.first_flight(q, inside, axes, dirs, v, 0.85, np.full(3, 0.05))
    assert thin is not None and thin.weight.tolist() == [1.0, 1.0, 1.0]
    f = thin.field
    assert f.shape == n + (3,) and f.dtype == np.float32 and np.all(np.isfinite(f))
    # light that left the beam reaches the whole box, most of it near the beam
    assert np.all(f[..., 0] > 0.0)
    assert f[12, 6, 6, 0] > 5.0 * f[12, 0, 0, 0]
    # the second flight: scattered again inside the box (sigma_s* 0.04 of the 0.05 /m), it
    # adds light, less than sigma_s* / sigma_t* of the first's (most of the first flights
    # leave this box)
    both = ff.first_flight(q, inside, axes, dirs, v, 0.85, np.full(3, 0.05), np.full(3, 0.04))
    added = float(both.field.sum() - f.sum())
    assert 0.0 < added < 0.8 * float(f.sum())
    assert np.all(both.field >= f - 1e-6 * f.max())
    q, inside, axes, dirs = beam_box(n)
    assert ff.first_flight(q, inside, axes, dirs, v, 0.85, np.full(3, 50.0)) is None
    # nothing to fly: no power, or a medium that does not scatter
    assert ff.first_flight(np.zeros(n + (3,)), inside, axes, dirs, v, 0.8,
                           np.full(3, 0.05)) is None
    assert ff.first_flight(q, inside, axes, dirs, v, 0.8, np.zeros(3)) is None
    # a channel that does not scatter nor absorb flies nowhere; the others still do
    q[..., 2] = 0.0
    part = ff.first_flight(q, inside, axes, dirs, v, 0.8, np.array([0.05, 0.05, 0.0]))
    assert part.weight.tolist() == [1.0, 1.0, 0.0] and not np.any(part.field[..., 2])


def test_channels_of_one_source_shape_fly_once():
    """A grey medium under a coloured light: channels whose sources are proportional share
    one convolution, and give what separate ones give."""
    n = (16, 10, 10)
    v = np.tile([0.0, -0.6, 0.8], (int(np.prod(n)), 1))
    q, inside, axes, dirs = beam_box(n)
    q *= np.array([1.0, 0.5, 0.2])
    shared = ff.first_flight(q, inside, axes, dirs, v, 0.85, np.full(3, 0.05))
    apart = q.copy()
    apart[8, 5, 5, 1] *= 1.001   # no longer proportional: three convolutions
    alone = ff.first_flight(apart, inside, axes, dirs, v, 0.85, np.full(3, 0.05))
    assert np.allclose(shared.field[..., 1], 0.5 * shared.field[..., 0], rtol=1e-5)
    assert np.allclose(shared.field, alone.field, rtol=2e-3, atol=1e-6 * shared.field.max())


@pytest.mark.parametrize("spread", [(0.15, 0.03), (0.1, 0.1), (0.01, 0.12)])
def test_the_camera_directions_interpolate_across_the_view(spread):
    """Directions to the camera spread along one or both axes of the view: a grid along the
    two principal axes, each point's bilinear mix within half a diagonal of the grid's step
    of its own direction (one axis alone left the second's spread: up to 15 degrees)."""
    rng = np.random.default_rng(0)
    v = rng.normal(size=(2000, 3)) * [spread[0], spread[1], 0.0] + [0.0, 0.0, -1.0]
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    dirs, wts = ff.camera_directions(v, v)
    assert 2 <= len(dirs) <= ff.MAX_DIRECTIONS
    assert np.allclose(wts.sum(axis=1), 1.0) and np.all(wts >= 0.0)
    mix = wts @ dirs
    mix /= np.linalg.norm(mix, axis=1, keepdims=True)
    off = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", mix, v), -1, 1)))
    step = np.degrees(ff.DIRECTION_STEP)
    assert np.percentile(off, 90) < 0.75 * step   # half a diagonal: 0.71 step
    # the same test of the directions along the first axis alone fails for 2-D spreads
    c0 = v.mean(axis=0) / np.linalg.norm(v.mean(axis=0))
    ax = np.linalg.svd(v - c0, full_matrices=False)[2][0]
    along = c0 + np.outer(v @ ax, ax)
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    off1 = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", along, v), -1, 1)))
    if min(spread) > 0.05:
        assert np.percentile(off1, 90) > np.percentile(off, 90) + 3.0
    one, w1 = ff.camera_directions(v[:1], v[:1])
    assert len(one) == 1 and np.allclose(w1, 1.0)


def test_a_camera_inside_the_medium_convolves_at_most_max_directions():
    """Directions to the camera from all round it (a camera in the fog): the grid's step
    widens so that no more than MAX_DIRECTIONS convolutions are made; weights still sum to 1."""
    v = ff.sphere_directions(3000)
    dirs, wts = ff.camera_directions(v, v)
    assert 4 <= len(dirs) <= ff.MAX_DIRECTIONS
    assert np.allclose(wts.sum(axis=1), 1.0) and np.all(wts >= 0.0)


@pytest.mark.parametrize("g", [0.0, 0.5, 0.85])
def test_the_walk_after_the_exact_flights_is_the_walk_less_their_paths(g):
    """Per level, weight(all) - weight(exact_flights=1) = int e^-(sigma_a + sigma_s*) l dl over
    the level's paths (those that have not scattered again), and weight(1) - weight(2) =
    int sigma_s* l e^-(sigma_a + sigma_s*) l dl (those that scattered once more); the mean
    cosine drops with each."""
    ss, sa, h, n = np.array([4.0, 2.0, 0.5]), np.array([0.3, 0.1, 0.05]), 0.05, 10
    rho = np.array([1.0])
    tabs = [table_lookup(level_table(g, ss, sa, h, n, exact_flights=e), rho)[:, 0]
            for e in (0, 1, 2)]
    keep = 1.0 - delta_fraction(g)
    for c in range(3):
        l_tr = 1.0 / (ss[c] * max(1.0 - g, 1e-6))
        s1, st = ss[c] * keep, sa[c] + ss[c] * keep
        for k, (lo, hi, _) in enumerate(level_paths(h, n, np.array(l_tr), delta_g(g))):
            straight = (np.exp(-st * lo) - np.exp(-st * hi)) / st
            l = np.linspace(lo, hi, 20001)
            once = np.trapz(s1 * l * np.exp(-st * l), l)
            assert tabs[0][k, c] - tabs[1][k, c] == pytest.approx(float(straight), rel=1e-6,
                                                                  abs=1e-12)
            assert tabs[1][k, c] - tabs[2][k, c] == pytest.approx(float(once), rel=1e-5,
                                                                  abs=1e-10)
    for a, b in zip(tabs, tabs[1:]):
        assert np.all(b[:, :3] >= 0.0) and np.all(b[:, :3] <= a[:, :3] + 1e-15)
        if g > 0:
            assert np.all(b[:, 3:] <= a[:, 3:] + 1e-12) and np.all(b[:, 3:] >= 0.0)
    with pytest.raises(ValueError):
        level_table(g, ss, sa, h, n, exact_flights=3)


@pytest.mark.parametrize("g", [-0.4, 0.3, 0.85])
def test_the_second_flight_turns_twice_out_of_the_peak(g):
    """The second flight's direction is outside_peak composed with itself: normalised, its
    mean cosine the square of one scattering's, equal to a direct integral over the sphere,
    HG(g^2) where there is no peak."""
    mu = np.linspace(-1.0, 1.0, 200001)
    twice = ff.peak_free_twice(mu, g)
    once = outside_peak(mu, g)
    assert np.trapz(twice, mu) * 2 * np.pi == pytest.approx(1.0, rel=1e-4)
    m1 = np.trapz(once * mu, mu) * 2 * np.pi
    assert np.trapz(twice * mu, mu) * 2 * np.pi == pytest.approx(m1 * m1, rel=2e-3, abs=1e-6)
    om = ff.sphere_directions(200000)
    d = np.array([0.0, 0.0, 1.0])
    for c in (0.95, 0.5, -0.6):
        w = np.array([np.sqrt(1 - c * c), 0.0, c])
        direct = np.mean(outside_peak(om @ d, g) * outside_peak(om @ w, g)) * 4 * np.pi
        assert float(ff.peak_free_twice(c, g)) == pytest.approx(float(direct), rel=0.01)
    if g <= 0:
        assert np.allclose(twice[::1000], hg(mu[::1000], g * g))
    half = ff.first_phase(mu, g, 0.5, order=2)
    assert np.allclose(half, 0.5 * twice + 0.5 / (4 * np.pi))


def test_the_flattened_level_takes_the_first_flight_by_its_weight():
    """One light whose walk is zero: the flattened level is the exact flight times its weight;
    a weight of 0 leaves what the walk gives."""
    from mpp_render import march
    from mpp_render.media import prepare
    from mpp_render.precompute import MultipleField
    from mpp_render.scene import Camera, Light, Medium
    n = 8
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.1
    pm = prepare(Medium("box", np.ones((n, n, n), np.float32), i2w, np.full(3, 1.0),
                        np.full(3, 0.1), 0.5, source="MESH"))
    c2w = np.array([[1.0, 0, 0, 0.3], [0, 0, -1, -4.0], [0, 1, 0, 0.4], [0, 0, 0, 1]])
    cam = Camera("PERSP", c2w, 8, 8, (-0.3, 0.3, -0.3, 0.3), 0.1, 100.0)
    light = Light("SUN", "sun", np.full(3, 2.0), direction=np.array([0.0, 0.0, -1.0]))
    shape = (6, 6, 6)
    levels = [np.zeros(shape + (3,), np.float32), np.zeros((3, 3, 3, 3), np.float32)]
    field = np.random.default_rng(1).random(shape + (3,)).astype(np.float32)
    table = level_table(0.5, pm.sigma_s, pm.sigma_a, 0.1, 2)
    after = level_table(0.5, pm.sigma_s, pm.sigma_a, 0.1, 2, exact_flights=2)
    mf = MultipleField(2, 0.2, levels, ff.FirstFlight(field, np.array([1.0, 0.5, 0.0])))
    out = flatten_levels(pm, [mf], [light], table, cam, after)
    assert np.allclose(out, field * np.array([1.0, 0.5, 0.0], np.float32))
    levels[0][:] = 1.0
    mf0 = MultipleField(2, 0.2, levels, ff.FirstFlight(field, np.zeros(3)))
    walk = flatten_levels(pm, [MultipleField(2, 0.2, levels)], [light], table, cam)
    assert np.array_equal(flatten_levels(pm, [mf0], [light], table, cam, after), walk)


@pytest.mark.parametrize("g", [-0.99, 0.0, 0.5, 0.99])
@pytest.mark.parametrize("sigma", [1e-6, 0.05, 1e4])
def test_stiff_flights_stay_finite(g, sigma):
    """Anisotropy near +-1, a nearly transparent and an opaque medium (optical depth 1e3 per
    lattice step), albedo 1 (both flights), the light from all sides (its mean direction 0):
    finite, non-negative."""
    n = (12, 8, 8)
    q, inside, axes, dirs = beam_box(n)
    dirs = np.random.default_rng(2).normal(size=dirs.shape)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs[: len(dirs) // 2] = -dirs[len(dirs) - len(dirs) // 2:][: len(dirs) // 2]
    v = np.tile([0.0, -1.0, 0.0], (int(np.prod(n)), 1))
    out = ff.first_flight(q, inside, axes, dirs, v, g, np.full(3, sigma), np.full(3, sigma))
    if sigma >= 1e4:
        assert out is None   # every flight ends in its own cell: the walk alone
    else:
        assert out is not None and out.weight.tolist() == [1.0, 1.0, 1.0]
        assert np.all(np.isfinite(out.field)) and np.all(out.field >= 0.0)
        assert out.field.max() > 0.0


def test_the_flights_are_the_same_on_any_number_of_threads_and_stop_on_esc():
    """The camera directions' convolutions run on threads and are added in order: the same
    bits on 1 and 3 threads; Esc (should_cancel) at any point raises Cancelled, without a hang."""
    n = (20, 12, 12)
    q, inside, axes, dirs = beam_box(n)
    rng = np.random.default_rng(0)
    v = rng.normal(size=(int(np.prod(n)), 3)) * [0.4, 0.05, 0.0] + [0.0, -1.0, 0.0]
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    args = (q, inside, axes, dirs, v, 0.85, np.full(3, 0.05), np.full(3, 0.04))
    one = ff.first_flight(*args, threads=1)
    three = ff.first_flight(*args, threads=3)
    assert len(ff.camera_directions(v, v)[0]) > 3
    assert np.array_equal(one.field, three.field)
    # the kernels' bases beyond half of the FFT memory: built per direction, the same flights
    apart = ff.first_flight(*args, threads=3, fft_memory=1 << 16)
    assert np.array_equal(one.field, apart.field)
    for k in (1, 2, 4, 8):
        calls = [0]

        def esc():
            calls[0] += 1
            return calls[0] > k

        with pytest.raises(Cancelled):
            ff.first_flight(*args, should_cancel=esc, threads=3)
