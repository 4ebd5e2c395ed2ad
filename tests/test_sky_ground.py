"""The sky's light in a medium over a ground (precompute/skydeficit.py's surfaces, docs/method.md
§9.8): the furnace with the ground sending the sky's radiance back, less the ground's own
deficit traced, against independent random walks over the same ground."""
from __future__ import annotations

import numpy as np
import pytest

from mpp_render.media import prepare
from mpp_render.precompute import precompute
from mpp_render.scene import Camera, Medium, Surface, World
from mpp_render.surfaces import prepare_surfaces

N = 20          # voxels a side
VOXEL = 0.05    # m: a 1 m cube
FLOOR = 0.1     # m: the cube's bottom face over the ground (z = 0)
SIGMA_T = 3.0   # 1/m: optical side 3
LO = np.array([-0.5, -0.5, FLOOR])
HI = LO + N * VOXEL


def cube(albedo: float):
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([VOXEL] * 3)
    i2w[:3, 3] = LO + 0.5 * VOXEL
    return prepare(Medium("cube", np.ones((N, N, N), np.float32), i2w,
                          np.full(3, albedo * SIGMA_T), np.full(3, (1.0 - albedo) * SIGMA_T),
                          0.0))


def ground(albedo: float):
    v = np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], float)
    return prepare_surfaces([Surface("ground", v, np.array([[0, 1, 2], [0, 2, 3]]),
                                     np.full(3, albedo))])


def camera():
    cam = np.eye(4)
    cam[:3, 3] = [0.0, -4.0, 0.6]
    cam[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]   # looking along +y
    return Camera("PERSP", cam, 8, 8, (-0.2, 0.2, -0.2, 0.2))


def _box_span(p, w):
    """(entry, exit) distances along w from p through the cube (entry > exit: missed)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (LO - p) / w, (HI - p) / w
    return np.nanmax(np.minimum(t1, t2), axis=1), np.nanmin(np.maximum(t1, t2), axis=1)


def walk_mean_radiance(points, albedo: float, floor: float, n: int = 200_000,
                       seed: int = 5) -> float:
    """The mean over directions of the radiance at ``points`` (M,3) in the cube under a sky
    of radiance 1 over the ground plane z = 0 of diffuse albedo ``floor``, isotropic
    scattering, averaged over the points: random walks from them (by reciprocity), each
    scattering weighing ``albedo``, each bounce off the ground (a cosine lobe) ``floor``;
    a walk that leaves upwards sees the sky."""
    rng = np.random.default_rng(seed)
    p = np.asarray(points, np.float64)[rng.integers(0, len(points), n)]
    weight, out = np.ones(n), np.zeros(n)
    alive, inside = np.ones(n, bool), np.ones(n, bool)

    def sphere(m):
        mu, phi = 2.0 * rng.random(m) - 1.0, 2.0 * np.pi * rng.random(m)
        s = np.sqrt(1.0 - mu * mu)
        return np.stack([s * np.cos(phi), s * np.sin(phi), mu], axis=1)

    w = sphere(n)
    for _ in range(400):
        idx = np.flatnonzero(alive)
        if not len(idx):
            break
        ins = idx[inside[idx]]
        if len(ins):
            _, exit_t = _box_span(p[ins], w[ins])
            t = -np.log(1.0 - rng.random(len(ins))) / SIGMA_T
            stay = t < exit_t
            s = ins[stay]
            p[s] += t[stay, None] * w[s]
            weight[s] *= albedo
            w[s] = sphere(len(s))
            gone = ins[~stay]
            p[gone] += exit_t[~stay, None] * w[gone]
            inside[gone] = False
        outs = idx[~inside[idx]]
        if len(outs):
            up = outs[w[outs, 2] >= 0.0]
            out[up] = weight[up]
            alive[up] = False
            down = outs[w[outs, 2] < 0.0]
            p[down] += (p[down, 2] / -w[down, 2])[:, None] * w[down]
            p[down, 2] = 0.0
            weight[down] *= floor
            u1, u2 = rng.random(len(down)), rng.random(len(down))
            r, phi = np.sqrt(u1), 2.0 * np.pi * u2
            w[down] = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - u1)], axis=1)
            entry, exit_t = _box_span(p[down], w[down])
            hit = exit_t > np.maximum(entry, 0.0)
            back = down[hit]
            p[back] += np.maximum(entry[hit], 0.0)[:, None] * w[back]
            inside[back] = True
            sky = down[~hit]
            out[sky] = weight[sky]
            alive[sky] = False
    return float(out.mean())


@pytest.mark.parametrize("floor", [0.0, 0.5])
def test_the_skys_light_over_a_ground_matches_a_random_walk(floor):
    """A cube of medium (albedo 0.9, isotropic, optical side 3) 0.1 m over a wide ground,
    under a sky of radiance 1, no lamp: the sky's light a voxel scatters (A + A_ms, per unit
    sigma_s) is the mean radiance there, which walks give independently, by three layers
    (the bottom, the middle and the top fifth of the cube, away from its sides).  The ground
    hides half the sky and sends back what it reflects; the model that scaled the collided
    light of the hidden directions alone by the share of the sky was 2.03 / 1.48 / 1.07x the
    walks over a black ground and 1.06 / 1.01 / 0.88x over a grey one (measured); the
    furnace with the ground's own deficit traced is within 5 % (measured, seeds 2-5: 1.00-1.05
    over the black ground, 1.00-1.02 over the grey one; what stays above 1 is not found)."""
    pm = cube(0.9)
    pre = precompute([pm], [], World(color=np.ones(3)), camera(), multiple=True,
                     multiple_paths=4_000_000, seed=2, surfaces=ground(floor))
    f = pre.fields[0]
    v = f.reshape(-1, f.shape[-1])
    light = v[:, pre.layout.ambient_channel] + v[:, pre.layout.ambient_multiple_channel]
    ijk = np.stack(np.meshgrid(*[np.arange(s) for s in f.shape[:3]], indexing="ij"),
                   -1).reshape(-1, 3)
    pts = pm.to_world(ijk.astype(np.float64))
    core = np.all((pts > LO) & (pts < HI), axis=1) & np.all(np.abs(pts[:, :2]) < 0.3, axis=1)
    z = pts[:, 2] - FLOOR
    for layer in (z < 0.2, np.abs(z - 0.5) < 0.1, z > 0.8):
        sel = core & layer
        assert float(light[sel].mean()) == pytest.approx(
            walk_mean_radiance(pts[sel], 0.9, floor), rel=0.05)


def stiff_sky_light(albedo: float, scale: float, g: float):
    """(A, A_ms) fields of the cube made stiff (its coefficients times ``scale``, anisotropy
    ``g``) over a black glossy ground (F0 0.04, roughness 0.05: its Fresnel near 1 at
    grazing) under a sky of radiance 1, no lamp."""
    import dataclasses
    pm = cube(albedo)
    pm = dataclasses.replace(pm, sigma_s=pm.sigma_s * scale, sigma_a=pm.sigma_a * scale,
                             sigma_t=pm.sigma_t * scale, g=g)
    v = np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], float)
    glossy = prepare_surfaces([Surface("ground", v, np.array([[0, 1, 2], [0, 2, 3]]),
                                       np.zeros(3), specular=0.04, roughness=0.05)])
    pre = precompute([pm], [], World(color=np.ones(3)), camera(), multiple=True,
                     multiple_paths=100_000, seed=1, surfaces=glossy)
    f, lay = pre.fields[0], pre.layout
    return (f[..., lay.ambient_channel:lay.ambient_channel + 3],
            f[..., lay.ambient_multiple_channel:lay.ambient_multiple_channel + 3])


@pytest.mark.parametrize("albedo, scale, g", [(0.5, 2000.0, 0.0), (1e-6, 1.0, 0.0),
                                              (0.999999, 1.0, 0.99), (0.9, 1.0, -0.99)])
def test_stiff_media_over_a_glossy_ground_give_finite_light(albedo, scale, g):
    """Optical depth across the cube 6000 (too dense for paths: the share-of-sky model
    stands), albedo 0 and 1, anisotropy near +-1: the sky's light stays finite, its direct
    part within [0, L_w]; without the anisotropy its multiply scattered part too."""
    a, ms = stiff_sky_light(albedo, scale, g)
    assert np.all(np.isfinite(a)) and np.all(np.isfinite(ms))
    assert float(a.min()) >= 0.0 and float(a.max()) <= 1.0 + 1e-6
    if g == 0.0:
        assert float(ms.max()) <= 1.05


@pytest.mark.xfail(strict=True, reason="near g = +-1 the ground's deficit towards the camera "
                   "does not converge (docs/method.md §10): voxels of A_ms reach 30-100x the "
                   "sky's radiance")
@pytest.mark.parametrize("g", [0.99, -0.99])
def test_the_skys_light_over_a_ground_stays_under_the_sky_near_g_1(g):
    """The maximum principle: under a sky alone no radiance exceeds the sky's."""
    a, ms = stiff_sky_light(0.9, 1.0, g)
    assert float((a + ms).max()) <= 1.05
