"""Numpy twins of the hot kernels: the readable specification and the test oracle.

Each kernel here has a compiled twin of the same name in ``mpp_render._kernels``
(``mpp_render/csrc/``, C, releases the GIL); ``mpp_render.kernels`` picks one.  Both must agree
to 1e-4 relative.  The helpers beside them are the twins of the C file's static helpers.  The
light record's layout is mpp_render.lightrecord's; the walk model whose tables the march
reads (level_table, table_lookup) is mpp_render.walk's.
"""
from __future__ import annotations

import numpy as np

from .lightrecord import (KIND_AREA, KIND_SUN, L_AREA, L_AX, L_AY, L_BEAM,
                          L_BLEND, L_CHANNEL, L_COND, L_COSHALF, L_DIR, L_DISC, L_INDIRECT, L_INV,
                          L_KIND, L_NORMAL, L_NORMALIZE, L_POS, L_RADIUS, L_ROUND, L_STRENGTH,
                          LIGHT_FIELDS)
from .media import BRICK, density_from, trilinear
from .walk import table_lookup
from .lights import light_sample, path_stretch, polygon_solid_angle
from .rng import uniform
from .phase import hg


CROSSING_HALVINGS = 6  # bisection steps that bracket a sharp surface inside a segment


def inside_fraction(value, s_a, s_b, va, vb, threshold):
    """Fraction of the segments [s_a, s_b] (arrays, metres along their rays) inside a sharp
    medium, given the interpolated occupancy ``value(s)`` (a function of the same rays'
    positions) and its values ``va``, ``vb`` at the ends; the medium is where the occupancy is
    >= ``threshold`` (media.density_from).  A segment with one end in and one out is halved
    ``CROSSING_HALVINGS`` times around the crossing and the crossing is then interpolated
    linearly in the last bracket, so a surface anywhere within the segment is placed where
    the trilinear occupancy crosses the threshold (exactly, for a flat face)."""
    va = np.asarray(va, np.float64)
    vb = np.asarray(vb, np.float64)
    ia, ib = va >= threshold, vb >= threshold
    out = np.where(ia & ib, 1.0, 0.0)
    mixed = np.flatnonzero(ia != ib)
    if mixed.size:
        lo, hi = np.asarray(s_a, np.float64)[mixed], np.asarray(s_b, np.float64)[mixed]
        vlo, vhi = va[mixed], vb[mixed]
        for _ in range(CROSSING_HALVINGS):
            mid = 0.5 * (lo + hi)
            vm = value(mid, mixed)
            same_as_lo = (vm >= threshold) == (vlo >= threshold)
            lo, vlo = np.where(same_as_lo, mid, lo), np.where(same_as_lo, vm, vlo)
            hi, vhi = np.where(same_as_lo, hi, mid), np.where(same_as_lo, vhi, vm)
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.clip((threshold - vlo) / (vhi - vlo), 0.0, 1.0)
        f = np.where(np.isfinite(f), f, 0.5)
        cross = lo + f * (hi - lo)
        s0, s1 = np.asarray(s_a, np.float64)[mixed], np.asarray(s_b, np.float64)[mixed]
        length = np.maximum(s1 - s0, 1e-300)
        out[mixed] = np.where(ia[mixed], cross - s0, s1 - cross) / length
    return out


def media_exit(grids, w2is, points, dirs, t_max):
    """(N,) where rays p + s dir leave the last of the grids' padded boxes they cross (the far
    end of the union of their intervals, as media.union_interval), capped at ``t_max``; 0
    where they meet none ahead."""
    far = np.full(len(points), -np.inf)
    for g, w2i in zip(grids, w2is):
        o, v = ray_to_index(w2i, points, dirs)
        dims = np.array(g.shape[:3], np.float64) - 1.0
        par = np.abs(v) < 1e-300
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / np.where(par, 1.0, v)
            ta, tb = -o * inv, (dims - o) * inv
        t0 = np.where(par, -np.inf, np.minimum(ta, tb))
        t1 = np.where(par, np.inf, np.maximum(ta, tb))
        outside = par & ~((o >= 0.0) & (o <= dims))
        lo, hi = t0.max(axis=1), t1.min(axis=1)
        hit = (hi > lo) & ~outside.any(axis=1)
        far = np.where(hit, np.maximum(far, hi), far)
    t = np.minimum(far, np.asarray(t_max, np.float64))
    return np.where(t > 0.0, t, 0.0)


def optical_depth(points, dirs, t_max, grids, w2is, sigma_ts, thresholds, step, offset=0.5,
                  bricks=None, clip=False, stop=None, stop_depth=np.inf):
    """RGB optical depth (N,3) along rays p + s*dir, s in [0, t_max], through every medium.

    ``points`` (N,3), ``dirs`` (N,3) unit, ``t_max`` (N,) metres; ``grids`` padded float32
    density arrays, ``w2is`` their (3,4) world->index maps, ``sigma_ts`` their RGB extinction
    per unit density (1/m), ``thresholds`` their sharp-boundary thresholds (-1: smooth; see
    media.density_from).  Each ray is cut into n = ceil(t_max/step) equal segments.  A smooth
    grid is read at the fraction ``offset`` of each segment (midpoint rule for 0.5); a sharp
    grid is read at both ends of each segment and the segment counts by the fraction of it
    inside (``inside_fraction``, which brackets a crossing), so a surface lying anywhere within a segment is placed
    where it is rather than rounded to a whole segment (a midpoint that lands on the
    surface would otherwise drop or add up to half a segment on every ray).

    With ``clip`` t_max is first cut where the rays leave the media's boxes (``media_exit``).

    ``bricks`` (the media's ``media.brick_bounds`` grids, or None) lets the compiled twin add
    the steps that lie wholly in empty or constant bricks in one go (its ``Walk``): the same
    sum up to rounding, so this twin ignores them.

    ``stop`` (3,3) and ``stop_depth`` (> 0; inf: never): a ray ends after the first step at
    whose end every channel of tau @ stop is at least ``stop_depth`` (the caller's optical
    depth where tau holds other units, lightdepth.density_lengths).  Up to there the depth is
    exact; a ray that ends has at least ``stop_depth`` (the compiled twin adds a run of empty
    or constant bricks whole before it tests, so it may end further on)."""
    if not (stop_depth > 0.0):
        raise ValueError("stop_depth must be > 0 (inf: never)")
    use_stop = stop is not None and np.isfinite(stop_depth)
    if use_stop:
        stop = np.asarray(stop, np.float64).reshape(3, 3)
        if not (np.all(np.isfinite(stop)) and np.all(stop >= 0.0)):
            raise ValueError("stop must be finite and >= 0")
    points = np.asarray(points, np.float64)
    dirs = np.asarray(dirs, np.float64)
    if clip:
        t_max = media_exit(grids, w2is, points, dirs, t_max)
    t_max = np.maximum(np.asarray(t_max, np.float64), 0.0)
    n = np.ceil(t_max / step).astype(np.int64)
    h = np.where(n > 0, t_max / np.maximum(n, 1), 0.0)
    tau = np.zeros((len(points), 3))
    done = np.zeros(len(points), bool)
    for j in range(int(n.max()) if len(n) else 0):
        live = (n > j) & ~done
        if not live.any():
            break
        p, dl, hl = points[live], dirs[live], h[live]
        acc = np.zeros((len(p), 3))
        for g, w2i, st, thr in zip(grids, w2is, sigma_ts, thresholds):
            def value(s, rows=slice(None)):
                x = p[rows] + dl[rows] * s[:, None]
                return trilinear(g, x @ w2i[:, :3].T + w2i[:, 3])
            if thr >= 0.0:
                sa, sb = j * hl, (j + 1) * hl
                rho = inside_fraction(value, sa, sb, value(sa), value(sb), thr)
            else:
                rho = value((j + offset) * hl)
            acc += rho[:, None] * st[None, :]
        tau[live] += acc * hl[:, None]
        if use_stop:
            done[live] = np.all(tau[live] @ stop >= stop_depth, axis=1)
    return tau


def _other_axes(axis):
    """The two index axes (b, c) across slabs of ``axis``, in increasing order."""
    return (1, 2) if axis == 0 else ((0, 2) if axis == 1 else (0, 1))


def column_index(axis, coef, i, p, q):
    """Index coordinates (..., 3) in the target grid of sweep columns ``p``, ``q`` (arrays of
    column numbers) on slab ``i``: along ``axis`` the slab, across it
    (coef[0] + i coef[2] + B p, coef[1] + i coef[3] + B q) with spacing B = coef[4] + i coef[5]
    (B = 1 for parallel columns, B proportional to the distance from the light for columns
    fanning out from a point)."""
    bax, cax = _other_axes(axis)
    p, q = np.broadcast_arrays(np.asarray(p, np.float64), np.asarray(q, np.float64))
    b = coef[4] + i * coef[5]
    idx = np.empty(p.shape + (3,))
    idx[..., axis] = i
    idx[..., bax] = coef[0] + i * coef[2] + b * p
    idx[..., cax] = coef[1] + i * coef[3] + b * q
    return idx


def segment_tau(grids, w2is, sigma_ts, thresholds, P, D, n_sub, vprev, tau):
    """Add to ``tau`` (N,3) the optical depth of the segments P -> P + D (world (N,3), D not
    unit) through every medium, each cut into ``n_sub`` equal pieces: Simpson's rule on smooth
    grids (exact for the cubic that trilinear interpolation is along a line within a cell),
    ``inside_fraction`` on sharp ones.  ``vprev`` (N, media): channel 0 of each medium at P on
    entry, at P + D on return (updated in place)."""
    n = len(P)
    length = np.sqrt(np.einsum("ij,ij->i", D, D)) / n_sub
    for u in range(n_sub):
        sa, sb = u / n_sub, (u + 1) / n_sub
        for m, (g, w2i, st, thr) in enumerate(zip(grids, w2is, sigma_ts, thresholds)):
            def value(s, rows=slice(None), g=g, w2i=w2i):
                x = P[rows] + D[rows] * s[:, None]
                return trilinear(g, x @ w2i[:, :3].T + w2i[:, 3])
            va = vprev[:, m].copy()
            vb = value(np.full(n, sb))
            if thr >= 0.0:
                rho = inside_fraction(value, np.full(n, sa), np.full(n, sb), va, vb, thr)
            else:
                rho = (va + 4.0 * value(np.full(n, 0.5 * (sa + sb))) + vb) / 6.0
            tau += rho[:, None] * np.asarray(st, np.float64)[None, :] * length[:, None]
            vprev[:, m] = vb


def light_sweep(out, channel, a2w, axis, sign, i_first, i_last, coef, light_index, cone, init,
                p_lo, p_hi, n_sub, grids, w2is, sigma_ts, thresholds):
    """Optical depth towards a light for the voxels of one grid, written into
    ``out[..., channel:channel + 3]`` (``out``: (X,Y,Z,C) float32, the medium's field).

    The light's rays are followed as *columns*, numbered (p, q) on a lattice, from slab
    ``i_first`` (nearest the light) to slab ``i_last`` of the grid along ``axis`` (``sign``
    +1 or -1 the direction of travel); column (p, q) crosses slab i at ``column_index``
    (index coordinates of the grid; ``a2w`` (3,4) maps them to world metres).  Each column
    starts with ``init[p, q]`` (RGB optical depth from its point on slab i_first to the light,
    computed by the caller) and adds, slab to slab, the optical depth of the segment between
    (``segment_tau`` through every medium of ``grids``, ``n_sub`` pieces per segment).  Every
    voxel of a slab then takes the bilinear interpolation of the four columns around it on
    that slab.  (The compiled twin skips the segments outside every medium's box, which add 0.)

    Only columns p in [p_lo, p_hi] are followed, and only voxels whose cell floor(p) lies in
    [p_lo, p_hi) are written (a partition of the cells [0, P - 1) lets chunks run in
    parallel).  With ``cone`` only the voxels whose largest index offset from
    ``light_index`` (the light in index coordinates) is along ``axis`` with sign ``sign``
    are written (ties go to the later axis), the part of space this pyramid of columns
    covers; otherwise (a sun) every voxel."""
    dims = out.shape[:3]
    bax, cax = _other_axes(axis)
    NP, NQ = init.shape[:2]
    ps = np.arange(p_lo, p_hi + 1, dtype=np.float64)
    qs = np.arange(NQ, dtype=np.float64)
    PP, QQ = np.meshgrid(ps, qs, indexing="ij")
    PP, QQ = PP.ravel(), QQ.ravel()
    tau = np.array(init[p_lo:p_hi + 1].reshape(-1, 3), np.float64)
    a2w = np.asarray(a2w, np.float64)

    def world(i):
        return column_index(axis, coef, float(i), PP, QQ) @ a2w[:, :3].T + a2w[:, 3]

    x = world(i_first)
    vprev = np.stack([trilinear(g, x @ w[:, :3].T + w[:, 3]) for g, w in zip(grids, w2is)], 1)         if len(grids) else np.zeros((len(x), 0))
    J = np.arange(dims[bax], dtype=np.float64)[:, None]
    K = np.arange(dims[cax], dtype=np.float64)[None, :]
    i = i_first
    while True:
        if i != i_first:
            P = world(i - sign)
            segment_tau(grids, w2is, sigma_ts, thresholds, P, world(i) - P, n_sub, vprev, tau)
        Bi, Ab, Ac = coef[4] + i * coef[5], coef[0] + i * coef[2], coef[1] + i * coef[3]
        iB = 1.0 / Bi
        p = np.broadcast_to((J - Ab) * iB, (dims[bax], dims[cax]))
        q = np.broadcast_to((K - Ac) * iB, (dims[bax], dims[cax]))
        pcell = np.clip(np.floor(p), 0, NP - 2).astype(np.int64)
        qcell = np.clip(np.floor(q), 0, NQ - 2).astype(np.int64)
        mine = (pcell >= p_lo) & (pcell < p_hi)
        if cone:
            da = i - light_index[axis]
            db, dc = np.abs(J - light_index[bax]), np.abs(K - light_index[cax])
            okb = abs(da) > db if bax < axis else abs(da) >= db
            okc = abs(da) > dc if cax < axis else abs(da) >= dc
            mine &= (sign * da > 0.0) & okb & okc
        jj, kk = np.nonzero(mine)
        if jj.size:
            fp = np.clip(p[jj, kk] - pcell[jj, kk], 0.0, 1.0)[:, None]
            fq = np.clip(q[jj, kk] - qcell[jj, kk], 0.0, 1.0)[:, None]
            c00 = (pcell[jj, kk] - p_lo) * NQ + qcell[jj, kk]
            t = ((1.0 - fp) * ((1.0 - fq) * tau[c00] + fq * tau[c00 + 1])
                 + fp * ((1.0 - fq) * tau[c00 + NQ] + fq * tau[c00 + NQ + 1]))
            vox = [None, None, None]
            vox[axis] = np.full(jj.size, i)
            vox[bax], vox[cax] = jj, kk
            out[vox[0], vox[1], vox[2], channel:channel + 3] = t.astype(np.float32)
        if i == i_last:
            break
        i += sign


def upsample(lattice, stride, shape, dtype=np.float32):
    """Trilinear upsampling of a lattice (cx,cy,cz,C) whose point j sits at fine index
    j * stride, onto the fine grid ``shape`` (X,Y,Z): separable linear interpolation, one
    vectorised pass per axis (the same values as media.trilinear at those points); in
    ``dtype`` (float32)."""
    out = np.asarray(lattice).astype(dtype)
    for ax in range(3):
        i = np.arange(shape[ax])
        lo = np.minimum(i // stride, out.shape[ax] - 1)
        hi = np.minimum(lo + 1, out.shape[ax] - 1)
        f = ((i - lo * stride) / float(stride)).astype(dtype)
        sh = [1] * out.ndim
        sh[ax] = -1
        out = (np.take(out, lo, axis=ax) * (1 - f).reshape(sh)
               + np.take(out, hi, axis=ax) * f.reshape(sh))
    return out


GEO_FLOOR = 1e-30   # the logarithm's floor in upsample_into (a corner of weight 0 may hold 0)


def upsample_into(field, channel, lattice, stride, flat, inside=None):
    """Write ``upsample(lattice, stride, field.shape[:3])`` into
    ``field[..., channel:channel + C]`` at the flat voxel indices ``flat`` only (None: every
    voxel; C = the lattice's channels; ``field`` (X,Y,Z,F) float32, modified in place).
    ``inside``: None, or bool (cx,cy,cz) the lattice points inside the medium: at a voxel
    whose lattice points of weight > 0 are all inside, each channel whose values there are
    all > 0 is interpolated geometrically (its logarithm trilinearly, then exp: exact where
    it falls exponentially, as light does into a medium)."""
    nc = lattice.shape[3]
    shape = field.shape[:3]
    fine = upsample(lattice, int(stride), shape).reshape(-1, nc)
    if inside is not None:
        lat = np.asarray(lattice, np.float64)
        ins = upsample(np.asarray(inside, np.float64)[..., None], int(stride), shape, np.float64)
        pos = upsample((lat > 0.0).astype(np.float64), int(stride), shape, np.float64)
        logs = upsample(np.log(np.maximum(lat, GEO_FLOOR)), int(stride), shape, np.float64)
        geo = (ins.reshape(-1, 1) >= 1.0 - 1e-9) & (pos.reshape(-1, nc) >= 1.0 - 1e-9)
        fine = np.where(geo, np.exp(logs.reshape(-1, nc)), fine).astype(np.float32)
    if flat is None:
        flat = slice(None)
    field.reshape(-1, field.shape[3])[flat, channel:channel + nc] = fine[flat]


DIM_JITTER = 1000       # random dimension of the step jitter; lights use 2*i, 2*i + 1
DIM_ROULETTE = 1001     # random dimension of the march's Russian roulette
DIM_STRATUM = 1002      # random dimension of the shuffle of the steps' strata (step_stratum)
REFINE_STEPS = 8
EDGE_EPS = 1e-6        # occupancies within this of 0 or 1 count as outside / inside
T_MIN = 1e-6


def _fetch(field, w2i, x, c0, nc, read=trilinear):
    """(N, nc) channels c0.. of ``field`` read trilinearly at world points ``x`` (N,3) by
    ``read`` (media.trilinear's contract; kernels.trilinear for the compiled one)."""
    idx = x @ w2i[:, :3].T + w2i[:, 3]
    v = read(field, idx)
    v = v if np.ndim(v) == 2 else np.reshape(v, (-1, 1))
    return v[:, c0:c0 + nc]


def _extinction(field, w2i, thr, sig_t, xc, x, read=trilinear):
    """(N,3) extinction (1/m) of one medium at world points ``x``: its density
    (``density_from``) times ``sig_t``, or with an extinction channel ``xc`` >= 0 (None: none)
    channel c of the field's extinction density times ``sig_t[c]`` (csrc/march.c
    extinction_at).  ``read``: _fetch's."""
    st = np.asarray(sig_t, np.float64)[None, :]
    if xc is not None and xc >= 0:
        return _fetch(field, w2i, x, xc, 3, read) * st
    return density_from(_fetch(field, w2i, x, 0, 1, read)[:, 0], thr)[:, None] * st


def _refined_tau(fields, w2is, thrs, sig_ts, mi, c, x, w, dist, delta, xcs=None):
    """Optical depth from points x near medium mi's sharp surface towards a light: exact over
    up to REFINE_STEPS half-voxel steps, then medium mi's precomputed field channel c.
    ``xcs``: None or per medium its extinction channel (``_extinction``)."""
    n = len(x)
    tau = np.zeros((n, 3))
    end = x.copy()
    done = np.zeros(n, bool)
    for k in range(1, REFINE_STEPS + 1):
        todo = np.flatnonzero(~done)
        if not todo.size:
            break
        seg = np.clip(dist[todo] - (k - 1) * delta, 0.0, delta)
        mid = x[todo] + w[todo] * ((k - 1) * delta + 0.5 * seg)[:, None]
        for j, (f, w2i, thr, st) in enumerate(zip(fields, w2is, thrs, sig_ts)):
            xc = None if xcs is None else xcs[j]
            tau[todo] += seg[:, None] * _extinction(f, w2i, thr, st, xc, mid)
        pk = x[todo] + w[todo] * ((k - 1) * delta + seg)[:, None]
        occ = _fetch(fields[mi], w2is[mi], pk, 0, 1)[:, 0]
        end[todo] = pk
        fin = (occ <= EDGE_EPS) | (occ >= 1.0 - EDGE_EPS) | (seg < delta)
        done[todo[fin]] = True
    return tau + _fetch(fields[mi], w2is[mi], end, c, 3)


def _corner_max(field, idx, sig_t, xc, sig_max) -> np.ndarray:
    """(N,) the largest extinction (1/m) among the 8 voxels of the cell holding each point of
    index coordinates ``idx`` (N,3): the density (channel 0) times ``sig_max``, or with an
    extinction channel ``xc`` >= 0 the largest of its 3 channels times ``sig_t``'s; 0 outside
    the grid's cells (csrc/march.c thick_tri)."""
    shape = np.array(field.shape[:3])
    f = np.floor(idx)
    ok = np.all((idx >= 0.0) & (idx < shape - 1), axis=1)
    i0 = np.where(ok[:, None], f, 0.0).astype(np.int64)
    st = np.asarray(sig_t, np.float64)
    top = np.zeros(len(idx))
    for corner in range(8):
        o = np.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1])
        c = i0 + o
        if xc is not None and xc >= 0:
            v = field[c[:, 0], c[:, 1], c[:, 2], xc:xc + 3].astype(np.float64) * st[None, :]
            top = np.maximum(top, v.max(axis=1))
        else:
            top = np.maximum(top, field[c[:, 0], c[:, 1], c[:, 2], 0].astype(np.float64)
                             * float(sig_max))
    return np.where(ok, top, 0.0)


LAMP_PLANES = 1.25   # _walk_tau stops this many voxel steps before a lamp (the C twin's)
WALK_IN = 1e-6       # _walk_tau tests the cell beyond a plane this many voxels in (the C twin's)
PLANE_EPS = 1e-9     # _plane_tau reads the grid's last plane this far inside it (the C twin's)


def _plane_tau(fields, w2is, thrs, sig_ts, mi, c, x, w, dist, tau, xcs=None, read=trilinear):
    """(N,3) the optical depth from points ``x`` (N,3) towards a light (unit directions ``w``,
    its centre ``dist`` metres away) in medium mi's density grid: its field's channel c read
    where the light's path crosses the next plane of voxel centres along the index axis it
    runs most along, plus every medium's extinction over the segment to that plane (at its
    midpoint); ``tau`` (the trilinear read) kept where that plane lies outside the grid or a
    lamp lies within ``LAMP_PLANES`` steps along the axis beyond it (csrc/march.c
    plane_tau).  ``read``: _fetch's."""
    w2i = np.asarray(w2is[mi], np.float64)
    idx = x @ w2i[:, :3].T + w2i[:, 3]
    u = w @ w2i[:, :3].T
    n = len(x)
    a = np.zeros(n, np.int64)
    for r in (1, 2):   # the first axis of the largest |u| (the C loop's strict >)
        a = np.where(np.abs(u[:, r]) > np.abs(u[np.arange(n), a]), r, a)
    rows = np.arange(n)
    ua, ia = u[rows, a], idx[rows, a]
    # a point within WALK_IN of a plane (where _walk_tau ends) reads that plane itself
    kp = np.where(ua > 0.0, np.ceil(ia - WALK_IN), np.floor(ia + WALK_IN))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.maximum((kp - ia) / ua, 0.0)
    ip = idx + u * np.where(np.isfinite(t), t, 0.0)[:, None]
    last = np.array(fields[mi].shape[:3]) - 1
    ip[rows, a] = np.where(kp < last[a], kp, last[a] - PLANE_EPS)   # the last plane: from below
    ok = (np.abs(ua) > 0.0) & (np.abs(ia) < 4.0e15) & (t >= 0.0) & \
        ((dist - t) * np.abs(ua) > LAMP_PLANES) & \
        np.all((ip >= 0.0) & (ip < last), axis=1)
    out = np.array(tau, np.float64, copy=True)
    if not ok.any():
        return out
    k = np.flatnonzero(ok)
    v = np.asarray(read(fields[mi], ip[k]))[:, c:c + 3]
    mid = x[k] + w[k] * (0.5 * t[k])[:, None]
    seg = np.zeros((len(k), 3))
    for j, (f, wj, thr, st) in enumerate(zip(fields, w2is, thrs, sig_ts)):
        xc = None if xcs is None else xcs[j]
        seg += t[k][:, None] * _extinction(f, wj, thr, st, xc, mid, read)
    out[k] = v + seg
    return out


def _walk_tau(fields, w2is, thrs, sig_ts, mi, c, x, w, dist, tau, sig_max, voxel, cell_tau,
              cells, xcs=None, read=trilinear):
    """(N,3) the optical depth from points ``x`` (N,3) in optically thick cells of medium mi's
    density grid towards a light (unit directions ``w``, its centre ``dist`` metres away): the
    path followed cell by cell through the grid's cells (their faces the planes of voxel
    centres), each piece integrated by Simpson's rule over every medium, for at most ``cells``
    pieces and while the cells entered (tested ``WALK_IN`` voxels past each plane) have their
    most extinguishing corner at least ``cell_tau`` deep (``_corner_max``); then the field's
    channel c read by ``_plane_tau`` from where the path ends (the next plane along the axis
    the light runs most along).  It ends before a piece that would leave the grid's cells or
    whose plane lies within ``LAMP_PLANES`` voxel steps of a lamp; from ``x`` itself with
    ``tau`` (the trilinear read there) where no piece was taken.  ``read``: _fetch's
    (csrc/march.c walk_tau)."""
    f = fields[mi]
    w2i = np.asarray(w2is[mi], np.float64)
    last = np.array(f.shape[:3]) - 1
    i0 = x @ w2i[:, :3].T + w2i[:, 3]
    u = w @ w2i[:, :3].T
    umax = np.abs(u).max(axis=1)
    n = len(x)
    xcm = -1 if xcs is None or xcs[mi] is None else xcs[mi]
    kk = np.where(u > 0.0, np.floor(i0) + 1.0, -np.floor(-i0) - 1.0)
    step = np.where(u > 0.0, 1.0, -1.0)
    with np.errstate(divide="ignore"):   # 1 / u: a plane's distance to the next per axis
        iu = np.where(u != 0.0, 1.0 / np.where(u != 0.0, u, 1.0), 0.0)

    def ext(p):
        out = np.zeros((len(p), 3))
        for j, (fj, wj, thr, st) in enumerate(zip(fields, w2is, thrs, sig_ts)):
            out += _extinction(fj, wj, thr, st, None if xcs is None else xcs[j], p, read)
        return out

    # no piece from a point outside the grid's cells (the march's samples lie in them)
    going = (umax > 0.0) & np.all(np.abs(i0) < 4.0e15, axis=1) & \
        np.all((i0 >= 0.0) & (i0 < last), axis=1)
    s = np.zeros(n)
    acc = np.zeros((n, 3))
    ea = np.zeros((n, 3))
    if going.any():
        ea[going] = ext(x[going])
    moved = np.zeros(n, bool)
    for _ in range(int(cells)):
        k = np.flatnonzero(going)
        if not k.size:
            break
        sr = np.where(u[k] != 0.0, (kk[k] - i0[k]) * iu[k], np.inf)
        sn = sr.min(axis=1)
        pin = i0[k] + u[k] * (sn + WALK_IN / umax[k])[:, None]
        ok = ((dist[k] - sn) * umax[k] > LAMP_PLANES) & \
            np.all((pin >= 0.0) & (pin < last), axis=1)
        going[k[~ok]] = False
        k, sn, sr, pin = k[ok], sn[ok], sr[ok], pin[ok]
        if not k.size:
            break
        xm = x[k] + w[k] * (0.5 * (s[k] + sn))[:, None]
        xe = x[k] + w[k] * sn[:, None]
        em, ee = ext(xm), ext(xe)
        acc[k] += (sn - s[k])[:, None] / 6.0 * (ea[k] + 4.0 * em + ee)
        ea[k] = ee
        kk[k] += np.where((u[k] != 0.0) & (sr <= sn[:, None]), step[k], 0.0)
        s[k] = sn
        moved[k] = True
        going[k] &= _corner_max(f, pin, sig_ts[mi], xcm, sig_max) * float(voxel) >= cell_tau
    start = np.array(tau, np.float64, copy=True)
    mv = np.flatnonzero(moved)
    if mv.size:
        pe = i0[mv] + u[mv] * s[mv][:, None]
        start[mv] = np.asarray(read(f, pe))[:, c:c + 3]
    xe = x + w * s[:, None]   # on along the light's main axis from where the path ends
    return _plane_tau(fields, w2is, thrs, sig_ts, mi, c, xe, w, dist - s, start, xcs, read) + acc


DISC_STEPS_MAX = 4096   # disc_correction's steps at most (the C twin's)
# disc_correction's step in the finest voxels: on p_point_in_plume's 0.3 m lamp 1 and 2 give
# the same single scattering (bias -0.0049, -0.0050; the march 1.41x and 1.22x the plain
# one's at 960x540), 4 drifts (rel_rmse_4 0.0125)
DISC_STEP_VOXELS = 2.0


def disc_correction(fields, w2is, thrs, sig_ts, x, wc, dc, wd, ds, stretch, step, xcs=None):
    """(N,3) optical depth over every medium from points ``x`` (N,3, m) to a lamp's disc
    point or an area light's emitter point (unit directions ``wd``, distances ``ds``) minus
    ``stretch`` (N,) times that to the lamp's centre (``wc``, ``dc``): what the field's
    stretched depth to the centre (lights.path_stretch) misses where the medium is not
    homogeneous across the disc or emitter.  Both paths take n = ceil(dc / ``step``) steps
    (at least 1, at most DISC_STEPS_MAX), each read at its midpoint (trilinear density;
    ``xcs``: None or per medium its extinction channel, ``_extinction``).  Twin of
    csrc/march.c disc_correction."""
    n = np.clip(np.ceil(dc / step), 1, DISC_STEPS_MAX).astype(np.int64)
    hc, hd = dc / n, ds / n
    tc = np.zeros((len(x), 3))
    td = np.zeros((len(x), 3))
    for k in range(int(n.max()) if len(x) else 0):
        sel = np.flatnonzero(n > k)
        pc = x[sel] + wc[sel] * ((k + 0.5) * hc[sel])[:, None]
        pd = x[sel] + wd[sel] * ((k + 0.5) * hd[sel])[:, None]
        for j, (f, w2i, thr, st) in enumerate(zip(fields, w2is, thrs, sig_ts)):
            xc = None if xcs is None else xcs[j]
            tc[sel] += _extinction(f, w2i, thr, st, xc, pc)
            td[sel] += _extinction(f, w2i, thr, st, xc, pd)
    return td * hd[:, None] - stretch[:, None] * tc * hc[:, None]


def read_level(level, idx, d):
    """(N,3) a multiple-scattering level read at index points ``idx``: its 3 channels as they
    are, or a level of 12 (the traced paths' moments M0, M1, paths.py "Moments") towards
    v = -d (rays ``d`` (N,3)): per channel 4 pi M0 HG(v . G / |G|; |G|), G = M1 / M0
    (csrc/march.c read_level; phase.hg clamps |G| to phase.G_LIMIT)."""
    q = trilinear(level, idx)
    if q.shape[1] != 12:
        return q[:, :3]
    out = np.zeros((len(q), 3))
    for a in range(3):
        m0 = q[:, a]
        ok = m0 > 0.0
        G = np.stack([q[:, 3 + a], q[:, 6 + a], q[:, 9 + a]], axis=1) / np.where(ok, m0, 1.0)[:, None]
        gl = np.sqrt(G[:, 0] * G[:, 0] + G[:, 1] * G[:, 1] + G[:, 2] * G[:, 2])
        cs = np.where(gl > 0.0, -(G[:, 0] * d[:, 0] + G[:, 1] * d[:, 1] + G[:, 2] * d[:, 2])
                      / np.where(gl > 0.0, gl, 1.0), 0.0)
        out[:, a] = np.where(ok, 4.0 * np.pi * m0 * hg(cs, gl), 0.0)
    return out


def multiple_source(ms_fields, table, rho, x, w2i, cos, d):
    """Multiply scattered radiance (N,3), W/(m^2 sr), arriving at world points ``x`` (N,3)
    of one medium of density ``rho`` (N,) and scattered towards the camera (before the final
    sigma_s), summed over lights: the path-length integral of docs/method.md on the light
    pyramid.

    ``ms_fields``: per light None or (levels, stride, h) of precompute.MultipleField;
    ``table``: the medium's walk.level_table; ``w2i`` world -> padded index map; ``cos`` (L,N)
    the cosine between each light's propagation direction and the direction to the camera;
    ``d`` (N,3) the rays' directions (a level of moments is read towards -d, ``read_level``).
    Level k adds pyramid_k(x) weight_k HG(cos; g_k), by colour channel.  The levels come
    moved by their paths' drift towards what the camera sees (precompute.drift_levels), having
    lost the light that leaves through the medium's surface (boundary.py)."""
    out = np.zeros((len(x), 3))
    tab = table_lookup(table, rho)
    for li, msf in enumerate(ms_fields):
        if msf is None:
            continue
        levels, stride, h = msf
        idx0 = (x @ w2i[:, :3].T + w2i[:, 3]) / float(stride)
        for k in range(min(len(levels), len(tab))):
            q = read_level(levels[k], idx0 / float(2 ** k), d)
            out += q * (tab[k, :, :3] * hg(cos[li][:, None], tab[k, :, 3:]))
    return out


SUPER = 4  # march steps per super-step (the compiled twin's SUPER)


def ray_to_index(w2i, origins, dirs):
    """Rays o + s d (world) as lines lo + s lv in a grid's index coordinates, computed term by
    term in the compiled twin's order (its brick decisions must match)."""
    w = np.asarray(w2i, np.float64)
    o, d = np.asarray(origins, np.float64), np.asarray(dirs, np.float64)
    lo = np.stack([w[r, 0] * o[:, 0] + w[r, 1] * o[:, 1] + w[r, 2] * o[:, 2] + w[r, 3]
                   for r in range(3)], axis=1)
    lv = np.stack([w[r, 0] * d[:, 0] + w[r, 1] * d[:, 1] + w[r, 2] * d[:, 2] for r in range(3)], axis=1)
    return lo, lv


def segment_majorant(shape, bricks, lo, lv, s_a, s_b, brick=BRICK, least=False):
    """The largest density bound (media.brick_bounds [..., 1], bricks of ``brick`` cells)
    among the bricks touched by the bounding box of each segment [s_a, s_b] of the lines
    lo + s lv (index coordinates of a grid of ``shape``); 0 for segments wholly outside the
    grid, inf where the coordinates are not finite.  ``least``: the least bound ([..., 0])
    instead, 0 where the segment leaves the grid or its coordinates are not finite."""
    nb = np.array(bricks.shape[:3])
    p0, p1 = lo + s_a[:, None] * lv, lo + s_b[:, None] * lv
    mn, mx = np.minimum(p0, p1), np.maximum(p0, p1)
    bad = np.any(np.isnan(mn) | np.isnan(mx), axis=1)
    mn, mx = np.where(bad[:, None], 0.0, mn), np.where(bad[:, None], 0.0, mx)
    dims = np.array(shape[:3], np.float64) - 1.0
    out_of = np.any((mx < 0.0) | (mn > dims), axis=1)
    blo = np.clip(np.floor(np.clip(mn / brick, -1.0, nb)), 0, nb - 1).astype(np.int64)
    bhi = np.clip(np.floor(np.clip(mx / brick, -1.0, nb)), 0, nb - 1).astype(np.int64)
    best = np.full(len(lo), np.inf if least else 0.0, np.float32)
    span = bhi - blo
    for di in range(int(span[:, 0].max(initial=0)) + 1):
        for dj in range(int(span[:, 1].max(initial=0)) + 1):
            for dk in range(int(span[:, 2].max(initial=0)) + 1):
                i = np.minimum(blo[:, 0] + di, bhi[:, 0])
                j = np.minimum(blo[:, 1] + dj, bhi[:, 1])
                k = np.minimum(blo[:, 2] + dk, bhi[:, 2])
                best = np.minimum(best, bricks[i, j, k, 0]) if least else \
                    np.maximum(best, bricks[i, j, k, 1])
    if least:
        partly = np.any((mn < 0.0) | (mx > dims), axis=1)
        return np.where(bad | out_of | partly, 0.0, best.astype(np.float64))
    return np.where(bad, np.inf, np.where(out_of, 0.0, best.astype(np.float64)))


LIGHT_VARIATION = 0.2  # relative change of a light's irradiance that keeps the steps short


def area_omega(rec, x):
    """(N,) the solid angle (sr) that the rectangular (or parallelogram) emitter of the area
    light record ``rec`` subtends at the points ``x`` (N,3), from its emitting side (0 behind
    it): Van Oosterom and Strackee's formula on its two triangles.  Twin of march.c's."""
    c, ax, ay = rec[L_POS:L_POS + 3], rec[L_AX:L_AX + 3], rec[L_AY:L_AY + 3]
    omega = polygon_solid_angle(np.array([c - ax - ay, c + ax - ay, c + ax + ay, c - ax + ay]),
                                x)[2]
    front = (x - c) @ rec[L_NORMAL:L_NORMAL + 3] > 0.0
    return np.where(front, omega, 0.0)


def varies_value(rec, x, dirs, g):
    """(N,) what light_varies weighs for the light record ``rec`` at the points ``x`` for rays
    along ``dirs`` in a medium of anisotropy ``g``: the irradiance summed over the channels
    times the HG phase.  A rectangular area light: its emitter's exact irradiance L_e Omega
    (``area_omega``) seen along the direction from its centre; any other light: light_sample
    at the middle of its draw.  Twin of march.c's."""
    if int(rec[L_KIND]) == KIND_AREA and not rec[L_ROUND] > 0:
        v = x - rec[L_POS:L_POS + 3]
        dist = np.sqrt(np.einsum("ni,ni->n", v, v))
        inv = 1.0 / np.maximum(dist, 1e-30)
        area = rec[L_AREA]
        norm = area if (rec[L_NORMALIZE] > 0 and area > 0) else 1.0
        e = rec[L_STRENGTH:L_STRENGTH + 3].sum() / np.pi / norm * area_omega(rec, x)
        return e * hg(-np.einsum("ni,ni->n", v, dirs) * inv, g)
    half = np.full(len(x), 0.5)
    wi, e = light_sample(rec, x, half, half)[:2]
    return e.sum(axis=1) * hg(-np.einsum("ij,ij->i", wi, dirs), g)


def light_varies(lights, origins, dirs, s_a, s_b, g):
    """(N,) whether the light a lit local light scatters towards the camera (its irradiance at
    its centre, before the media, times the HG phase of anisotropy ``g``) differs by more
    than ``LIGHT_VARIATION`` between the ends of the segments [s_a, s_b] of the rays: a spot's
    cone edge, a nearby light or a forward-scattering lobe, whose shape longer steps would
    miss."""
    xa = origins + dirs * s_a[:, None]
    xb = origins + dirs * s_b[:, None]
    out = np.zeros(len(xa), bool)
    for rec in np.asarray(lights, np.float64).reshape(-1, LIGHT_FIELDS):
        if rec[L_CHANNEL] < 0 or int(rec[L_KIND]) == KIND_SUN:
            continue
        va, vb = varies_value(rec, xa, dirs, g), varies_value(rec, xb, dirs, g)
        hi, lo = np.maximum(va, vb), np.minimum(va, vb)
        out |= (hi > 0.0) & ~(lo >= (1.0 - LIGHT_VARIATION) * hi)
    return out


def step_stratum(bands, keys, k: int, n: int) -> np.ndarray:
    """The strata (0 .. n - 1, int64) of step ``k`` of rays on strata ``bands`` whose pixels'
    keys are ``keys`` (uint32): each band shuffled by a bijection of the n strata drawn per
    pixel and step (XOR with a mask when n is a power of two, which keeps the adaptive
    rounds' first 2^m samples on distinct 2^m-ths of the step; a shift modulo n otherwise):
    a pixel's samples cover every stratum of each step, one ray's steps lie on unrelated
    strata (so a ray's points are no more alike from step to step than independent ones)."""
    m = np.minimum((uniform(keys, k, DIM_STRATUM) * n).astype(np.int64), n - 1)
    b = np.asarray(bands, np.int64)
    return b ^ m if n & (n - 1) == 0 else (b + m) % n


def march(origins, dirs, t0, t1, axial, keys, fields, w2is, sigma_ss, sigma_ts, gs, thresholds,
          voxels, lights, ambient, step, depth_opacity, depth_miss, multiple=None, emissions=None,
          bricks=None, adapt_tau=0.0, emission_channels=None, roulette=0.0, disc_reach=None,
          scatter_channels=None, extinction_channels=None, cell_tau=0.0, cell_walk=0,
          jitter_bands=None, jitter_count=1, jitter_keys=None):
    """March camera rays through media fields: the numpy twin of ``_kernels.march``.

    Rays ``origins + t dirs`` (N,3), t in [t0, t1] (N,) metres; ``axial`` (N,) turns t into
    axial depth; ``keys`` (N,) uint32 seed the per-ray random numbers (``uniform``).
    Per medium: ``fields`` (X,Y,Z,C) float32 (channel 0 density, then per-light optical
    depths and the world light, see precompute.FieldLayout), ``w2is`` (3,4), ``sigma_ss`` /
    ``sigma_ts`` RGB 1/m per unit density, ``gs`` HG anisotropy, ``thresholds`` (sharp
    boundary, < 0 smooth), ``voxels`` voxel size in metres.  ``lights`` (L, LIGHT_FIELDS)
    packed records; ``ambient`` the world-light channel or -1.  ``step`` metres.
    ``multiple``: None, or a kernels.MultipleInputs (ambient_ms channel or -1, per medium a
    list with, per light, None or the kernels.LevelField (levels, stride, h) of its
    MultipleField, per medium its walk.level_table, and per medium None or its flat level on
    its field's voxels) to accumulate multiple scattering too.
    (kernels.MarchInputs holds these arguments as one record; kernels.march takes it.)

    ``emissions``: None or per medium the RGB emitted radiance per metre (W/(m^3 sr)), given
    off wherever the medium's density is > 0 (not scaled by density, as Cycles' Principled
    Volume).
    ``emission_channels``: None or per medium the first of 3 field channels holding its
    emission grid (W/(m^3 sr), read with the same trilinear fetch and given off wherever it
    is non-zero, whatever the density), or -1 for none.
    ``scatter_channels``: None or per medium the first of 3 field channels holding its
    scatter colour grid (media.PreparedMedium.scatter_grid: the factor on ``sigma_ss``,
    negative values read as 0), or -1 for none.
    ``extinction_channels``: None or per medium the first of 3 field channels holding its
    extinction density (media.PreparedMedium.extinction_density: channel c's extinction is
    ``sigma_ts[c]`` times it), or -1 for none (the density's).
    ``cell_tau`` > 0: in a density grid (threshold < 0), a sample whose cell's most
    extinguishing corner (``_corner_max``) times its voxel size is at least ``cell_tau``
    reads each light's optical depth by ``_walk_tau`` (at most ``cell_walk`` cells; 0: the
    next plane alone) instead of trilinearly.
    ``jitter_bands``: None, or per ray its stratum b (0 .. ``jitter_count`` - 1), with
    ``jitter_keys`` (N,) uint32 its pixel's key: the ray's point on step k is drawn
    uniformly on the step's fraction [b_k / jitter_count, (b_k + 1) / jitter_count) instead
    of on the whole step, b_k = ``step_stratum`` (b, key, k) (a pixel's samples on
    different strata cover each step: their mean varies less than independent draws').

    Super-step K covers [t0 + SUPER K h, t0 + SUPER (K + 1) h] (the last one ends at t1) and
    is cut into n_sub equal steps of length H (the ray's last one cut at t1), step j read at
    one point drawn uniformly on it (random
    numbers of step index SUPER K + j): n_sub = SUPER without ``bricks``; with ``bricks``
    (media.brick_bounds per medium) n_sub = 0 where every medium is empty on the super-step
    (``segment_majorant``) and, with ``adapt_tau`` > 0, the fewest steps (at least 1) that keep
    the majorant's optical depth per step within ``adapt_tau`` (thin medium: longer steps),
    unless a light's scattered light changes along the super-step (``light_varies``) or a
    sharp (mesh) medium's surface may be on it (the bricks' least bound below 1: not wholly
    inside).
    Each step adds T S (1 - exp(-sigma_t H)) / sigma_t with S the in-scattered radiance at its
    point, then T *= exp(-sigma_t H).  ``roulette`` > 0: Russian roulette once the largest
    channel of T is below it: the ray goes on with probability q = max T / ``roulette``
    (random dimension DIM_ROULETTE of the step), T divided by q, or ends with T = 0 (the
    same mean, fewer steps behind nearly opaque media).  ``disc_reach``: None or per light
    the distance (m) within which a point or spot light's sampled disc point, or an area
    light's emitter point, gets the optical depth ``disc_correction`` adds to the stretched
    centre's.  Returns (single (N,3), T (N,3),
    depth (N,), multiple (N,3), steps (N,), emission (N,3)) float64, steps being the number
    of samples each ray took."""
    n = len(origins)
    single = np.zeros((n, 3))
    multi = np.zeros((n, 3))
    emitted = np.zeros((n, 3))
    steps = np.zeros(n)
    trans = np.ones((n, 3))
    depth = np.full(n, float(depth_miss))
    keys = np.asarray(keys, np.uint32)
    bands, jitter_w = None, 1.0   # each ray's stratum of its steps
    if jitter_bands is not None:
        bands = np.asarray(jitter_bands).reshape(n).astype(np.int64)
        if not 1 <= int(jitter_count) <= 1 << 24 or np.any(bands < 0) or \
                np.any(bands >= int(jitter_count)):
            raise ValueError("jitter_bands must lie in [0, jitter_count), count in [1, 2^24]")
        jitter_keys = np.asarray(jitter_keys, np.uint32).reshape(n)
        jitter_w = 1.0 / int(jitter_count)
    lights = np.asarray(lights, np.float64).reshape(-1, LIGHT_FIELDS)
    h = float(step)
    t0 = np.asarray(t0, np.float64)
    t1 = np.asarray(t1, np.float64)
    sig_max = [float(np.max(st)) if np.max(st) > 0 else 1.0 for st in sigma_ts]
    lines = [ray_to_index(w, origins, dirs) for w in w2is] if bricks is not None else None
    running = np.flatnonzero(t0 < t1)
    K = 0
    while running.size:
        s_lo = t0[running] + float(SUPER * K) * h
        if not np.all(s_lo < t1[running]):  # past the end (after an empty super-step)
            running = running[s_lo < t1[running]]
            s_lo = t0[running] + float(SUPER * K) * h
        s_hi = np.minimum(t0[running] + float(SUPER * (K + 1)) * h, t1[running])
        n_sub = np.full(running.size, SUPER)
        if bricks is not None:
            maj = np.zeros(running.size)
            sharp = np.zeros(running.size, bool)  # a mesh volume's surface keeps steps short
            for mi in range(len(fields)):
                lo, lv = lines[mi][0][running], lines[mi][1][running]
                mm = segment_majorant(fields[mi].shape[:3], bricks[mi], lo, lv, s_lo, s_hi)
                maj += mm * sig_max[mi]
                if adapt_tau > 0.0 and thresholds[mi] >= 0.0:  # may it cross the mesh's surface?
                    inside = segment_majorant(fields[mi].shape[:3], bricks[mi], lo, lv, s_lo,
                                              s_hi, least=True) >= 1.0
                    sharp |= (mm > 0.0) & ~inside
            n_sub = np.where(maj > 0.0, n_sub, 0)
            if adapt_tau > 0.0:
                want = np.ceil(maj * (s_hi - s_lo) / adapt_tau)
                short = sharp | light_varies(lights, origins[running], dirs[running], s_lo, s_hi,
                                             max(gs, key=abs) if len(gs) else 0.0)
                n_sub = np.where(maj > 0.0, np.where(short, SUPER, np.clip(want, 1, SUPER)),
                                 0).astype(np.int64)
        H = float(SUPER) * h / np.maximum(n_sub, 1)
        going = np.ones(running.size, bool)
        for jj in range(SUPER):
            sel = np.flatnonzero(going & (n_sub > jj))
            seg = s_lo[sel] + jj * H[sel]
            inside = seg < t1[running[sel]]
            going[sel[~inside]] = False
            sel, seg = sel[inside], seg[inside]
            if not sel.size:
                continue
            alive = running[sel]
            Hs = H[sel]
            k = SUPER * K + jj
            o, d = origins[alive], dirs[alive]
            ka = keys[alive]
            hl = np.minimum(Hs, t1[alive] - seg)
            # uniform on the step (the last one too), on the ray's stratum of it where given
            u = uniform(ka, k, DIM_JITTER)
            if bands is not None:
                u = (step_stratum(bands[alive], jitter_keys[alive], k, int(jitter_count)) + u) \
                    * jitter_w
            ts = seg + u * hl
            x = o + d * ts[:, None]
            m = len(alive)
            sig_t = np.zeros((m, 3))
            src = np.zeros((m, 3))
            src_ms = np.zeros((m, 3))
            src_em = np.zeros((m, 3))
            emit = []
            for li, rec in enumerate(lights):
                emit.append(light_sample(rec, x, uniform(ka, k, 2 * li), uniform(ka, k, 2 * li + 1)))
            for mi in range(len(fields)):
                f = fields[mi]
                v = _fetch(f, w2is[mi], x, 0, f.shape[3])
                rho = density_from(v[:, 0], thresholds[mi])
                xc = -1 if extinction_channels is None else extinction_channels[mi]
                if xc >= 0:
                    sig_t += (rho > 0)[:, None] * v[:, xc:xc + 3] * sigma_ts[mi][None, :]
                else:
                    sig_t += rho[:, None] * sigma_ts[mi][None, :]
                if emission_channels is not None and emission_channels[mi] >= 0:
                    src_em += v[:, emission_channels[mi]:emission_channels[mi] + 3]
                if emissions is not None:
                    src_em += (rho > 0)[:, None] * np.asarray(emissions[mi], np.float64)[None, :]
                edge = np.flatnonzero((v[:, 0] > EDGE_EPS) & (v[:, 0] < 1.0 - EDGE_EPS) & (rho > 0)) \
                    if thresholds[mi] >= 0 else np.zeros(0, np.int64)
                thick = np.zeros(0, np.int64)
                if thresholds[mi] < 0 and cell_tau > 0.0:
                    w2i = np.asarray(w2is[mi], np.float64)
                    top = _corner_max(f, x @ w2i[:, :3].T + w2i[:, 3], sigma_ts[mi], xc,
                                      sig_max[mi])
                    thick = np.flatnonzero((rho > 0) & (top * voxels[mi] >= cell_tau))
                inc = np.zeros((m, 3))
                beam_inc = np.zeros((m, 3))
                ind_inc = np.zeros((m, 3))   # indirect lights' single scattering
                for li, rec in enumerate(lights):
                    c = int(rec[L_CHANNEL])
                    if c < 0:
                        continue
                    wi, e, wc, dc, ds = emit[li]
                    raw = v[:, c:c + 3]
                    tau = raw
                    if edge.size:
                        tau = tau.copy()
                        tau[edge] = _refined_tau(fields, w2is, thresholds, sigma_ts, mi, c, x[edge],
                                                 wc[edge], dc[edge], 0.5 * voxels[mi],
                                                 extinction_channels)
                    if thick.size:
                        tau = tau.copy() if tau is raw else tau
                        tau[thick] = _walk_tau(fields, w2is, thresholds, sigma_ts, mi, c,
                                               x[thick], wc[thick], dc[thick], tau[thick],
                                               sig_max[mi], voxels[mi], cell_tau, cell_walk,
                                               extinction_channels)
                    off = ds != dc  # light from an emitter point off the centre
                    if off.any():
                        tau = tau.copy() if tau is raw else tau
                        st = path_stretch(ds[off], dc[off], voxels[mi])
                        tau[off] = tau[off] * st[:, None]
                        reach = 0.0 if disc_reach is None else float(disc_reach[li])
                        cd = int(rec[L_DISC])
                        if cd >= 1:   # beyond the reach: the disc's mean (discdepth.py)
                            far = np.flatnonzero(off)[~(dc[off] < reach)] \
                                if reach > 0.0 else np.flatnonzero(off)
                            tau[far] = np.maximum(tau[far] + v[far, cd:cd + 3], 0.0)
                        if reach > 0.0:
                            near = np.flatnonzero(dc[off] < reach)
                            if near.size:
                                on = np.flatnonzero(off)[near]
                                dt = disc_correction(fields, w2is, thresholds, sigma_ts, x[on],
                                                     wc[on], dc[on], -wi[on], ds[on], st[near],
                                                     DISC_STEP_VOXELS * min(voxels),
                                                     extinction_channels)
                                tau[on] = np.maximum(tau[on] + dt, 0.0)
                    cos = -np.einsum("ij,ij->i", wi, d)
                    pe = hg(cos, gs[mi])[:, None] * e
                    if rec[L_INDIRECT] > 0.5:
                        ind_inc += pe * np.exp(-tau)
                    else:
                        inc += pe * np.exp(-tau)
                    cb = int(rec[L_BEAM])
                    if multiple is not None and cb >= 1:  # channel 0 is the density: none
                        beam_inc += hg(cos, gs[mi])[:, None] * np.maximum(v[:, cb:cb + 3], 0.0)
                if ambient >= 0:
                    inc += v[:, ambient:ambient + 3]
                ss = rho[:, None] * sigma_ss[mi][None, :]
                if scatter_channels is not None and scatter_channels[mi] >= 0:
                    sc = scatter_channels[mi]
                    ss = ss * np.maximum(v[:, sc:sc + 3], 0.0)
                src += ss * inc
                src_ms += ss * ind_inc
                if multiple is not None:
                    src_ms += ss * beam_inc
                    amb_ms, per_medium, tables, on_field = multiple
                    ms_fields = per_medium[mi]
                    live = np.flatnonzero(rho > 0)
                    if live.size:
                        wd = np.stack([emit[li][0][live] for li in range(len(lights))]) \
                            if len(lights) else np.zeros((0, live.size, 3))
                        cos = -np.einsum("lij,ij->li", wd, d[live])
                        ms_inc = multiple_source(ms_fields, tables[mi], rho[live], x[live], w2is[mi], cos,
                                                 d[live])
                        if on_field is not None and on_field[mi] is not None:
                            # the level on the field's voxels, weighed by the flat table
                            ms_inc += _fetch(on_field[mi], w2is[mi], x[live], 0, 3) * (
                                tables[mi][0, 0, :3] * hg(np.zeros(1), 0.0)[0])
                        if amb_ms >= 0:
                            ms_inc += v[live, amb_ms:amb_ms + 3]
                        # never below 0 (march.c: the sky's less its absorption's noise)
                        ms_inc = np.where(ms_inc > 0.0, ms_inc, 0.0)
                        src_ms[live] += ss[live] * ms_inc
            x_t = sig_t * hl[:, None]
            frac = np.where(x_t > 1e-7, -np.expm1(-x_t) / np.maximum(x_t, 1e-300), 1.0 - 0.5 * x_t)
            T_before = trans[alive]
            single[alive] += T_before * src * (frac * hl[:, None])
            multi[alive] += T_before * src_ms * (frac * hl[:, None])
            emitted[alive] += T_before * src_em * (frac * hl[:, None])
            T_after = T_before * np.exp(-x_t)
            trans[alive] = T_after
            tb, ta = T_before.mean(axis=1), T_after.mean(axis=1)
            thr = 1.0 - depth_opacity
            hit = (depth[alive] >= depth_miss) & (ta <= thr) & (tb > thr)
            if hit.any():
                with np.errstate(divide="ignore", invalid="ignore"):
                    fr = np.clip(np.log(tb[hit] / thr) / np.log(tb[hit] / np.maximum(ta[hit], 1e-300)), 0, 1)
                depth[alive[hit]] = (seg[hit] + fr * hl[hit]) * axial[alive[hit]]
            steps[alive] += 1
            tmax = T_after.max(axis=1)
            if roulette > 0.0:
                low = np.flatnonzero(tmax < roulette)
                if low.size:
                    q = tmax[low] / roulette
                    live = uniform(ka[low], k, DIM_ROULETTE) < q
                    kept, lost = low[live], low[~live]
                    trans[alive[kept]] = T_after[kept] / q[live][:, None]
                    trans[alive[lost]] = 0.0
                    tmax[kept], tmax[lost] = roulette, 0.0
            stop = (tmax <= T_MIN) | ~(seg + Hs > seg)  # opaque, or t stalls
            going[sel[stop]] = False
        running = running[going]
        K += 1
    return single, trans, depth, multi, steps, emitted


RAY_CHUNK = 4096    # rays per block in the ray x triangle tests


def _box_hit(lo, hi, o, d, tmax):
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        ta = (lo - o) * inv
        tb = (hi - o) * inv
    t0 = np.nanmax(np.minimum(ta, tb), axis=1)
    t1 = np.nanmin(np.maximum(ta, tb), axis=1)
    return (t1 >= np.maximum(t0, 0.0)) & (t0 <= tmax)


def intersect_triangles(o, d, tmax, triangles):
    """(t (N,), triangle (N,) int64): the closest hit of rays o + t d among ``triangles``
    (T,9: corner and two edges) for t in (0, ``tmax``) (N,), tmax and -1 where none; a
    vectorised Moller-Trumbore test after a cull by one box per 64 triangles (as
    csrc/triangles.h).  The twin of csrc/intersect.c."""
    o = np.asarray(o, np.float64)
    d = np.asarray(d, np.float64)
    tri = np.asarray(triangles, np.float64).reshape(-1, 9)
    v0s, e1s, e2s = tri[:, 0:3], tri[:, 3:6], tri[:, 6:9]
    n = len(o)
    t_best = np.array(np.asarray(tmax, np.float64).reshape(n))
    out = np.full(n, -1, np.int64)
    boxes = []
    for a in range(0, len(tri), 64):
        b = min(len(tri), a + 64)
        pts = np.concatenate([v0s[a:b], v0s[a:b] + e1s[a:b], v0s[a:b] + e2s[a:b]])
        boxes.append((pts.min(axis=0), pts.max(axis=0), a, b))
    for lo, hi, a, b in boxes:
        cand = np.flatnonzero(_box_hit(lo - 1e-9, hi + 1e-9, o, d, t_best))
        for c0 in range(0, len(cand), RAY_CHUNK):
            rays = cand[c0:c0 + RAY_CHUNK]
            oo, dd = o[rays], d[rays]
            for t0 in range(a, b, 256):
                sl = slice(t0, min(b, t0 + 256))
                e1, e2, v0 = e1s[sl], e2s[sl], v0s[sl]
                p = np.cross(dd[:, None, :], e2[None, :, :])            # (R,T,3)
                det = np.einsum("rtk,tk->rt", p, e1)
                ok = np.abs(det) > 1e-300
                inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
                s = oo[:, None, :] - v0[None, :, :]
                u = np.einsum("rtk,rtk->rt", s, p) * inv
                q = np.cross(s, e1[None, :, :])
                v = np.einsum("rk,rtk->rt", dd, q) * inv
                t = np.einsum("tk,rtk->rt", e2, q) * inv
                hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
                t = np.where(hit, t, np.inf)
                j = np.argmin(t, axis=1)
                tj = t[np.arange(len(rays)), j]
                better = tj < t_best[rays]
                t_best[rays[better]] = tj[better]
                out[rays[better]] = t0 + j[better]
    return t_best, out


NODAL_CHUNK = 32768   # nodal_fit's lattice points fitted at a time (about 1 kB a point with moments)


def nodal_fit(mean, offsets, mass, signed, ridge):
    """(X,Y,Z,C) float32: the tent means ``mean`` (X,Y,Z,C) moved from their centroids to the
    lattice points (precompute/nodal.py): at each point with ``mass`` (X,Y,Z) > 0 and an
    offset (``offsets`` (X,Y,Z,3), centroid less point, lattice steps) the mean less the
    offset times the gradient fitted by least squares to the differences to its 26 neighbours
    that hold mass, each weighing m_z / (m_z + m_y), against their centroids' offsets from its
    own, ``ridge`` (lattice steps^2) added to the normal matrix; the first C - ``signed``
    channels stopped at 0.  The rest as they came."""
    mean = np.asarray(mean, np.float32)
    shape = mean.shape[:3]
    d = np.asarray(offsets, np.float64)
    sel = np.flatnonzero((np.abs(d).max(axis=-1) > 1e-6) & (np.asarray(mass) > 0.0))
    out = np.array(mean, np.float32, order="C")
    if not len(sel):
        return out
    C = mean.shape[-1]
    # padded by one point on every side (no mass there), read at the selected points'
    # neighbours by flat index; float32 as the means come
    pm = np.pad(mean, ((1, 1),) * 3 + ((0, 0),)).reshape(-1, C)
    pd = np.pad(d, ((1, 1),) * 3 + ((0, 0),)).reshape(-1, 3)
    pw = np.pad(np.asarray(mass, np.float64), 1).reshape(-1)
    ps = tuple(n + 2 for n in shape)
    centre = int(np.ravel_multi_index((1, 1, 1), ps))
    steps = [(st, int(np.ravel_multi_index(st + 1, ps)) - centre)
             for st in np.argwhere(np.ones((3, 3, 3), bool)) - 1 if st.any()]
    flat = out.reshape(-1, C)
    for a in range(0, len(sel), NODAL_CHUNK):   # the fit's arrays a chunk of points at a time
        part = sel[a:a + NODAL_CHUNK]
        here = np.ravel_multi_index((np.stack(np.unravel_index(part, shape), axis=1) + 1).T, ps)
        m0, d0, w0 = pm[here].astype(np.float64), pd[here], pw[here]
        A = np.zeros((len(part), 3, 3))
        b = np.zeros((len(part), 3, C))
        for step, off in steps:
            there = here + off
            wz = pw[there]
            wt = np.divide(wz, wz + w0, out=np.zeros_like(wz), where=wz > 0.0)
            dc = step + pd[there] - d0
            wdc = wt[:, None] * dc
            A += wdc[:, :, None] * dc[:, None, :]
            b += wdc[:, :, None] * (pm[there] - m0)[:, None, :]
        A += ridge * np.eye(3)
        grad = np.linalg.solve(A, b)                       # (n,3,C)
        fixed = m0 - np.einsum("na,nac->nc", d0, grad)
        if signed < C:
            fixed[:, :C - signed] = np.maximum(fixed[:, :C - signed], 0.0)
        flat[part] = fixed
    return out


# ---- the lobe's local-linear fit (csrc/lobefit.c) ----

def box_sum(x: np.ndarray, r: int) -> np.ndarray:
    """The sums of ``x`` (LX,LY,LZ,...) over the (2 r + 1)^3 lattice points round each point
    (zero beyond the lattice), by cumulative sums along each of the first three axes."""
    out = np.asarray(x, np.float64)
    for axis in range(3):
        n = out.shape[axis]
        pad = [(0, 0)] * out.ndim
        pad[axis] = (r + 1, r)
        c = np.cumsum(np.pad(out, pad), axis=axis)
        out = c.take(range(2 * r + 1, 2 * r + 1 + n), axis=axis) - c.take(range(0, n), axis=axis)
    return out


# standard deviations of a window's weighted spread beyond which the point it is fitted for
# lies too far from its weight for the local line (lobe_ratio; csrc/lobefit.c): the three-sigma
# rule; a full window's corner point at the lattice's edge lies 2.3 away
LOBE_REACH = 3.0


def lobe_ratio(md: np.ndarray, mc: np.ndarray, u: np.ndarray, r: int,
               channels: int = 3) -> np.ndarray:
    """float64 (LX,LY,LZ,3): M_r = M_c a, a the local-linear fit of M_d / M_c over each
    window of radius ``r`` with weights ``u`` (LX,LY,LZ) (precompute/lobefit.py's docstring,
    step 1), a the window's weighted mean ratio where the point lies beyond ``LOBE_REACH``
    standard deviations of the window's weighted spread; M_d where the window holds no weight, M_c is 0 throughout it, or M_c is 0 at
    the point.  ``channels`` 1: a grey medium's, channel 0 fitted and copied to 1 and 2."""
    shape = md.shape[:3]
    X = np.stack(np.meshgrid(*[np.arange(n, dtype=np.float64) for n in shape], indexing="ij"),
                 -1)
    out = np.array(md, np.float64)
    f = [np.ones(shape)] + [X[..., i] for i in range(3)]
    grey = channels == 1
    for c in range(1 if grey else 3):
        m, d = mc[..., c], md[..., c]
        # the normal equations of sum u / m (d - m a)^2: sums of u d f_i and u m f_i f_j,
        # over the points the lobe holds light at
        w = np.where(m > 0.0, u, 0.0)
        A = np.zeros(shape + (4, 4))
        rhs = np.zeros(shape + (4,))
        for i in range(4):
            rhs[..., i] = box_sum(w * d * f[i], r)
            for j in range(i, 4):
                A[..., i, j] = A[..., j, i] = box_sum(w * m * f[i] * f[j], r)
        ok = A[..., 0, 0] > 0.0
        a00 = np.where(ok, A[..., 0, 0], 1.0)
        # the slope about the window's weighted centre (its Schur complement), with a ridge
        # of 1e-9 of its scale where the window's points lie in a plane or on a line
        mu = A[..., 0, 1:] / a00[..., None]
        C = A[..., 1:, 1:] - a00[..., None, None] * mu[..., :, None] * mu[..., None, :]
        ridge = 1e-9 * (np.trace(C, axis1=-2, axis2=-1) / 3.0 + a00)
        C = C + np.eye(3) * ridge[..., None, None]
        rc = rhs[..., 1:] - mu * rhs[..., :1]
        slope = _lobe_solve3(C, rc)
        a0 = (rhs[..., 0] - (slope * A[..., 0, 1:]).sum(-1)) / a00
        # the point's distance from the window's weighted centre in units of the window's
        # spread (Mahalanobis, squared): beyond LOBE_REACH the line is an extrapolation (the
        # window's weight in a plane or on a line the point lies off: a lit face seen edge
        # on), and the window's weighted mean ratio serves instead
        delta = X - mu
        far = a00 * (delta * _lobe_solve3(C, delta)).sum(-1) > LOBE_REACH * LOBE_REACH
        a = np.where(far, rhs[..., 0] / a00, a0 + (slope * X).sum(-1))
        # where the lobe holds none of the light (no moments there: they come from a share
        # of the paths) the deposits stay
        out[..., c] = np.where(ok & (m > 0.0), m * a, d)
    if grey:   # one fit serves the three equal channels
        out[..., 1] = out[..., 2] = out[..., 0]
    return out


def _lobe_solve3(C: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x (...,3) with C x = b for symmetric (...,3,3) C, by Cramer's rule (0 where C is
    singular)."""
    c00, c01, c02 = C[..., 0, 0], C[..., 0, 1], C[..., 0, 2]
    c11, c12, c22 = C[..., 1, 1], C[..., 1, 2], C[..., 2, 2]
    a00 = c11 * c22 - c12 * c12
    a01 = c02 * c12 - c01 * c22
    a02 = c01 * c12 - c02 * c11
    a11 = c00 * c22 - c02 * c02
    a12 = c01 * c02 - c00 * c12
    a22 = c00 * c11 - c01 * c01
    det = c00 * a00 + c01 * a01 + c02 * a02
    inv = np.where(det != 0.0, 1.0 / np.where(det != 0.0, det, 1.0), 0.0)
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([(a00 * b0 + a01 * b1 + a02 * b2) * inv,
                     (a01 * b0 + a11 * b1 + a12 * b2) * inv,
                     (a02 * b0 + a12 * b1 + a22 * b2) * inv], -1)
