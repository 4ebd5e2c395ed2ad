"""The sky's light that absorbing media and the surfaces round them take away, once it has
scattered (docs/method.md §9.8).

Under a constant sky of radiance L_w (W/(m^2 sr)), a medium that absorbs nothing has the
radiance L_w everywhere in it, along every direction, whatever its phase function and
density (the furnace: what a straight path loses by scattering, others scatter into it).
Where it absorbs, its radiance falls short of L_w by D(x, w), and D obeys the transfer
equation of the same medium with the source sigma_a(x) L_w (W/(m^3 sr)) and nothing coming
in from outside: D is the light of a fictitious emission sigma_a L_w, spread by the medium.
So the sky's light arriving at x along w after one scattering or more is

    A_ms(x, w) = L_w (1 - e^{-tau_t}) - D(x, w)                     [W/(m^2 sr)]

(tau_t the optical depth from x to the sky along -w). D's first flight, the fictitious
emission unscattered, is L_w integral sigma_a e^{-tau_t(s)} ds = L_w (tau_a / tau_t)
(1 - e^{-tau_t}) where the albedo is the same along the path (one medium), so
worldlight.world_light takes L_w (tau_s / tau_t)(1 - e^{-tau_t}) for the collided part (in
closed form, along its own directions), and the fictitious emission's later flights D_2+,
traced as a glow's (emissionlight.scattered_glow, its Em), are taken off the world light's
multiply scattered channel here.  The estimate converges with the paths; the first flight,
most of D where the medium absorbs much, has no noise.

Where surfaces stand round the medium (a ground), the furnace holds if each surface sends the
sky's radiance L_w back, as the sky behind it would.  A surface that reflects the share R of a
uniform sky (its directional albedo, every layer of its BSDF: surfaces.sky_albedo) sends
R L_w, so it falls short by (1 - R) L_w: a second fictitious emission, pi (1 - R) L_w per unit
area in a cosine lobe from the side that faces the medium (pathstarts.sky_ground_starts, R
its cosine-weighted mean there), whose light spread by the medium (and reflected by the
surfaces) is taken off too.  So, exactly,

    L(x, w) = L_w - D(x, w) - G(x, w)

with G the surfaces' deficit.  Along a direction that ends on a surface the sky's direct
light is 0; the furnace's light there, L_w e^{-tau} unscattered from the surface, less G's
first flight, (1 - R) L_w e^{-tau}, leaves R L_w e^{-tau}, and the collided part is the whole
furnace's up to the surface (worldlight.world_light's ``ground``); G's later flights are
traced (``sky_deficit``'s ``ground``: paths aimed at the medium, paths.py lobe 3) and taken off
with D_2+.  This holds the ground's light too: the sky's light off the surfaces is the
ground's R L_w less what G takes off.  (Scaling the collided light of the hidden directions
by the share s(x) of the sky that x sees, as stood before, left the light the medium
scatters to x from the directions that see the sky as bright as without the ground: over a
black ground a cube's sky light was 2x the walks' at its bottom, tests/test_sky_ground.py.)
Where the deficit is not traced (a world fog, no camera, a medium too dense for paths) that
older model stands: the collided part of a hidden direction times s(x), and D's emission
sigma_a L_w s(x) (``seen_share``).

The paths start where the camera can see their light (``camera_odds``): the fictitious
emission fills the whole medium, but in a thick absorbing one the camera sees a thin layer,
and a path's light stays within the distance it walks before it is absorbed.  Each voxel's
odds of starting a path are mix + (1 - mix) v / <v> (``Tuning.sky_deficit_mix``; <v> the
power-weighted mean), v = exp(-max(tau_c - r, 0)) with tau_c the optical depth from the
voxel to the camera and r = sqrt(2 / ((1 - a)(1 - g))) the root-mean-square optical distance
of a random walk of 1 / (1 - a) flights of mean square length 2 / (1 - g) (albedo a, the
largest channel's; anisotropy g; camerareach.walk_reach).  The weights divide by the odds:
the estimate is the same, its noise lower where the camera looks (p_sphere_lowalbedo, albedo
0.5: Volume Multiple's seed-to-seed noise 0.0079 -> about 0.0054 of the image's mean;
method.md §9.8).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from .. import kernels
from ..media import PreparedMedium, density_from
from ..scene import Tuning
from .camerareach import largest_albedo, walk_reach
from .emissionlight import scattered_glow
from .lightdepth import eye_depth
from .lightpaths import cell_volume
from .pathstarts import sky_ground_starts, surface_reach
from .worldlight import on_lattice, sky_share, world_lattice

SHARE_CHUNK = 1 << 11   # lattice points whose sky share is found at a time


def deficit_paths(multiple_paths: int, floor: int, share: float) -> int:
    """The paths traced for the fictitious emission: ``share`` (Tuning.sky_deficit_paths)
    of the Paths setting ``multiple_paths``, or of ``floor`` where that is more (the glow's
    number: the walk's Preview has no paths of its own)."""
    return max(1, int(share * max(int(floor), int(multiple_paths))))


def walls_follow_lights(multiple: bool, multiple_paths: int, surfaces, sky, media) -> bool:
    """Whether the surfaces' deficit (``sky_deficit``'s ``ground``) is traced with as many
    paths as weigh what the lights' paths weigh: multiple scattering by traced paths
    (``multiple_paths`` > 0), surfaces, a sky of RGB radiance ``sky`` above 0 and no world
    fog among ``media`` (it hides the sky).  The cache (cache.py) then keys the lights' part
    by the sky's colour, and a changed sky recomputes both parts."""
    return bool(multiple and int(multiple_paths) > 0 and surfaces is not None
                and not surfaces.empty and np.any(np.asarray(sky, np.float64) > 0.0)
                and not any(pm.endless for pm in media))


def sky_deficit(pm: PreparedMedium, colour, camera, n_paths: int, resolution: int,
                seed: int = 0, threads: int = 0, should_cancel=None, around=None, partners=(),
                surfaces=None, n_dirs: int = 64, setting: Optional[int] = None,
                tuning: Tuning = Tuning(), path_weight: Optional[float] = None,
                ground: bool = False):
    """(stride, D, cross) or None: D_2+ (float32 (LX,LY,LZ,3), W/(m^2 sr), phase-weighted
    towards the camera, module docstring) on ``pm``'s light-path lattice from the
    fictitious emission sigma_a rho L_w s of ``pm`` (``colour`` L_w, RGB), and ``cross``
    the same on each of the ``partners``' lattices ((PreparedMedium, PathLattice), the media
    its paths fly through).  None where ``pm`` absorbs nothing (and no surface's deficit is
    traced), the sky is black, there is no camera or nowhere to scatter.  ``n_paths`` paths
    (``setting`` the Paths setting that scales their cap), ``around`` the surfaces they
    reflect off; ``surfaces`` those that hide the sky (s: ``n_dirs`` directions a point of
    the world light's lattice).  ``path_weight``: None, or the mean weight (W a path) of the
    lights' paths in ``pm``: the paths are then as many as give the fictitious emission's
    scattered power the same weight a path (``weighted_paths``), at most ``setting`` (or
    ``n_paths`` without one), where that is more than ``n_paths`` (fewer, cloud_vdb's 78 000
    instead of 375 000, took its full render 0.0161 -> 0.0170).

    ``ground`` (with ``around``'s surfaces): the surfaces round ``pm`` have their own
    deficit (module docstring): s is 1, and D also holds the flights after the first of
    the surfaces' fictitious emission (pathstarts.sky_ground_starts), on paths of their own
    that fly through ``pm`` alone (another medium traces its own): as many as give their
    light into its bounding sphere (``sphere_share``) the lights' paths' weight, at least
    ``n_paths`` and at most ``setting`` (all of it without a ``path_weight``: no lamp)."""
    colour = np.asarray(colour, np.float64).reshape(3)
    if camera is None or pm.endless or not np.any(colour > 0.0):
        return None
    walled = bool(ground and around is not None and around.surfaces is not None
                  and not around.surfaces.empty)
    rho = density_from(pm.grid, pm.threshold).reshape(-1)
    flat = np.flatnonzero(rho > 0.0)
    e = absorption_at(pm, flat, rho[flat]) * colour[None, :]
    keep = e.sum(axis=1) > 0.0
    flat, e = flat[keep], e[keep]
    got = None
    if len(flat):
        if surfaces is not None and not surfaces.empty and not walled:
            e *= seen_share(pm, flat, surfaces, n_dirs, seed,
                            tuning.ambient_resolution)[:, None]
        n_abs = n_paths
        if path_weight is not None and path_weight > 0.0:
            n_abs = max(int(n_paths), weighted_paths(pm, e, path_weight,
                                                     n_paths if setting is None else setting))
        odds = camera_odds(pm, flat, e, camera, resolution, tuning.sky_deficit_mix,
                           threads=threads, should_cancel=should_cancel)
        got = scattered_glow(pm, (flat, e), camera, n_abs, resolution, True, seed=seed,
                             threads=threads, should_cancel=should_cancel, around=around,
                             partners=partners, deposits=tuning.path_deposits,
                             nodal=tuning.path_nodal, setting=setting, signed=True,
                             first_order=False, odds=odds, lobe_window=tuning.lobe_window)
    walls = None
    if walled:
        starts = sky_ground_starts(pm, around, seed, colour)
        if starts is not None:
            p, power, normals, jitter = starts
            # each point as likely as the next: they lie denser near the medium (1/d^3 a
            # unit of area), where more of their light reaches it, and their paths are
            # aimed at it (paths.py, lobe 3); each path's weight is its point's power over
            # those odds.  (Drawn by the power each sends into the medium's bounding sphere
            # instead, the cube of tests/test_sky_ground.py over a black ground scattered
            # 0.97-1.07 of the walks over four seeds, against 1.00-1.05.)
            entering = power.sum(axis=1) * sphere_share(pm, p, normals)
            bias = 1.0 / np.maximum(power.sum(axis=1), 1e-300)
            most = n_paths if setting is None else max(int(n_paths), int(setting))
            n_walls = most if path_weight is None or not path_weight > 0.0 else \
                int(min(most, max(int(n_paths), np.ceil(
                    float(entering.sum()) * largest_albedo(pm) / float(path_weight)))))
            walls = scattered_glow(pm, None, camera, n_walls, resolution, True,
                                   seed=seed + 7, threads=threads,
                                   should_cancel=should_cancel, around=around,
                                   deposits=tuning.path_deposits, nodal=tuning.path_nodal,
                                   setting=setting, signed=True, first_order=False,
                                   lobe_window=tuning.lobe_window,
                                   starts=[(p, power, normals, jitter, 3, None, bias)])
    if got is None and walls is None:
        return None
    if got is None:
        return walls[0], walls[2], []
    stride, _, later, cross, _ = got
    if walls is not None:
        later = later + walls[2]
    return stride, later, [m for _, m in cross]


def sphere_share(pm: PreparedMedium, points, normals) -> np.ndarray:
    """(N,) about the share of a cosine lobe from each of ``points`` (normals ``normals``)
    that enters ``pm``'s bounding sphere: cos(theta) sin^2(alpha) (theta the sphere's centre
    off the normal, alpha the half-angle of its cone), 1 inside the sphere."""
    centre, _, radius = surface_reach(pm)   # its scale r0: the bounding radius
    axis = centre[None, :] - np.asarray(points, np.float64)
    d2 = np.einsum("ij,ij->i", axis, axis)
    cos = np.einsum("ij,ij->i", axis, normals) / np.sqrt(np.maximum(d2, 1e-300))
    return np.where(d2 > radius * radius,
                    np.clip(cos, 0.0, 1.0) * radius * radius / np.maximum(d2, 1e-300), 1.0)


def absorption_at(pm: PreparedMedium, flat: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """(N,3) sigma_a (1/m) at the voxels ``flat`` of ``pm`` of density ``rho`` (N,): its
    extinction (per channel from the extinction grid where it has one) less its scattering
    (times the scattering colour's factor where it varies), at least 0."""
    st = np.asarray(pm.sigma_t, np.float64).reshape(1, 3)
    ss = np.asarray(pm.sigma_s, np.float64).reshape(1, 3)
    ext = pm.extinction_density
    if ext is None and pm.scatter_grid is None:   # one albedo: sigma_a per unit density
        return np.asarray(rho, np.float64)[:, None] * np.maximum(st - ss, 0.0)
    t = st * (rho[:, None] if ext is None else ext.reshape(-1, 3)[flat].astype(np.float64))
    factor = pm.scatter_at(flat)
    sc = ss * rho[:, None] * (1.0 if factor is None else factor)
    return np.maximum(t - sc, 0.0)


def seen_share(pm: PreparedMedium, flat: np.ndarray, surfaces, n_dirs: int, seed: int,
               resolution: int) -> np.ndarray:
    """(N,) the share of the sky the voxels ``flat`` of ``pm`` see past the ``surfaces``:
    worldlight.sky_share at the points of the world light's lattice, interpolated
    trilinearly."""
    got = world_lattice(pm, resolution)
    cpts = got[3]
    share = np.zeros(len(cpts))
    for a in range(0, len(cpts), SHARE_CHUNK):
        b = min(len(cpts), a + SHARE_CHUNK)
        share[a:b] = sky_share(surfaces, cpts[a:b], seed, a, b, n_dirs)
    return at_voxels(pm, flat, got, share)


def at_voxels(pm: PreparedMedium, flat: np.ndarray, lattice, values: np.ndarray) -> np.ndarray:
    """(N,) ``values`` (one per point of ``lattice`` = worldlight.world_lattice's (stride,
    shape, flat, points)) interpolated trilinearly at the voxels ``flat`` of ``pm``, within
    [0, 1] (a share, a transmittance)."""
    stride, shape, cflat, _ = lattice
    grid = on_lattice(shape, cflat, np.repeat(np.asarray(values)[:, None], 3, axis=1))
    ijk = np.stack(np.unravel_index(flat, pm.grid.shape[:3]), axis=1).astype(np.float64)
    return np.clip(kernels.trilinear(grid, ijk / stride)[:, 0].astype(np.float64), 0.0, 1.0)


def weighted_paths(pm: PreparedMedium, e: np.ndarray, path_weight: float, most: int) -> int:
    """The paths for the fictitious emission ``e`` (N,3) W/(m^3 sr) at ``pm``'s voxels so that
    each carries, once it has scattered, the lights' mean weight ``path_weight`` (W a path):
    its power 4 pi e V summed over the voxels and channels, times the largest albedo (what
    scatters at the first collision), over that weight; at least 1, at most ``most``.  The
    lights' paths start in proportion to their power (paths.from_power); the deficit's, whose
    light is taken off the sky's in the same pass, follow the same rule, so that neither's
    noise outweighs the other's for its power."""
    scattered = 4.0 * np.pi * cell_volume(pm, 1) * float(np.asarray(e, np.float64).sum()) * \
        largest_albedo(pm)
    return int(min(max(1, int(most)), max(1.0, np.ceil(scattered / float(path_weight)))))


def camera_odds(pm: PreparedMedium, flat: np.ndarray, e: np.ndarray, camera, resolution: int,
                mix: float, threads: int = 0, should_cancel=None) -> Optional[np.ndarray]:
    """(N,) the relative odds of starting a path at the voxels ``flat`` of ``pm`` (emission
    ``e`` (N,3)): mix + (1 - mix) v / <v> (module docstring), v from the optical depth to the
    camera's position at the points of a lattice of ``resolution`` points along the grid's
    longest side (the paths' own: a coarser one, the world light's 32, spread the seen layer
    and kept less of the gain), interpolated trilinearly; None (every voxel by its power
    alone) where ``mix`` >= 1 or the walk reaches everywhere the medium is."""
    reach = walk_reach(largest_albedo(pm), pm.g)
    if not (mix < 1.0) or not np.isfinite(reach):
        return None
    lattice = world_lattice(pm, resolution)
    tau = eye_depth(pm, np.asarray(camera.cam_to_world, np.float64)[:3, 3], lattice[3],
                    threads=threads, should_cancel=should_cancel)
    v = at_voxels(pm, flat, lattice, np.exp(-np.maximum(tau - reach, 0.0)))
    power = np.asarray(e, np.float64).sum(axis=1)
    mean = float((v * power).sum() / max(float(power.sum()), 1e-300))
    if not mean > 0.0:
        return None
    return mix + (1.0 - mix) * v / mean

