"""Multiple scattering by light paths traced through the medium (the converging estimate).

The walk of the light pyramid (walk.py, precompute/lightpyramid.py) is a model: smooth and
cheap, but with errors no setting removes.  This module estimates the same quantity by Monte
Carlo, so that it converges as paths are added and the lattice is refined:

    M(y) = integral of rho(x) t_y(x) [integral over directions of L_1+(x, w) p(w . v(y); g) dw]
           d^3x / integral of rho(x) t_y(x) d^3x                                  [W/(m^2 sr)]

(t_y the trilinear tent of lattice point y, rho the density) where L_1+ is the radiance of
the light that has scattered at least once, v(y) the unit direction from the lattice point y
to the camera and p the medium's Henyey-Greenstein phase function (phase.py: cosine between
propagation directions).  The march reads it as one flattened level (march.MarchContext):
J_ms(x) = rho(x) sigma_s M(x), the radiance that the medium at x scatters towards the camera
from the light that has scattered before, i.e. every order from the second on.  Single
scattering stays the march's exact one.

**Paths.**  Each path starts where the light's unscattered beam first scatters: a lattice
point drawn in proportion to its first-scattering power Q V (precompute.source:
Q = sigma_s E exp(-tau), W/m^3, tent-shared from the voxels, so a tent-distributed offset of
one lattice step per axis undoes the sharing), with the direction drawn from p about the
light's propagation there.  It then flies through the voxels' density (nearest voxel), with
tentative collisions at a rate mu = max(majorant, k / h) per metre (h the lattice spacing,
k = Tuning.path_deposits, the deposits per spacing at least, via PathInputs.rate;
null-collision tracking, Woodcock et al. 1965): at each tentative point the path deposits
its weight / mu times the density there, times the trilinear share of each of the 8 lattice
points around it and p(w . v) at that point (the track-length estimate of the integral of
rho L p against each point's tent, unbiased for any mu >= the majorant; divided by the
tent's integral of rho, precompute.lightpaths makes M the medium's mean under the tent, so
a lattice point beside the medium's surface is not diluted by the empty side); a tentative
point is a real collision with probability P = rho sigma_t,max / mu.  Chromatic media use
spectral tracking (Kutz et al. 2017, "Spectral and decomposition tracking"): P =
rho sigma_t,max / (rho sigma_t,max + mu - rho sigma_t,min), so that a null collision stays
possible while any channel has null density; a real collision multiplies channel c by
rho sigma_s,c / (mu P), a null one by (mu - rho sigma_t,c) / (mu (1 - P)).
After ``MAX_COLLISIONS`` real collisions and bounces a path ends; below a tenth of its start
weight it survives a Russian roulette; after ``MAX_EVENTS`` tentative collisions it ends too.
A rate that would put more than ``MAX_RATE_SPAN`` tentative points along the grid's diagonal
is refused (``rate_span``), and beyond ``PATHS_MAX_SPAN`` the precompute keeps the walk.

**The camera's roulette** (``odds``).  Deep in a thick absorbing medium a path's light never
reaches the camera, yet its flights cost as much as any.  With ``odds`` (one value in (0, 1]
per lattice point; precompute/camerareach.py makes them from the camera's optical depth), at
each real collision inside the paths' own grid the nearest lattice point's odds q are read;
where q is below the lowest odds the path has survived (``held``, 1 at its start), it goes on
with probability q / held, its weight (and its start weight, so that the weight's own roulette
sees the same path) times held / q, and held becomes q.  A path that has reached odds q has
survived with probability q and weighs 1 / q of its plain weight: unbiased, and played once
a path however often it comes back (played at every collision, the weights compounded to
q^-k and spotted the image).  One random number, ``_D_CAMERA``, at the collision's event.

**Beyond the grid.**  The grid's box in index space is [-0.5, n - 0.5] per axis (the
nearest-voxel domain).  A flight that crosses its face stops there and starts again
(exponential flights forget their past).  Outside, the medium has the density ``outside``
(1 for the world's fog, which fills all space; 0 for any other medium): a path flies there
with the rate outside x sigma_t,max and deposits nothing; in empty space it flies straight to
the box, or away for good.  A path outside beyond ``reach_radius`` of ``reach_centre`` ends.

**Several media** (``others``, PathMedium).  Where media overlap (a cube of smoke inside a
sphere of haze), a path flies through all of them: each medium keeps its own tentative
collisions at its own rate mu_j inside its own box, so their sum is the whole's rate, and a
tentative point is medium j's with probability mu_j over the sum (one more random number,
``_D_MEDIUM``, drawn only with several media).  It then deposits on medium j's lattice (with
j's phase function) and is a real collision by j's coefficients, turning by j's phase
function.  What one medium's paths deposit on another's lattice is added to that medium's M
(precompute.run): the light scattered in one and again in another, and the shadow each
casts on the other's multiply scattered light.  The world's fog, which fills all space,
traces alone.

**Surfaces.**  Every flight is tested against the ``triangles`` (Moller-Trumbore, culled by
boxes of 64 triangles); the nearest one hit before the flight's end stops it, and the path
reflects diffusely (a cosine-distributed direction on the side it came from) with its weight
times the triangle's ``albedo`` (RGB), a bounce that counts as a collision for the roulette
and the cap.  Albedo 0 absorbs.

**Starts.**  ``lobe`` 0: the first direction is drawn from p about ``dirs`` and the start is
offset by a tent of half-width ``jitter`` lattice steps per index axis (1: the lattice
point's own tent; 0: the point itself), rejection-sampled against the voxels' own
first-scattering source ``start_source`` (without one: 1 in the medium, 0 outside), so
that the starts follow the voxels' source and not the tent alone (``start_positions``).
The tent alone spread the light that first scatters in the thin layer under a lit surface
a lattice step around it, part of it outside the medium: p_sphere_lowalbedo's multiple
scattering was 0.91 of Cycles'.  ``lobe`` 1 (a surface): the direction is
cosine-distributed about ``dirs`` (the lit side's normal), and the offset a tent of half-width
``jitter`` metres in the plane across it.  ``lobe`` 2 (an emitting voxel,
precompute.emissionlight): the direction is uniform over the sphere, the offset as lobe 0's.
``lobe`` 3 (a surface far from the medium, aimed): the offset as lobe 1's; the direction is
cosine-distributed with probability ``AIM_COSINE``, else uniform within the cone that the
reach sphere (``reach_centre``, ``reach_radius``) subtends from the start, and the weight
is multiplied by the cosine lobe's density over that mixture's (a defensive mixture: every
direction above the surface keeps a density, so the light that reaches the medium after a
bounce elsewhere is kept; one below it ends the path).  From a ground tens of metres wide
the cosine lobe alone sends nearly every path past a medium a metre across, and the few
that reach it weigh the most (a sky's deficit off a black ground, tests/test_sky_ground.py).
A start inside the sphere draws the cosine lobe alone.

**Moments** (``moments``).  M above is the light scattered towards the camera, v(y) fixed per
lattice point; a surface's gather looks through the medium along other directions (the ground
under a cloud sees the light scattered down, not towards the camera).  With ``moments`` every
deposit also adds, per channel, M0 += deposit / (4 pi) (channels 3..5) and
M1 += g w deposit / (4 pi) (channels 6 + 3 j + c, axis j; w the path's direction), all of it
on one of the 8 lattice points round it, drawn with the trilinear shares as probabilities
(the same mean as sharing it, an eighth of the work: the moments' sums were most of the
precompute where they were shared).  These are
the first two Legendre moments of M(v) for every v: M(v) = M0 (1 + 3 G . v + ...) with
G = M1 / M0, whatever the paths' directions.  The march (kernels_np.read_level) closes the
series with a Henyey-Greenstein lobe, M(v) ~ 4 pi M0 HG(v . G / |G|; |G|), exact where the
directions w about a point are themselves HG-distributed (the phase function's convolution
multiplies the Legendre coefficients, g^l m^l = (g m)^l), and exact in the first two moments
always.  In a cube lit at one point (tests/test_moments.py) the closure's sum over the lattice
is within 1 % of the exact M towards v for g = 0.3, 6 % for 0.6, 15 % for 0.85 (cutting the
series after two terms instead: 1 %, 21 %, 4x).

Random numbers are the march's counter hash (rng.uniform) of (path key, event,
dimension), so the C kernel (csrc/paths.c) and this numpy twin draw the same numbers and
trace the same paths.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .rng import hash32, uniform
from .phase import clamp_g, hg, sample_hg

__all__ = ["PathInputs", "trace_paths_np", "MAX_COLLISIONS", "ROULETTE", "PATHS_MAX_SPAN"]

MAX_COLLISIONS = 4096    # real collisions after which a path ends (albedo 1, optical depth 1e4)
ROULETTE = 0.1           # below this fraction of its start weight a path plays roulette
AIM_COSINE = 0.25        # an aimed surface start (lobe 3): the share drawn by the cosine lobe
MAX_EVENTS = 1_000_000   # tentative collisions after which a path ends (csrc/paths.c)
MAX_RATE_SPAN = 1e6      # the most tentative collisions along the grid's diagonal (csrc/paths.c)
T_MIN = 1e-9             # m: a surface nearer than this along a flight is not hit (csrc/paths.c)
FAR = 1e30               # m: how far a flight into empty space is tested against surfaces
# Beyond this many tentative collisions along the grid's diagonal (an optical size of about
# 2000) the precompute keeps the walk: an albedo-1 medium of optical depth 1e3 took 370 us a
# path (4096 collisions each), 6 minutes for a default render's paths.
PATHS_MAX_SPAN = 2000.0

# random dimensions
_D_PICK, _D_JIT, _D_DIR, _D_FLY, _D_HIT, _D_TURN, _D_RR, _D_BOUNCE = 0, 1, 7, 10, 11, 12, 14, 15
_D_RETRY = 16     # a start's offset drawn again: 6 dimensions per try (csrc/paths.c)
_D_ACCEPT = 512   # a start's acceptance draw, one dimension per try
_D_CORNER = 600   # the lattice corner a deposit's moments go to
_D_MEDIUM = 17    # which medium a tentative collision is in, with several (csrc/paths.c)
_D_LIGHT = 700    # the emitter point a first scattering's light comes from (csrc/paths.c)
_D_LIGHT_MORE = 702   # the other candidate emitter points, two dimensions each
LIGHT_CANDIDATES = 8  # emitter points a start with a start_rate draws one from (csrc/paths.c)
_D_LIGHT_PICK = _D_LIGHT_MORE + 2 * (LIGHT_CANDIDATES - 1)   # which of them (716)
_D_AIM = 5        # an aimed surface start's choice of lobe or cone (csrc/paths.c)
_D_CAMERA = 800   # the camera's roulette at a real collision (csrc/paths.c)
PATH_MEDIA = 8    # media one trace flies through at most: its own and 7 others
BOX_TIE = 1e-9    # m (relative beyond 1 m): box faces this close are crossed together
START_TRIES = 64  # offsets drawn for a first scattering until one is accepted
# deposits with the moments: 3 towards the camera, 3 of order 0, 3 x 3 of order 1 (x, y, z)
MOMENT_CHANNELS = 15
SIGNED_CHANNELS = 9   # the last of them, the order-1 moments, may be below 0


@dataclass
class PathMedium:
    """Another medium a trace's paths fly through, scatter in and deposit on
    (``PathInputs.others``): ``density`` float32 (X,Y,Z) per voxel, ``w2i`` (3,4) world ->
    voxel index, ``sigma_s``, ``sigma_t`` (3,) 1/m per unit density, ``g``, ``stride``
    voxels per lattice step, ``towards`` float64 (LX,LY,LZ,3) unit directions from its
    lattice points to the camera, ``rate`` its tentative collisions per metre inside its
    box (above its largest extinction, as PathInputs.rate), ``threshold``, ``scatter`` and
    ``extinction`` as PathInputs'."""

    density: np.ndarray
    w2i: np.ndarray
    sigma_s: np.ndarray
    sigma_t: np.ndarray
    g: float
    stride: int
    towards: np.ndarray
    rate: float
    threshold: float = -1.0
    scatter: Optional[np.ndarray] = None
    extinction: Optional[np.ndarray] = None


@dataclass
class PathInputs:
    """What the tracer reads.  ``density``: float32 (X,Y,Z) the medium's density per voxel
    (media.density_from applied); ``w2i``: (3,4) world -> voxel index; ``i2w``: (3,3) voxel
    index steps in world metres; ``sigma_s``, ``sigma_t``: (3,) 1/m per unit density; ``g``;
    ``stride``: voxels per lattice step (lattice point k at voxel index k stride);
    ``towards``: float64 (LX,LY,LZ,3) unit directions from each lattice point to the camera;
    ``starts``: (N,3) world positions of the lattice points that scatter; ``weights``: (N,3)
    W, the weight of a path from each (its first-scattering power over the probability of
    drawing it, ``from_power``); ``dirs``: (N,3) unit propagation of the light there;
    ``cdf``: (N,) the cumulative probabilities of the starts; ``rate``: mu, tentative
    collisions per metre; ``n_paths``; ``seed``; ``max_collisions``: real collisions (and
    bounces) after which a path ends (1: the first flights alone, the second order);
    ``min_collisions``: real collisions and bounces a path has made before its deposits
    count (0: all; 1: only the light that has scattered at least once, what a trace to the
    end less one with ``max_collisions`` 1 would give, in one trace);
    ``jitter``, ``lobe``: how a path leaves its start (module docstring, "Starts");
    ``outside``: the density beyond the grid; ``reach_centre`` (3,) m, ``reach_radius`` m:
    where a path outside ends; ``triangles``: (T,3,3) each triangle's corner and two edges
    (m); ``albedo``: (T,3) their diffuse albedo; ``moments``: the deposits also hold the
    moments of order 0 and 1 (module docstring,
    "Moments"); ``start_source``: None, or float32 (X,Y,Z)
    each voxel's first-scattering source (any unit) that a first scattering's start within
    its lattice point's tent is drawn by, with ``start_peak`` (N,) its largest value under
    each start's tent (``start_positions``).  ``others``: PathMedium, the other media the paths
    fly through (at most ``PATH_MEDIA`` - 1, none of them the world's fog): each keeps its own
    tentative collisions at its own rate inside its box, so a path meets them all, scatters
    in whichever it collides in with that medium's albedo and phase function, and deposits
    on that medium's lattice (module docstring, "Several media").  ``threshold``: >= 0 for a
    sharp surface, the medium being density 1 where ``density``'s trilinear value is >= it
    (a mesh volume, as the march reads it; ``density_at``), else -1: the nearest voxel's
    density.  ``light``: None, or the packed record (lights.pack_light) of the light whose
    first scatterings the starts are (``lobe`` 0): each path's incoming direction is then
    drawn at its start from the light's emitter as the march draws it (lights.light_sample:
    a point of a sphere light's disc, a direction in an area light's solid angle) instead
    of ``dirs``, the light's direction at the lattice point (from its centre, or an area
    light's axis), which near a large emitter is one of many.  ``scatter``: None, or float32
    (X,Y,Z,3) each voxel's factor on ``sigma_s`` on the voxels of ``density``
    (media.PreparedMedium.scatter_grid), applied to a path's weight at each real
    collision, read at the nearest voxel (``_colour_factor``): the paths scatter with each
    point's colour, as the march does, and converge to the multiple scattering of the
    coloured medium.  ``extinction``: None, or float32 (X,Y,Z,3) per voxel the density each
    channel's extinction reads (media.PreparedMedium.extinction_density: sigma_t[c] times
    channel c, at most ``density``), read at the nearest voxel (``_extinction_density``);
    the collisions are then by spectral tracking.  ``moment_share``: with ``moments``, the
    share of the paths (the first ones of each of kernels.PATH_BLOCKS blocks) whose moments
    are deposited, scaled to all of them (kernels.moment_ends); 1: every path's.
    ``odds``: None, or float32 (LX,LY,LZ) on the lattice, each point's odds in (0, 1] for the
    camera's roulette (module docstring, "The camera's roulette").  ``start_rate``: None, or
    float64 (N,) per start the mean extinction (1/m) along the light's path to its centre
    (the field's depth over the distance): with ``light`` the emitter point is then drawn
    among ``LIGHT_CANDIDATES`` by their stretched transmittance exp(-rate d) times their
    light (``start_directions``), as the light arrives there, not by the solid angle alone."""

    density: np.ndarray
    w2i: np.ndarray
    i2w: np.ndarray
    sigma_s: np.ndarray
    sigma_t: np.ndarray
    g: float
    stride: int
    towards: np.ndarray
    starts: np.ndarray
    weights: np.ndarray
    dirs: np.ndarray
    cdf: np.ndarray
    rate: float
    n_paths: int
    seed: int = 0
    max_collisions: int = MAX_COLLISIONS
    jitter: float = 1.0
    lobe: int = 0
    outside: float = 0.0
    reach_centre: np.ndarray = field(default_factory=lambda: np.zeros(3))
    reach_radius: float = np.inf
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    albedo: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    start_source: Optional[np.ndarray] = None
    start_peak: Optional[np.ndarray] = None
    moments: bool = False
    others: tuple = ()
    threshold: float = -1.0
    light: Optional[np.ndarray] = None
    scatter: Optional[np.ndarray] = None
    extinction: Optional[np.ndarray] = None
    min_collisions: int = 0
    moment_share: float = 1.0
    odds: Optional[np.ndarray] = None
    start_rate: Optional[np.ndarray] = None

    @property
    def channels(self) -> int:
        """Channels of the deposits: 3, or ``MOMENT_CHANNELS`` with the ``moments``."""
        return MOMENT_CHANNELS if self.moments else 3


def from_power(power: np.ndarray, bias: Optional[np.ndarray] = None):
    """(weights (N,3), cdf (N,)) for starts of first-scattering power ``power`` (N,3) W > 0:
    each drawn with probability proportional to its power summed over channels, times
    ``bias`` (N,) > 0 where given (a start more likely to matter drawn more often), its
    weight its power over that probability (so the estimate is the same)."""
    lum = power.sum(axis=1)
    if bias is not None:
        lum = lum * np.asarray(bias, np.float64)
    total = float(lum.sum())
    return power * (total / lum)[:, None], np.cumsum(lum) / total


def rate_span(rate: float, i2w: np.ndarray, shape) -> float:
    """Tentative collisions at ``rate`` (1/m) along the diagonal of a grid of ``shape`` voxels
    whose index steps are the columns of ``i2w`` (3,3, m)."""
    diagonal = np.asarray(i2w, np.float64) @ np.asarray(shape, np.float64)
    return float(rate) * float(np.linalg.norm(diagonal))


def path_keys(seed: int, n: int) -> np.ndarray:
    """uint32 keys of paths 0..n-1 for ``seed``."""
    base = hash32(np.uint32((seed * 0x27D4EB2F + 0x165667B1) & 0xFFFFFFFF))
    return hash32(np.arange(n, dtype=np.uint32) ^ base)


def _turn(u1, u2, g, axis):
    """HG-distributed unit directions about ``axis`` (phase.sample_hg, renormalised as the C
    twin does)."""
    d = sample_hg(u1, u2, g, axis)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _dot(a, b):
    """Row-wise dot products of (..., 3) arrays, summed in the C kernel's order."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _cross(a, b):
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def _to_index(inp, p):
    w = inp.w2i
    return np.stack([w[r, 0] * p[:, 0] + w[r, 1] * p[:, 1] + w[r, 2] * p[:, 2] + w[r, 3]
                     for r in range(3)], axis=1)


def source_at(inp, p):
    """What a first scattering's start is weighed by at world points ``p`` (N,3): the
    nearest voxel's ``start_source``, or without it 1 where its density is > 0; 0 outside
    the grid's box, and with a ``threshold`` outside the sharp surface (csrc/paths.c
    source_at)."""
    idx = _to_index(inp, p)
    f = np.floor(idx + 0.5)
    shape = np.array(inp.density.shape)
    ok = np.all((f >= 0) & (f < shape), axis=1)
    v = np.where(ok[:, None], f, 0).astype(np.int64)
    if inp.start_source is not None:
        q = np.asarray(inp.start_source)[v[:, 0], v[:, 1], v[:, 2]].astype(np.float64)
    else:
        q = (inp.density[v[:, 0], v[:, 1], v[:, 2]] > 0.0).astype(np.float64)
    if float(inp.threshold) >= 0.0:   # a sharp surface: only inside it, as the march reads it
        inside = density_at(inp, idx) > 0.0
        q = np.where(inside, q if inp.start_source is not None else 1.0, 0.0)
    return np.where(ok & (q > 0.0), q, 0.0)


def _box_cross(inp, pos, d, want_exit):
    """Ray parameter (m) where o + t d leaves (``want_exit``) or enters the grid's box in index
    space, [-0.5, n - 0.5] per axis; inf where it does not (csrc/paths.c box_cross)."""
    io = _to_index(inp, pos)
    w = inp.w2i
    idd = np.stack([w[r, 0] * d[:, 0] + w[r, 1] * d[:, 1] + w[r, 2] * d[:, 2] for r in range(3)], 1)
    t0 = np.zeros(len(pos))
    t1 = np.full(len(pos), np.inf)
    miss = np.zeros(len(pos), bool)
    for r in range(3):
        lo, hi = -0.5, float(inp.density.shape[r]) - 0.5
        zero = idd[:, r] == 0.0
        miss |= zero & ~((io[:, r] >= lo) & (io[:, r] <= hi))
        with np.errstate(divide="ignore", invalid="ignore"):
            ta = (lo - io[:, r]) / idd[:, r]
            tb = (hi - io[:, r]) / idd[:, r]
        a, b = np.where(ta > tb, tb, ta), np.where(ta > tb, ta, tb)
        t0 = np.where(~zero & (a > t0), a, t0)
        t1 = np.where(~zero & (b < t1), b, t1)
    res = np.where(want_exit, t1, np.where(t0 > 0.0, t0, np.inf))
    return np.where(miss | ~(t1 >= t0), np.inf, res)


def _surface_hit(inp, o, d, tmax, skip):
    """(t, triangle) of the nearest surface hit on (T_MIN, tmax), not triangle ``skip``;
    triangle -1 and t = tmax where none (csrc/paths.c surface_hit)."""
    tri = np.asarray(inp.triangles, np.float64).reshape(-1, 3, 3)
    v0, e1, e2 = tri[None, :, 0], tri[None, :, 1], tri[None, :, 2]
    dd, oo = d[:, None, :], o[:, None, :]
    p = _cross(dd, e2)
    det = _dot(p, e1)
    ok = np.abs(det) > 1e-300
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / np.where(ok, det, 1.0)
        s = oo - v0
        u = _dot(s, p) * inv
        q = _cross(s, e1)
        v = _dot(dd, q) * inv
        t = _dot(e2, q) * inv
        hit = ok & (u >= 0.0) & (u <= 1.0) & (v >= 0.0) & (u + v <= 1.0) & (t > T_MIN) \
            & (t < tmax[:, None]) & (np.arange(len(tri))[None, :] != skip[:, None])
    t = np.where(hit, t, np.inf)
    k = np.argmin(t, axis=1) if len(tri) else np.zeros(len(o), np.int64)
    tk = t[np.arange(len(o)), k] if len(tri) else np.full(len(o), np.inf)
    found = np.isfinite(tk)
    return np.where(found, tk, tmax), np.where(found, k, -1)


def _cosine(u1, u2, n):
    """Cosine-distributed unit directions about unit normals ``n`` (csrc/paths.c cosine_dir)."""
    return _about(np.sqrt(u1), u2, n)


def _about(c, u2, axis):
    """Unit directions at cosine ``c`` and azimuth 2 pi ``u2`` about the unit ``axis`` (N,3)
    (csrc/paths.c about)."""
    from .phase import orthonormal_basis
    st = np.sqrt(np.maximum(0.0, 1.0 - c * c))
    phi = 2.0 * np.pi * u2
    t1, t2 = orthonormal_basis(axis)
    out = t1 * (st * np.cos(phi))[:, None] + t2 * (st * np.sin(phi))[:, None] + axis * c[:, None]
    return out / np.sqrt(_dot(out, out))[:, None]


def _aimed(inp: PathInputs, keys, pos, normal):
    """(directions (N,3), aim (N,)) of aimed surface starts (lobe 3, module docstring,
    "Starts"; csrc/paths.c trace_one): with probability ``AIM_COSINE`` cosine-distributed
    about ``normal``, else uniform within the cone the reach sphere subtends from ``pos``;
    ``aim`` the cosine lobe's density over the mixture's (0 below the surface).  A start
    inside the sphere draws the cosine lobe alone (aim 1)."""
    u1, u2 = uniform(keys, 0, _D_DIR), uniform(keys, 0, _D_DIR + 1)
    d = _cosine(u1, u2, normal)
    aim = np.ones(len(keys))
    centre = np.asarray(inp.reach_centre, np.float64).reshape(1, 3)
    r2 = float(inp.reach_radius) ** 2
    axis = centre - pos
    dist2 = _dot(axis, axis)
    far = (dist2 > r2) & np.isfinite(dist2) & (r2 > 0.0)
    if not np.any(far):
        return d, aim
    dist = np.sqrt(dist2[far])
    ax = axis[far] / dist[:, None]
    cmax = np.sqrt(1.0 - r2 / dist2[far])
    omega = 2.0 * np.pi * (1.0 - cmax)
    cone = ~(uniform(keys[far], 0, _D_AIM) < AIM_COSINE)
    df = d[far]
    if np.any(cone):
        df[cone] = _about(1.0 - u1[far][cone] * (1.0 - cmax[cone]), u2[far][cone], ax[cone])
    cn = _dot(df, normal[far])
    ca = _dot(df, ax)
    lobe = np.where(cn > 0.0, cn / np.pi, 0.0)
    mix = AIM_COSINE * lobe + np.where((ca >= cmax) & (omega > 0.0),
                                       (1.0 - AIM_COSINE) / np.where(omega > 0.0, omega, 1.0),
                                       0.0)
    d[far] = df
    aim[far] = np.where(mix > 0.0, lobe / np.where(mix > 0.0, mix, 1.0), 0.0)
    return d, aim


def _survive(keys, ev, w, w0, hits, max_hits):
    """Russian roulette after a real collision or a bounce (csrc/paths.c survive): (alive, w)."""
    m = w.max(axis=1) / np.maximum(w0, 1e-300)
    q = np.where(m < ROULETTE, m / ROULETTE, 1.0)
    live = uniform(keys, ev, _D_RR) < q
    w = w / np.maximum(q, 1e-300)[:, None]
    return live & (hits < max_hits) & (w.max(axis=1) > 0.0), w


def _camera_roulette(m, odds, lsh, pos, keys, ev, w, w0, held, ids):
    """The camera's roulette (csrc/paths.c camera_roulette) at the real collisions ``pos``
    inside ``m`` of the paths ``ids``: (alive, w); ``w0`` and ``held`` (per path) are
    updated in place for the survivors."""
    lat = np.floor(_to_index(m, pos) / m.stride + 0.5)
    lat = np.where(lat >= 0.0, lat, 0.0)
    v = np.minimum(lat, lsh - 1).astype(np.int64)
    q = odds[(v[:, 0] * lsh[1] + v[:, 1]) * lsh[2] + v[:, 2]]
    h = held[ids]
    play = q < h
    live = ~play | (uniform(keys, ev, _D_CAMERA) * h < q)
    f = np.where(play & live, h / np.where(play, q, 1.0), 1.0)
    w0[ids] = w0[ids] * f
    held[ids] = np.where(play & live, q, h)
    return live, w * f[:, None]


def start_positions(inp: PathInputs, keys: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(N,3) world points where the paths of random ``keys`` leave their starts ``k``
    (module docstring, "Starts"; csrc/paths.c trace_one).  A surface start (lobe 1) is
    offset by a tent in its plane; a lattice start by a tent of ``jitter`` lattice steps per
    index axis.  A first scattering's (lobe 0) offset is then rejection-sampled against the
    source ``source_at`` (``start_source``, else 1 in the medium and 0 outside): accepted
    with probability source / ``start_peak`` (1 without a source), drawn again up to
    ``START_TRIES`` times, after which the draw with the most source is kept.  The lattice
    point holds its voxels' power shared by the tent, so the accepted starts follow the
    voxels' source: the light that first scatters within a lattice step of a lit surface
    starts where it scatters, not spread a step around it (and outside the medium)."""
    n = len(keys)
    off = np.stack([uniform(keys, 0, _D_JIT + 2 * a) + uniform(keys, 0, _D_JIT + 2 * a + 1) - 1.0
                    for a in range(3)], axis=1)
    if int(inp.lobe) in (1, 3):   # a surface: a tent of half-width jitter metres in its plane
        from .phase import orthonormal_basis
        t1, t2 = orthonormal_basis(inp.dirs[k])
        off = off * float(inp.jitter)
        return inp.starts[k] + t1 * off[:, :1] + t2 * off[:, 1:2]
    scale = inp.stride * float(inp.jitter)
    pos = inp.starts[k] + np.stack([_dot(off * scale, inp.i2w[a]) for a in range(3)], axis=1)
    if int(inp.lobe) != 0 or not float(inp.jitter) > 0.0:   # lobe 2 emits where it is drawn
        return pos
    peak = np.ones(n) if inp.start_source is None else \
        np.asarray(inp.start_peak, np.float64).reshape(-1)[k]
    best, best_q = pos.copy(), np.full(n, -1.0)
    todo = np.arange(n)
    for t in range(START_TRIES):
        if t:
            base = _D_RETRY + 6 * (t - 1)
            o2 = np.stack([uniform(keys[todo], 0, base + 2 * a) +
                           uniform(keys[todo], 0, base + 2 * a + 1) - 1.0 for a in range(3)],
                          axis=1) * scale
            pos[todo] = inp.starts[k[todo]] + np.stack([_dot(o2, inp.i2w[a]) for a in range(3)],
                                                       axis=1)
        q = source_at(inp, pos[todo])
        take = uniform(keys[todo], 0, _D_ACCEPT + t) * peak[todo] < q
        better = ~take & (q > best_q[todo])
        best[todo[better]] = pos[todo[better]]
        best_q[todo[better]] = q[better]
        todo = todo[~take]
        if not todo.size:
            break
    pos[todo] = best[todo]
    return pos


def trace_paths_np(inp: PathInputs) -> np.ndarray:
    """The numpy twin of csrc/paths.c: float64 (LX,LY,LZ,3) sums of weight / mu x density x
    trilinear share x p(w . v) over every tentative point of ``inp.n_paths`` paths inside the
    grid (W m / sr; divide by the cell volume times the mean density under the point's tent
    for M): ``trace_paths_media_np``'s first."""
    return trace_paths_media_np(inp)[0]


def _own_medium(inp: PathInputs) -> PathMedium:
    return PathMedium(inp.density, inp.w2i, inp.sigma_s, inp.sigma_t, inp.g, inp.stride,
                      inp.towards, inp.rate, inp.threshold, inp.scatter, inp.extinction)


def _nearest_voxel(m, idx) -> np.ndarray:
    """int64 (N,3) the voxel of medium ``m`` nearest to index coordinates ``idx`` (N,3): the
    edge voxel on the box's face and for NaN (csrc/paths.c nearest_voxel)."""
    vox = np.floor(idx + 0.5)
    return np.minimum(np.where(vox >= 0.0, vox, 0.0),
                      np.array(m.density.shape) - 1).astype(np.int64)


def _colour_factor(m, idx) -> np.ndarray:
    """float64 (N,3) the factor on ``m.sigma_s`` at index coordinates ``idx`` (N,3): its
    scatter grid's nearest voxel (negative and NaN read as 0), or 1 without one
    (csrc/paths.c apply_colour)."""
    if m.scatter is None:
        return np.ones((len(idx), 3))
    f = np.asarray(m.scatter)[tuple(_nearest_voxel(m, idx).T)].astype(np.float64)
    return np.where(f > 0.0, f, 0.0)


def _extinction_density(m, idx) -> np.ndarray:
    """float64 (N,3) the density each channel's extinction reads in medium ``m`` at index
    coordinates ``idx`` (N,3): its extinction grid's nearest voxel (negative and NaN read as
    0) (csrc/paths.c, the collision)."""
    e = np.asarray(m.extinction)[tuple(_nearest_voxel(m, idx).T)].astype(np.float64)
    return np.where(e > 0.0, e, 0.0)


def density_at(m, idx) -> np.ndarray:
    """float64 (N,) density of medium ``m`` (PathInputs or PathMedium) at index coordinates
    ``idx`` (N,3) (csrc/paths.c density_at): with ``m.threshold`` >= 0 its trilinear value
    (0 outside [0, n-1] per axis, media.trilinear) thresholded to 1 or 0, a mesh volume's
    sharp surface as the march reads it; else the nearest voxel's (the edge voxel on the
    box's face); 0 for NaN or below 0."""
    shape = np.array(m.density.shape)
    if float(m.threshold) >= 0.0:
        f = np.floor(idx)
        ok = np.all((f >= 0.0) & (f < shape - 1), axis=1)
        i0 = np.where(ok[:, None], f, 0.0).astype(np.int64)
        fr = idx - f
        v = np.zeros(len(idx))
        for corner in range(8):
            o = np.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1])
            w = np.prod(np.where(o == 1, fr, 1.0 - fr), axis=1)
            c = i0 + o
            v = v + w * m.density[c[:, 0], c[:, 1], c[:, 2]].astype(np.float64)
        return np.where(ok & (v >= float(m.threshold)), 1.0, 0.0)
    r = m.density[tuple(_nearest_voxel(m, idx).T)].astype(np.float64)
    return np.where(r >= 0.0, r, 0.0)


def start_directions(inp: PathInputs, keys, k, pos) -> np.ndarray:
    """(N,3) the propagation of the light at each path's start ``pos`` (N,3, m; start ``k``):
    ``dirs[k]``, or with ``inp.light`` and ``lobe`` 0 the direction drawn from the light's
    emitter there (lights.light_sample with the path's own jitter, dimensions ``_D_LIGHT``),
    kept where it is a unit vector that brings light (csrc/paths.c trace_one).  With
    ``inp.start_rate`` > 0 at the start, ``LIGHT_CANDIDATES`` emitter points (the first at
    ``_D_LIGHT``, the others at ``_D_LIGHT_MORE``) and one of them drawn (``_D_LIGHT_PICK``)
    with probability proportional to its light's mean over the channels times
    exp(-rate (d - d_min)), d its distance: through a dense medium the light of a wide
    emitter arrives mostly along the shorter paths (resampled importance: the candidates'
    distribution tends to that one as their count grows)."""
    din = np.asarray(inp.dirs, np.float64)[k]
    if inp.light is None or int(inp.lobe) != 0:
        return din
    from .lights import light_sample
    rec = np.asarray(inp.light, np.float64)
    dl, el, _, _, ds = light_sample(rec, pos, uniform(keys, 0, _D_LIGHT),
                                    uniform(keys, 0, _D_LIGHT + 1))
    rate = np.zeros(len(pos)) if inp.start_rate is None else \
        np.asarray(inp.start_rate, np.float64).reshape(-1)[k]
    many = np.flatnonzero(rate > 0.0)
    if many.size:
        c_d = [dl[many]]
        c_e = [el[many]]
        c_s = [ds[many]]
        for j in range(1, LIGHT_CANDIDATES):
            got = light_sample(rec, pos[many], uniform(keys[many], 0, _D_LIGHT_MORE + 2 * (j - 1)),
                               uniform(keys[many], 0, _D_LIGHT_MORE + 2 * (j - 1) + 1))
            c_d.append(got[0])
            c_e.append(got[1])
            c_s.append(got[4])
        cd, ce, cs = np.stack(c_d, 1), np.stack(c_e, 1), np.stack(c_s, 1)   # (M,K,3), (M,K)
        n2 = np.einsum("mkc,mkc->mk", cd, cd)
        good = (n2 > 0.25) & (n2 < 4.0) & (ce.max(axis=2) > 0.0) & np.isfinite(cs)
        dmin = np.min(np.where(good, cs, np.inf), axis=1)
        w = np.where(good, ce.mean(axis=2) * np.exp(-rate[many, None] * np.maximum(
            np.where(good, cs, 0.0) - np.where(np.isfinite(dmin), dmin, 0.0)[:, None], 0.0)),
            0.0)
        cum = np.cumsum(w, axis=1)
        tot = cum[:, -1]
        u = uniform(keys[many], 0, _D_LIGHT_PICK) * tot
        pick = np.minimum(np.sum(cum <= u[:, None], axis=1), LIGHT_CANDIDATES - 1)
        has = tot > 0.0
        sel = many[has]
        dl[sel] = cd[has, pick[has]]
        el[sel] = ce[has, pick[has]]
    n2 = np.einsum("ij,ij->i", dl, dl)
    ok = (n2 > 0.25) & (n2 < 4.0) & (el.max(axis=1) > 0.0)
    unit = dl / np.sqrt(np.where(ok, n2, 1.0))[:, None]
    return np.where(ok[:, None], unit, din)


def trace_paths_media_np(inp: PathInputs, paths: Optional[tuple] = None) -> list:
    """The numpy twin of csrc/paths.c with ``inp.others``: one float64 (LX,LY,LZ,channels)
    array of deposits per medium on its own lattice, the paths' own medium first.
    ``paths``: None, or (lo, hi) to trace only paths lo..hi-1 of the ``n_paths`` (each still
    weighed by 1 / n_paths; kernels.trace_paths_media's halves)."""
    grids = [_own_medium(inp)] + list(inp.others)
    if len(grids) > PATH_MEDIA:
        raise ValueError(f"trace_paths: at most {PATH_MEDIA - 1} other media")
    nm = len(grids)
    nc = inp.channels
    lshapes = [tuple(m.towards.shape[:3]) for m in grids]
    outs = [np.zeros((int(np.prod(sh)), nc)) for sh in lshapes]
    n = int(inp.n_paths)
    if n <= 0 or len(inp.cdf) == 0:
        return [o.reshape(sh + (nc,)) for o, sh in zip(outs, lshapes)]
    gs = [clamp_g(m.g) for m in grids]
    g = gs[0]
    keys = path_keys(inp.seed, n)
    if paths is not None:
        keys = keys[max(0, int(paths[0])):max(0, int(paths[1]))]
    k = np.minimum(np.searchsorted(inp.cdf, uniform(keys, 0, _D_PICK), side="right"),
                   len(inp.cdf) - 1)
    pos = start_positions(inp, keys, k)
    din = start_directions(inp, keys, k, pos)
    aim = np.ones(len(keys))
    if int(inp.lobe) == 1:
        d = _cosine(uniform(keys, 0, _D_DIR), uniform(keys, 0, _D_DIR + 1), din)
    elif int(inp.lobe) == 3:    # a surface aimed at the reach sphere
        d, aim = _aimed(inp, keys, pos, din)
    else:                       # lobe 2, an emitting voxel: uniform (the phase of g 0)
        d = _turn(uniform(keys, 0, _D_DIR), uniform(keys, 0, _D_DIR + 1),
                  0.0 if int(inp.lobe) == 2 else g, din)
    w = inp.weights[k] / n * aim[:, None]
    w0 = w.max(axis=1)
    held = np.ones(len(keys))   # the lowest camera odds each path has survived
    odds = None if inp.odds is None or not np.size(inp.odds) else \
        np.asarray(inp.odds, np.float32).astype(np.float64).reshape(-1)
    event = np.zeros(len(keys), np.int64)
    hits = np.zeros(len(keys), np.int64)
    skip = np.full(len(keys), -1, np.int64)
    shapes = [np.array(m.density.shape) for m in grids]
    inside = np.stack([np.all((np.floor(_to_index(m, pos) + 0.5) >= 0)
                              & (np.floor(_to_index(m, pos) + 0.5) < sh), axis=1)
                       for m, sh in zip(grids, shapes)], axis=1)
    alive = np.flatnonzero(aim > 0.0)   # an aimed start below its surface: no light
    sts = [np.asarray(m.sigma_t, np.float64) for m in grids]
    sss = [np.asarray(m.sigma_s, np.float64) for m in grids]
    mus = [float(m.rate) for m in grids]
    outside = float(inp.outside)
    centre = np.asarray(inp.reach_centre, np.float64).reshape(3)
    radius = float(inp.reach_radius)
    albedo = np.asarray(inp.albedo, np.float64).reshape(-1, 3)
    n_tri = len(albedo)
    tws = [m.towards.reshape(-1, 3) for m in grids]
    while alive.size:
        kk = keys[alive]
        ev = event[alive] + 1
        event[alive] = ev
        ins = inside[alive]
        tbs = np.stack([_box_cross(m, pos[alive], d[alive], ins[:, j])
                        for j, m in enumerate(grids)], axis=1)
        past = ins & ~(tbs < np.inf)     # no way out ahead: past the face (csrc/paths.c)
        if np.any(past):
            for j, m in enumerate(grids):
                pj = past[:, j]
                if np.any(pj):
                    inside[alive[pj], j] = False
                    tbs[pj, j] = _box_cross(m, pos[alive[pj]], d[alive[pj]],
                                            np.zeros(int(pj.sum()), bool))
            ins = inside[alive]
        tb = tbs.min(axis=1)
        if nm == 1:
            rate = np.where(ins[:, 0], mus[0], outside * float(np.max(sts[0])))
        else:       # each medium's tentative collisions at its own rate inside its box
            rate = np.zeros(len(alive))
            for j in range(nm):
                rate = rate + np.where(ins[:, j], mus[j], 0.0)
        with np.errstate(divide="ignore"):
            t = np.where(rate > 0.0, -np.log(1.0 - uniform(kk, ev, _D_FLY)) /
                         np.where(rate > 0.0, rate, 1.0), np.inf)
        tseg = np.minimum(t, tb)
        keep = np.ones(len(alive), bool)
        bounced = np.zeros(len(alive), bool)
        if n_tri:
            ts, tri = _surface_hit(inp, pos[alive], d[alive], np.minimum(tseg, FAR), skip[alive])
            bounced = tri >= 0
            if np.any(bounced):
                b = alive[bounced]
                tk = tri[bounced]
                pos[b] += ts[bounced, None] * d[b]
                tv = np.asarray(inp.triangles, np.float64).reshape(-1, 3, 3)[tk]
                nrm = _cross(tv[:, 1], tv[:, 2])
                nrm = nrm / np.sqrt(_dot(nrm, nrm))[:, None]
                nrm = np.where((_dot(nrm, d[b]) > 0.0)[:, None], -nrm, nrm)
                w[b] *= albedo[tk]
                d[b] = _cosine(uniform(kk[bounced], ev[bounced], _D_BOUNCE),
                               uniform(kk[bounced], ev[bounced], _D_BOUNCE + 1), nrm)
                hits[b] += 1
                skip[b] = tk
                live, w[b] = _survive(kk[bounced], ev[bounced], w[b], w0[b], hits[b],
                                      inp.max_collisions)
                keep[bounced] = live
        rest = ~bounced
        skip[alive[rest]] = -1
        gone = rest & ~(tseg < np.inf)
        keep[gone] = False
        cross = rest & ~gone & (tb <= t)
        if np.any(cross):
            c = alive[cross]
            pos[c] += tb[cross, None] * d[c]
            # every box whose face is there (boxes that share a face are crossed together)
            tie = tbs[cross] <= (tb[cross] + BOX_TIE * (1.0 + tb[cross]))[:, None]
            inside[c] = inside[c] ^ tie
        coll = rest & ~gone & ~cross
        pick = np.zeros(len(alive), np.int64)
        if nm > 1 and np.any(coll):     # whose tentative point it is
            u = uniform(kk, ev, _D_MEDIUM) * rate
            cum = np.zeros(len(alive))
            done = np.zeros(len(alive), bool)
            for q in range(nm):
                iq = ins[:, q] & ~done
                pick[iq] = q
                cum = np.where(iq, cum + mus[q], cum)
                done |= iq & (u < cum)
            rate = np.asarray(mus)[pick]
        if np.any(coll):
            pos[alive[coll]] += t[coll, None] * d[alive[coll]]
        for j in range(nm):
            sel = coll & (pick == j)
            if not np.any(sel):
                continue
            _collide(grids[j], outs[j], tws[j], gs[j], sts[j], sss[j], mus[j], sel, alive,
                     ins[:, j], rate, kk, ev, pos, d, w, w0, hits, keep, nc, lshapes[j],
                     outside, centre, radius, inp.max_collisions, inp.min_collisions,
                     odds=odds if j == 0 else None, held=held)
        alive = alive[keep & (ev < MAX_EVENTS)]
    return [o.reshape(sh + (nc,)) for o, sh in zip(outs, lshapes)]


def _collide(m, out, tw, g, st, ss, mu, coll, alive, ins, rate, kk, ev, pos, d, w, w0, hits,
             keep, nc, lshape, outside, centre, radius, max_collisions, min_collisions=0,
             odds=None, held=None):
    """The tentative collisions ``coll`` (a mask over ``alive``) in medium ``m``: their
    deposits on its lattice ``out`` (of the paths with at least ``min_collisions`` real
    collisions and bounces), then real or null collisions (csrc/paths.c); with ``odds``
    (the lattice's flattened, PathInputs.odds) the camera's roulette after a real collision
    inside the grid, ``held`` (per path) the lowest odds each has survived."""
    lsh = np.array(lshape)
    st_max, st_min = float(np.max(st)), float(np.min(st))
    ci = alive[coll]
    rho = np.full(len(ci), outside)
    out_c = ~ins[coll]
    if np.any(out_c):
        r2 = np.sum((pos[ci[out_c]] - centre) ** 2, axis=1)
        far = ~(r2 <= radius * radius)
        idx_far = np.flatnonzero(coll)[np.flatnonzero(out_c)[far]]
        keep[idx_far] = False
    inn = ins[coll]
    if np.any(inn):
        pi = ci[inn]
        idx = _to_index(m, pos[pi])
        r = density_at(m, idx)
        rho[inn] = r
        # deposit, weighted by the density: the 8 lattice points round the point,
        # each with its own phase (none from a flight whose light is not asked for)
        r = r * (hits[pi] >= min_collisions)
        lat = idx / m.stride
        base = np.floor(lat).astype(np.int64)
        fr = lat - base
        wd = w[pi] * (r / mu)[:, None]
        da = d[pi]
        for corner in range(8):
            o = np.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1])
            cc = base + o
            ok = np.all((cc >= 0) & (cc < lsh), axis=1)
            share = np.prod(np.where(o == 1, fr, 1.0 - fr), axis=1) * ok
            flat = np.ravel_multi_index(tuple(np.where(ok[:, None], cc, 0).T), lshape)
            ph = hg(_dot(da, tw[flat]), g)
            for ch in range(3):
                out[:, ch] += np.bincount(flat, wd[:, ch] * share * ph, minlength=len(out))
        if nc == MOMENT_CHANNELS:
            # the moments on one corner drawn by the shares (module docstring)
            u = uniform(kk[coll][inn], ev[coll][inn], _D_CORNER)
            ups = []
            for a in range(3):     # one draw picks the corner axis by axis
                up = u < fr[:, a]
                with np.errstate(divide="ignore", invalid="ignore"):
                    u = np.where(up, u / fr[:, a], (u - fr[:, a]) / (1.0 - fr[:, a]))
                ups.append(up)
            cc = base + np.stack(ups, axis=1)
            ok = np.all((cc >= 0) & (cc < lsh), axis=1)
            flat = np.ravel_multi_index(tuple(np.where(ok[:, None], cc, 0).T), lshape)
            for ch in range(3):
                m0 = wd[:, ch] * ok * (1.0 / (4.0 * np.pi))
                out[:, 3 + ch] += np.bincount(flat, m0, minlength=len(out))
                for jj in range(3):
                    out[:, 6 + 3 * jj + ch] += np.bincount(flat, m0 * g * da[:, jj],
                                                           minlength=len(out))
    live_c = keep[coll]
    rc = rate[coll]
    kc, ec = kk[coll], ev[coll]
    wc = w[ci]
    stc = rho[:, None] * st[None, :]
    ext = getattr(m, "extinction", None)
    if ext is not None and np.any(inn):   # the extinction's own density per channel
        stc[inn] = _extinction_density(m, _to_index(m, pos[ci[inn]])) * st[None, :]
    if st_min == st_max and ext is None:
        p_hit = np.minimum(rho * st_max / rc, 1.0)
        hit = uniform(kc, ec, _D_HIT) < p_hit
        num = 1.0 - stc / rc[:, None]
        wc = np.where(hit[:, None], wc * (ss / st_max)[None, :],
                      wc * num / np.maximum(1.0 - p_hit, 1e-12)[:, None])
    else:
        real = stc.max(axis=1)
        nul = np.maximum(rc - stc.min(axis=1), 0.0)
        p_hit = real / np.maximum(real + nul, 1e-300)
        hit = uniform(kc, ec, _D_HIT) < p_hit
        w_null = np.maximum(rc[:, None] - stc, 0.0) / \
            np.maximum(rc * (1.0 - p_hit), 1e-300)[:, None]
        w_real = rho[:, None] * ss[None, :] / np.maximum(rc * p_hit, 1e-300)[:, None]
        wc = wc * np.where(hit[:, None], w_real, w_null)
    if np.any(hit):
        hi = ci[hit]
        if m.scatter is not None:    # the scattering colour of the point (inside only)
            col = hit & inn
            if np.any(col):
                wc[col] = wc[col] * _colour_factor(m, _to_index(m, pos[ci[col]]))
        d[hi] = _turn(uniform(kc[hit], ec[hit], _D_TURN),
                      uniform(kc[hit], ec[hit], _D_TURN + 1), g, d[hi])
        hits[hi] += 1
        live_h, wc[hit] = _survive(kc[hit], ec[hit], wc[hit], w0[hi], hits[hi], max_collisions)
        live_c[hit] &= live_h
        if odds is not None:
            cam = hit & inn & live_c
            if np.any(cam):
                live_k, wc[cam] = _camera_roulette(m, odds, lsh, pos[ci[cam]], kc[cam], ec[cam],
                                                   wc[cam], w0, held, ci[cam])
                live_c[cam] &= live_k
    live_c[~hit] &= wc[~hit].max(axis=1) > 0.0
    w[ci] = wc
    keep[coll] = live_c
