"""The world light: the RGB radiance the constant world background brings to each voxel
after the phase function towards the camera and the attenuation through all media,
A(x) = L_world * integral p(w_in . w_cam(x)) T(x, -w_in) dw_in, estimated with directions
drawn from the phase lobe (so the estimate is the mean transmittance; each direction's optical
depth marched until it is lightdepth.OPAQUE_DEPTH in every channel, past which its
transmittance is below half an ulp of 1).  w_cam(x) points from x to the camera, which is
exact for camera rays through x.  It is mostly smooth: computed on a
coarse lattice (``Tuning.ambient_resolution`` points along the grid's longest side) and interpolated
to the voxels whose trilinear support touches non-zero density (lattice.needed_flat; the rest
stay 0): geometrically (its logarithm trilinearly) in the cells whose lattice points all lie
inside the medium, where A falls exponentially and a linear chord reads it too bright,
linearly across the medium's surface (``inside_lattice``).  Its multiply scattered part A_ms
rises into the medium as A falls: in a medium of one albedo alpha, alone, A_ms + alpha A is
alpha L_world wherever the sky is seen (``furnace_albedo``), so that sum is interpolated
linearly and A_ms taken from it and the interpolated A; elsewhere A_ms linearly (a
geometric chord would read its rise too dark).  Where a cell still misses (the
sky's lit layer of a medium optically thick across a lattice cell, where A falls by a large
factor between the cell's corners), the voxels of that cell get their own value
(``refine_flat``, ``Tuning.ambient_refine``).
"""
from __future__ import annotations

from typing import List, Optional

import numpy as np

from .. import kernels
from ..camera import towards_camera
from ..media import PreparedMedium, density_from
from ..parallel import run_chunks
from ..phase import sample_hg
from ..scene import Camera, Tuning, World
from ..surfaces import intersect, occluded, sky_albedo
from .lattice import coarse_lattice, grid_points, lattice_index, lattice_values
from .lightdepth import density_lengths, depth_rows


REFINE_SEED = 104729  # offsets the refined voxels' streams from the lattice's
SHARE_SEED = 15485863  # offsets sky_share's directions' streams from the sky's own
REFINE_CHUNK = 1 << 20  # voxels whose cells refine_flat looks up at a time
WORLD_RNG_BLOCK = 1 << 11  # points sharing one random stream in world_light
WORLD_CHUNK_RAYS = 1 << 14  # rays (points x directions) per world-light chunk, for a quick Esc
GOLDEN = 0.6180339887498949  # the golden ratio's fraction: the directions' azimuth sequence


def world_chunk(n_dirs: int) -> int:
    """Points per world-light chunk: at most ``WORLD_CHUNK_RAYS`` rays, a power of two that
    divides ``WORLD_RNG_BLOCK`` (at least 16 points)."""
    chunk = WORLD_RNG_BLOCK
    while chunk > 16 and chunk * max(1, int(n_dirs)) > WORLD_CHUNK_RAYS:
        chunk //= 2
    return chunk


def _block_uniforms(seed, a, b):
    """(b - a, 2) uniforms for points a..b-1: point i takes row i mod WORLD_RNG_BLOCK of the
    stream seeded by (seed, 7919, start of its block), so the numbers do not depend on how
    the points are cut into chunks."""
    parts = []
    s = a
    while s < b:
        block = s - s % WORLD_RNG_BLOCK
        e = min(b, block + WORLD_RNG_BLOCK)
        rows = np.random.default_rng([seed, 7919, block]).random((e - block, 2))
        parts.append(rows[s - block:])
        s = e
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def phase_directions(seed: int, a: int, b: int, n_dirs: int, g: float, to_cam) -> np.ndarray:
    """((b - a) * n_dirs, 3) unit propagation directions of light arriving at points a..b-1
    and scattered towards the camera (``to_cam`` (b - a, 3) unit), ``n_dirs`` per point drawn
    from the HG lobe of ``g``: stratified in the cosine, a golden-ratio sequence in the
    azimuth, each point's pair shifted by its own uniforms (``_block_uniforms``)."""
    j = np.arange(n_dirs)
    r = _block_uniforms(seed, a, b)
    u1 = np.mod((j[None, :] + 0.5) / n_dirs + r[:, :1], 1.0).ravel()
    u2 = np.mod(j[None, :] * GOLDEN + r[:, 1:], 1.0).ravel()
    return sample_hg(u1, u2, g, np.repeat(np.asarray(to_cam, np.float64), n_dirs, axis=0))


def sky_share(surfaces, points, seed: int, a: int, b: int, n_dirs: int) -> np.ndarray:
    """(b - a,) the share of the sphere of directions from ``points`` (points a..b-1 of the
    lattice) that no surface hides: ``n_dirs`` directions each, uniform and stratified as
    ``phase_directions`` draws them (g = 0) on a stream of their own."""
    m = len(points)
    w = phase_directions(seed + SHARE_SEED, a, b, n_dirs, 0.0, np.tile([0.0, 0.0, 1.0], (m, 1)))
    hit = occluded(surfaces, np.repeat(points, n_dirs, axis=0), w, np.full(m * n_dirs, np.inf))
    return 1.0 - hit.reshape(m, n_dirs).mean(axis=1)


def world_light(media: List[PreparedMedium], pm: PreparedMedium, world: World, camera: Camera,
                points, n_dirs, step, seed=0, chunk=None, should_cancel=None, surfaces=None,
                threads=0, multiple=False, tuning: Tuning = Tuning(), fog_sigma_t=None,
                deficit: bool = False, ground: Optional[bool] = None):
    """A(x) (N,3): world radiance scattered towards the camera per unit sigma_s, attenuated;
    with ``multiple`` also A_ms(x) (N,3), the same for the sky light that has scattered on
    its way in, and the pair is returned: with ``deficit`` (the absorption's later flights
    are traced and taken off, precompute.skydeficit) the collided part of a furnace less the
    absorption's first flight, (tau_s / tau_t)(1 - exp(-tau_t)); without (the world fog's
    glow, or no camera) the model exp(-tau_a) (1 - exp(-tau_s)) (docs/method.md §9.8).
    Points draw their jitter from streams seeded by (seed, block of ``WORLD_RNG_BLOCK``
    points), so the result depends on neither the thread count nor the chunk size (by
    default ``world_chunk(n_dirs)``, short enough to serve Esc quickly).
    ``fog_sigma_t``: None for the sky (the surfaces cut it off), or the RGB extinction (1/m)
    of the endless fog whose glow ``world.color`` is (precompute.fogglow.glow_on_medium): a
    surface at t metres along a direction hides only the fog behind it, the glow from there
    scaled by 1 - exp(-sigma t).  ``ground``: with ``deficit``, None, or where the
    surfaces' own deficit is traced (pathstarts.sky_ground_starts) whether they reflect
    light (Settings.surface_bounce): along a direction that ends on a surface the furnace
    holds as if the surface sent L_w back, so the collided part is the whole furnace's up to
    it, and the multiply scattered part also takes the surface's light less that deficit's
    first flight, R L_w exp(-tau), R the surface's directional albedo towards the point
    (surfaces.sky_albedo; 0 where they do not reflect) (docs/method.md §9.8); without
    ``ground`` the collided part there is scaled by the point's share of the sky
    (``sky_share``).  Raises cancel.Cancelled on Esc."""
    colour = np.asarray(world.color, np.float64)
    n = len(points)
    if n == 0 or not np.any(colour > 0):
        return (np.zeros((n, 3)), np.zeros((n, 3))) if multiple else np.zeros((n, 3))
    # (M, 3); with no media but the fog (which has no extinction where the sky still shows)
    # every optical depth is 0
    tracks, sig_t, sig_s = depth_rows(media)
    out = np.zeros((n, 3))
    out_ms = np.zeros((n, 3))
    chunk = world_chunk(n_dirs) if chunk is None else int(chunk)

    def work(a, b):
        p = points[a:b]
        m = len(p)
        to_cam = towards_camera(camera, p)
        w_in = phase_directions(seed, a, b, n_dirs, pm.g, to_cam)  # the arriving light's
        d = -w_in  # march towards where the light comes from
        pp = np.repeat(p, n_dirs, axis=0)
        t_max = np.full(len(pp), np.inf)
        seen = 1.0
        walled = surfaces is not None and not surfaces.empty
        hidden = None
        tri = None
        if walled:   # the media's path ends at the surface
            t, tri = intersect(surfaces, pp, d, t_max)
            t_max = np.where(tri >= 0, t, np.inf)
            if fog_sigma_t is not None:   # the fog before the surface still glows
                seen = np.where((tri >= 0)[:, None],
                                -np.expm1(-np.asarray(fog_sigma_t)[None, :] * t[:, None]), 1.0)
            else:
                # a surface hides the sky beyond it; the medium before it still scatters
                # the sky's light it gets from elsewhere along the direction (below)
                hidden = tri >= 0
        lengths = density_lengths(tracks, pp, d, t_max, step, tuning, sig_t) \
            if tracks else np.zeros((len(pp), 0))
        tau = lengths @ sig_t
        direct = np.exp(-tau) if hidden is None else \
            np.where(hidden[:, None], 0.0, np.exp(-tau))
        out[a:b] = (direct * seen).reshape(m, n_dirs, 3).mean(axis=1) * colour
        if multiple:
            tau_s = np.minimum(lengths @ sig_s, tau)
            if deficit:
                collided = np.divide(tau_s, tau, out=np.zeros_like(tau), where=tau > 0.0) * \
                    -np.expm1(-tau) * seen
            else:
                collided = np.exp(-(tau - tau_s)) * -np.expm1(-tau_s) * seen
            if hidden is not None and np.any(hidden) and deficit and ground is not None:
                # the furnace with the surface sending L_w back: its traced deficit
                # (skydeficit.py) takes off what the surface lacks of that, but for its
                # first flight, which is this
                if ground:
                    collided[hidden] += sky_albedo(surfaces, tri[hidden], d[hidden]) * \
                        np.exp(-tau[hidden])
            elif hidden is not None and np.any(hidden):
                # the medium between the point and a surface is lit by the share of the
                # sky the point itself sees (half over a wide ground)
                vis = sky_share(surfaces, p, seed, a, b, n_dirs)
                collided = np.where(hidden[:, None],
                                    collided * np.repeat(vis, n_dirs)[:, None], collided)
            out_ms[a:b] = collided.reshape(m, n_dirs, 3).mean(axis=1) * colour

    run_chunks(n, chunk, work, threads, should_cancel)
    return (out, out_ms) if multiple else out


def fill_world_light(f: np.ndarray, channels, media: List[PreparedMedium], pm: PreparedMedium,
                     world: World, camera: Camera, flat, n_dirs, step, seed=0,
                     should_cancel=None, surfaces=None, threads=0, tuning: Tuning = Tuning(),
                     deficit: bool = False, ground: Optional[bool] = None):
    """Write the world light (``world_light`` through ``media``, on ``coarse_lattice``,
    interpolated to the needed voxels ``flat``: geometrically in the cells inside the
    medium, A_ms from A where ``furnace_albedo`` holds, see the module's docstring) into
    ``pm``'s field ``f`` at ``channels`` = (A's first channel, A_ms's or None); the voxels
    of the lattice cells that ``refine_flat`` picks (``tuning.ambient_refine``) get A computed at their own
    centres instead; ``deficit``, ``ground``: world_light's.  Returns the number of points computed
    (lattice and voxels)."""
    amb, amb_ms = channels
    stride, cshape, cflat, cpts = world_lattice(pm, tuning.ambient_resolution)

    def light(points, s):
        return world_light(media, pm, world, camera, points, n_dirs, step, seed=s,
                           should_cancel=should_cancel, surfaces=surfaces, threads=threads,
                           multiple=amb_ms is not None, tuning=tuning, deficit=deficit,
                           ground=ground)
    a = light(cpts, seed)
    lattices = [on_lattice(cshape, cflat, vals) for vals in (a if amb_ms is not None else (a,))]
    # A falls into the medium: geometric in the cells wholly inside it.  Its collided part
    # rises as A falls, alpha (L_w - A) where the sky is seen (the furnace): where that holds
    # A_ms + alpha A is even, read linearly, and A_ms follows A's interpolation; else linear
    alpha = furnace_albedo(media, pm) if amb_ms is not None and deficit else None
    if alpha is not None:
        lattices[1] = lattices[1] + alpha * lattices[0]
    geometric = (inside_lattice(pm, stride, cshape), None)
    for ch, lat, inside in zip((amb, amb_ms), lattices, geometric):
        kernels.upsample_into(f, ch, lat, stride, flat, inside=inside)
    if alpha is not None:
        view = f.reshape(-1, f.shape[-1])
        at = slice(None) if flat is None else np.asarray(flat, np.int64)
        view[at, amb_ms:amb_ms + 3] -= (alpha[None, :] * view[at, amb:amb + 3]).astype(f.dtype)
    have = np.zeros(int(np.prod(cshape)), bool)
    have[cflat] = True
    fine = refine_flat(lattices[0], have.reshape(cshape), stride, pm.grid.shape, flat,
                       world.color, tuning.ambient_refine)
    if len(fine):
        b = light(grid_points(pm, fine), seed + REFINE_SEED)
        view = f.reshape(-1, f.shape[-1])
        for ch, vals in zip((amb, amb_ms), b if amb_ms is not None else (b,)):
            view[fine, ch:ch + 3] = vals
    return len(cpts) + len(fine)


def interpolation_error(hi: np.ndarray, lo: np.ndarray) -> np.ndarray:
    """The error of interpolating linearly, at the middle, a quantity that falls
    exponentially from ``hi`` to ``lo`` (>= 0, elementwise): hi ((1 + r) / 2 - sqrt(r)),
    r = lo / hi (0 where hi is 0).  The sky's light falls so into a medium's lit layer."""
    hi = np.asarray(hi, np.float64)
    r = np.divide(lo, hi, out=np.zeros_like(hi), where=hi > 0.0)
    r = np.clip(r, 0.0, 1.0)
    return hi * (0.5 * (1.0 + r) - np.sqrt(r))


def refine_flat(values: np.ndarray, have: np.ndarray, stride: int, shape, flat, colour,
                tol: float) -> np.ndarray:
    """The voxels of ``flat`` (flat indices into a padded grid of ``shape``) that lie in a
    cell of the world light's lattice (``stride`` voxels a side; ``values`` (LX,LY,LZ,3) the
    light at its points, ``have`` (LX,LY,LZ) bool where it was computed) whose
    ``interpolation_error`` between its computed corners' largest and smallest values is
    above ``tol`` times the world's radiance ``colour`` in some channel; the lattice's own
    points left out (they hold their value).  Empty where ``tol`` <= 0, the lattice is one
    voxel apart or has fewer than 2 points along an axis."""
    none = np.zeros(0, np.int64)
    shp = np.asarray(have.shape)
    flat = np.asarray(flat, np.int64)
    if not (tol > 0.0) or stride <= 1 or np.any(shp < 2) or len(flat) == 0:
        return none
    col = np.asarray(colour, np.float64).reshape(3)
    v = np.asarray(values, np.float64)
    hi = np.full(tuple(shp - 1) + (3,), -np.inf)
    lo = np.full(tuple(shp - 1) + (3,), np.inf)
    for di in (0, 1):
        for dj in (0, 1):
            for dk in (0, 1):
                sl = (slice(di, shp[0] - 1 + di), slice(dj, shp[1] - 1 + dj),
                      slice(dk, shp[2] - 1 + dk))
                h = have[sl][..., None]
                hi = np.maximum(hi, np.where(h, v[sl], -np.inf))
                lo = np.minimum(lo, np.where(h, v[sl], np.inf))
    some = np.isfinite(hi[..., 0])
    err = interpolation_error(np.where(some[..., None], hi, 0.0),
                              np.where(some[..., None], lo, 0.0))
    scale = np.where(col > 0.0, col, np.inf)
    coarse = np.any(err > tol * scale, axis=-1)
    if not coarse.any():
        return none
    pick = np.zeros(len(flat), bool)
    for a in range(0, len(flat), REFINE_CHUNK):   # bounded memory on a large grid
        ijk = np.unravel_index(flat[a:a + REFINE_CHUNK], tuple(shape))
        cell = [np.minimum(i // stride, n - 2) for i, n in zip(ijk, shp)]
        on_point = (ijk[0] % stride == 0) & (ijk[1] % stride == 0) & (ijk[2] % stride == 0)
        pick[a:a + REFINE_CHUNK] = coarse[cell[0], cell[1], cell[2]] & ~on_point
    return flat[pick]


def furnace_albedo(media, pm: PreparedMedium) -> Optional[np.ndarray]:
    """(3,) alpha = sigma_s / sigma_t of ``pm``, where each of the sky's directions at a
    point of its lattice brings alpha (1 - e^-tau) L_w collided for e^-tau L_w direct (the
    furnace with the absorption's first flight taken off, world_light's ``deficit``): the
    medium alone in ``media`` and of one albedo (no scattering or extinction colour grid);
    else None.  Where the sky is seen from a point, A_ms + alpha A is alpha L_w there."""
    if len(media) != 1 or pm.scatter_grid is not None or pm.extinction_density is not None:
        return None
    st = np.asarray(pm.sigma_t, np.float64)
    return np.divide(np.asarray(pm.sigma_s, np.float64), st, out=np.zeros(3), where=st > 0.0)


def inside_lattice(pm: PreparedMedium, stride: int, shape) -> np.ndarray:
    """uint8 (shape) 1 at the lattice points (every ``stride`` voxels of ``pm``'s padded grid)
    where the medium has density (a mesh volume's: at or above its threshold), else 0 (and
    on the grid's last plane and beyond, its padding: lattice.lattice_values): the cells
    between points that are all inside take the world light geometrically
    (``fill_world_light``)."""
    rho = lattice_values(pm.grid, lattice_index(shape), stride)
    return np.ascontiguousarray((density_from(rho, pm.threshold) > 0.0).reshape(shape),
                                np.uint8)


def world_lattice(pm: PreparedMedium, resolution: int = Tuning.ambient_resolution):
    """(stride, shape, flat, points) of the world light's coarse lattice on ``pm``: about
    ``resolution`` points along the grid's longest side (lattice.coarse_lattice)."""
    stride = max(1, int(round(max(pm.grid.shape) / max(1, int(resolution)))))
    return (stride,) + tuple(coarse_lattice(pm, stride))


def on_lattice(shape, flat, values) -> np.ndarray:
    """float32 (shape + (3,)): ``values`` (N,3) at the lattice points ``flat``, 0 elsewhere."""
    out = np.zeros((int(np.prod(shape)), 3), np.float32)
    out[flat] = values
    return out.reshape(tuple(shape) + (3,))
