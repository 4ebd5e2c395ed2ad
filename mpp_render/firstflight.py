"""The first flights of multiple scattering, evaluated exactly on the light pyramid's lattice.

Every multiply scattered path starts at a first scattering out of the beam (the source Q of
``precompute.source.restricted_source``, W/m^3) and flies straight to its next event.  The walk of the
light pyramid spreads that first flight, like every later one, as an isotropic Gaussian about
its mean displacement; where the first flights are long -- a medium thinner than its mean
free path, such as fog round a spot light's beam -- that puts their light in the wrong place:
a flight's direction is tied to where it goes, and the last scattering towards the camera
(HG of the medium's own g) favours the flights that travel along the line of sight.  Here
the first flight is instead the convolution

    F1(x) = int Q(y) p1(d . r^) e^(-sigma_t* |r|) / |r|^2  p(r^ . w) d^3y ,   r = x - y

(W/(m^2 sr) per unit sigma_s at x: the march multiplies by the local sigma_s), with p1 the
medium's own HG(g) outside its forward peak (``first_phase``: the light scattered into the
peak is the beam channels', precompute.source.peak_light) about the light's direction d at the
sources, sigma_t* the delta-scaled medium's extinction (1/m; the forward peak's scatterings
keep the light on its course), p the medium's own HG(g) and w the direction to the camera.
The second flight is the same convolution of the second-scattering source sigma_s* phi1
(phi1 the first flights' fluence, Q convolved with the kernel without its camera factor)
with p1 composed with itself as its direction (``peak_free_twice``).  They are evaluated by
FFT on the lattice, one kernel per colour channel, flight and camera direction (a few
directions spread over what the camera sees of the medium, interpolated between); the walk
then carries only the paths with at least two more scatterings
(``walk.level_table(..., exact_flights=2)``; scene.Tuning.exact_flights).  See docs/method.md, "The
first flight, exact".

Where the first flights mostly stay in the medium the walk's calibration (its escape through
the surface) holds and the exact flight changes little or does worse (a dense, forward slab);
where they mostly leave, the walk misplaces them.  The two are blended by the fraction of the
first flights' power that leaves the medium before its next event (``escape_fraction``):
the walk alone below ``ESCAPE_LOW``, the exact flight alone above ``ESCAPE_HIGH``, linear in
between (thresholds from the public scenes: docs/method.md).

Conventions: lattice index axes map to world by ``stride * pm.i2w[:3, :3]`` (metres per
lattice step; any affine grid), directions are unit world vectors of propagation, sigma in
1/m, HG in 1/sr.  No bpy.
"""
from __future__ import annotations

import functools
import threading
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from .parallel import check, run_chunks, worker_count
from .phase import delta_fraction, hg, outside_peak, peak_cone_cos

ESCAPE_LOW = 0.3    # escape fraction at or below which the walk alone is used
ESCAPE_HIGH = 0.5   # escape fraction at or above which the exact first flight alone is used
ESCAPE_RESOLUTION = 32   # lattice points along the longest axis for the escape fraction
MAX_DIRECTIONS = 24      # camera directions convolved at most (the step widens to fit)
DIRECTION_STEP = np.radians(15.0)  # angle between neighbouring camera directions, at most
FFT_MEMORY = 1 << 30       # bytes the parallel convolutions may hold at once
MAX_FFT_POINTS = 1 << 24   # larger lattices keep the walk alone (memory: ~0.2 GB per transform)
NEAR_RADIUS = 6          # cells within this many lattice steps of a flight's start ...
NEAR_DIRECTIONS = 16384  # ... are integrated along this many rays (``near_cells``)


@dataclass
class FirstFlight:
    """The exact first flights of one light on one medium: ``field`` (X,Y,Z,3) float32 on a
    lattice ``stride`` voxels apart (W/(m^2 sr) per unit sigma_s, RGB; precompute sets the
    stride, None: the light pyramid's finest lattice), and per channel the ``weight`` (3,)
    in [0, 1] with which they replace the walk's."""

    field: np.ndarray
    weight: np.ndarray
    stride: Optional[int] = None


def first_phase(cos_theta, g: float, spread: float, order: int = 1):
    """The direction of a flight out of the beam (1/sr), about the light's direction: for
    the first flight (``order`` 1) HG(g) without its forward peak (phase.outside_peak: the
    peak's light is the beam channels'), for the second (``order`` 2) that composed with
    itself (``peak_free_twice``: the second scattering out of the peak turns the first
    flight's direction again), for light arriving along one direction.  ``spread`` in [0, 1]
    (the length of the mean of the light's directions at the sources) mixes it with the
    isotropic 1 / (4 pi), which keeps the mean of the flights' directions where light
    arrives from several."""
    p = outside_peak(cos_theta, g) if order == 1 else peak_free_twice(cos_theta, g)
    return spread * p + (1.0 - spread) / (4.0 * np.pi)


LEGENDRE_TERMS = 400   # terms of the composed phase function's Legendre series


@functools.lru_cache(maxsize=16)
def _twice_table(g: float):
    """(cos grid, values) of phase.outside_peak(., g) composed with itself, from its Legendre
    series: the coefficients t_l = 2 pi int p P_l dcos multiply, p o p = sum_l (2l + 1) /
    (4 pi) t_l^2 P_l."""
    x, wx = np.polynomial.legendre.leggauss(4 * LEGENDRE_TERMS)
    c = peak_cone_cos(g)   # outside_peak is 0 beyond c: integrate over [-1, c] only
    nodes, wts = 0.5 * (c + 1.0) * x + 0.5 * (c - 1.0), 0.5 * (c + 1.0) * wx
    p = outside_peak(np.minimum(nodes, np.nextafter(c, -1.0)), g)
    grid = np.cos(np.linspace(0.0, np.pi, 2049))
    coef = np.empty(LEGENDRE_TERMS)
    pl_prev, pl = np.ones_like(nodes), nodes.copy()
    qg_prev, qg = np.ones_like(grid), grid.copy()
    out = np.full(grid.shape, 1.0 / (4.0 * np.pi))          # l = 0: t_0 = 1
    for l in range(1, LEGENDRE_TERMS):
        coef[l] = 2.0 * np.pi * float(np.sum(wts * p * pl))
        out += (2 * l + 1) / (4.0 * np.pi) * coef[l] ** 2 * qg
        pl_prev, pl = pl, ((2 * l + 1) * nodes * pl - l * pl_prev) / (l + 1)
        qg_prev, qg = qg, ((2 * l + 1) * grid * qg - l * qg_prev) / (l + 1)
    return grid[::-1].copy(), np.maximum(out[::-1], 0.0)


def peak_free_twice(cos_theta, g: float):
    """phase.outside_peak(., g) composed with itself (1/sr): the direction, about the
    light's, after two scatterings out of the forward peak (``_twice_table``, interpolated
    in cos).  HG(g^2) for g <= 0 (HG composed with HG)."""
    if delta_fraction(g) <= 0.0:
        return hg(cos_theta, g * g)
    grid, vals = _twice_table(round(float(g), 6))
    return np.interp(np.asarray(cos_theta, np.float64), grid, vals)


def sphere_directions(n: int) -> np.ndarray:
    """``n`` unit vectors spread evenly over the sphere (a Fibonacci lattice), (n,3)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5.0 ** 0.5) * i
    s = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


@functools.lru_cache(maxsize=4)   # ~10 MB each at the defaults
def _near_segments(axes_bytes: bytes, sigma_t: float, n_dirs: int, radius: int):
    """The rays of ``near_cells`` cut into their pieces in each cell: (directions (n,3),
    per piece its ray, its cell's flat index in the (2 radius + 1)^3 block, and
    int e^(-sigma_t r) dr over it (m))."""
    axes = np.frombuffer(axes_bytes, np.float64).reshape(3, 3)
    omega = sphere_directions(n_dirs)
    step = omega @ np.linalg.inv(axes).T   # index units per metre along each ray
    safe = np.where(step != 0.0, np.abs(step), 1e-300)
    bounds = np.arange(radius + 1) + 0.5
    planes = (bounds[None, None, :] / safe[:, :, None]).reshape(n_dirs, -1)
    exit_r = np.min((radius + 0.5) / safe, axis=1)
    rs = np.concatenate([np.zeros((n_dirs, 1)), np.sort(planes, axis=1)], axis=1)
    size = 2 * radius + 1
    rays, cells, masses = [], [], []
    for j in range(rs.shape[1] - 1):
        a, b = rs[:, j], np.minimum(rs[:, j + 1], exit_r)
        ok = np.flatnonzero(b > a)
        if not ok.size:
            break
        mid = 0.5 * (a[ok] + b[ok])
        cell = np.rint(step[ok] * mid[:, None]).astype(np.int64) + radius
        keep = np.all((cell >= 0) & (cell < size), axis=1)
        rays.append(ok[keep].astype(np.int32))
        cells.append(np.ravel_multi_index(tuple(cell[keep].T), (size,) * 3).astype(np.int32))
        masses.append((np.exp(-sigma_t * a[ok][keep]) - np.exp(-sigma_t * b[ok][keep])) / sigma_t)
    return omega, np.concatenate(rays), np.concatenate(cells), np.concatenate(masses)


def near_cells(axes, d, first, sigma_t: float, w=None, g2: float = 0.0,
               n_dirs: int = NEAR_DIRECTIONS, radius: int = NEAR_RADIUS) -> np.ndarray:
    """The kernel's integral over each cell within ``radius`` lattice steps of the origin
    ((2 radius + 1)^3), exactly along every ray from the origin -- the cell's share of
    int e^(-sigma_t r) dr = the difference of e^(-sigma_t r) where the ray enters and leaves
    it, over sigma_t -- and by ``n_dirs`` evenly spread directions over the sphere: the steep
    1/r^2 and e^(-sigma_t r) of a dense medium's first flights, and the edge of the forward
    peak's cone (first_phase), which a few points per cell would miss (for the kernel's sum
    that was 5-10 % next to the cone's edge with 27 cells; within 1 % with radius 6)."""
    axes = np.ascontiguousarray(axes, np.float64)
    omega, rays, cells, mass = _near_segments(axes.tobytes(), float(sigma_t), int(n_dirs),
                                              int(radius))
    ang = first_phase(omega @ np.asarray(d, np.float64), *first) * (4.0 * np.pi / n_dirs)
    if w is not None:
        ang = ang * hg(omega @ np.asarray(w, np.float64), g2)
    size = 2 * radius + 1
    return np.bincount(cells, weights=ang[rays] * mass, minlength=size ** 3).reshape((size,) * 3)


class KernelBase:
    """The parts of flight_kernel that do not depend on the camera direction, for one
    lattice (``axes``, ``half``), flight direction (``d``, ``first``) and ``sigma_t``:
    ``bare`` p1(d . r^) e^(-sigma_t |r|) / |r|^2 x cell volume (float64) and the offsets'
    unit vectors ``u`` (3 float32 arrays): the camera's factor p2(r^ . w) is then one
    product per direction (``kernel``)."""

    def __init__(self, axes, half, d, first, sigma_t: float, n_dirs: int = NEAR_DIRECTIONS):
        self.axes = np.asarray(axes, np.float64)
        self.d = np.asarray(d, np.float64)
        self.first, self.sigma_t, self.n_dirs = first, float(sigma_t), n_dirs
        self.half = tuple(int(n) for n in half)
        vol = abs(float(np.linalg.det(self.axes)))
        ranges = [np.arange(-(n - 1), n, dtype=np.float64) for n in self.half]
        shape = tuple(len(r) for r in ranges)
        self.bare = np.empty(shape)
        self.u = np.empty((3,) + shape, np.float32)
        yz = np.stack(np.meshgrid(ranges[1], ranges[2], indexing="ij"), -1) @ self.axes[:, 1:].T
        for i, a in enumerate(ranges[0]):   # plane by plane: a few arrays of a plane at a time
            r = yz + a * self.axes[:, 0]
            with np.errstate(over="ignore", under="ignore", divide="ignore",
                             invalid="ignore"):
                rr = np.sqrt(np.einsum("...i,...i->...", r, r))
                safe = np.maximum(rr, 1e-300)
                u = r / safe[..., None]
                self.bare[i] = first_phase(u @ self.d, *first) * np.exp(-self.sigma_t * rr) \
                    / (safe * safe) * vol
            self.u[:, i] = np.moveaxis(u, -1, 0)

    def kernel(self, w=None, g2: float = 0.0) -> np.ndarray:
        """flight_kernel's kernel towards ``w`` (None: the bare kernel)."""
        if w is None:
            k = self.bare.copy()
        else:
            w = np.asarray(w, np.float64)
            cos = self.u[0] * w[0] + self.u[1] * w[1] + self.u[2] * w[2]
            k = self.bare * hg(cos, g2)
        near = near_cells(self.axes, self.d, self.first, self.sigma_t, w, g2, self.n_dirs,
                          NEAR_RADIUS)
        r = NEAR_RADIUS
        c = [n - 1 for n in self.half]
        lo = [max(0, ci - r) for ci in c]
        hi = [min(k.shape[i], c[i] + r + 1) for i in range(3)]
        k[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = near[lo[0] - c[0] + r:hi[0] - c[0] + r,
                                                        lo[1] - c[1] + r:hi[1] - c[1] + r,
                                                        lo[2] - c[2] + r:hi[2] - c[2] + r]
        return k


def flight_kernel(axes, half, d, first, sigma_t: float, w=None, g2: float = 0.0,
                  n_dirs: int = NEAR_DIRECTIONS) -> np.ndarray:
    """The first-flight kernel on the lattice offsets -(n-1)..(n-1) per axis (``half`` = n,
    3 ints): each cell's integral of p1(d . r^) e^(-sigma_t |r|) / |r|^2 [p2(r^ . w)] over
    its volume (m for the bare kernel: int of 1/m^2 over m^3; times 1/sr with ``w``).
    ``axes`` (3,3): world vector (m) of one lattice step along each index axis (columns);
    p1 = first_phase(., *first) (``first`` = (g, spread)), p2 = HG(g2) towards unit ``w``
    (omitted when None).  The cells within NEAR_RADIUS steps of the origin, where 1/r^2 is
    steep, are integrated along rays (``near_cells``); the others take their centre's value.
    Over all space the bare kernel integrates to 1 / sigma_t, and with ``w`` to (p1 composed
    with p2)(d . w) / sigma_t.  (KernelBase builds it for many ``w``.)"""
    return KernelBase(axes, half, d, first, sigma_t, n_dirs).kernel(w, g2)


def _smooth_length(n: int) -> int:
    """The smallest 2^a 3^b 5^c >= n: FFT lengths numpy transforms fast (2n - 1 is often a
    prime, several times slower)."""
    best = 1 << max(0, int(n - 1).bit_length())
    p3 = 1
    while p3 < best:
        p35 = p3
        while p35 < best:
            m = p35
            while m < n:
                m *= 2
            best = min(best, m)
            p35 *= 5
        p3 *= 3
    return best


def fft_shape(shape):
    """The FFT size of a linear convolution of a lattice of ``shape`` with a kernel over
    its offsets -(n-1)..(n-1): at least 2n - 1 per axis (the periodic copies then fall
    outside the part kept)."""
    return tuple(_smooth_length(2 * n - 1) for n in shape)


def spectrum(a, shape):
    """The FFT of a source or kernel on the padded size of ``shape``'s linear convolution."""
    return np.fft.rfftn(a, s=fft_shape(shape))


def convolve(fq, fk, shape) -> np.ndarray:
    """The linear (not circular) convolution of a source on a lattice of ``shape`` with a
    kernel of flight_kernel(half = shape), from their ``spectrum``s ``fq`` and ``fk``:
    (X,Y,Z) float64 on the source's lattice."""
    return inverse(fq * fk, shape)


def inverse(product, shape) -> np.ndarray:
    """The part on the source's lattice of the inverse transform of a product of spectra
    (or a sum of such products): ``convolve`` without its product."""
    out = np.fft.irfftn(product, s=fft_shape(shape))
    return out[shape[0] - 1:2 * shape[0] - 1, shape[1] - 1:2 * shape[1] - 1,
               shape[2] - 1:2 * shape[2] - 1]


def _block_sum(a, c):
    """Sum of ``a`` (X,Y,Z,...) over blocks of c^3 lattice points (zero-padded)."""
    pad = [(0, (-n) % c) for n in a.shape[:3]] + [(0, 0)] * (a.ndim - 3)
    p = np.pad(a, pad)
    s = p.shape
    return p.reshape(s[0] // c, c, s[1] // c, c, s[2] // c, c, *s[3:]).sum(axis=(1, 3, 5))


def escape_fraction(q, inside, axes, d, first, sigma_t) -> np.ndarray:
    """Per colour channel, the fraction (3,) of the first flights' power that leaves the
    medium before its next event: 1 - sigma_t int_inside phi / int Q, phi the fluence of the
    first flights (Q convolved with the bare kernel).  ``q`` (X,Y,Z,3) W/m^3, ``inside``
    (X,Y,Z) bool, ``sigma_t`` (3,) 1/m.  Computed on a lattice of at most
    ESCAPE_RESOLUTION points along its longest axis (blocks of the source summed): it is one
    number per channel.  Channels without power or extinction give 0."""
    c = max(1, int(np.ceil(max(q.shape[:3]) / ESCAPE_RESOLUTION)))
    qc = _block_sum(q, c) / float(c ** 3)               # mean power density per block
    occ = _block_sum(inside.astype(np.float64), c) / float(c ** 3)
    shape = qc.shape[:3]
    out = np.zeros(3)
    total = qc.sum(axis=(0, 1, 2))
    kernels = {}
    for ch in range(3):
        if not (total[ch] > 0.0 and sigma_t[ch] > 0.0):
            continue
        s = float(sigma_t[ch])
        if s not in kernels:
            kernels[s] = spectrum(flight_kernel(axes * c, shape, d, first, s), shape)
        phi = convolve(spectrum(qc[..., ch], shape), kernels[s], shape)
        collided = s * float(np.sum(np.maximum(phi, 0.0) * occ))
        out[ch] = min(1.0, max(0.0, 1.0 - collided / float(total[ch])))
    return out


def blend_weight(escape) -> np.ndarray:
    """The exact first flight's weight from the escape fraction: 0 at ESCAPE_LOW and below,
    1 at ESCAPE_HIGH and above, linear between."""
    return np.clip((np.asarray(escape, np.float64) - ESCAPE_LOW) / (ESCAPE_HIGH - ESCAPE_LOW),
                   0.0, 1.0)


def camera_directions(v, inside_v):
    """(directions (n,3), per point weights (N,n)) for the directions to the camera ``v``
    (N,3, unit, one per lattice point): a grid of directions about the mean of ``inside_v``
    (the directions from the medium's points) along the two principal axes of their spread,
    DIRECTION_STEP apart (a wider step where that would take more than MAX_DIRECTIONS),
    each point interpolating the four nearest bilinearly.  Both axes matter: the last scattering's HG(g) towards the
    camera is narrow (half its peak 7 degrees off the peak for g = 0.85), and a medium as
    high as the view is wide sees the camera from directions 10 degrees apart vertically
    too (fog_beam: one axis left the light above and below a beam 40 % too bright)."""
    c0 = inside_v.mean(axis=0)
    c0 = c0 / max(float(np.linalg.norm(c0)), 1e-30)
    dev = inside_v - c0
    if len(dev) > 1 and np.any(dev):
        axes = np.linalg.svd(dev, full_matrices=False)[2][:2]
    else:
        axes = np.zeros((2, 3))
    spans = [(float(t.min()), float(t.max())) for t in (inside_v @ axes.T).T]
    step = DIRECTION_STEP
    while True:
        ns = [int(max(1, np.ceil((hi - lo) / step) + 1)) for lo, hi in spans]
        if ns[0] * ns[1] <= MAX_DIRECTIONS:
            break
        step *= 1.1
    grids, pos = [], []
    for axis, (lo, hi), n in zip(axes, spans, ns):
        grids.append(np.linspace(lo, hi, n) if n > 1 else np.array([0.5 * (lo + hi)]))
        pos.append(np.clip((v @ axis - lo) / max(hi - lo, 1e-30) * (n - 1), 0.0,
                           max(n - 1 - 1e-9, 0.0)))
    n1, n2 = len(grids[0]), len(grids[1])
    dirs = (c0[None, None, :] + grids[0][:, None, None] * axes[0]
            + grids[1][None, :, None] * axes[1]).reshape(-1, 3)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    wts = np.zeros((len(v), n1 * n2))
    rows = np.arange(len(v))
    i1, i2 = np.floor(pos[0]).astype(np.int64), np.floor(pos[1]).astype(np.int64)
    t1, t2 = pos[0] - i1, pos[1] - i2
    for a, wa in ((0, 1.0 - t1), (1, t1)):
        for b, wb in ((0, 1.0 - t2), (1, t2)):
            col = np.minimum(i1 + a, n1 - 1) * n2 + np.minimum(i2 + b, n2 - 1)
            np.add.at(wts, (rows, col), wa * wb)
    return dirs, wts


def flight_weight(q, inside, axes, source_dirs, g: float, sigma_t):
    """(weight (3,), d (3,), spread) of the exact flights of the source ``q`` (arguments as
    ``first_flight``'s): the blend weight per channel (``blend_weight`` of the escape
    fraction), the sources' power-weighted mean direction d and the length of that mean;
    None where no channel takes the flights (every weight 0, no power) -- the
    walk's coarser lattice then answers for a finer one (precompute.lightpyramid.multiple_field)."""
    power = q.sum(axis=-1).reshape(-1)
    total = float(power.sum())
    sigma_t = np.broadcast_to(np.asarray(sigma_t, np.float64), (3,))
    if not total > 0.0 or not np.any(inside) or not np.any(sigma_t > 0.0):
        return None
    mean = (source_dirs * power[:, None]).sum(axis=0) / total
    norm = float(np.linalg.norm(mean))
    d = mean / norm if norm > 1e-12 else np.array([0.0, 0.0, 1.0])
    spread = min(norm, 1.0)
    weight = blend_weight(escape_fraction(q, inside, axes, d, (float(g), spread), sigma_t))
    weight[~(sigma_t > 0.0)] = 0.0
    if not np.any(weight > 0.0):
        return None
    return weight, d, spread


def first_flight(q, inside, axes, source_dirs, v, g: float, sigma_t, sigma_s=None,
                 should_cancel: Optional[Callable[[], bool]] = None,
                 threads: int = 0, exact_flights: int = 2,
                 fft_memory: int = FFT_MEMORY) -> Optional[FirstFlight]:
    """The exact first flights of one light on one medium, or None where the walk alone
    serves (every channel's escape fraction at or below ESCAPE_LOW, no power); raises
    cancel.Cancelled on Esc.  The first flight out of the beam and, where ``sigma_s`` is
    given, the second (``exact_flights`` 2; scene.Tuning.exact_flights), from the
    second-scattering source sigma_s* phi1 (phi1 the first flights' fluence in the medium)
    with the direction ``first_phase(..., order=2)``.

    ``q`` (X,Y,Z,3): the first-scattering source on the pyramid's lattice (W/m^3, the walk's,
    of the delta-scaled medium); ``inside`` (X,Y,Z) bool: the lattice points in the medium;
    ``axes`` (3,3): world metres per lattice step (columns); ``source_dirs`` (N,3): the
    light's propagation direction at every lattice point; ``v`` (N,3): the direction from
    every lattice point to the camera; ``g`` the medium's own HG anisotropy (the scatterings'
    outside its forward peak, ``first_phase``, and the last one's towards the camera);
    ``sigma_t``, ``sigma_s`` (3,) the delta-scaled medium's mean extinction and scattering
    where it has density (1/m).  The camera directions' convolutions run on ``threads``
    threads (<= 0: one per core; numpy's FFTs release the GIL), fewer where ``fft_memory``
    bytes (default FFT_MEMORY) would not hold them.

    d is the sources' power-weighted mean direction, and the length of that mean spreads the
    flights' directions (``first_phase``): round a point light inside the medium they are
    isotropic."""
    shape = q.shape[:3]
    if int(np.prod(fft_shape(shape))) > MAX_FFT_POINTS:
        return None
    got = flight_weight(q, inside, axes, source_dirs, g, sigma_t)
    if got is None:
        return None
    weight, d, spread = got
    sigma_t = np.broadcast_to(np.asarray(sigma_t, np.float64), (3,))
    second = sigma_s is not None and exact_flights >= 2   # what the walk's table leaves out
    sigma_s = np.zeros(3) if sigma_s is None else \
        np.broadcast_to(np.asarray(sigma_s, np.float64), (3,))
    dirs, wts = camera_directions(v, v[inside.reshape(-1)])
    out = np.zeros(tuple(shape) + (3,))
    # a channel whose source is another's times a constant, with the same coefficients (a
    # grey medium under a light of any colour), is that channel's flight times the constant
    sums = q.sum(axis=(0, 1, 2))
    same = {}
    for ch in (c for c in range(3) if weight[c] > 0.0 and sums[c] > 0.0):
        for r in same:
            if sigma_t[r] == sigma_t[ch] and sigma_s[r] == sigma_s[ch] and np.allclose(
                    q[..., ch] * sums[r], q[..., r] * sums[ch], rtol=1e-6, atol=0.0):
                same[r].append(ch)
                break
        else:
            same[ch] = [ch]
    orders = {r: [1, 2] if second and sigma_s[r] > 0.0 else [1] for r in same}
    # per (sigma_t, order): the kernel's parts that no camera direction changes, built once
    # where they fit in half of fft_memory (else per use, as flight_kernel does)
    keys = sorted({(float(sigma_t[r]), order) for r in same for order in orders[r]})
    base_bytes = 20 * int(np.prod([2 * n - 1 for n in shape]))
    bases = {}
    if len(keys) * base_bytes <= fft_memory // 2:
        for key in keys:
            check(should_cancel)
            bases[key] = KernelBase(axes, shape, d, (float(g), spread, key[1]), key[0])

    def base(key):
        return bases[key] if key in bases else \
            KernelBase(axes, shape, d, (float(g), spread, key[1]), key[0])

    sources = {}   # per representative channel: the spectra of the first and second sources
    bare = {}      # per sigma_t: the first flight's bare kernel's spectrum (for phi1)
    for r in same:
        check(should_cancel)
        fq = spectrum(q[..., r], shape)
        sources[r] = [(fq, 1)]
        if 2 in orders[r]:
            s = float(sigma_t[r])
            if s not in bare:
                bare[s] = spectrum(base((s, 1)).kernel(), shape)
            phi1 = np.maximum(convolve(fq, bare[s], shape), 0.0)
            q2 = np.where(inside, float(sigma_s[r]) * phi1, 0.0)
            sources[r].append((spectrum(q2, shape), 2))
    turn = threading.Condition()
    added = [0]   # directions added to ``out`` so far: they are added in order, so that the
    # sum (and the render) does not depend on which thread finished first

    def directions(a, b):   # one camera direction per chunk, on the pool's threads
        for j in range(a, b):
            part = {}
            try:
                fk = {}
                for r in same:
                    if should_cancel and should_cancel():
                        return
                    s = float(sigma_t[r])
                    prod = 0.0   # the flights' spectra summed: one inverse transform
                    for fq, order in sources[r]:
                        if (s, order) not in fk:
                            fk[(s, order)] = spectrum(base((s, order)).kernel(
                                dirs[j], float(g)), shape)
                        prod = prod + fq * fk[(s, order)]
                    part[r] = inverse(prod, shape) * wts[:, j].reshape(shape)
            finally:
                with turn:
                    turn.wait_for(lambda: added[0] == j)
                    for r, f in part.items():
                        for ch in same[r]:
                            out[..., ch] += f * (sums[ch] / sums[r])
                    added[0] += 1
                    turn.notify_all()

    # each thread holds a kernel, its spectrum, a product and a result of the FFT's size,
    # beside the kernels' bases (float64 and three float32 per offset)
    per_thread = 4 * 8 * int(np.prod(fft_shape(shape)))
    held = sum(b.bare.nbytes + b.u.nbytes for b in bases.values())
    n_threads = worker_count(threads)
    n_threads = max(1, min(n_threads, (fft_memory - held) // per_thread))
    run_chunks(len(dirs), 1, directions, n_threads, should_cancel)
    check(should_cancel)   # a direction that saw Esc left its part out
    return FirstFlight(np.ascontiguousarray(np.maximum(out, 0.0), np.float32), weight)
