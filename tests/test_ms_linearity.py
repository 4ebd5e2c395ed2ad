"""Multiple scattering is linear in the light: doubling every light's power (and the sky)
doubles every radiance pass, and changes neither transmittance nor depth."""
import copy

import numpy as np

from mpp_render.render import render
from mpp_render.scene import Light

from test_stiff import cube, scene


def lit_scene(world):
    lights = [Light("SUN", "sun", np.array([3.0, 2.5, 2.0]), direction=np.array([0.3, 0.2, -0.93])),
              Light("POINT", "lamp", np.array([40.0, 60.0, 80.0]), position=np.array([1.8, -0.6, 0.4]),
                    radius=0.1)]
    rng = np.random.default_rng(7)
    grid = (rng.random((10, 10, 10)) * 2.0).astype(np.float32)
    media = [cube(sigma_s=3.0, sigma_a=0.4, g=0.6, n=10, grid=grid),
             cube(sigma_s=1.0, sigma_a=0.0, g=0.0, n=6, size=1.0, source="MESH")]
    return scene(media, lights, width=16, height=12, world=world)


def doubled(desc):
    d = copy.deepcopy(desc)
    for light in d.lights:
        light.strength = 2.0 * np.asarray(light.strength)
    d.world.color = 2.0 * np.asarray(d.world.color)
    return d


def test_doubling_every_light_doubles_every_radiance_pass():
    for world in (0.0, 0.2):
        desc = lit_scene(world)
        a = render(desc).passes
        b = render(doubled(desc)).passes
        assert a["Volume Multiple"].max() > 0 and a["Volume Single"].max() > 0
        for name in ("Volume Single", "Volume Multiple"):
            assert np.allclose(b[name], 2.0 * a[name], rtol=1e-5, atol=1e-9), name
        assert np.allclose(b["Combined"][..., :3], 2.0 * a["Combined"][..., :3], rtol=1e-5, atol=1e-9)
        assert np.array_equal(b["Transmittance"], a["Transmittance"])
        assert np.array_equal(b["Depth"], a["Depth"])


def test_one_light_at_a_time_adds_up():
    """Passes of the two lights rendered separately sum to the passes of both together."""
    desc = lit_scene(0.0)
    both = render(desc).passes
    parts = []
    for keep in range(2):
        d = copy.deepcopy(desc)
        for i, light in enumerate(d.lights):
            if i != keep:
                light.strength = np.zeros(3)
        parts.append(render(d).passes)
    for name in ("Volume Single", "Volume Multiple"):
        assert np.allclose(parts[0][name] + parts[1][name], both[name], rtol=1e-5, atol=1e-9), name


def test_infinite_medium_point_light_follows_diffusion_theory():
    """A point light in a homogeneous, isotropically scattering medium much larger than the
    diffusion length L = 1/sqrt(3 sigma_a sigma_t): far from the light the collided fluence is
    diffusion theory's phi(r) = (sigma_s/sigma_t) P exp(-r/L) / (4 pi D r), D = 1/(3 sigma_t)
    (a Monte Carlo of the same medium agrees with it to 5 % at 1-2.5 L, see docs/method.md).
    The MPP model's multiply scattered in-scatter F (what the march multiplies by sigma_s) is
    phi/(4 pi) for isotropic scattering; averaged over spheres of radius r it must follow
    diffusion within 25 % at r = 1.25, 1.75 and 2.5 L (measured 0.86-0.98: the lattice and the
    path-length quadrature) and decay like it, its decay length within ~15 % of diffusion's:
    the ratio changes by < 20 % over that range (measured 13 %), wherever the light sits on
    the pyramid's lattice.  Before the pyramid averaged the source around the light
    (precompute.cell_mean_source), a light on a lattice point gave 1e6 times too much
    multiple scattering (its 1/r^2 read at r ~ 0)."""
    from mpp_render.kernels_np import multiple_source
    from mpp_render.walk import level_table
    from mpp_render.media import prepare
    from mpp_render.precompute import precompute
    from mpp_render.scene import Camera, Medium, World

    albedo, sigma_t = 0.9, 1.0
    ss, sa = albedo * sigma_t, (1 - albedo) * sigma_t
    L = 1.0 / np.sqrt(3.0 * sa * sigma_t)
    size, n = 14.0 * L, 96
    vox = size / n
    i2w = np.eye(4)
    i2w[:3, :3] *= vox
    i2w[:3, 3] = -size / 2 + vox / 2
    pm = prepare(Medium("fog", np.ones((n, n, n), np.float32), i2w, np.full(3, ss), np.full(3, sa), 0.0))
    power = 1000.0
    cam = Camera("PERSP", np.eye(4), 4, 4, (-1, 1, -1, 1))
    D = 1.0 / (3.0 * sigma_t)
    # the light on a point of the pyramid's lattice (padded index 2j: world -vox/2) and halfway
    # between two: the result must not depend on where the light falls on the lattice
    for where in (np.full(3, -0.5 * vox), np.full(3, 0.5 * vox)):
        light = Light("POINT", "lamp", np.full(3, power), position=where)
        pre = precompute([pm], [light], World(), cam, multiple=True)
        msf = pre.multiple[0][0]
        assert msf.stride == 2
        table = level_table(0.0, ss, sa, msf.h, len(msf.levels))
        rng = np.random.default_rng(3)
        ratios = []
        for r in np.array([1.25, 1.75, 2.5]) * L:
            u = rng.normal(size=(3000, 3))
            x = light.position + r * u / np.linalg.norm(u, axis=1, keepdims=True)
            F = multiple_source([(msf.levels, msf.stride, msf.h)], table, np.ones(len(x)), x,
                                pm.w2i, np.zeros((1, len(x))), np.zeros((len(x), 3)))[:, 0]
            phi = (ss / sigma_t) * power * np.exp(-r / L) / (4 * np.pi * D * r)
            ratios.append(4 * np.pi * F.mean() / phi)
        ratios = np.array(ratios)
        print("light at", where, "F / diffusion at 1.25, 1.75, 2.5 L:", np.round(ratios, 3))
        assert np.all(np.abs(ratios - 1.0) < 0.25), ratios
        assert ratios.max() / ratios.min() < 1.20, ratios


def test_multiple_scattering_resolution_sets_the_pyramid_lattice_and_is_cached_apart():
    """Settings.multiple_resolution is the light pyramid's lattice (points along the longest
    side, never finer than the voxels): a coarse one has fewer base points, a render with
    another resolution does not reuse the cached pyramids, and every setting gives a finite,
    non-negative Volume Multiple of the same order (the pass shifts with the lattice)."""
    from mpp_render import cache, precompute as P
    from mpp_render.media import prepare
    from test_stiff import check

    grid = np.full((40, 40, 40), 1.0, np.float32)
    desc = scene([cube(sigma_s=4.0, sigma_a=0.2, n=40, grid=grid)], width=16, height=12, world=0.0)
    pm = prepare(desc.media[0])
    pre = {r: P.precompute([pm], desc.lights, desc.world, desc.camera, multiple=True,
                           multiple_resolution=r) for r in (8, 20, 400)}
    bases = {r: p.multiple[0][0].levels[0].shape[:3] for r, p in pre.items()}
    assert max(bases[8]) < max(bases[20]) < max(bases[400])
    assert max(bases[400]) == max(pm.grid.shape)   # never finer than the voxels
    c = cache.Cache(limit=1 << 30)
    kw = dict(n_dirs=8, seed=0, multiple=True, cache=c)
    got = [cache.precompute_cached([pm], desc.lights, desc.world, desc.camera,
                                   multiple_resolution=r, **kw) for r in (16, 64, 16)]
    assert [g.stats["reused"] for g in got] == [[], [], ["lights"]]   # (no world light)
    assert got[0].multiple[0][0].stride != got[1].multiple[0][0].stride
    means = {}
    for r in (16, 64):
        d = copy.deepcopy(desc)
        d.settings.multiple_resolution = r
        means[r] = float(check(render(d))["Volume Multiple"].mean())
    print("Volume Multiple mean at resolution 16 / 64:", means[16] / means[64])
    assert means[16] > 0 and 0.5 < means[16] / means[64] < 2.0, means
