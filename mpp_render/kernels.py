"""The kernels, by name: the compiled twin when it is built, otherwise the numpy twin.

Each kernel is an attribute (``kernels.march(inputs)``, ``kernels.optical_depth(...)``,
``kernels.light_sweep(...)``, ``kernels.upsample_into(...)``, ``kernels.trilinear(...)``) that
runs the active backend, or the one its ``backend`` argument names ("c" or "numpy").  The
march takes its inputs as one ``MarchInputs`` record (the multiple-scattering part a
``MultipleInputs`` of ``LevelField``s) and returns a ``MarchResult``.

``backend()`` says which one runs: numpy where the compiled module is missing, where
``MPP_KERNELS=numpy`` is set in the environment (the user's switch, read at import) and inside
a ``numpy_backend()`` block (the tests' way to hold the two twins to each other; it holds in
every thread while the block runs).  The wrappers hand the C kernels contiguous arrays of the
exact dtypes they check for, and turn results into numpy.
"""
from __future__ import annotations

import contextlib
import dataclasses
import os
import threading
from typing import List, NamedTuple, Optional

import numpy as np

from . import kernels_np, lights
from .lightrecord import KIND_AREA, L_KIND, L_ROUND, LIGHT_FIELDS
from .media import BRICK
from .parallel import run_chunks
from .walk import DLOG_RHO, LOG_RHO0

try:  # pragma: no cover - depends on the build
    from . import _kernels as _c  # built in place (setup.py build_ext --inplace)
except ImportError:
    try:  # the installed extension: the wheel of ``python -m mpp_render package``
        from mpp_render_kernels import _kernels as _c
    except ImportError:  # the engine still renders, on numpy
        _c = None

_ENV_NUMPY = os.environ.get("MPP_KERNELS", "").lower() == "numpy"
_numpy_blocks = 0  # numpy_backend() blocks now open
_blocks_lock = threading.Lock()


def backend() -> str:
    """"c" or "numpy": the backend a kernel called without ``backend`` runs on now."""
    return "numpy" if (_c is None or _ENV_NUMPY or _numpy_blocks) else "c"


@contextlib.contextmanager
def numpy_backend():
    """Every kernel called while the block runs (in any thread) runs on its numpy twin."""
    global _numpy_blocks
    with _blocks_lock:
        _numpy_blocks += 1
    try:
        yield
    finally:
        with _blocks_lock:
            _numpy_blocks -= 1


def _on_c(which: Optional[str]) -> bool:
    """Whether a kernel asked for backend ``which`` (None: the active one) runs compiled."""
    if which is None:
        return backend() == "c"
    if which == "c":
        if _c is None:
            raise RuntimeError("the compiled kernels are not built")
        return True
    if which != "numpy":
        raise ValueError(f"backend must be 'c' or 'numpy', not {which!r}")
    return False


FALLBACK_MESSAGE = ("MPP: the compiled kernels are not installed; rendering on the numpy path, "
                    "which gives the same image several times slower")
_fallback_said = False


def fallback_notice():
    """``FALLBACK_MESSAGE`` the first time it is asked for in a process whose compiled kernels
    are missing (not when ``MPP_KERNELS=numpy`` chose numpy), None otherwise: said once."""
    global _fallback_said
    if _c is not None or _fallback_said:
        return None
    _fallback_said = True
    return FALLBACK_MESSAGE


def _f64(a):
    return np.ascontiguousarray(a, np.float64)


def _f32(a):
    return np.ascontiguousarray(a, np.float32)


def optical_depth(points, dirs, t_max, grids, w2is, sigma_ts, thresholds, step, offset=0.5,
                  bricks=None, clip=False, stop=None, stop_depth=np.inf, *, backend=None):
    """RGB optical depth (N,3) along rays (kernels_np.optical_depth)."""
    if not _on_c(backend):
        return kernels_np.optical_depth(points, dirs, t_max, grids, w2is, sigma_ts, thresholds,
                                        step, offset, bricks, clip, stop, stop_depth)
    n = len(points)
    buf = _c.optical_depth(_f64(points).reshape(n, 3), _f64(dirs).reshape(n, 3),
                           _f64(t_max).reshape(n), [_f32(g) for g in grids],
                           [_f64(w) for w in w2is], [_f64(s).reshape(3) for s in sigma_ts],
                           [float(t) for t in thresholds], float(step), float(offset),
                           None if bricks is None else [_f32(b) for b in bricks], BRICK,
                           bool(clip), None if stop is None else _f64(stop).reshape(3, 3),
                           float(stop_depth))
    return np.frombuffer(buf, np.float64).reshape(n, 3)


@dataclasses.dataclass
class SweepJob:
    """One job of the light sweep: the slabs ``p_lo``..``p_hi`` of one pyramid of light
    columns (precompute.lightdepth.sweep_pyramids) over a medium whose padded index maps to
    world by ``a2w`` (3,4).  ``axis``, ``sign``, ``i_first``, ``i_last``, ``coef`` (6,),
    ``cone``: the pyramid; ``light_index`` (3,): the light in index coordinates; ``init``
    (P,Q,3): the optical depth at the pyramid's first slab; ``n_sub``: sub-steps per slab;
    ``grids``, ``w2is``, ``sigma_ts``, ``thresholds``: the media it crosses
    (lightdepth.kernel_arrays).  kernels_np.light_sweep documents the sweep itself."""

    a2w: np.ndarray
    axis: int
    sign: int
    i_first: int
    i_last: int
    coef: np.ndarray
    light_index: np.ndarray
    cone: bool
    init: np.ndarray
    p_lo: int
    p_hi: int
    n_sub: int
    grids: list
    w2is: list
    sigma_ts: list
    thresholds: list

    def args(self) -> tuple:
        """The fields in the kernels' order."""
        return (self.a2w, self.axis, self.sign, self.i_first, self.i_last, self.coef,
                self.light_index, self.cone, self.init, self.p_lo, self.p_hi, self.n_sub,
                self.grids, self.w2is, self.sigma_ts, self.thresholds)


def light_sweep(out, channel: int, job: SweepJob, *, backend=None):
    """Optical depth towards a light, written into channels ``channel``..+2 of ``out``
    (X,Y,Z,C) float32 for ``job`` (a SweepJob; the numpy twin is kernels_np.light_sweep)."""
    if not _on_c(backend):
        return kernels_np.light_sweep(out, channel, *job.args())
    if not (isinstance(out, np.ndarray) and out.dtype == np.float32 and out.flags.c_contiguous
            and out.flags.writeable and out.ndim == 4):
        raise ValueError("light_sweep: out must be a writable C-contiguous (X,Y,Z,C) float32 array")
    _c.light_sweep(out, int(channel), _f64(job.a2w).reshape(3, 4), int(job.axis), int(job.sign),
                   int(job.i_first), int(job.i_last), _f64(job.coef).reshape(6),
                   _f64(job.light_index).reshape(3), int(bool(job.cone)), _f64(job.init),
                   int(job.p_lo), int(job.p_hi), int(job.n_sub), [_f32(g) for g in job.grids],
                   [_f64(w) for w in job.w2is], [_f64(s).reshape(3) for s in job.sigma_ts],
                   [float(t) for t in job.thresholds])


def upsample_into(field, channel, lattice, stride, flat, *, inside=None, backend=None):
    """A lattice's trilinear values written into ``field`` at voxels ``flat`` (None: every
    voxel), geometric where ``inside`` says (kernels_np.upsample_into)."""
    if not _on_c(backend):
        return kernels_np.upsample_into(field, channel, lattice, stride, flat, inside)
    if not (isinstance(field, np.ndarray) and field.dtype == np.float32 and field.flags.c_contiguous
            and field.flags.writeable and field.ndim == 4):
        raise ValueError("upsample_into: field must be a writable C-contiguous (X,Y,Z,C) float32 array")
    _c.upsample_into(field, int(channel), _f32(lattice), int(stride),
                     None if flat is None else np.ascontiguousarray(flat, np.int64).reshape(-1),
                     None if inside is None else np.ascontiguousarray(inside, np.uint8))


NODAL_CHANNELS = 64   # the most channels the compiled nodal fit takes (csrc/nodal.c)


def nodal_fit(mean, offsets, mass, signed: int, ridge: float, *, backend=None):
    """The tent means moved to the lattice points (kernels_np.nodal_fit): (X,Y,Z,C) float32."""
    if not _on_c(backend):
        return kernels_np.nodal_fit(mean, offsets, mass, signed, ridge)
    m = _f32(mean)
    if m.ndim != 4 or m.shape[-1] > NODAL_CHANNELS:
        return kernels_np.nodal_fit(mean, offsets, mass, signed, ridge)
    buf = _c.nodal_fit(m, _f64(offsets).reshape(m.shape[:3] + (3,)),
                       _f64(mass).reshape(m.shape[:3]), int(signed), float(ridge))
    return np.frombuffer(buf, np.float32).reshape(m.shape)


def light_sample(rec, x, u1, u2, normal=None, *, backend=None):
    """lights.light_sample of packed light ``rec`` at points ``x`` (N,3, m) with jitter
    ``u1``, ``u2`` (N,) in [0, 1): (propagation direction (N,3), irradiance (N,3), unit
    direction to the centre (N,3), the centre's distance (N,), the sampled point's (N,)).
    ``normal`` (N,3) warps a rectangle light's points towards a surface's cosine
    (lights.cosine_warp), which only the numpy twin does: such calls run there."""
    rec = _f64(rec).reshape(-1)
    rect = int(rec[L_KIND]) == KIND_AREA and not rec[L_ROUND] > 0
    if not _on_c(backend) or (normal is not None and rect):
        return lights.light_sample(rec, x, u1, u2, normal=normal)
    x = _f64(x).reshape(-1, 3)
    n = len(x)
    u1 = _f64(np.broadcast_to(u1, (n,)))
    u2 = _f64(np.broadcast_to(u2, (n,)))
    out = np.frombuffer(_c.light_samples(rec, x, u1, u2), np.float64).reshape(n, 11).copy()
    return out[:, 0:3], out[:, 3:6], out[:, 6:9], out[:, 9], out[:, 10]


def emitter_transmittance(x, tau, dc, nodes, weights, normal, voxel: float, *, backend=None):
    """lights.emitter_transmittance (its numpy twin): (N,3) float64, the transmittance an
    emitter's quadrature ``nodes`` (K,3) with ``weights`` (K,) reach points ``x`` (N,3)
    with, from their depth ``tau`` (N,3) to its centre ``dc`` (N,) metres away."""
    if not _on_c(backend):
        return lights.emitter_transmittance(x, tau, dc, nodes, weights, normal, voxel)
    x = _f64(x).reshape(-1, 3)
    n = len(x)
    buf = _c.emitter_transmittance(x, _f64(tau).reshape(n, 3), _f64(dc).reshape(n),
                                   _f64(nodes).reshape(-1, 3), _f64(weights).reshape(-1),
                                   _f64(normal).reshape(3), float(voxel))
    return np.frombuffer(buf, np.float64).reshape(n, 3).copy()


def lobe_ratio(md, mc, u, r: int, channels: int = 3, *, backend=None):
    """The lobe's local-linear fit (kernels_np.lobe_ratio): (X,Y,Z,3) float64."""
    if not _on_c(backend) or int(r) < 1:
        return kernels_np.lobe_ratio(md, mc, u, r, channels)
    d = _f64(md)
    buf = _c.lobe_ratio(d, _f64(mc).reshape(d.shape), _f64(u).reshape(d.shape[:3]), int(r),
                        int(channels))
    return np.frombuffer(buf, np.float64).reshape(d.shape)


def trilinear(grid, idx, *, backend=None):
    """media.trilinear: (N,C) for a 4-D grid, (N,) for a 3-D one.  A grid that is not float32
    is read by the numpy twin (the kernel would round it to float32)."""
    if not _on_c(backend) or np.asarray(grid).dtype != np.float32:
        return kernels_np.trilinear(grid, idx)
    g = np.ascontiguousarray(grid)
    flat = g.ndim == 3
    g4 = g.reshape(g.shape + (1,)) if flat else g
    idx = _f64(idx).reshape(-1, 3)
    out = np.frombuffer(_c.trilinear(g4, idx), np.float64).reshape(len(idx), g4.shape[3])
    return out[:, 0] if flat else out


def walk_tau(grid, w2i, sigma_t, xc: int, channel: int, x, w, dist, tau, sig_max: float,
             voxel: float, cell_tau: float, cells: int, *, backend=None) -> np.ndarray:
    """(N,3) the optical depth towards a light from points ``x`` (N,3, world) in optically
    thick cells of one density grid, as the march takes it there (kernels_np._walk_tau with
    this grid alone): ``grid`` (X,Y,Z,C) float32 with the density in channel 0, the light's
    depth at the voxel centres in ``channel``..+2 and the extinction density in ``xc``..+2
    (or ``xc`` -1), ``w2i`` (3,4) world to index, ``sigma_t`` (3,) 1/m per unit density, ``w``
    (N,3) unit directions to the light, ``dist`` (N,) its centre's distance (m, inf for a
    sun), ``tau`` (N,3) the trilinear read at ``x``; ``sig_max``, ``voxel`` (m), ``cell_tau``
    and ``cells`` as Tuning's."""
    x = _f64(x).reshape(-1, 3)
    n = len(x)
    if not _on_c(backend) or not hasattr(_c, "walk_depth") or np.asarray(grid).dtype != np.float32:
        return kernels_np._walk_tau([np.asarray(grid)], [np.asarray(w2i, np.float64)], [-1.0],
                                    [np.asarray(sigma_t, np.float64)], 0, int(channel), x,
                                    np.asarray(w, np.float64).reshape(n, 3),
                                    np.asarray(dist, np.float64).reshape(n),
                                    np.asarray(tau, np.float64).reshape(n, 3), float(sig_max),
                                    float(voxel), float(cell_tau), int(cells), xcs=[int(xc)],
                                    read=kernels_np.trilinear)
    out = _c.walk_depth(np.ascontiguousarray(grid), _f64(w2i).reshape(3, 4),
                        _f64(sigma_t).reshape(3), int(xc), int(channel), x,
                        _f64(w).reshape(n, 3), _f64(dist).reshape(n), _f64(tau).reshape(n, 3),
                        float(sig_max), float(voxel), float(cell_tau), int(cells))
    return np.frombuffer(out, np.float64).reshape(n, 3).copy()


class LevelField(NamedTuple):
    """One light's multiple-scattering pyramid in one medium, as the march reads it."""
    levels: list    # float32 (X,Y,Z,3) lattices; level k's spacing is h 2^k
    stride: int     # voxels of the medium's grid per level-0 lattice step
    h: float        # level 0's lattice spacing (m)


class MultipleInputs(NamedTuple):
    """The march's multiple scattering.  ``on_field``: None, or per medium None or its one
    level (float32 (X,Y,Z,3), the radiance 4 pi M of its lights' summed level before the flat
    table's weight) resampled on its field's voxels (march.on_field), read with the field's
    own trilinear stencil; such a medium's table is flat (march.FLAT_TABLE) and its
    ``per_medium`` entry holds no level."""
    ambient: int                                    # the world light's multiple channel, or -1
    per_medium: List[List[Optional[LevelField]]]    # per medium, per light (None: no pyramid)
    tables: List[np.ndarray]                        # per medium its walk.level_table (K, R, 6)
    on_field: Optional[List[Optional[np.ndarray]]] = None


@dataclasses.dataclass(frozen=True)
class MarchInputs:
    """Everything the march kernel reads (kernels_np.march documents each field).

    Per ray (N): ``origins``, ``dirs`` (N,3) world, unit directions; ``t0``, ``t1`` the
    interval (m) to march; ``axial`` the factor from distance along the ray to depth; ``keys``
    uint32 random keys.  Per medium: ``fields`` (X,Y,Z,C) float32 (density, then the
    FieldLayout's channels), ``w2is`` (3,4) world -> padded index maps, ``sigma_ss``,
    ``sigma_ts`` RGB (1/m per unit density), ``gs`` HG anisotropies, ``thresholds`` (< 0:
    smooth), ``voxels`` voxel sizes (m).  ``lights`` (L, LIGHT_FIELDS) records
    (lightrecord); ``ambient`` the world light's single channel or -1; ``step`` (m);
    ``depth_opacity``, ``depth_miss`` the depth pass's threshold and miss value; then the
    optional parts: ``multiple``, per-medium RGB ``emissions``, ``bricks``
    (media.brick_bounds), ``adapt_tau`` (> 0: longer steps in thin media) and
    ``emission_channels`` (per medium the first channel of its emission grid, or -1) and
    ``roulette`` (> 0: Russian roulette below that transmittance) and ``disc_reach`` (per
    light, the distance in metres within which a point or spot light's disc point or an area
    light's emitter point gets its optical depth corrected by a march,
    kernels_np.disc_correction; None or 0: off) and
    ``scatter_channels`` (per medium the first channel of its scatter colour grid, or -1) and
    ``extinction_channels`` (per medium the first channel of its extinction density, or -1:
    its extinction reads the density) and ``cell_tau`` (> 0: a density grid's cell whose most
    extinguishing corner is at least that optical depth across follows each light's path
    cell by cell for at most ``cell_walk`` cells, then reads its depth on the next plane of
    voxel centres along the light's main axis, kernels_np._walk_tau; 0: off) and
    ``jitter_bands`` (per ray its stratum, 0 .. ``jitter_count`` - 1, shuffled per step by
    its pixel's key ``jitter_keys``, kernels_np.step_stratum; None: the whole step)."""
    origins: np.ndarray
    dirs: np.ndarray
    t0: np.ndarray
    t1: np.ndarray
    axial: np.ndarray
    keys: np.ndarray
    fields: list
    w2is: list
    sigma_ss: list
    sigma_ts: list
    gs: list
    thresholds: list
    voxels: list
    lights: np.ndarray
    ambient: int
    step: float
    depth_opacity: float
    depth_miss: float
    multiple: Optional[MultipleInputs] = None
    emissions: Optional[list] = None
    bricks: Optional[list] = None
    adapt_tau: float = 0.0
    emission_channels: Optional[list] = None
    roulette: float = 0.0
    disc_reach: Optional[list] = None
    scatter_channels: Optional[list] = None
    extinction_channels: Optional[list] = None
    cell_tau: float = 0.0
    cell_walk: int = 0
    jitter_bands: Optional[np.ndarray] = None
    jitter_count: int = 1
    jitter_keys: Optional[np.ndarray] = None

    def replace(self, **changes) -> "MarchInputs":
        return dataclasses.replace(self, **changes)


class MarchResult(NamedTuple):
    """Per ray: single-scattered radiance (N,3), transmittance T (N,3), depth (N,),
    multiple-scattered radiance (N,3), march steps taken (N,), emitted radiance (N,3)."""
    single: np.ndarray
    T: np.ndarray
    depth: np.ndarray
    multiple: np.ndarray
    steps: np.ndarray
    emission: np.ndarray


def march(inputs: MarchInputs, *, backend=None) -> MarchResult:
    """March camera rays through the media (kernels_np.march)."""
    a = inputs
    if not _on_c(backend):
        return MarchResult(*kernels_np.march(
            a.origins, a.dirs, a.t0, a.t1, a.axial, a.keys, a.fields, a.w2is, a.sigma_ss,
            a.sigma_ts, a.gs, a.thresholds, a.voxels, a.lights, a.ambient, a.step,
            a.depth_opacity, a.depth_miss, a.multiple, a.emissions, a.bricks, a.adapt_tau,
            a.emission_channels, a.roulette, a.disc_reach, a.scatter_channels,
            a.extinction_channels, a.cell_tau, a.cell_walk, a.jitter_bands, a.jitter_count,
            a.jitter_keys))
    n = len(a.origins)
    nl = len(np.asarray(a.lights).reshape(-1, LIGHT_FIELDS))
    packed = None
    if a.multiple is not None:
        amb_ms, per_medium, tables, on_field = a.multiple
        levels, table = [], np.zeros((len(a.fields), nl, 4))
        table[:, :, 0] = -1
        for m, mfs in enumerate(per_medium):
            for li, msf in enumerate(mfs or []):
                if msf is None:
                    continue
                lv, stride, h = msf
                table[m, li] = (len(levels), len(lv), stride, h)
                levels.extend(_f32(x) for x in lv)
        packed = (int(amb_ms), levels, table, [_f64(t) for t in tables], LOG_RHO0, DLOG_RHO,
                  [None] * len(a.fields) if on_field is None else
                  [None if f is None else _f32(f) for f in on_field])
    s, t, d, m, k, e = _c.march(
        _f64(a.origins).reshape(n, 3), _f64(a.dirs).reshape(n, 3), _f64(a.t0).reshape(n),
        _f64(a.t1).reshape(n), _f64(a.axial).reshape(n),
        np.ascontiguousarray(a.keys, np.uint32).reshape(n), [_f32(f) for f in a.fields],
        [_f64(w) for w in a.w2is], [_f64(x).reshape(3) for x in a.sigma_ss],
        [_f64(x).reshape(3) for x in a.sigma_ts], [float(g) for g in a.gs],
        [float(x) for x in a.thresholds], [float(v) for v in a.voxels],
        _f64(a.lights).reshape(-1, LIGHT_FIELDS), int(a.ambient), float(a.step),
        float(a.depth_opacity), float(a.depth_miss), packed,
        None if a.emissions is None else [_f64(x).reshape(3) for x in a.emissions],
        None if a.bricks is None else [_f32(b) for b in a.bricks], BRICK, float(a.adapt_tau),
        None if a.emission_channels is None else [int(c) for c in a.emission_channels],
        float(a.roulette),
        None if a.disc_reach is None else [float(x) for x in a.disc_reach],
        None if a.scatter_channels is None else [int(c) for c in a.scatter_channels],
        None if a.extinction_channels is None else [int(c) for c in a.extinction_channels],
        float(a.cell_tau), int(a.cell_walk),
        None if a.jitter_bands is None else
        np.ascontiguousarray(a.jitter_bands, np.uint32).reshape(n), int(a.jitter_count),
        None if a.jitter_bands is None else
        np.ascontiguousarray(a.jitter_keys, np.uint32).reshape(n))
    return MarchResult(np.frombuffer(s, np.float64).reshape(n, 3),
                       np.frombuffer(t, np.float64).reshape(n, 3),
                       np.frombuffer(d, np.float64).reshape(n),
                       np.frombuffer(m, np.float64).reshape(n, 3),
                       np.frombuffer(k, np.float64).reshape(n),
                       np.frombuffer(e, np.float64).reshape(n, 3))


def _colour(grid) -> np.ndarray:
    """A medium's 3-channel grid (scatter colour, extinction density) as trace_paths takes
    it: float32 (X,Y,Z,3), or (0,0,0,3) for none."""
    return _f32(grid) if grid is not None else np.zeros((0, 0, 0, 3), np.float32)


def union_interval(media, origins, dirs, t_lo, t_hi, *, backend=None):
    """(t0, t1) (N,) each: the smallest interval of rays ``origins`` + t ``dirs`` (N,3) that
    covers every one of the prepared ``media``'s sampling boxes they cross, clipped to
    [``t_lo``, ``t_hi``] (t0 > t1 where they cross none): media.union_interval, its twin."""
    from .media import union_interval as union_np
    if not _on_c(backend) or not hasattr(_c, "union_interval") or not len(media):
        return union_np(media, origins, dirs, t_lo, t_hi)
    n = len(origins)
    w2is = np.stack([np.asarray(pm.w2i, np.float64).reshape(3, 4) for pm in media])
    last = np.array([np.array(pm.grid.shape[:3], np.float64) - 1.0 for pm in media])
    lo = np.broadcast_to(np.asarray(t_lo, np.float64), (n,))
    hi = np.broadcast_to(np.asarray(t_hi, np.float64), (n,))
    a, b = _c.union_interval(_f64(origins).reshape(n, 3), _f64(dirs).reshape(n, 3), _f64(lo),
                             _f64(hi), _f64(w2is), _f64(last))
    return np.frombuffer(a, np.float64), np.frombuffer(b, np.float64)


def intersect(origins, dirs, tmax, triangles, *, backend=None):
    """(t (N,), triangle (N,) int64): the closest hit of rays ``origins`` + t ``dirs`` (N,3)
    for t in (0, ``tmax``) (N,) among ``triangles`` (T,9: corner and two edges), tmax and
    -1 where none (the numpy twin: kernels_np.intersect_triangles)."""
    o = _f64(origins).reshape(-1, 3)
    n = len(o)
    if not _on_c(backend) or not hasattr(_c, "intersect"):
        return kernels_np.intersect_triangles(o, _f64(dirs).reshape(n, 3),
                                              _f64(tmax).reshape(n),
                                              _f64(triangles).reshape(-1, 9))
    t, k = _c.intersect(o, _f64(dirs).reshape(n, 3), _f64(tmax).reshape(n),
                        _f64(triangles).reshape(-1, 9))
    return np.frombuffer(t, np.float64), np.frombuffer(k, np.int64)


def trace_paths(inp, *, threads: int = 1, should_cancel=None, backend=None):
    """Light paths' deposits (LX,LY,LZ,inp.channels) float64 for ``inp`` (a paths.PathInputs
    without others; the numpy twin is paths.trace_paths_np): ``trace_paths_media``'s first."""
    return trace_paths_media(inp, threads=threads, should_cancel=should_cancel,
                             backend=backend)[0]


def trace_paths_media(inp, *, threads: int = 1, should_cancel=None, backend=None,
                      halves: bool = False):
    """Light paths' deposits for ``inp`` (a paths.PathInputs; the numpy twin is
    paths.trace_paths_media_np): one float64 array (LX,LY,LZ,inp.channels) per medium on its
    own lattice, the paths' own medium first, then ``inp.others`` in their order.  The paths
    are cut into ``PATH_BLOCKS`` blocks, each with its own sums added in a fixed order, which
    ``threads`` workers share (the caller sizes them: parallel.worker_count): the result is
    the same bits for any thread count (frames match across farm machines).  Each block runs
    ``PATH_CHUNK`` paths a call on parallel.run_chunks' pool, while this thread asks
    ``should_cancel`` every parallel.POLL_S s: when it says so, a stop flag the compiled
    loops read every few paths ends them, and cancel.Cancelled is raised.  ``halves``:
    returns (that list, (first, k)), first the own medium's light deposits (LX,LY,LZ,3) of
    paths 0..k-1 alone, the blocks of the first half (weighed, as every path, by
    1 / n_paths), or (list, None) with under 2 blocks: two independent estimates
    (first x n / k and the rest x n / (n - k)) whose difference measures the deposits' noise
    (precompute/lobefit.py)."""
    from .paths import ROULETTE, trace_paths_media_np
    n = int(inp.n_paths)
    if not _on_c(backend) or not hasattr(_c, "trace_paths"):
        if n <= 0 or len(inp.cdf) == 0 or not (halves or inp.moments):
            full = trace_paths_media_np(inp)
            return (full, None) if halves else full
        return _trace_blocks_np(inp, halves)
    grids = [inp] + list(inp.others)
    shapes = [tuple(m.towards.shape[:3]) for m in grids]
    if n <= 0 or len(inp.cdf) == 0:
        empty = [np.zeros(sh + (inp.channels,)) for sh in shapes]
        return (empty, None) if halves else empty
    blocks = min(PATH_BLOCKS, n)
    workers = max(1, min(int(threads), blocks))
    cuts = np.linspace(0, n, blocks + 1).astype(np.int64)
    outs = [[np.zeros(sh + (3,)) for sh in shapes] for _ in range(blocks)]
    moms = [[np.zeros(sh + (12,) if inp.moments else (0, 0, 0, 12)) for sh in shapes]
            for _ in range(blocks)]
    ends = moment_ends(inp, cuts)      # each block's paths up to ends[i] deposit the moments
    bare = np.zeros((0, 0, 0, 12))
    args = (_f32(inp.density), _f64(inp.w2i).reshape(3, 4), _f64(inp.i2w).reshape(3, 3),
            _f64(inp.sigma_s).reshape(3), _f64(inp.sigma_t).reshape(3), float(inp.g),
            int(inp.stride),
            _f64(inp.towards), _f64(inp.starts), _f64(inp.weights), _f64(inp.dirs),
            _f64(inp.cdf).reshape(-1), float(inp.rate))
    tri = _f64(inp.triangles).reshape(-1, 9)
    extra = (float(inp.jitter), int(inp.lobe), float(inp.outside),
             _f64(np.append(np.asarray(inp.reach_centre, np.float64).reshape(3),
                            float(inp.reach_radius))),
             tri, _f64(inp.albedo).reshape(len(tri), 3),
             _f32(inp.start_source) if inp.start_source is not None else np.zeros((0, 0, 0), np.float32),
             _f64(inp.start_peak).reshape(-1) if inp.start_source is not None else np.zeros(0))
    fixed = [(_f32(m.density), _f64(m.w2i).reshape(3, 4), _f64(m.sigma_s).reshape(3),
              _f64(m.sigma_t).reshape(3), float(m.g), int(m.stride), _f64(m.towards),
              float(m.rate), float(m.threshold), cell_classes(m.density, m.threshold),
              _colour(m.scatter), _colour(m.extinction))
             for m in inp.others]
    colour, extinction = _colour(inp.scatter), _colour(inp.extinction)
    cells = cell_classes(inp.density, inp.threshold)
    light = _f64(inp.light).reshape(-1) if inp.light is not None else np.zeros(0)
    # the camera's roulette odds, after the stop flag where there are some
    odds = (_f32(inp.odds),) if inp.odds is not None else ()
    if inp.start_rate is not None:   # the starts' rates, after the odds (None: no odds)
        rate = np.ascontiguousarray(np.asarray(inp.start_rate, np.float64).reshape(-1))
        if len(rate) != len(inp.starts):
            raise ValueError("trace_paths: start_rate must hold one value per start")
        odds = (odds[0] if odds else None, rate)

    stop = np.zeros(1, np.uint8)   # set by run_chunks on Esc: the compiled loops stop

    def work(i, _):
        others = tuple((outs[i][1 + k], moms[i][1 + k]) + f for k, f in enumerate(fixed))
        plain = tuple((outs[i][1 + k], bare) + f for k, f in enumerate(fixed))
        end = int(ends[i])
        for a in range(int(cuts[i]), int(cuts[i + 1]), PATH_CHUNK):
            if stop[0]:
                return
            b = min(a + PATH_CHUNK, int(cuts[i + 1]))
            # the paths before ``end`` with their moments, the rest without
            for lo, hi, mom, oth in ((a, min(b, end), moms[i][0], others),
                                     (max(a, end), b, bare, plain)):
                if hi > lo:
                    _c.trace_paths(outs[i][0], *args, lo, hi, n, int(inp.seed) & 0xFFFFFFFF,
                                   int(inp.max_collisions), float(ROULETTE), *extra, mom, oth,
                                   float(inp.threshold), cells, light, colour, extinction,
                                   int(inp.min_collisions), stop, *odds)

    run_chunks(blocks, 1, work, threads=workers, should_cancel=should_cancel, stop=stop)
    result, first = [], None
    for g in range(len(grids)):
        total, moments = outs[0][g], moms[0][g]
        for i in range(1, blocks):
            if halves and g == 0 and i == blocks // 2:   # the first half's sum, on the way
                first = (total.copy(), int(cuts[i]))
            total += outs[i][g]
            moments += moms[i][g]
        if inp.moments and not np.array_equal(ends, cuts[1:]):   # a share's, for all the paths
            moments *= n / float(np.sum(ends - cuts[:-1]))
        result.append(np.concatenate([total, moments], axis=-1) if inp.moments else total)
    return (result, first) if halves else result


# the most cells cell_classes maps (one byte each); a larger grid reads every cell's voxels
CELL_CLASSES_MAX = 1 << 27


def cell_classes(density, threshold: float) -> np.ndarray:
    """For a grid ``density`` (n0,n1,n2) read as a sharp medium at ``threshold`` > 0 (the
    trilinear value >= threshold is inside, paths.PathInputs.threshold): (n0-1,n1-1,n2-1)
    uint8, each cell between 8 voxels 0 where all 8 lie below threshold x (1 - 1e-9), so that
    any trilinear mix of them is below it, 1 where all lie at or above threshold x
    (1 + 1e-9), so that any mix is inside, else 2 (non-finite voxels too): the compiled
    tracer reads the 8 voxels only in cells of class 2 and finds the same values.  Empty
    (0,0,0) where there is no such threshold, a side has under 2 voxels, or the grid has
    more than ``CELL_CLASSES_MAX`` cells."""
    d = np.asarray(density)
    thr = float(threshold)
    if not thr > 0.0 or d.ndim != 3 or min(d.shape) < 2 or \
            int(np.prod(np.asarray(d.shape) - 1)) > CELL_CLASSES_MAX:
        return np.zeros((0, 0, 0), np.uint8)
    d = np.asarray(d, np.float32)
    corners = [d[a:d.shape[0] - 1 + a, b:d.shape[1] - 1 + b, c:d.shape[2] - 1 + c]
               for a in (0, 1) for b in (0, 1) for c in (0, 1)]
    lo, hi = corners[0].copy(), corners[0].copy()
    for v in corners[1:]:
        np.minimum(lo, v, out=lo)   # NaN propagates: such a cell stays class 2
        np.maximum(hi, v, out=hi)
    lo64, hi64 = lo.astype(np.float64), hi.astype(np.float64)
    ok = np.isfinite(lo64) & np.isfinite(hi64)
    out = np.full(lo.shape, 2, np.uint8)
    out[ok & (hi64 <= thr * (1.0 - 1e-9))] = 0
    out[ok & (lo64 >= thr * (1.0 + 1e-9))] = 1
    return out


PATH_BLOCKS = 4   # trace_paths' blocks of paths (its sums' order, whatever the threads)
PATH_CHUNK = 16384   # paths per call of the compiled tracer (each call sorts its paths by start)


def _trace_blocks_np(inp, halves: bool):
    """trace_paths_media's numpy twin with the moments or the halves: the compiled tracer's
    blocks of paths (``PATH_BLOCKS``), each path traced once, with its moments where it lies
    before its block's ``moment_ends`` and without them after; the first half's light summed
    on the way as the compiled one sums it."""
    from .paths import trace_paths_media_np
    n = int(inp.n_paths)
    blocks = min(PATH_BLOCKS, n)
    cuts = np.linspace(0, n, blocks + 1).astype(np.int64)
    ends = moment_ends(inp, cuts) if inp.moments else cuts[1:]
    plain = dataclasses.replace(inp, moments=False)
    light, moms, first = None, None, None
    for i in range(blocks):
        if halves and i == blocks // 2 and i > 0:   # the first half's sum, on the way
            first = (light[0].copy(), int(cuts[i]))
        for lo, hi, what in ((cuts[i], ends[i], inp), (ends[i], cuts[i + 1], plain)):
            if hi <= lo:
                continue
            got = trace_paths_media_np(what, paths=(int(lo), int(hi)))
            part = [g[..., :3] for g in got]
            light = part if light is None else [a + b for a, b in zip(light, part)]
            if what.moments:
                part = [g[..., 3:] for g in got]
                moms = part if moms is None else [a + b for a, b in zip(moms, part)]
    if inp.moments:   # a share's moments, for all the paths
        scale = n / float(np.sum(ends - cuts[:-1]))
        light = [np.concatenate([a, b * scale], axis=-1) for a, b in zip(light, moms)]
    return (light, first) if halves else light


def moment_ends(inp, cuts: np.ndarray) -> np.ndarray:
    """int64 (blocks,): for the blocks of paths cuts[i]..cuts[i+1]-1, the path before which
    each block's paths deposit the moments: the block's end, or with ``inp.moment_share``
    below 1 that share of its paths (at least one), so that every block, and every thread,
    carries its part of the moments' cost (their moments scaled to all the paths,
    trace_paths_media)."""
    cuts = np.asarray(cuts, np.int64)
    share = float(inp.moment_share)
    if not share < 1.0:
        return cuts[1:].copy()
    size = cuts[1:] - cuts[:-1]
    return cuts[:-1] + np.clip(np.ceil(share * size).astype(np.int64), np.minimum(size, 1), size)
