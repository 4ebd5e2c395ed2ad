"""The sky's light on a medium's voxels (precompute/worldlight.py): the coarse lattice and the
voxels refined where the light falls too steeply between its points to be interpolated."""
from __future__ import annotations

import numpy as np
import pytest

from mpp_render.media import prepare
from mpp_render.precompute.lattice import grid_points, needed_flat
from mpp_render.precompute.worldlight import (fill_world_light, interpolation_error, refine_flat,
                                              world_lattice, world_light)
from mpp_render.scene import Camera, Medium, Tuning, World


def test_interpolation_error_is_the_exponentials_miss_at_the_middle():
    for k in (0.05, 1.0, 6.0):
        hi, lo = 2.0, 2.0 * np.exp(-k)
        want = 0.5 * (hi + lo) - 2.0 * np.exp(-0.5 * k)
        assert interpolation_error(np.array([hi]), np.array([lo]))[0] == pytest.approx(want)
    # nothing to miss where the corners agree or hold no light; a low end above the high one
    # counts as equal
    assert np.all(interpolation_error(np.array([0.0, 1.0, 1.0]), np.array([0.0, 1.0, 3.0])) == 0.0)


def lattice_with_a_dark_corner(dark=0.01):
    """A 3x3x3 lattice 4 voxels apart over a 9^3 grid, the light 1 everywhere but at its far
    corner; every voxel needed."""
    values = np.ones((3, 3, 3, 3))
    values[2, 2, 2] = dark
    have = np.ones((3, 3, 3), bool)
    return values, have, 4, (9, 9, 9), np.arange(9 ** 3)


def test_refine_flat_picks_the_voxels_of_the_cell_where_the_light_falls():
    values, have, stride, shape, flat = lattice_with_a_dark_corner()
    got = refine_flat(values, have, stride, shape, flat, np.ones(3), 0.01)
    ijk = np.stack(np.unravel_index(got, shape), axis=1)
    # the far cell (voxels 4..8 on every axis), less its lattice points
    assert np.all(ijk >= 4)
    on_points = np.all(np.isin(ijk, (4, 8)), axis=1)
    assert not on_points.any()
    assert len(got) == 5 ** 3 - 8
    # the criterion is relative to the world's radiance, per channel
    assert len(refine_flat(values, have, stride, shape, flat, np.full(3, 1e3), 0.01)) == 0
    assert len(refine_flat(values, have, stride, shape, flat, np.array([1e3, 1e3, 1.0]), 0.01)) \
        == len(got)
    # off, and a gentle fall
    assert len(refine_flat(values, have, stride, shape, flat, np.ones(3), 0.0)) == 0
    gentle = lattice_with_a_dark_corner(dark=0.9)
    assert len(refine_flat(*gentle[:4], gentle[4], np.ones(3), 0.01)) == 0


def test_refine_flat_ignores_the_corners_it_did_not_compute():
    values, have, stride, shape, flat = lattice_with_a_dark_corner(dark=0.0)
    have[2, 2, 2] = False   # the lattice left it out (no density near it): its 0 is no value
    assert len(refine_flat(values, have, stride, shape, flat, np.ones(3), 0.01)) == 0
    # and only the needed voxels are candidates
    few = np.ravel_multi_index(([5, 1], [5, 1], [5, 1]), shape)
    values[2, 2, 2], have[2, 2, 2] = 0.01, True
    assert list(refine_flat(values, have, stride, shape, few, np.ones(3), 0.01)) == [few[0]]


def dense_bar(density=80.0):
    """A bar 128 voxels long and 10 across of uniform dense smoke (voxels 1 cm): the sky's lit
    layer on its long faces is about a voxel deep, a quarter of the world light's lattice."""
    d = np.full((128, 10, 10), density, np.float32)
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([0.01, 0.01, 0.01])
    i2w[:3, 3] = [-0.64, -0.05, -0.05]
    return prepare(Medium("bar", d, i2w, np.full(3, 0.9), np.full(3, 0.1), 0.0))


def test_refined_voxels_take_the_sky_light_the_lattice_would_interpolate_too_bright():
    """The sky's light (A) on the voxels of a dense bar, against A computed at every voxel:
    interpolated from the coarse lattice alone it is too bright in the lit layer (the
    exponential's fall is convex); with the refinement (the default tolerance) the bias goes."""
    pm = dense_bar()
    cam = np.eye(4)
    cam[:3, 3] = [0.0, -3.0, 0.3]
    camera = Camera("PERSP", cam, 4, 4, (-1, 1, -1, 1))
    world = World(color=np.array([1.0, 0.8, 0.6]))
    flat = needed_flat(pm)
    assert world_lattice(pm)[0] == 4
    dense = pm.grid.reshape(-1)[flat] > 0.0
    n_dirs, step = 64, 0.005
    truth = world_light([pm], pm, world, camera, grid_points(pm, flat), n_dirs, step, seed=3)

    def field(tol):
        f = np.zeros(pm.grid.shape + (3,), np.float32)
        got = fill_world_light(f, (0, None), [pm], pm, world, camera, flat, n_dirs, step,
                               seed=1, tuning=Tuning(ambient_refine=tol))
        return f.reshape(-1, 3)[flat], got

    (coarse, n_coarse), (fine, n_fine) = field(0.0), field(Tuning().ambient_refine)
    assert n_fine > n_coarse
    lit = dense & (truth[:, 0] > 0.01)
    bias_coarse = float(np.mean(coarse[lit] - truth[lit]))
    bias_fine = float(np.mean(fine[lit] - truth[lit]))
    assert bias_coarse > 0.02
    assert abs(bias_fine) < 0.2 * bias_coarse
    assert np.all(np.isfinite(fine)) and np.all(fine >= 0.0)


def test_the_lattice_reaches_past_the_grids_far_faces():
    """The bar's padded grid (12 voxels across) ends between two points of the lattice 4
    apart: the point beyond it is computed, so the lit layer on the far faces interpolates
    towards its light, as on the near faces, not towards 0."""
    pm = dense_bar()
    stride, shape, cflat, cpts = world_lattice(pm)
    assert (pm.grid.shape[1] - 1) % stride != 0 and shape[1] * stride > pm.grid.shape[1]
    ijk = np.stack(np.unravel_index(cflat, shape), axis=1)
    assert ijk[:, 1].max() == shape[1] - 1
    camera = Camera("PERSP", np.eye(4), 4, 4, (-1, 1, -1, 1))
    world = World(color=np.ones(3))
    flat = needed_flat(pm)
    f = np.zeros(pm.grid.shape + (3,), np.float32)
    fill_world_light(f, (0, None), [pm], pm, world, camera, flat, 32, 0.005, seed=1,
                     tuning=Tuning(ambient_refine=0.0))
    a = f[..., 0]
    near, far = a[20:100, 1, 3:9].mean(), a[20:100, 10, 3:9].mean()
    assert far == pytest.approx(near, rel=0.2)


def test_the_medium_before_a_ground_still_scatters_the_skys_light():
    """A cube of thin isotropic medium (albedo 1, g 0) standing on a wide ground, under a
    constant sky: the ground hides the sky below it from the cube's centre (half the
    sphere, sky_share), and the sky's direct light A through those directions is 0, but the
    medium between the centre and the ground still scatters the sky's light it gets from
    above: its collided part A_ms counts there at the centre's share of the sky.  By the
    cube's symmetry the lower half's collided light equals the upper half's, so with the
    ground A_ms is 3/4 of A_ms without it (it was 1/2 when the ground hid it all), and A half."""
    from mpp_render.precompute.worldlight import sky_share
    from mpp_render.scene import Surface
    from mpp_render.surfaces import prepare_surfaces

    n = 16
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([1.0 / n] * 3)
    i2w[:3, 3] = [-0.5 + 0.5 / n, -0.5 + 0.5 / n, 0.5 / n]
    pm = prepare(Medium("cube", np.full((n, n, n), 0.5, np.float32), i2w, np.full(3, 0.5),
                        np.zeros(3), 0.0))
    v = np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], float)
    ground = prepare_surfaces([Surface("ground", v, np.array([[0, 1, 2], [0, 2, 3]]),
                                       np.zeros(3))])
    centre = np.array([[0.0, 0.0, 0.5]])
    assert sky_share(ground, centre, 1, 0, 1, 64)[0] == pytest.approx(0.5, abs=0.02)
    camera = Camera("PERSP", np.eye(4), 4, 4, (-1, 1, -1, 1))
    world = World(color=np.ones(3))
    pts = np.repeat(centre, 64, axis=0)   # 64 points, their directions' strata shifted apart

    def sky(surfaces):
        a, ms = world_light([pm], pm, world, camera, pts, 64, 0.01, seed=2,
                            surfaces=surfaces, multiple=True)
        return a.mean(), ms.mean()

    (a_open, ms_open), (a_ground, ms_ground) = sky(None), sky(ground)
    assert ms_open > 0.05
    assert a_ground / a_open == pytest.approx(0.5, rel=0.03)
    assert ms_ground / ms_open == pytest.approx(0.75, rel=0.03)


def test_the_skys_collided_light_follows_its_direct_light_between_the_lattice_points():
    """A cube of uniform smoke (albedo 0.8, 1.2 of optical depth across a cell of the sky's
    lattice) under a coloured sky, no refinement.  Where the sky is seen from every lattice
    point, its collided light on the lattice is alpha (L_w - A) (the furnace, docs/method.md
    §9.8): between the points the field keeps that identity to float precision, so that the
    collided part rises into the medium as the direct part falls (geometrically inside it).
    Against the light computed at the voxels themselves, in the lit cells wholly inside the
    medium (A between 0.05 and 0.6 of the sky), the direct light's bias is under a quarter
    of its linear interpolation's (measured: +0.31 -> +0.06 of the light), and the collided
    light's too (-0.032 -> -0.006)."""
    from mpp_render import kernels_np
    from mpp_render.precompute.worldlight import inside_lattice, on_lattice

    n = 64
    i2w = np.eye(4)
    i2w[:3, :3] = np.diag([0.02] * 3)
    i2w[:3, 3] = -0.01 * (n - 1)
    pm = prepare(Medium("cube", np.full((n, n, n), 30.0, np.float32), i2w, np.full(3, 0.8),
                        np.full(3, 0.2), 0.3))
    cam = np.eye(4)
    cam[:3, 3] = [0.0, -3.0, 0.3]
    camera = Camera("PERSP", cam, 4, 4, (-1, 1, -1, 1))
    world = World(color=np.array([1.0, 0.8, 0.6]))
    flat = needed_flat(pm)
    stride, cshape, cflat, cpts = world_lattice(pm)
    assert stride == 2
    f = np.zeros(pm.grid.shape + (6,), np.float32)
    fill_world_light(f, (0, 3), [pm], pm, world, camera, flat, 32, 0.01, seed=1,
                     tuning=Tuning(ambient_refine=0.0), deficit=True)
    v = f.reshape(-1, 6)[flat]
    a, ms = v[:, :3], v[:, 3:]
    dense = pm.grid.reshape(-1)[flat] > 0.0
    np.testing.assert_allclose(ms[dense] + 0.8 * a[dense],
                               np.broadcast_to(0.8 * world.color, a[dense].shape), atol=1e-6)
    # the voxels of the lit cells whose lattice points all lie inside
    inside = inside_lattice(pm, stride, cshape)
    ijk = np.stack(np.unravel_index(flat, pm.grid.shape), axis=1)
    c0 = np.minimum(ijk // stride, np.array(cshape) - 2)
    wholly = np.ones(len(flat), bool)
    for o in np.ndindex(2, 2, 2):
        c = c0 + np.array(o)
        wholly &= inside[c[:, 0], c[:, 1], c[:, 2]] > 0
    la, lms = world_light([pm], pm, world, camera, cpts, 32, 0.01, seed=1, multiple=True,
                          deficit=True)
    lin_a = kernels_np.upsample(on_lattice(cshape, cflat, la), stride, pm.grid.shape)
    lin_ms = kernels_np.upsample(on_lattice(cshape, cflat, lms), stride, pm.grid.shape)
    lin_a, lin_ms = lin_a.reshape(-1, 3)[flat], lin_ms.reshape(-1, 3)[flat]
    pick = np.flatnonzero(wholly & (lin_a[:, 0] > 0.05) & (lin_a[:, 0] < 0.6))
    pick = pick[np.random.default_rng(0).choice(len(pick), 600, replace=False)]
    a_t, ms_t = world_light([pm], pm, world, camera, grid_points(pm, flat[pick]), 32, 0.01,
                            seed=3, multiple=True, deficit=True)

    def bias(x, t):
        return float(np.mean((x[pick] - t) / t))
    assert bias(lin_a, a_t) > 0.1 and bias(lin_ms, ms_t) < -0.01
    assert abs(bias(a, a_t)) < 0.25 * bias(lin_a, a_t)
    assert abs(bias(ms, ms_t)) < 0.25 * abs(bias(lin_ms, ms_t))
