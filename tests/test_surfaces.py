"""Opaque surfaces: intersection, shadows on surfaces and in media, and the Principled BSDF
(energy, reciprocity, limits, tables against direct integration, the render pipeline)."""
import math

import numpy as np
import pytest

from mpp_render.render import render
from mpp_render.scene import Camera, Light, Medium, SceneDescription, Settings, Surface, World
from mpp_render import principled as S
from mpp_render import surfaces
from mpp_render.principled import Principled
from mpp_render.surfaces import intersect, prepare_surfaces, surface_params


def quad(z, half, albedo=0.5, name="plane", centre=(0.0, 0.0)):
    cx, cy = centre
    v = np.array([[cx - half, cy - half, z], [cx + half, cy - half, z],
                  [cx + half, cy + half, z], [cx - half, cy + half, z]], float)
    return Surface(name, v, np.array([[0, 1, 2], [0, 2, 3]]), np.full(3, albedo))


def test_intersect_closest_hit():
    ss = prepare_surfaces([quad(0.0, 1.0), quad(1.0, 0.5, name="upper")])
    o = np.array([[0.0, 0.0, 5.0], [0.9, 0.0, 5.0], [3.0, 0.0, 5.0], [0.0, 0.0, -1.0]])
    d = np.tile([0.0, 0.0, -1.0], (4, 1))
    t, tri = intersect(ss, o, d, np.full(4, 100.0))
    assert np.allclose(t[:2], [4.0, 5.0]) and tri[2] == -1 and tri[3] == -1
    assert tri[0] >= 2 and tri[1] < 2   # the upper quad's triangles come second


def top_down_scene(surfaces, media=(), sun_dir=(0.0, 0.0, -1.0)):
    cam = Camera("ORTHO", np.eye(4), 20, 20, (-2.0, 2.0, -2.0, 2.0))
    cam.cam_to_world[:3, 3] = [0, 0, 10]
    sun = Light("SUN", "sun", np.full(3, 3.0), direction=np.asarray(sun_dir, float))
    return SceneDescription(cam, [sun], list(media), surfaces=list(surfaces),
                            world=World(np.zeros(3)), settings=Settings(samples=4))


def test_lambertian_plane_under_sun_and_its_shadow():
    blocker = quad(1.0, 0.5, albedo=0.0, name="blocker")
    out = render(top_down_scene([quad(0.0, 3.0), blocker],
                                sun_dir=(math.sin(0.3), 0.0, -math.cos(0.3))))
    img = out.passes["Combined"][..., :3]
    # unshadowed ground: albedo / pi * E * cos
    want = 0.5 / math.pi * 3.0 * math.cos(0.3)
    assert np.allclose(img[1, 1], want, rtol=1e-6)
    # the blocker (|x| < 0.5, 1 m up, albedo 0) is black; the sun propagates towards +x, so
    # its shadow on the ground covers x in [-0.19, 0.81]; pixel column 13 sees x in [0.6, 0.8]
    assert np.all(img[10, 10] == 0.0)
    assert np.allclose(img[10, 3], want, rtol=1e-6)
    assert np.all(img[10, 13] == 0.0)
    assert np.all(out.passes["Depth"][1, 1] == 10.0)


def test_surface_casts_volumetric_shadow():
    n = 10
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.4
    i2w[:3, 3] = [-1.8, -1.8, 0.2]
    med = Medium("fog", np.ones((n, n, 3), np.float32), i2w, np.full(3, 0.2), np.zeros(3), 0.0)
    lit = render(top_down_scene([], [med]))
    shaded = render(top_down_scene([quad(2.0, 1.0, albedo=0.0, name="roof")], [med]))
    a = lit.passes["Volume Single"]
    b = shaded.passes["Volume Single"]
    assert a[10, 10].min() > 0
    # under the roof (which also hides the fog from the camera) -> nothing; far from it, as
    # before up to the jitter (the surfaces draw their own random numbers)
    assert np.all(b[10, 10] == 0)
    assert np.allclose(b[1, 1], a[1, 1], rtol=0.03)
    # a tilted sun puts fog beside the roof into its shadow: darker than without the roof
    tilt = (np.sin(0.5), 0.0, -np.cos(0.5))
    a = render(top_down_scene([], [med], sun_dir=tilt)).passes["Volume Single"]
    b = render(top_down_scene([quad(2.0, 1.0, albedo=0.0, name="roof")], [med],
                              sun_dir=tilt)).passes["Volume Single"]
    assert np.all(b[10, 16] < 0.8 * a[10, 16])


def test_glossy_plane_renders_the_bsdf_exactly():
    """Top-down orthographic camera and a sun: every pixel sees the same view and light, so
    each pixel is the BSDF times the sun's irradiance; a uniform sky adds albedo x sky."""
    tilt = np.array([np.sin(0.3), 0.0, -np.cos(0.3)])
    plane = quad(0.0, 3.0)
    plane.specular, plane.roughness = 0.04, 0.3
    desc = top_down_scene([plane], sun_dir=tilt)
    desc.world = World(np.array([0.2, 0.1, 0.05]))
    img = render(desc).passes["Combined"][..., :3]
    n = np.array([[0.0, 0.0, 1.0]])
    b = Principled({k: v[None] for k, v in surface_params(plane).items()}, n, n)
    want = b.eval(-tilt[None])[0] * 3.0 + b.albedo()[0] * [0.2, 0.1, 0.05]
    np.testing.assert_allclose(img[7, 9], want, rtol=1e-6)
    # the half vector is 0.15 rad from the normal: a clear highlight over the Lambertian part
    assert b.eval(-tilt[None])[0, 0] > 1.1 * b.diff_w[0, 0] * np.cos(0.3) / np.pi


# -- the Principled BSDF ----------------------------------------------------------------

def params(n=1, **kw):
    """Per-point shading inputs of ``n`` points of one Surface with fields ``kw``."""
    prm = surface_params(Surface("s", np.zeros((3, 3)), np.zeros((1, 3), int), **kw))
    return {k: np.repeat(v[None], n, axis=0) for k, v in prm.items()}


def view(cos_v):
    return np.array([math.sqrt(1.0 - cos_v * cos_v), 0.0, cos_v])


def hemisphere(n_theta=256, n_phi=512):
    """Unit directions (K,3) over the upper hemisphere and their solid-angle weights (sr)."""
    x, w = np.polynomial.legendre.leggauss(n_theta)
    mu, w_mu = 0.5 * (x + 1.0), 0.5 * w
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2.0 * np.pi
    m, p = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1.0 - m * m)
    dirs = np.stack([s * np.cos(p), s * np.sin(p), m], axis=-1).reshape(-1, 3)
    return dirs, (w_mu[:, None] * np.full(n_phi, 2.0 * np.pi / n_phi)).ravel()


def integrated_albedo(cos_v, **kw):
    """(int f cos dw over the light directions, the BSDF's own albedo()) at one view."""
    dirs, w = hemisphere()
    k = len(dirs)
    b = Principled(params(k, **kw), np.tile([0.0, 0.0, 1.0], (k, 1)), np.tile(view(cos_v), (k, 1)))
    return (b.eval(dirs) * w[:, None]).sum(axis=0), b.albedo()[0]


def test_ggx_albedo_table_against_closed_form_and_integration():
    # alpha = 1, normal view: D = 1/pi and E = int_0^1 c / (1 + c) dc = 1 - ln 2
    e = S.ggx_albedo(np.array([1.0]), np.array([1.0]))[0]
    assert e == pytest.approx(1 - math.log(2), abs=2e-4)
    dirs, w = hemisphere()
    for rough in (0.4, 0.7, 1.0):
        a = rough ** 2
        for cv in (0.2, 0.5, 0.9):
            v = view(cv)
            h = dirs + v
            h /= np.linalg.norm(h, axis=1, keepdims=True)
            f = S.ggx_reflection(np.full(len(dirs), a), np.full(len(dirs), cv), dirs[:, 2], h[:, 2])
            direct = float((f * w).sum())
            table = S.ggx_albedo(np.array([rough]), np.array([cv]))[0]
            assert table == pytest.approx(direct, abs=3e-3)
    # E_avg = 2 int E mu dmu
    x, wq = np.polynomial.legendre.leggauss(32)
    mu = 0.5 * (x + 1.0)
    for rough in (0.5, 1.0):
        e = S.ggx_albedo(np.full(32, rough), mu)
        e_avg = float((wq * mu * e).sum())
        assert S.ggx_avg_albedo(np.array([rough]))[0] == pytest.approx(e_avg, abs=2e-3)


FURNACE = [dict(specular=0.04, roughness=1.0), dict(specular=0.04, roughness=0.5),
           dict(specular=0.04, roughness=0.3), dict(specular=0.5, roughness=0.5),
           dict(specular=0.04, roughness=0.5, multiscatter=False),
           dict(metallic=1.0, roughness=0.5), dict(metallic=0.5, specular=0.04, roughness=0.6),
           dict(specular=0.04, roughness=0.5, coat_weight=1.0, coat_roughness=0.3),
           dict(specular=0.04, roughness=0.7, diffuse_roughness=1.0),
           dict(diffuse_roughness=0.5)]


@pytest.mark.parametrize("kw", FURNACE,
                         ids=[",".join(f"{k}={v}" for k, v in kw.items()) for kw in FURNACE])
def test_white_furnace(kw):
    """A white surface under a uniform white sky reflects at most what arrives, and the light
    its BRDF reflects (integrated over the sky) is what albedo() (the tables) says: within 1.1 %
    (the tables estimate the specular albedo as Cycles does, E x the mean Fresnel over the
    visible normals, which misses their correlation at grazing views)."""
    for cos_v in (0.1, 0.4, 0.9):
        got, table = integrated_albedo(cos_v, base_color=np.ones(3), **kw)
        assert np.all(got <= 1.0 + 2e-3), (cos_v, got)
        np.testing.assert_allclose(got, table, rtol=0.011)
        if kw.get("multiscatter", True):
            # Multiscatter GGX and the layering lose next to no energy
            assert np.all(got >= 0.985), (cos_v, got)


def test_white_furnace_of_a_tinted_metal():
    got, table = integrated_albedo(0.3, base_color=np.array([0.9, 0.6, 0.2]), metallic=1.0,
                                   roughness=0.4, specular_tint=np.array([1.0, 0.8, 0.5]))
    # 0.5 %: the tables are read with linear interpolation between view cosines 1/15 apart
    np.testing.assert_allclose(got, table, rtol=1e-2)
    assert got[0] > got[1] > got[2] > 0.1


def test_reciprocity():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(200, 3))
    b = rng.normal(size=(200, 3))
    a[:, 2], b[:, 2] = np.abs(a[:, 2]), np.abs(b[:, 2])
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    h = a + b
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    alpha = np.full(200, 0.3)

    def ggx(v, l):   # the single-scattering GGX lobe with dielectric Fresnel, f (1/sr)
        return (S.ggx_reflection(alpha, v[:, 2], l[:, 2], h[:, 2]) / l[:, 2]
                * S.fresnel_dielectric(np.einsum("ij,ij->i", v, h), 1.5))
    np.testing.assert_allclose(ggx(a, b), ggx(b, a), rtol=1e-10)
    # Oren-Nayar (single and multiple scattering terms) and Lambert diffuse
    n = np.tile([0.0, 0.0, 1.0], (200, 1))
    for rough in (0.0, 0.7):
        prm = params(200, base_color=np.array([0.8, 0.5, 0.2]), diffuse_roughness=rough)
        fab = Principled(prm, n, a).eval(b) / b[:, 2:]
        fba = Principled(prm, n, b).eval(a) / a[:, 2:]
        np.testing.assert_allclose(fab, fba, rtol=1e-10)


def test_limit_ior_to_one_is_lambert():
    n = np.tile([0.0, 0.0, 1.0], (3, 1))
    wv = np.array([view(0.2), view(0.6), view(1.0)])
    wl = np.array([view(0.9), view(0.3), view(0.5)]) * [-1, 1, 1]
    base = np.array([0.7, 0.4, 0.1])
    lambert = base * wl[:, 2:] / np.pi
    b = Principled(params(3, base_color=base, specular=0.0, roughness=0.4), n, wv)
    np.testing.assert_allclose(b.eval(wl), lambert, rtol=1e-12)
    np.testing.assert_allclose(b.albedo(), np.tile(base, (3, 1)), rtol=1e-12)
    # the specular layer grows continuously from there (IOR 1.0006)
    b = Principled(params(3, base_color=base, specular=1e-7, roughness=0.4), n, wv)
    assert np.all(np.abs(b.eval(wl) / lambert - 1.0) < 0.005)
    assert np.all(np.abs(b.albedo() - base) < 0.002)


def test_limit_roughness_to_zero_is_a_fresnel_mirror():
    mu = np.arange(1, 16) / 15.0           # the tables' view cosines
    n = np.tile([0.0, 0.0, 1.0], (len(mu), 1))
    wv = np.array([view(m) for m in mu])
    b = Principled(params(len(mu), base_color=np.zeros(3), specular=0.04, roughness=0.0), n, wv)
    np.testing.assert_allclose(b.albedo()[:, 0], S.fresnel_dielectric(mu, 1.5), atol=2e-3)
    # a mirror reflects no light from lights (delta lobe), only the sky through its albedo
    wl = wv * [-1, 1, 1]
    assert np.all(b.eval(wl) == 0.0)
    # a white base takes the rest: the layering keeps the sum at one
    b = Principled(params(len(mu), base_color=np.ones(3), specular=0.04, roughness=0.0), n, wv)
    np.testing.assert_allclose(b.albedo()[:, 0], 1.0, atol=1e-9)


def test_metallic_is_the_f82_conductor_and_mixes_linearly():
    f0, tint = np.array([0.9, 0.6, 0.2]), np.array([1.0, 0.8, 0.5])
    b82 = S.f82_tint_b(f0, tint)
    np.testing.assert_allclose(S.fresnel_f82(1.0, f0, b82), f0)
    schlick = f0 + (1 - f0) * (6 / 7) ** 5
    np.testing.assert_allclose(S.fresnel_f82(1 / 7, f0, b82), tint * schlick, rtol=1e-12)
    x, w = np.polynomial.legendre.leggauss(64)
    mu = 0.5 * (x + 1.0)
    numeric = np.sum((w * mu)[:, None] * (f0 + (1 - f0) * (1 - mu[:, None]) ** 5
                                          - b82 * mu[:, None] * (1 - mu[:, None]) ** 6), axis=0)
    np.testing.assert_allclose(S.fresnel_f82_avg(f0, b82), numeric, rtol=1e-10)
    # Metallic 1: the metal lobe alone, no diffuse; between 0 and 1 Cycles mixes linearly
    n = np.tile([0.0, 0.0, 1.0], (4, 1))
    wv = np.array([view(0.3), view(0.7), view(0.9), view(0.5)])
    wl = np.array([view(0.4) * [-1, 1, 1], [0.0, 0.8, 0.6], view(0.2) * [-1, 1, 1], view(0.95)])
    kw = dict(base_color=f0, specular_tint=tint, specular=0.04, roughness=0.5)
    e = {m: Principled(params(4, metallic=m, **kw), n, wv).eval(wl) for m in (0.0, 0.5, 1.0)}
    np.testing.assert_allclose(e[0.5], 0.5 * (e[0.0] + e[1.0]), rtol=1e-12)
    b = Principled(params(4, metallic=1.0, **kw), n, wv)
    assert np.all(b.diff_w == 0.0) and np.all(b.spec_w == 0.0)
    h = wl + wv
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    single = S.ggx_reflection(np.full(4, 0.25), wv[:, 2], wl[:, 2], h[:, 2])[:, None] * \
        S.fresnel_f82(np.einsum("ij,ij->i", wv, h)[:, None], f0, b82)
    ratio = e[1.0] / single                 # the Multiscatter GGX energy compensation, >= 1
    assert np.all(ratio >= 1.0) and np.all(ratio < 1.3)


def test_coat_layers_over_the_rest_and_tints_the_emission():
    n = np.array([[0.0, 0.0, 1.0]])
    wv = view(0.5)[None]
    kw = dict(base_color=np.full(3, 0.5), specular=0.04, roughness=0.6, emission=np.ones(3))
    bare = Principled(params(**kw), n, wv)
    coated = Principled(params(coat_weight=1.0, coat_roughness=0.2, coat_ior=1.5,
                               coat_tint=np.array([1.0, 0.5, 0.25]), **kw), n, wv)
    cos_t = math.sqrt(1 - (1 - 0.25) / 1.5 ** 2)
    through = np.array([1.0, 0.5, 0.25]) ** (1 / cos_t)
    layer = 1.0 - coated.coat_alb[0, 0] / 1.0            # what the coat lets through
    np.testing.assert_allclose(coated.emission[0], through * layer, rtol=1e-9)
    np.testing.assert_allclose(coated.diff_w[0] / bare.diff_w[0], through * layer, rtol=1e-9)
    assert 0.03 < coated.coat_alb[0, 0] < 0.1               # about a dielectric's Fresnel


def test_oren_nayar_albedo_closed_form():
    dirs, w = hemisphere(128, 256)
    for cos_l in (0.05, 0.3, 0.7, 1.0):
        l = view(cos_l)
        t = dirs @ l - cos_l * dirs[:, 2]
        t = np.where(t > 0, t / np.maximum(cos_l, dirs[:, 2]), t)
        g = float((t * dirs[:, 2] * w).sum())
        assert g == pytest.approx(float(S.oren_nayar_g(cos_l)), abs=2e-4)
    # the mean of G over the cosine lobe is OpenPBR's (2 pi - 5.6) / 3
    assert S.OREN_NAYAR_G_AVG == pytest.approx((2 * math.pi - 5.6) / 3, abs=1e-6)


def test_fresnel_helpers():
    assert S.fresnel_dielectric(1.0, 1.5) == pytest.approx(0.04)
    assert S.fresnel_dielectric(0.0, 1.5) == pytest.approx(1.0)
    assert S.ior_from_f0(S.f0_from_ior(1.33)) == pytest.approx(1.33)
    x, w = np.polynomial.legendre.leggauss(128)
    mu = 0.5 * (x + 1.0)
    # Kulla & Conty's fit of the mean Fresnel (Cycles' F_ss), good to 0.007 from IOR 1.05 to 3
    for eta in (1.05, 1.1, 1.5, 2.0, 3.0):
        exact = float(np.sum(w * mu * S.fresnel_dielectric(mu, eta)))
        assert S.fresnel_dielectric_avg(eta) == pytest.approx(exact, abs=0.007)


def layer_over_ground(sigma_a, H, half, albedo, world, emission=None, name="layer",
                      cache=True):
    """The passes of a homogeneous layer (sigma_a 1/m, thickness H m, 2 half m wide, 1 mm above
    it) over a Lambertian ground of ``albedo``, seen from above by an 8x8 orthographic camera,
    64 samples, single scattering only, world colour ``world``; the ground's gathered light
    from the surface cache (surfacecache.py) or, without ``cache``, gathered per sample."""
    n = (32, 32, 4)
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([2 * half / n[0], 2 * half / n[1], H / n[2]])
    i2w[:3, 3] = [-half + half / n[0], -half + half / n[1], 0.001 + H / (2 * n[2])]
    layer = Medium(name, np.ones(n, np.float32), i2w, np.zeros(3), np.full(3, sigma_a), 0.0,
                   emission=np.zeros(3) if emission is None else np.full(3, emission),
                   source="MESH")
    cam = Camera("ORTHO", np.eye(4), 8, 8, (-0.5, 0.5, -0.5, 0.5))
    cam.cam_to_world[:3, 3] = [0, 0, 10]
    desc = SceneDescription(cam, [], [layer], surfaces=[quad(0.0, 12.0, albedo=albedo)],
                            world=World(np.full(3, float(world))),
                            settings=Settings(samples=64, multiple=False, surface_cache=cache))
    return render(desc).passes


def cosine_integral_through_layer(f, H, half):
    """int f(l(theta, phi)) cos dw over the hemisphere at the ground's centre, by quadrature
    in (theta, phi), l the path through the layer of thickness H and half-width half (out
    through its top or a side)."""
    th = (np.arange(2000) + 0.5) / 2000 * (math.pi / 2)
    ph = (np.arange(720) + 0.5) / 720 * (2 * math.pi)
    TH, PH = np.meshgrid(th, ph, indexing="ij")
    up = np.cos(TH)
    side = np.sin(TH) * np.maximum(np.abs(np.cos(PH)), np.abs(np.sin(PH)))
    with np.errstate(divide="ignore"):
        length = np.minimum(H / up, np.where(side > 0, half / side, np.inf))
    return float(np.sum(f(length) * np.cos(TH) * np.sin(TH)) * (math.pi / 2 / 2000)
                 * (2 * math.pi / 720))


@pytest.mark.parametrize("cache", [True, False])
def test_volume_light_reaches_the_ground(cache):
    """A glowing, absorbing layer (emission e W/(m^3 sr), sigma_a, thickness H, 16 m wide)
    just above a Lambertian ground, no lights, black world: every direction above the ground
    sees L(theta) = e/sigma_a (1 - exp(-sigma_a l(theta))) with l the path through the layer,
    so the ground reflects albedo/pi x int L cos dw (computed here by quadrature over the
    hemisphere, the layer's sides included).  The renderer gathers that light with one
    cosine-distributed march per sample (surfaces.shade's media_radiance); without it the
    ground would be black.  Seen from above through the layer, the ground's part of Combined
    is T x that radiance with T = exp(-sigma_a H).  Measured 0.998 of the quadrature with 64
    samples x 64 pixels (4096 gathering marches); 5 % allowed."""
    e, sigma_a, H, half, albedo = 0.4, 2.0, 0.5, 8.0, 0.5
    out = layer_over_ground(sigma_a, H, half, albedo, 0.0, emission=e, name="glow", cache=cache)
    T = out["Transmittance"][..., 0]
    assert np.allclose(T, math.exp(-sigma_a * H), rtol=1e-3)
    ground = ((out["Combined"][..., :3] - out["Emission"]) / T[..., None]).mean()
    irradiance = cosine_integral_through_layer(
        lambda length: e / sigma_a * -np.expm1(-sigma_a * length), H, half)
    want = albedo / math.pi * irradiance
    print("ground / quadrature:", ground / want)
    assert abs(ground / want - 1.0) < 0.05, (ground, want)


@pytest.mark.parametrize("cache", [True, False])
def test_the_sky_reaches_the_ground_through_the_gathers_own_transmittance(cache):
    """An absorbing layer (sigma_a, thickness H, 16 m wide, no scattering, no emission) just
    above a Lambertian ground under a white sky: the ground reflects albedo/pi x
    int exp(-sigma_a l(theta)) cos dw, l the path through the layer (quadrature as above).
    The gathers read the sky through the transmittance of the same march that gathers the
    media's light (tiles.FrameMarch.radiance_towards), not through a second pass of the
    optical depth; a march whose transmittance were wrong (or 1) would miss this."""
    sigma_a, H, half, albedo = 2.0, 0.5, 8.0, 0.5
    out = layer_over_ground(sigma_a, H, half, albedo, 1.0, name="dark", cache=cache)
    T = out["Transmittance"][..., 0]
    assert np.allclose(T, math.exp(-sigma_a * H), rtol=1e-3)
    ground = (out["Combined"][..., :3] / T[..., None]).mean()
    seen = cosine_integral_through_layer(lambda length: np.exp(-sigma_a * length), H, half)
    want = albedo / math.pi * seen
    print("ground / quadrature:", ground / want)
    assert abs(ground / want - 1.0) < 0.05, (ground, want)


def test_gathers_and_the_pixels_latin_hypercube_keep_the_mean_and_cut_the_noise():
    """A grey ground at the foot of a black wall under a uniform sky gathers half the sky
    (the wall hides the half of the cosine-weighted hemisphere beyond it): its radiance is
    albedo x 0.5 x sky.  More gathers per sample and the Latin hypercube of a pixel's 16
    samples keep that mean and shrink the spread of the pixel means."""
    ground = quad(0.0, 50.0, albedo=0.5, name="ground")
    wall = Surface("wall", np.array([[0, -50, 0], [0, 50, 0], [0, 50, 50], [0, -50, 50]], float),
                   np.array([[0, 1, 2], [0, 2, 3]]), np.zeros(3))
    ss = prepare_surfaces([ground, wall])
    spp, pixels = 16, 400
    n = spp * pixels
    p = np.tile([[0.01, 0.0, 0.0]], (n, 1))
    d = np.tile([[0.0, 0.3, -1.0]], (n, 1)) / np.hypot(0.3, 1.0)
    _, tri = intersect(ss, p - 5 * d, d, np.full(n, 10.0))
    no_media = lambda pts, dirs, t: np.zeros((len(pts), 3))
    rng = np.random.default_rng(5)
    expect = 0.5 * 0.5 * 1.0
    spreads = []
    for gathers, strata in ((1, None), (4, None), (1, "lhs")):
        st = None
        if strata:
            bands = np.argsort(rng.random((2, pixels, spp)), axis=2).reshape(2, n)
            st = (bands[0], bands[1], spp)
        out = surfaces.shade(ss, tri, p, d, [], np.ones(3), no_media, rng, None, bounces=1,
                      gathers=gathers, strata=st)[:, 0]
        per_pixel = out.reshape(pixels, spp).mean(axis=1)
        assert per_pixel.mean() == pytest.approx(expect, rel=0.03), (gathers, strata)
        spreads.append(per_pixel.std())
    assert spreads[1] < 0.6 * spreads[0] and spreads[2] < 0.6 * spreads[0], spreads


def emitter_above(kind, height, size, radius):
    """A 100 W emitter at ``height`` metres over the origin: an area light (a square of side
    ``size`` facing down) or a point light with ``radius``."""
    if kind == "AREA":
        m = np.eye(4)
        m[:3, 3] = [0.0, 0.0, height]
        return Light("AREA", "a", np.full(3, 100.0), matrix=m, shape="SQUARE", size_x=size,
                     size_y=size, direction=np.array([0.0, 0.0, -1.0]))
    return Light("POINT", "p", np.full(3, 100.0), position=np.array([0.0, 0.0, height]),
                 radius=radius)


@pytest.mark.parametrize("kind", ["AREA", "POINT"])
def test_a_pixels_samples_share_out_the_emitter_in_a_soft_shadow(kind):
    """surfaces.shade with a pixel's bands (``strata``): its samples draw the emitter point
    (an area light, a lamp's disc) on the bands too.  A ground point in the penumbra of a
    black wall under the light: the pixels' mean stays that of independent draws (within its
    standard error) and the pixels' means spread less than half as much."""
    ground = quad(0.0, 10.0, albedo=0.5, name="ground")
    wall = Surface("wall", np.array([[0, -10, 0.5], [0, 10, 0.5], [0, 10, 5], [0, -10, 5]],
                                    float), np.array([[0, 1, 2], [0, 2, 3]]), np.zeros(3))
    ss = prepare_surfaces([ground, wall])
    light = emitter_above(kind, 2.0, size=1.0, radius=0.5)
    spp, pixels = 16, 1000
    n = spp * pixels
    p = np.tile([[0.12, 0.0, 0.0]], (n, 1))       # the wall hides part of the emitter
    d = np.tile([[0.0, 0.0, -1.0]], (n, 1))
    _, tri = intersect(ss, p - 2 * d, d, np.full(n, 5.0))
    no_media = lambda pts, dirs, t: np.zeros((len(pts), 3))
    rng = np.random.default_rng(8)
    means, spreads = [], []
    for strata in (None, "bands"):
        st = None
        if strata:
            bands = np.argsort(rng.random((2, pixels, spp)), axis=2).reshape(2, n)
            st = (bands[0], bands[1], spp)
        out = surfaces.shade(ss, tri, p, d, [light], np.zeros(3), no_media, rng, None,
                             bounces=0, gathers=1, strata=st)[:, 0]
        per_pixel = out.reshape(pixels, spp).mean(axis=1)
        means.append(per_pixel.mean())
        spreads.append(per_pixel.std())
    assert 0.1 < means[0] and np.ptp(out) > 0.2 * means[0]   # a penumbra: some draws hidden
    assert abs(means[1] - means[0]) <= 4 * np.hypot(*spreads) / np.sqrt(pixels)
    assert spreads[1] < 0.5 * spreads[0], spreads


@pytest.mark.parametrize("kind", ["AREA", "POINT"])
def test_a_surfaces_shadow_ray_runs_to_the_emitter_point_drawn(kind):
    """surfaces.shade: the light's optical depth and visibility are taken along the drawn
    direction as far as the emitter point drawn (an area light's solid angle, a lamp's
    disc), not as far as the light's centre: in fog under a large area light the centre's
    distance along a slanted direction counts the wrong length of fog."""
    ground = quad(0.0, 10.0)
    ss = prepare_surfaces([ground])
    n = 2000
    p = np.tile([[0.3, -0.2, 0.0]], (n, 1))
    d = np.tile([[0.0, 0.0, -1.0]], (n, 1))
    _, tri = intersect(ss, p + 2 * np.array([0.0, 0.0, 1.0]), d, np.full(n, 5.0))
    light = emitter_above(kind, 1.0, size=3.0, radius=0.6)
    seen = []

    def media(pts, dirs, t):
        seen.append((pts.copy(), dirs.copy(), np.asarray(t, float).copy()))
        return np.zeros((len(pts), 3))
    surfaces.shade(ss, tri, p, d, [light], np.zeros(3), media, np.random.default_rng(2), None,
                   bounces=0)
    pts, dirs, t = seen[0]
    end = pts + dirs * t[:, None]
    if kind == "AREA":   # every shadow ray ends on the emitter's plane, inside the square
        np.testing.assert_allclose(end[:, 2], 1.0, atol=1e-9)
        assert np.all(np.abs(end[:, :2]) <= 1.5 + 1e-9)
    else:                # on the lamp's disc facing the point, at most 0.6 m from its centre
        c = light.position
        w = c - pts
        w /= np.linalg.norm(w, axis=1)[:, None]
        np.testing.assert_allclose(np.einsum("ij,ij->i", end - c, w), 0.0, atol=1e-9)
        assert np.all(np.linalg.norm(end - c, axis=1) <= 0.6 + 1e-9)
    # and not all of the same length as the centre's
    assert np.ptp(t) > 0.05


def test_the_surfaces_shadow_rays_walk_the_bricks_and_give_the_same_image():
    """The tiles' shadow rays (tiles.FrameMarch.optical_depth: a surface point towards a light
    or the sky) pass the media's brick bounds where the grids are large enough
    (Tuning.skip_min_voxels): the image is the one they give without them."""
    import dataclasses
    import sys

    from mpp_render import tiles
    from mpp_render.render import render

    from test_cache import scene

    desc = scene()
    tun = desc.settings.tuning
    seen = []
    orig = tiles.kernels.optical_depth

    def spy(*args, **kw):   # the tiles' calls (the precompute's have their own bricks)
        if sys._getframe(1).f_code is tiles.FrameMarch.optical_depth.__code__:
            seen.append(kw.get("bricks") is not None)
        return orig(*args, **kw)

    def run(least):
        seen.clear()
        d = dataclasses.replace(desc, settings=dataclasses.replace(
            desc.settings, tuning=dataclasses.replace(tun, skip_min_voxels=least)))
        tiles.kernels.optical_depth = spy
        try:
            return render(d), list(seen)
        finally:
            tiles.kernels.optical_depth = orig

    walked, with_bricks = run(0)
    marched, without = run(1 << 40)
    assert with_bricks and all(with_bricks) and not any(without)
    for k in walked.passes:
        np.testing.assert_allclose(walked.passes[k], marched.passes[k], rtol=1e-9, atol=1e-12,
                                   err_msg=k)
    assert walked.passes["Combined"].max() > 0.0
