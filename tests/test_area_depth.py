"""An area light inside uneven smoke: the optical depth from a lit point to the sampled emitter
point.  The field holds the depth to the emitter's centre; stretched to the sampled point's
distance (lights.path_stretch) it is exact only where the medium is the same across the
emitter.  Within media.disc_reaches of the emitter the march marches each sampled point's
own path (kernels_np.disc_correction), as for a lamp's disc."""
import numpy as np
import pytest

from mpp_render import kernels
from mpp_render.kernels_np import _extinction
from mpp_render.lights import extent_radius, has_extent
from mpp_render.march import pack_lights
from mpp_render.media import disc_reaches, prepare
from mpp_render.precompute import precompute
from mpp_render.scene import Camera, Light, Medium, World
from rays import march_twins

needs_c = pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")

N, VOX = 32, 0.05                    # a 1.6 m cube of 5 cm voxels
THIN, DENSE = 0.5, 8.0               # sigma_t (1/m) for y < 0 and y > 0, albedo 1, g 0
SIDE, POWER, HEIGHT = 0.4, 100.0, 0.2  # the emitter: side (m), power (W), height of its plane


def scene():
    """The cube (its density steps at y = 0 across the emitter), a square area light facing
    down over the step, and the precompute's fields with the optical depth to the emitter's
    centre marched exactly at every voxel (``depth``; the sweep's own error next to the step,
    1-3 %, is not what is tested)."""
    i2w = np.eye(4)
    i2w[:3, :3] *= VOX
    i2w[:3, 3] = -0.5 * (N - 1) * VOX
    rho = np.full((N, N, N), THIN, np.float32)
    rho[:, N // 2:, :] = DENSE
    pm = prepare(Medium("step", rho, i2w, np.ones(3), np.zeros(3), 0.0))
    m = np.eye(4)
    m[:3, 3] = [0.0, 0.0, HEIGHT]
    light = Light("AREA", "a", np.full(3, POWER), position=m[:3, 3].copy(), matrix=m,
                  size_x=SIDE, direction=np.array([0.0, 0.0, -1.0]))
    pre = precompute([pm], [light], World(), Camera("PERSP", np.eye(4), 4, 4, (-1, 1, -1, 1)),
                     multiple=False)
    field = pre.fields[0]
    assert field.shape[3] == 7   # the density, the light's depth, its emitter's depth change
    idx = np.argwhere(np.ones(field.shape[:3], bool)).astype(np.float64)
    a = np.linalg.inv(np.vstack([pm.w2i, [0.0, 0.0, 0.0, 1.0]]))
    pts = idx @ a[:3, :3].T + a[:3, 3]
    field[..., 1:4] = depth(pm, pts, m[:3, 3]).reshape(field.shape[:3])[..., None]
    return pm, light, pre


def sigma(pm, p):
    """sigma_t (1/m) at world points ``p`` (N,3): the trilinear density, as the march reads it."""
    return _extinction(pm.grid[..., None], pm.w2i, pm.threshold, pm.sigma_t, None, p)[:, 0]


def depth(pm, xs, y, n=200):
    """Optical depth from each of the points ``xs`` (N,3) to the point ``y`` (3,) or points
    ``y`` (N,3): the midpoint rule over ``n`` steps."""
    seg = np.broadcast_to(y, xs.shape) - xs
    k = (np.arange(n) + 0.5) / n
    out = np.empty(len(xs))
    for a in range(0, len(xs), 4096):
        s = seg[a:a + 4096]
        p = xs[a:a + 4096, None, :] + s[:, None, :] * k[None, :, None]
        out[a:a + 4096] = sigma(pm, p.reshape(-1, 3)).reshape(len(s), n).mean(axis=1) \
            * np.linalg.norm(s, axis=1)
    return out


def ray_points(n):
    """Midpoints of ``n`` equal steps along the test ray: x from -0.3 to 0.3 m at y = 0.075,
    z = 0.125 (in the dense half, under the emitter, on a row of voxel centres: the field's
    trilinear read of the depth is exact there but for x); the ray and its step (m)."""
    o, d = np.array([-0.3, 0.075, 0.125]), np.array([1.0, 0.0, 0.0])
    h = 0.6 / n
    return o + d * ((np.arange(n) + 0.5) * h)[:, None], o, d, h


def exact_single(pm, n_ray=60, n_em=24):
    """The single scattering along the test ray by quadrature: for each point, the camera's
    transmittance from the ray's origin, sigma_s, the phase 1 / (4 pi), and the emitter's
    light L_e cos / r^2 e^{-tau} over a midpoint grid of its front face, tau marched through
    the trilinear density (``depth``)."""
    xs, o, d, h = ray_points(n_ray)
    u = (np.arange(n_em) + 0.5) / n_em - 0.5
    ys = np.array([[a * SIDE, b * SIDE, HEIGHT] for a in u for b in u])
    dA = (SIDE / n_em) ** 2
    le = POWER / (np.pi * SIDE * SIDE)
    total, t_cam = 0.0, 0.0
    for x in xs:
        seg = ys - x
        r = np.linalg.norm(seg, axis=1)
        tau = depth(pm, np.repeat(x[None], len(ys), 0), ys)
        e = np.sum(le * (seg[:, 2] / r) / r ** 2 * np.exp(-tau)) * dA
        s = sigma(pm, x[None])[0]
        t_here = t_cam + 0.5 * h * s
        total += np.exp(-t_here) * s * e / (4.0 * np.pi) * h
        t_cam += h * s
    return total


def march_at(pm, light, pre, reach, n=4000):
    """The march's mean single scattering along the test ray over ``n`` keys (each a fresh
    emitter point per step)."""
    _, o, d, _ = ray_points(1)
    inputs = kernels.MarchInputs(
        np.repeat(o[None], n, 0), np.repeat(d[None], n, 0), np.zeros(n), np.full(n, 0.6),
        np.ones(n), np.arange(n, dtype=np.uint32) * 2654435761 % 2**32, pre.fields, [pm.w2i],
        [pm.sigma_s], [pm.sigma_t], [pm.g], [pm.threshold], [pm.voxel_size],
        pack_lights([light], pre.layout), -1, 0.01, 0.01, 1e10, disc_reach=[reach])
    return inputs


def test_an_area_light_is_marched_near_it_only_in_uneven_media():
    """media.disc_reaches gives an area light Tuning.disc_exact half-diagonals (or
    disc_voxels voxels) where the media round it are uneven, 0 where they are not."""
    pm, light, _ = scene()
    assert has_extent(light) and extent_radius(light) == pytest.approx(SIDE / np.sqrt(2))
    for shape, want in (("RECTANGLE", np.hypot(1.0, 0.5) / 2), ("DISK", 0.5), ("ELLIPSE", 0.5)):
        other = Light("AREA", "b", np.ones(3), matrix=np.eye(4), shape=shape, size_x=1.0,
                      size_y=0.5)
        assert extent_radius(other) == pytest.approx(want), shape
    sun = Light("SUN", "s", np.ones(3), direction=np.array([0.0, 0.0, -1.0]))
    assert not has_extent(sun) and extent_radius(sun) == 0.0
    assert disc_reaches([pm], [light], 2.0) == [pytest.approx(np.sqrt(2) * SIDE)]
    assert disc_reaches([pm], [light], 2.0, 40.0) == [pytest.approx(40 * VOX)]
    i2w = np.eye(4)
    i2w[:3, :3] *= VOX
    i2w[:3, 3] = -0.5 * (2 * N - 1) * VOX
    flat = prepare(Medium("flat", np.ones((2 * N,) * 3, np.float32), i2w, np.ones(3),
                          np.zeros(3), 0.0))
    assert disc_reaches([flat], [light], 2.0) == [0.0]


@needs_c
def test_an_area_lights_points_get_their_own_depth_in_uneven_smoke():
    """Along a ray under the emitter, just inside the dense half: with each sampled emitter
    point's path marched (within the reach) the march's mean single scattering is the
    quadrature's within 1 % (the twins agree sample for sample); beyond the reach the
    precompute's change to the stretched depth (precompute/discdepth.py, the field's disc
    channels) within 1.5 %; the centre's depth stretched alone misses by more than 2 %
    (measured 2026-12-07: +0.27 %, +0.58 %, -3.1 %; a row between the voxel centres,
    y = 0.05 and z = 0.1, the march's +2.6 % and the stretch's -8.3 %, the field's trilinear
    read of the depth adding its own +2.6 % to both)."""
    pm, light, pre = scene()
    exact = exact_single(pm)
    reach = disc_reaches([pm], [light], 2.0)[0]
    _, near = march_twins(march_at(pm, light, pre, reach))
    got = near.single[:, 0].mean()
    far = march_twins(march_at(pm, light, pre, 0.0))[1].single[:, 0].mean()
    dc = pre.layout.disc_channels[0]
    field = pre.fields[0]
    assert np.abs(field[..., dc:dc + 3]).max() > 0.01
    field[..., dc:dc + 3] = 0.0
    bare = kernels.march(march_at(pm, light, pre, 0.0), backend="c").single[:, 0].mean()
    assert got == pytest.approx(exact, rel=0.01), (got, far, bare, exact)
    assert far == pytest.approx(exact, rel=0.015), (got, far, bare, exact)
    assert abs(bare / exact - 1.0) > 0.02, (got, far, bare, exact)


def test_an_area_lights_source_takes_its_points_own_depth():
    """The precompute's transmittance from the emitter (lights.disc_transmittance, what the
    first-scattering source and the paths' starts read) at points round the density step:
    with each emitter point's path marched (area_depth_change, ``reach``) the mean over the
    emitter's solid angle of a 48 x 48 brute force with exact depths within 10 % at each
    point and 3 % over them, with 6 points per axis within 5 % each (measured 2026-12-07:
    at the default 4 per axis -3 % to +9 %, their sum +0.2 %; at 6 -1.5 % to +4.7 %; at 3
    -20 % to +6.5 %); the stretched centre's depth alone misses by up to 73 % (a step
    across the emitter is Gauss-Legendre's worst case).  In a homogeneous medium the
    change is 0."""
    from mpp_render.lights import area_depth_change, disc_transmittance
    pm, light, _ = scene()

    def marched(p, w, length):
        return np.repeat(depth(pm, p, p + w * length[:, None])[:, None], 3, axis=1)

    xs = np.array([[0.0, 0.05, 0.1], [0.1, -0.05, 0.0], [0.0, 0.1, -0.2], [0.2, 0.0, -0.4],
                   [0.0, -0.2, -0.3]])
    centre = np.array([0.0, 0.0, HEIGHT])
    tau = np.repeat(depth(pm, xs, centre)[:, None], 3, axis=1)
    u = (np.arange(48) + 0.5) / 48 - 0.5
    ys = np.array([[a * SIDE, b * SIDE, HEIGHT] for a in u for b in u])
    brute = []
    for x in xs:
        v = x - ys
        d = np.linalg.norm(v, axis=1)
        w = np.maximum(-v[:, 2], 0.0) / d ** 3
        brute.append(np.sum(w * np.exp(-depth(pm, np.repeat(x[None], len(ys), 0), ys))) / w.sum())
    brute = np.array(brute)
    got = disc_transmittance(light, xs, tau, VOX, depth=marched, reach=np.inf)[:, 0]
    fine = disc_transmittance(light, xs, tau, VOX, nodes=36, depth=marched, reach=np.inf)[:, 0]
    plain = disc_transmittance(light, xs, tau, VOX)[:, 0]
    assert np.all(np.abs(got / brute - 1.0) < 0.10), (got, brute)
    assert abs(got.sum() / brute.sum() - 1.0) < 0.03, (got, brute)
    assert np.all(np.abs(fine / brute - 1.0) < 0.05), (fine, brute)
    assert np.max(np.abs(plain / brute - 1.0)) > 0.5, (plain, brute)
    flat = np.zeros((len(xs), 3))
    assert np.array_equal(area_depth_change(light, xs, flat, VOX, lambda p, w, n: flat, 3), flat)


@pytest.mark.parametrize("height,rate", [(0.05, 12.0), (0.2, 12.0)])
def test_the_paths_draw_their_first_light_by_its_transmittance(height, rate):
    """A path's first scattering below a wide emitter in a dense medium (0.5 m square, mean
    extinction ``rate`` 1/m towards it): the light arrives mostly along the shorter paths.
    With the start's rate (paths.PathInputs.start_rate) the drawn directions' mean cosine
    to the emitter's normal is within 2.5 % of the transmittance-weighted one (a 400 x 400
    quadrature over the emitter), by the solid angle alone more than 5 % off (measured
    2026-12-07: at 0.05 m -0.686 and -0.588 against -0.696; at 0.2 m -0.838 and -0.789
    against -0.844)."""
    import dataclasses
    from mpp_render.lights import pack_light
    from mpp_render.paths import PathInputs, start_directions
    m = np.eye(4)
    light = Light("AREA", "a", np.full(3, 100.0), position=m[:3, 3].copy(), matrix=m,
                  size_x=0.5, direction=np.array([0.0, 0.0, -1.0]))
    n = 100_000
    pos = np.tile([0.0, 0.0, -height], (n, 1))
    keys = (np.arange(n, dtype=np.uint64) * 2654435761 % 2**32).astype(np.uint32)
    z3 = np.zeros(3)
    inp = PathInputs(np.ones((4, 4, 4), np.float32), np.zeros((3, 4)), np.eye(3), z3 + 1.0,
                     z3 + 1.0, 0.0, 1, np.zeros((4, 4, 4, 3)), pos[:1], np.ones((1, 3)),
                     np.array([[0.0, 0.0, -1.0]]), np.ones(1), 1.0, 1, 0,
                     light=pack_light(light), start_rate=np.array([rate]))
    start = np.zeros(n, np.int64)
    rated = start_directions(inp, keys, start, pos)[:, 2].mean()
    plain = start_directions(dataclasses.replace(inp, start_rate=None), keys, start, pos)[:, 2].mean()
    u = (np.arange(400) + 0.5) / 400 - 0.5
    ys = np.stack(np.meshgrid(u * 0.5, u * 0.5, [0.0], indexing="ij"), -1).reshape(-1, 3)
    v = pos[0] - ys
    d = np.linalg.norm(v, axis=1)
    w = np.maximum(-v[:, 2], 0.0) / d ** 3 * np.exp(-rate * d)
    target = float(np.sum(w * v[:, 2] / d) / w.sum())
    assert rated == pytest.approx(target, rel=0.025), (rated, plain, target)
    assert abs(plain / target - 1.0) > 0.05, (rated, plain, target)


def test_no_exact_zone_where_the_fold_finds_no_change():
    """The march marches the emitter points' own paths only where the fold found a medium
    uneven across the emitter (discdepth.disc_changes): the density step keeps its reach;
    with the disc channels 0 (what the fold's pilot leaves where no depth changes, e.g. a
    lamp in a homogeneous box whose faces make media.disc_reaches count it uneven) the
    reach is 0 and no sample marches two paths."""
    from mpp_render.march import MarchContext
    from mpp_render.precompute.discdepth import disc_changes
    pm, light, pre = scene()
    k = pre.layout.disc_channels[0]
    assert disc_changes(pre.fields, k)
    ctx = MarchContext([pm], pre.fields, pre.layout, [light], 0.01)
    assert ctx.disc_reach[0] > 0.0
    assert ctx.disc_reach[0] == pytest.approx(disc_reaches([pm], [light], 2.0, 16.0)[0])
    flat = [f.copy() for f in pre.fields]
    flat[0][..., k:k + 3] = 0.0
    assert not disc_changes(flat, k)
    assert MarchContext([pm], flat, pre.layout, [light], 0.01).disc_reach == [0.0]


def test_the_distance_spread_bounds_the_emitters_distances():
    """lights.distance_spread (where the paths' first light is drawn by its transmittance,
    lightpaths.start_rates): at least the spread of the distances to points drawn over a
    square emitter and a lamp's facing disc, and within 5 % of it at points near and far,
    beside and behind."""
    from mpp_render.lights import distance_spread
    rng = np.random.default_rng(3)
    m = np.eye(4)
    square = Light("AREA", "a", np.ones(3), position=np.zeros(3), matrix=m, size_x=0.5,
                   direction=np.array([0.0, 0.0, -1.0]))
    lamp = Light("POINT", "p", np.ones(3), position=np.zeros(3), matrix=m, radius=0.2)
    pts = np.array([[0.0, 0.0, -0.1], [0.0, 0.0, -5.0], [3.0, 0.0, 0.0], [0.1, 0.1, 0.0],
                    [0.4, -0.2, 0.3]])
    ys = np.column_stack([rng.uniform(-0.25, 0.25, (40000, 2)), np.zeros(40000)])
    got = distance_spread(square, pts)
    sampled = np.array([np.ptp(np.linalg.norm(p - ys, axis=1)) for p in pts])
    assert np.all(got >= sampled) and np.all(got <= 1.05 * sampled), (got, sampled)
    # a disc of radius r facing the point: its rim at sqrt(d^2 + r^2), its centre at d
    d = np.linalg.norm(pts, axis=1)
    np.testing.assert_allclose(distance_spread(lamp, pts), np.sqrt(d * d + 0.04) - d)
