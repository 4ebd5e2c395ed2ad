"""A spot's irradiance as the paths' first-scattering source reads it (precompute.source.
voxel_irradiance): the mean over each voxel, so that a cone a few voxels wide brings the
same flux through a layer of voxels as through the plane, wherever the voxels fall."""
import numpy as np
import pytest

from mpp_render import kernels, lights
from mpp_render.lights import irradiance
from mpp_render.precompute.source import voxel_irradiance
from mpp_render.scene import Light


def narrow_spot():
    m = np.eye(4)
    m[:3, :3] = [[0, 0, -1], [0, 1, 0], [1, 0, 0]]    # the spot's -Z along world +x
    return Light("SPOT", "spot", np.full(3, 2000.0), position=np.zeros(3),
                 direction=np.array([1.0, 0.0, 0.0]), matrix=m, spot_size=np.radians(8.0),
                 spot_blend=0.1)


def layer_flux(light, h, shift, points=0):
    """W through the voxels of side ``h`` of the layer x = 1 m, the layer's lattice shifted by
    ``shift`` (m) across the beam: each voxel's irradiance times h^2, its mean over
    ``points``^3 points (0: read at the centre)."""
    g = np.arange(-0.3, 0.3, h) + shift
    y, z = np.meshgrid(g, g, indexing="ij")
    pts = np.stack([np.ones(y.size), y.ravel(), z.ravel()], axis=1)
    e = voxel_irradiance(light, pts, np.eye(3) * h, points) if points else \
        irradiance(light, pts)
    return float(e[:, 0].sum()) * h * h


def test_the_voxel_mean_keeps_a_narrow_cones_flux_wherever_the_voxels_fall():
    """The worst of five shifts of the layer: the centres alone miss by over 5 %, the
    default mean (3 points per axis) by under 3 %, 6 points per axis by under 1 %."""
    light = narrow_spot()
    fine = layer_flux(light, 0.002, 0.001)               # the plane's flux, finely read
    h = 0.05                                              # the cone is 0.14 m wide here
    worst = {}
    for points in (0, 3, 6):
        worst[points] = max(abs(layer_flux(light, h, shift, points) / fine - 1.0)
                            for shift in np.linspace(0.0, h, 5, endpoint=False))
    assert worst[0] > 0.05 and worst[3] < 0.03 and worst[6] < 0.01, worst
    assert worst[3] < worst[0] / 2


def test_other_lights_are_read_at_the_centre():
    light = Light("POINT", "pt", np.full(3, 100.0), position=np.zeros(3))
    pts = np.array([[1.0, 0.2, 0.0], [0.5, -0.1, 0.3]])
    np.testing.assert_array_equal(voxel_irradiance(light, pts, np.eye(3) * 0.1),
                                  irradiance(light, pts, kernels.light_sample))


def counted(monkeypatch):
    """kernels.light_sample wrapped to count its points; returns the list of counts."""
    seen, real = [], kernels.light_sample

    def sample(rec, x, u1, u2, *a, **k):
        seen.append(len(x))
        return real(rec, x, u1, u2, *a, **k)
    monkeypatch.setattr(kernels, "light_sample", sample)
    return seen


@pytest.mark.skipif(kernels._c is None, reason="compiled kernels not built")
@pytest.mark.parametrize("radius", [0.0, 0.05])
@pytest.mark.parametrize("kind", ["SPOT", "POINT"])
def test_the_voxel_means_sample_the_lamp_compiled_and_agree_with_numpy(monkeypatch, kind,
                                                                        radius):
    """The source's voxel irradiance reads every point through the compiled light sample
    (csrc/lightsample.c; numpy's twin took 2-4x as long on the spots' 27 points a voxel,
    performance.md), and gives numpy's irradiance to its twin's tolerance."""
    light = narrow_spot() if kind == "SPOT" else \
        Light("POINT", "pt", np.full(3, 100.0), position=np.zeros(3))
    light.radius = radius
    rng = np.random.default_rng(5)
    pts = np.column_stack([rng.uniform(0.5, 1.5, 400), rng.uniform(-0.3, 0.3, (400, 2))])
    seen = counted(monkeypatch)
    got = voxel_irradiance(light, pts, np.eye(3) * 0.05)
    assert sum(seen) >= len(pts)                   # every point through the compiled sample
    monkeypatch.setattr(kernels, "light_sample", lights.light_sample)
    want = voxel_irradiance(light, pts, np.eye(3) * 0.05)
    assert want[:, 0].max() > 0.0
    np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-12 * want.max())


def test_a_density_grids_optically_thick_voxels_take_their_source_from_their_cells():
    """source.thick_band_source: dense blocks (2.6 optical depth a voxel) under a sun.  The
    first-scattering power the paths start from, read at each voxel's centre, misses the
    light falling off within the lit voxels by about half; from their cells' 2 x 2 x 2
    points it comes within 7 % of a fine sum over 4 x 4 x 4 points a voxel of
    sigma_s rho E exp(-tau), rho read trilinearly and tau marched finely (which 8 x 8 x 8
    points move by 1 %; 2 x 2 x 2 with that tau are 4 % over)."""
    from mpp_render.media import prepare, trilinear
    from mpp_render.precompute import lightdepth as P
    from mpp_render.precompute.source import restricted_source, thick_band_source
    from mpp_render.scene import Tuning
    from test_sweep import dense_blocks
    pm = prepare(dense_blocks())
    sun = Light("SUN", "sun", np.full(3, 3.0), direction=np.array([0.45, 0.3, -0.84]))
    f = np.zeros(pm.grid.shape + (4,), np.float32)
    f[..., 0] = pm.grid
    assert P.sweep_light([pm], pm, sun, f, 1, pm.voxel_size) is True
    shape = pm.grid.shape
    band = thick_band_source(pm, f, sun, 1, Tuning().cell_tau)
    assert band is not None and band[0].size > 100
    vol = abs(np.linalg.det(pm.i2w[:3, :3]))
    centres = restricted_source(pm, f, sun, 1, 1, shape).sum() * vol
    cells = restricted_source(pm, f, sun, 1, 1, shape, band=band).sum() * vol
    k = 4
    sub = (np.arange(k) + 0.5) / k - 0.5
    offs = np.stack(np.meshgrid(sub, sub, sub, indexing="ij"), -1).reshape(-1, 3)
    ijk = np.stack(np.meshgrid(*[np.arange(s, dtype=np.float64) for s in shape],
                               indexing="ij"), -1).reshape(-1, 3)
    idx = (ijk[:, None, :] + offs[None]).reshape(-1, 3)
    idx = np.clip(idx, 0.0, np.array(shape) - 1.0 - 1e-9)
    rho = np.reshape(trilinear(pm.grid, idx), -1)
    live = rho > 0
    tau = P.light_optical_depth([pm], sun, pm.to_world(idx[live]), 0.01)
    want = (rho[live, None] * pm.sigma_s[None] * 3.0 * np.exp(-tau)).sum() * vol / len(offs)
    assert abs(cells / want - 1.0) < 0.07
    assert centres < 0.6 * want


def test_the_cells_round_a_lamp_take_the_tent_every_other_cell_takes():
    """source.cell_mean_source: the lattice points round a point light inside a medium take
    the voxels' source under their tent, weighed as restricted_source shares every other
    voxel's power, the light's falloff floored the same way (near_falloff) next to it.  A box
    of the voxels beside the point (2 of them a side at stride 2, offsets -1 and 0) had
    shifted that source half a voxel and taken hold-out lamps in clouds (v_cloud_lamp) from
    0.23 to 0.09 against Cycles when centred."""
    from mpp_render.media import Medium, prepare
    from mpp_render.precompute import lightdepth as P
    from mpp_render.precompute.lattice import lattice_shape
    from mpp_render.precompute.source import (cell_mean_source, near_light_cells,
                                              restricted_source)
    rng = np.random.default_rng(3)
    n = 20
    d = rng.random((n, n, n)).astype(np.float32) ** 2 * 2.0    # uneven smoke, no holes' edges
    i2w = np.eye(4)
    i2w[:3, :3] *= 0.05
    i2w[:3, 3] = -0.5
    pm = prepare(Medium("smoke", d, i2w, np.full(3, 3.0), np.full(3, 0.9), 0.3))
    for radius in (0.0, 0.12):
        lamp = Light("POINT", "lamp", np.full(3, 50.0), position=np.array([0.013, -0.021, 0.04]),
                     radius=radius)
        f = np.zeros(pm.grid.shape + (4,), np.float32)
        f[..., 0] = pm.grid
        P.sweep_light([pm], pm, lamp, f, 1, pm.voxel_size)
        for stride in (1, 2, 3):
            shape = lattice_shape(pm.grid.shape, stride)
            near = near_light_cells(pm, lamp, stride, shape)
            assert near.size >= 8
            tent = restricted_source(pm, f, lamp, 1, stride, shape)[near]
            cells = cell_mean_source(pm, f, lamp, 1, stride, shape, near)
            np.testing.assert_allclose(cells, tent, rtol=1e-9, atol=1e-12 * tent.max())
