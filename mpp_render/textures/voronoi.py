"""Blender's Voronoi Texture node (Worley noise), vectorised over points with numpy.

Written again in numpy from the published algorithms (Worley 1996; Inigo Quilez's smooth
Voronoi and distance-to-edge, shadertoy ldl3W8 / llG3zy) as Blender 4.2-5.0 implements them:
the per-octave cell searches of ``source/blender/blenlib/intern/noise.cc`` (namespace
``blender::noise``, ported from ``intern/cycles/kernel/svm/voronoi.h``), the fractal layering
added in 4.0 (``fractal_voronoi_x_fx`` and ``fractal_voronoi_distance_to_edge``, Cycles
``intern/cycles/kernel/svm/fractal_voronoi.h``) and the parameter handling of
``svm_node_tex_voronoi`` / ``node_shader_tex_voronoi.cc``.

Conventions (those of Blender):

* The coordinate is ``Vector * Scale`` (2D: its x, y; 3D: x, y, z; 4D: x, y, z, W * Scale),
  or ``W * Scale`` in 1D.  Space is cut into unit cells; cell ``c`` (its lower corner, a
  vector of integers) holds one feature point ``c + hash(c) * Randomness`` and one colour.
  1D hashes the corner's float32 bits with lookup3 (``.hash``); 2D-4D hash the integer
  corner with PCG (``.pcg``, Cycles ``intern/cycles/util/hash.h``), as Blender 5.0 does
  (bit for bit against bpy 5.0.1; the 4.x sources hashed the float corners in every
  dimension, so their 2D-4D patterns differ).
* F1, F2 and the distance-to-edge search the 3^d cells around the point's cell, Smooth F1
  the 5^d cells; neighbours are visited with the first axis varying fastest and the first
  of equal distances kept (strict ``<``), as Blender does.
* Detail > 0 adds octaves at ``coord * Lacunarity^i`` weighted ``Roughness^i`` (fractional
  Detail blends the last one in); Normalize divides Distance by the octaves' total weight
  times the largest distance a cell allows, and Color by the total weight.
* Randomness is clamped to [0, 1] and Smoothness / 2 to [0, 0.5] (as everywhere in Blender);
  Detail to [0, 15] and Roughness to [0, 1] as Cycles' SVM node does (``clamp_inputs``;
  Geometry Nodes passes those two unclamped).  Lacunarity, Scale, Exponent are used as given.
* Everything is computed in float32 (the hashes need the exact float32 cell corners) and the
  outputs are float32 arrays: 'Distance' (N,), 'Color' (N, 3), 'Position' (N, 3) (2D: z = 0),
  'W' (N,), 'Radius' (N,), each only where the node shows it for that feature and dimension.
"""
import itertools

import numpy as np

from .pcg import (hash_int2_to_float2, hash_int2_to_float3, hash_int3_to_float3,
                     hash_int4_to_float3, hash_int4_to_float4)
from .hash import hash_float_to_float, hash_float_to_float3

FEATURES = ("F1", "F2", "SMOOTH_F1", "DISTANCE_TO_EDGE", "N_SPHERE_RADIUS")
DISTANCES = ("EUCLIDEAN", "MANHATTAN", "CHEBYCHEV", "MINKOWSKI")
DIMENSIONS = {"1D": 1, "2D": 2, "3D": 3, "4D": 4}

F32 = np.float32
# The searches start from +inf: the same as Blender's FLT_MAX for any finite distance, and
# what Geometry Nodes returns when every distance is infinite (Minkowski exponent 0).
FAR = F32(np.inf)


# ---- cells and their hashes --------------------------------------------------------------

# Hash blocks of neighbour cells at once, up to this many point-cells per block.
_BLOCK = 1 << 18


class _Cells:
    """The cells around N coordinates (N, d): the float32 lower corner ``cell``, the
    position inside it ``local``, and the hashes of the cells at given offsets.

    1D hashes the float32 corner with lookup3 (``hash_float_to_float``, colour
    ``hash_float_to_float3``); 2D-4D hash the integer corner with PCG
    (``hash_int{2,3,4}_to_float{2,3,4}``, colour ``hash_int{2,3,4}_to_float3``)."""

    def __init__(self, coord, randomness):
        self.d = coord.shape[1]
        self.cell = np.floor(coord)
        self.local = coord - self.cell
        self.r = randomness[:, None]
        if self.d > 1:
            # float -> int as x86 converts: out of range (and NaN) gives INT_MIN.
            ok = np.abs(self.cell) < F32(2.0 ** 31)
            self.icell = np.where(ok, self.cell, F32(-2.0 ** 31)).astype(np.int64)
            self.icell = self.icell.astype(np.int32)

    def _corner(self, off):
        """Corners at offsets ``off`` ((d,), (N, d) or (M, 1, d)): float 1D, int 2D-4D."""
        if self.d == 1:
            return self.cell + off
        return self.icell + off.astype(np.int32)

    def hash(self, off):
        """Feature point offsets in [0, 1]^d of the cells at ``off``."""
        k = self._corner(off)
        if self.d == 1:
            return hash_float_to_float(k[..., 0])[..., None]
        return {2: hash_int2_to_float2, 3: hash_int3_to_float3, 4: hash_int4_to_float4}[self.d](k)

    def color(self, off):
        """Cell colours (..., 3) of the cells at ``off``."""
        k = self._corner(off)
        if self.d == 1:
            return hash_float_to_float3(k[..., 0])
        return {2: hash_int2_to_float3, 3: hash_int3_to_float3, 4: hash_int4_to_float3}[self.d](k)

    def point(self, off):
        """Feature points of the cells at ``off`` relative to this cell: off + hash * r."""
        return off + self.hash(off) * self.r

    def scan(self, reach, colors=False):
        """Yield (offset (d,), feature point (N, d), colour (N, 3) or None) for the
        (2 reach + 1)^d neighbour cells in Blender's loop order, hashed in blocks."""
        offsets = _offsets(self.d, reach)
        n = self.cell.shape[0]
        step = max(1, _BLOCK // max(n, 1))
        for s in range(0, len(offsets), step):
            block = offsets[s:s + step][:, None, :]
            hashes = self.hash(block)
            points = block + hashes * self.r
            if colors:
                # In 3D and 4D the colour hash is the point hash's first three components.
                cols = hashes[..., :3] if self.d > 2 else self.color(block)
            for j in range(block.shape[0]):
                yield block[j, 0], points[j], (cols[j] if colors else None)


def _offsets(d, reach):
    """Neighbour cell offsets (M, d) float32 in Blender's loop order (first axis fastest)."""
    rng = range(-reach, reach + 1)
    return np.array([o[::-1] for o in itertools.product(rng, repeat=d)], dtype=F32)


# ---- distances ----------------------------------------------------------------------


def _metric_distance(diff, metric, exponent):
    """``voronoi_distance`` of the difference vectors (N, d); components summed in order.
    1D is always |a - b| whatever the metric, as in Blender."""
    a = np.abs(diff)
    d = diff.shape[-1]
    if d == 1:
        return a[:, 0]
    if metric == "EUCLIDEAN":
        acc = diff[:, 0] * diff[:, 0]
        for c in range(1, d):
            acc = acc + diff[:, c] * diff[:, c]
        return np.sqrt(acc)
    if metric == "MANHATTAN":
        acc = a[:, 0]
        for c in range(1, d):
            acc = acc + a[:, c]
        return acc
    if metric == "CHEBYCHEV":
        return a.max(axis=1)
    if metric == "MINKOWSKI":
        e = exponent
        acc = np.power(a[:, 0], e)
        for c in range(1, d):
            acc = acc + np.power(a[:, c], e)
        with np.errstate(divide="ignore", over="ignore"):
            return np.power(acc, F32(1.0) / e)
    raise ValueError(f"unknown distance metric {metric!r}; one of {DISTANCES}")


def _dot(a, b):
    acc = a[:, 0] * b[:, 0]
    for c in range(1, a.shape[1]):
        acc = acc + a[:, c] * b[:, c]
    return acc


def _mix(a, b, t):
    """BLI noise ``mix``: (1 - t) * a + t * b."""
    return (F32(1.0) - t) * a + t * b


def _smoothstep01(x):
    t = np.clip(x, F32(0.0), F32(1.0))
    return (F32(3.0) - F32(2.0) * t) * (t * t)


# ---- one octave -----------------------------------------------------------------------


class _Octave:
    """One octave's outputs: distance (N,), color (N, 3) or None, position (N, d) absolute."""
    __slots__ = ("distance", "color", "position")

    def __init__(self, distance, color, position):
        self.distance, self.color, self.position = distance, color, position


def _voronoi_f1_f2(coord, randomness, metric, exponent, second):
    """F1 (``second`` False) or F2: the nearest (second nearest) feature point in 3^d cells."""
    cells = _Cells(coord, randomness)
    n, d = coord.shape
    d1 = np.full(n, FAR, F32)
    d2 = np.full(n, FAR, F32)
    off1 = np.zeros((n, d), F32)
    pos1 = np.zeros((n, d), F32)
    off2 = np.zeros((n, d), F32)
    pos2 = np.zeros((n, d), F32)
    for off, point, _ in cells.scan(1):
        dist = _metric_distance(point - cells.local, metric, exponent)
        nearer = dist < d1
        if second:
            between = ~nearer & (dist < d2)
            # Nearer than F1: the old F1 becomes F2.
            d2 = np.where(nearer, d1, np.where(between, dist, d2))
            off2 = np.where(nearer[:, None], off1, np.where(between[:, None], off, off2))
            pos2 = np.where(nearer[:, None], pos1, np.where(between[:, None], point, pos2))
        d1 = np.where(nearer, dist, d1)
        off1 = np.where(nearer[:, None], off, off1)
        pos1 = np.where(nearer[:, None], point, pos1)
    if second:
        d1, off1, pos1 = d2, off2, pos2
    return _Octave(d1, cells.color(off1), pos1 + cells.cell)


def _voronoi_smooth_f1(coord, randomness, smoothness, metric, exponent, calc_color):
    """Smooth F1: a smooth minimum over the 5^d cells (Quilez; Blender's GSoC 2019 form)."""
    cells = _Cells(coord, randomness)
    n, d = coord.shape
    s = smoothness
    sdist = np.zeros(n, F32)
    scol = np.zeros((n, 3), F32)
    spos = np.zeros((n, d), F32)
    first = True
    with np.errstate(divide="ignore", invalid="ignore"):
        for off, point, color in cells.scan(2, colors=calc_color):
            dist = _metric_distance(point - cells.local, metric, exponent)
            if first:
                h = np.ones(n, F32)
                first = False
            else:
                h = _smoothstep01(F32(0.5) + F32(0.5) * (sdist - dist) / s)
            corr = s * h * (F32(1.0) - h)
            sdist = _mix(sdist, dist, h) - corr
            corr = corr / (F32(1.0) + F32(3.0) * s)
            if calc_color:
                scol = _mix(scol, color, h[:, None]) - corr[:, None]
            spos = _mix(spos, point, h[:, None]) - corr[:, None]
    return _Octave(sdist, scol if calc_color else None, cells.cell + spos)


def _voronoi_distance_to_edge(coord, randomness):
    """Distance to the nearest Voronoi cell edge (Euclidean; 3^d cells, Quilez's two passes)."""
    cells = _Cells(coord, randomness)
    n, d = coord.shape
    if d == 1:
        x = cells.local[:, 0]
        mid = cells.point(np.array([0.0], F32))[:, 0]
        left = cells.point(np.array([-1.0], F32))[:, 0]
        right = cells.point(np.array([1.0], F32))[:, 0]
        to_left = np.abs((mid + left) / F32(2.0) - x)
        to_right = np.abs((mid + right) / F32(2.0) - x)
        return np.minimum(to_left, to_right)
    vectors = [point - cells.local for _, point, _ in cells.scan(1)]
    best = np.full(n, FAR, F32)
    to_closest = np.zeros((n, d), F32)
    for v in vectors:
        dsq = _dot(v, v)
        nearer = dsq < best
        best = np.where(nearer, dsq, best)
        to_closest = np.where(nearer[:, None], v, to_closest)
    best = np.full(n, FAR, F32)
    with np.errstate(divide="ignore", invalid="ignore"):
        for v in vectors:
            perp = v - to_closest
            psq = _dot(perp, perp)
            unit = perp / np.sqrt(psq)[:, None]
            edge = _dot((to_closest + v) / F32(2.0), unit)
            best = np.where(psq > F32(0.0001), np.minimum(best, edge), best)
    return best


def _voronoi_n_sphere_radius(coord, randomness):
    """Half the distance from the nearest feature point to its own nearest neighbour."""
    cells = _Cells(coord, randomness)
    n, d = coord.shape
    best = np.full(n, FAR, F32)
    closest = np.zeros((n, d), F32)
    closest_off = np.zeros((n, d), F32)
    for off, point, _ in cells.scan(1):
        dist = _metric_distance(point - cells.local, "EUCLIDEAN", None)
        nearer = dist < best
        best = np.where(nearer, dist, best)
        closest = np.where(nearer[:, None], point, closest)
        closest_off = np.where(nearer[:, None], off, closest_off)
    best = np.full(n, FAR, F32)
    neighbour = np.zeros((n, d), F32)
    for off in _offsets(d, 1):
        if not off.any():
            continue
        point = cells.point(off + closest_off)
        dist = _metric_distance(closest - point, "EUCLIDEAN", None)
        nearer = dist < best
        best = np.where(nearer, dist, best)
        neighbour = np.where(nearer[:, None], point, neighbour)
    return _metric_distance(neighbour - closest, "EUCLIDEAN", None) / F32(2.0)


# ---- fractal layering -----------------------------------------------------------------


def _octave(coord, p, feature, metric, calc_color):
    if feature == "F2":
        return _voronoi_f1_f2(coord, p["randomness"], metric, p["exponent"], True)
    if feature == "SMOOTH_F1":
        smooth = p["smoothness"] != 0.0
        if smooth.all():
            return _voronoi_smooth_f1(coord, p["randomness"], p["smoothness"], metric,
                                      p["exponent"], calc_color)
        # Smoothness 0 is plain F1 (Blender 4.1+); mixed arrays are evaluated both ways.
        hard = _voronoi_f1_f2(coord, p["randomness"], metric, p["exponent"], False)
        if not smooth.any():
            return hard
        idx = np.nonzero(smooth)[0]
        soft = _voronoi_smooth_f1(coord[idx], p["randomness"][idx], p["smoothness"][idx],
                                  metric, p["exponent"][idx], calc_color)
        hard.distance[idx] = soft.distance
        hard.position[idx] = soft.position
        if calc_color:
            hard.color[idx] = soft.color
        return hard
    return _voronoi_f1_f2(coord, p["randomness"], metric, p["exponent"], False)


def _take(p, idx):
    """The per-point cell parameters of the points ``idx``."""
    return {k: p[k][idx] for k in ("randomness", "exponent", "smoothness")}


def _fractal_voronoi(coord, p, feature, metric, calc_color):
    """``fractal_voronoi_x_fx``: distance (N,), color (N, 3), position (N, d) in coord units
    divided by Scale."""
    n, d = coord.shape
    detail, rough, lac = p["detail"], p["roughness"], p["lacunarity"]
    zero_input = (detail == 0.0) | (rough == 0.0)
    last = np.ceil(detail)
    remainder = detail - np.floor(detail)
    amp = np.ones(n, F32)
    max_amp = np.zeros(n, F32)
    scale = np.ones(n, F32)
    dist = np.zeros(n, F32)
    color = np.zeros((n, 3), F32)
    pos = np.zeros((n, d), F32)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for i in range(int(last.max(initial=0.0)) + 1):
            live = (i <= last) & (~zero_input | (i == 0))
            idx = np.nonzero(live)[0]
            if idx.size == 0:
                continue
            sc = scale[idx]
            o = _octave(coord[idx] * sc[:, None], _take(p, idx), feature, metric, calc_color)
            ocol = o.color if o.color is not None else np.zeros((idx.size, 3), F32)
            opos = o.position / sc[:, None]
            a = amp[idx]
            zero = zero_input[idx]
            full = ~zero & (i <= detail[idx])
            part = ~zero & ~full & (remainder[idx] != 0.0)
            # Zero input: the first octave alone.
            ma = np.where(zero, F32(1.0), max_amp[idx])
            di = np.where(zero, o.distance, dist[idx])
            co = np.where(zero[:, None], ocol, color[idx])
            po = np.where(zero[:, None], opos, pos[idx])
            # Whole octaves.
            ma = np.where(full, ma + a, ma)
            di = np.where(full, di + o.distance * a, di)
            co = np.where(full[:, None], co + ocol * a[:, None], co)
            po = np.where(full[:, None], _mix(po, opos, a[:, None]), po)
            # The fractional last octave, blended in by Detail's remainder.
            rem = remainder[idx]
            ma = np.where(part, _mix(ma, ma + a, rem), ma)
            di = np.where(part, _mix(di, di + o.distance * a, rem), di)
            co = np.where(part[:, None], _mix(co, co + ocol * a[:, None], rem[:, None]), co)
            po = np.where(part[:, None],
                          _mix(po, _mix(po, opos, a[:, None]), rem[:, None]), po)
            max_amp[idx], dist[idx], color[idx], pos[idx] = ma, di, co, po
            scale[idx] = np.where(full, sc * lac[idx], sc)
            amp[idx] = np.where(full, a * rough[idx], a)
        norm = p["normalize"]
        if norm:
            dist = dist / (max_amp * p["max_distance"])
            color = color / max_amp[:, None]
        s = p["scale"]
        pos = np.where((s != 0.0)[:, None], pos / s[:, None], F32(0.0))
    return dist, color, pos


def _fractal_distance_to_edge(coord, p):
    """``fractal_voronoi_distance_to_edge``: the octaves' distances to edge, min-blended."""
    n, d = coord.shape
    detail, rough, lac = p["detail"], p["roughness"], p["lacunarity"]
    md = p["max_distance"]
    zero_input = (detail == 0.0) | (rough == 0.0)
    last = np.ceil(detail)
    remainder = detail - np.floor(detail)
    amp = np.ones(n, F32)
    max_amp = md.copy()
    scale = np.ones(n, F32)
    dist = np.full(n, F32(8.0))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for i in range(int(last.max(initial=0.0)) + 1):
            live = (i <= last) & (~zero_input | (i == 0))
            idx = np.nonzero(live)[0]
            if idx.size == 0:
                continue
            sc = scale[idx]
            od = _voronoi_distance_to_edge(coord[idx] * sc[:, None], p["randomness"][idx])
            a = amp[idx]
            zero = zero_input[idx]
            full = ~zero & (i <= detail[idx])
            part = ~zero & ~full & (remainder[idx] != 0.0)
            di = np.where(zero, od, dist[idx])
            ma = max_amp[idx]
            mds = md[idx] / sc
            ma_full = _mix(ma, mds, a)
            di_full = _mix(di, np.minimum(di, od / sc), a)
            rem = remainder[idx]
            ma = np.where(full, ma_full, np.where(part, _mix(ma, ma_full, rem), ma))
            di = np.where(full, di_full,
                          np.where(part, _mix(di, np.minimum(di, di_full), rem), di))
            max_amp[idx], dist[idx] = ma, di
            scale[idx] = np.where(full, sc * lac[idx], sc)
            amp[idx] = np.where(full, a * rough[idx], a)
        if p["normalize"]:
            dist = dist / max_amp
    return dist


# ---- the node ---------------------------------------------------------------------------


def _per_point(x, n, name):
    a = np.asarray(x, dtype=F32)
    if a.ndim == 0:
        return np.full(n, a, F32)
    a = a.reshape(-1)
    if a.shape[0] != n:
        raise ValueError(f"{name} has {a.shape[0]} values for {n} points")
    return a


def _max_distance(randomness, d, feature, metric, exponent):
    """The largest F1 distance a cell allows (twice that for F2): the distance from the
    origin to (0.5 + 0.5 * randomness) in every coordinate."""
    half = F32(0.5) + F32(0.5) * randomness
    if d == 1:
        md = half
    else:
        md = _metric_distance(np.repeat(half[:, None], d, axis=1), metric, exponent)
    return md * F32(2.0) if feature == "F2" else md


def voronoi_texture(vector, w=0.0, dimensions="3D", feature="F1", distance="EUCLIDEAN",
                    scale=5.0, detail=0.0, roughness=0.5, lacunarity=2.0, smoothness=1.0,
                    exponent=0.5, randomness=1.0, normalize=False, outputs=None,
                    clamp_inputs=True):
    """Evaluate Blender's Voronoi Texture node at N points.

    vector: (N, 3) texture coordinates (may be None in 1D when ``w`` is an (N,) array).
    w, scale, detail, roughness, lacunarity, smoothness, exponent, randomness: floats or
    (N,) arrays (a linked socket).  dimensions: '1D'..'4D'; feature: one of FEATURES;
    distance: one of DISTANCES (used by F1, F2 and Smooth F1 in 2D-4D; distance to edge and
    n-sphere radius are Euclidean, as in Blender); normalize: the node's Normalize option.
    outputs: optional iterable of the output names wanted (only those are returned; Smooth
    F1's costly colour is skipped when 'Color' is not among them).  clamp_inputs: clamp Detail to [0, 15] and Roughness to
    [0, 1] as the shader node in Cycles does; False gives Geometry Nodes' values for inputs
    out of those ranges (the two agree inside them).

    Returns {name: float32 array} with the outputs the node shows for this feature and
    dimension: 'Distance' (N,), 'Color' (N, 3), 'Position' (N, 3), 'W' (N,) or 'Radius' (N,).
    """
    if dimensions not in DIMENSIONS:
        raise ValueError(f"unknown dimensions {dimensions!r}; one of {tuple(DIMENSIONS)}")
    if feature not in FEATURES:
        raise ValueError(f"unknown feature {feature!r}; one of {FEATURES}")
    if distance not in DISTANCES:
        raise ValueError(f"unknown distance {distance!r}; one of {DISTANCES}")
    d = DIMENSIONS[dimensions]
    if vector is None:
        if d != 1:
            raise ValueError("vector is needed in 2D-4D")
        n = np.asarray(w).reshape(-1).shape[0]
        vec = np.zeros((n, 3), F32)
    else:
        vec = np.asarray(vector, dtype=F32)
        if vec.ndim == 1:
            vec = vec[None, :]
        if vec.ndim != 2 or vec.shape[1] != 3:
            raise ValueError(f"vector must be (N, 3), got {vec.shape}")
        n = vec.shape[0]

    p = {
        "scale": _per_point(scale, n, "scale"),
        "detail": _per_point(detail, n, "detail"),
        "roughness": _per_point(roughness, n, "roughness"),
        "lacunarity": _per_point(lacunarity, n, "lacunarity"),
        "randomness": np.clip(_per_point(randomness, n, "randomness"), F32(0.0), F32(1.0)),
        "exponent": _per_point(exponent, n, "exponent"),
    }
    if clamp_inputs:
        p["detail"] = np.clip(p["detail"], F32(0.0), F32(15.0))
        p["roughness"] = np.clip(p["roughness"], F32(0.0), F32(1.0))
    if feature == "SMOOTH_F1":
        p["smoothness"] = np.clip(_per_point(smoothness, n, "smoothness") / F32(2.0),
                                  F32(0.0), F32(0.5))
    else:
        p["smoothness"] = np.zeros(n, F32)
    wv = _per_point(w, n, "w")
    coord = {1: wv[:, None], 2: vec[:, :2], 3: vec, 4: np.concatenate([vec, wv[:, None]], 1)}[d]
    coord = (coord * p["scale"][:, None]).astype(F32)
    metric = distance if d != 1 else "EUCLIDEAN"

    if feature == "N_SPHERE_RADIUS":
        return {"Radius": _voronoi_n_sphere_radius(coord, p["randomness"])}
    p["normalize"] = bool(normalize)
    if feature == "DISTANCE_TO_EDGE":
        p["max_distance"] = F32(0.5) + F32(0.5) * p["randomness"]
        return {"Distance": _fractal_distance_to_edge(coord, p)}

    p["max_distance"] = _max_distance(p["randomness"], d, feature, metric, p["exponent"])
    calc_color = outputs is None or "Color" in outputs
    dist, color, pos = _fractal_voronoi(coord, p, feature, metric, calc_color)
    out = {"Distance": dist, "Color": color}
    if d != 1:
        position = np.zeros((n, 3), F32)
        position[:, :min(d, 3)] = pos[:, :min(d, 3)]
        out["Position"] = position
    if d in (1, 4):
        out["W"] = pos[:, d - 1].copy()
    if outputs is not None:
        out = {k: v for k, v in out.items() if k in outputs}
    return out
