/* Compiled twins of mpp_render/kernels_np.py (the readable specification).
 *
 * Every buffer from Python is checked for type, dimensionality, contiguity and size before
 * use, and every grid index is bounds-checked: a bad call raises ValueError, it never reads
 * out of bounds.  The loops run without the GIL.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define MAX_MEDIA 64
#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

typedef struct {
    Py_buffer view;
    int held;
} Buf;

static void buf_release(Buf *b) {
    if (b->held) { PyBuffer_Release(&b->view); b->held = 0; }
}

/* Acquire a C-contiguous buffer of `fmt` ('d' float64 or 'f' float32) with `ndim` dims.
 * shape[i] >= 0 must match; -1 accepts any extent (then written back). */
static int get_buf_ex(PyObject *obj, Buf *b, char fmt, int ndim, Py_ssize_t *shape, const char *what,
                      int extra) {
    b->held = 0;
    if (PyObject_GetBuffer(obj, &b->view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | PyBUF_ND | extra) < 0) {
        PyErr_Clear();
        PyErr_Format(PyExc_ValueError, "%s: expected a C-contiguous%s numeric array", what,
                     extra & PyBUF_WRITABLE ? " writable" : "");
        return -1;
    }
    b->held = 1;
    const char *f = b->view.format ? b->view.format : "B";
    if (f[0] == '<' || f[0] == '=' || f[0] == '@') f++;
    Py_ssize_t item = (fmt == 'd') ? 8 : 4;
    if (f[0] != fmt || f[1] != '\0' || b->view.itemsize != item) {
        PyErr_Format(PyExc_ValueError, "%s: expected %s", what,
                     fmt == 'd' ? "float64" : (fmt == 'f' ? "float32" : "uint32"));
        buf_release(b);
        return -1;
    }
    if (b->view.ndim != ndim) {
        PyErr_Format(PyExc_ValueError, "%s: expected %d dimensions, got %d", what, ndim, b->view.ndim);
        buf_release(b);
        return -1;
    }
    for (int i = 0; i < ndim; i++) {
        if (b->view.shape[i] < 0 || (shape[i] >= 0 && b->view.shape[i] != shape[i])) {
            PyErr_Format(PyExc_ValueError, "%s: dimension %d has extent %zd, expected %zd",
                         what, i, b->view.shape[i], shape[i]);
            buf_release(b);
            return -1;
        }
        shape[i] = b->view.shape[i];
    }
    return 0;
}

static int get_buf(PyObject *obj, Buf *b, char fmt, int ndim, Py_ssize_t *shape, const char *what) {
    return get_buf_ex(obj, b, fmt, ndim, shape, what, 0);
}

typedef struct {
    const float *data;
    Py_ssize_t nx, ny, nz, nc;  /* nc: channels per voxel (last axis), 1 for a density grid */
    double w2i[12];             /* 3x4 world -> index */
    double sig[3];
    double thr;                 /* sharp-boundary threshold, < 0 for smooth grids */
} Grid;

static inline double density_from(const Grid *g, double v) {
    return g->thr >= 0.0 ? (v >= g->thr ? 1.0 : 0.0) : v;
}

/* The corner (fx, fy, fz) = floor(idx) of the cell holding index coordinates idx: 1 when the
 * cell lies in grid g (0 <= idx < n - 1 per axis; NaN is outside).  Truncation is the floor
 * there, without a libm call. */
static inline int cell_floor(const double idx[3], const Grid *g, double *fx, double *fy, double *fz) {
    if (!(idx[0] >= 0.0 && idx[1] >= 0.0 && idx[2] >= 0.0 && idx[0] < (double)(g->nx - 1) &&
          idx[1] < (double)(g->ny - 1) && idx[2] < (double)(g->nz - 1)))
        return 0;
    *fx = (double)(Py_ssize_t)idx[0];
    *fy = (double)(Py_ssize_t)idx[1];
    *fz = (double)(Py_ssize_t)idx[2];
    return 1;
}

/* Trilinear fetch of channel range [c0, c0+nc_out) at index coords; zeros outside. */
static inline int trilinear(const Grid *g, const double idx[3], int c0, int nc_out, double *out) {
    double fx, fy, fz;
    if (!cell_floor(idx, g, &fx, &fy, &fz)) {
        for (int c = 0; c < nc_out; c++) out[c] = 0.0;
        return 0;
    }
    Py_ssize_t i = (Py_ssize_t)fx, j = (Py_ssize_t)fy, k = (Py_ssize_t)fz;
    double tx = idx[0] - fx, ty = idx[1] - fy, tz = idx[2] - fz;
    Py_ssize_t sz = g->nc, sy = g->nz * sz, sx = g->ny * sy;
    const float *p = g->data + i * sx + j * sy + k * sz + c0;
    double w[8] = {(1 - tx) * (1 - ty) * (1 - tz), (1 - tx) * (1 - ty) * tz,
                   (1 - tx) * ty * (1 - tz),       (1 - tx) * ty * tz,
                   tx * (1 - ty) * (1 - tz),       tx * (1 - ty) * tz,
                   tx * ty * (1 - tz),             tx * ty * tz};
    Py_ssize_t off[8] = {0, sz, sy, sy + sz, sx, sx + sz, sx + sy, sx + sy + sz};
    for (int c = 0; c < nc_out; c++) {
        double v = 0.0;
        for (int q = 0; q < 8; q++) v += w[q] * (double)p[off[q] + c];
        out[c] = v;
    }
    return 1;
}

/* A trilinear stencil, set up once and read channel by channel. */
typedef struct {
    const float *p;
    Py_ssize_t off[8];
    double w[8];
} Tri;

/* The stencil of grid g at index coordinates idx; 0 outside (zeros there). */
static inline int tri_setup(const Grid *g, const double idx[3], Tri *t) {
    double fx, fy, fz;
    if (!cell_floor(idx, g, &fx, &fy, &fz))
        return 0;
    double tx = idx[0] - fx, ty = idx[1] - fy, tz = idx[2] - fz;
    Py_ssize_t sz = g->nc, sy = g->nz * sz, sx = g->ny * sy;
    t->p = g->data + (Py_ssize_t)fx * sx + (Py_ssize_t)fy * sy + (Py_ssize_t)fz * sz;
    double w[8] = {(1 - tx) * (1 - ty) * (1 - tz), (1 - tx) * (1 - ty) * tz,
                   (1 - tx) * ty * (1 - tz),       (1 - tx) * ty * tz,
                   tx * (1 - ty) * (1 - tz),       tx * (1 - ty) * tz,
                   tx * ty * (1 - tz),             tx * ty * tz};
    Py_ssize_t off[8] = {0, sz, sy, sy + sz, sx, sx + sz, sx + sy, sx + sy + sz};
    for (int q = 0; q < 8; q++) { t->w[q] = w[q]; t->off[q] = off[q]; }
    return 1;
}

static inline double tri_get1(const Tri *t, int c) {
    double v = 0.0;
    for (int q = 0; q < 8; q++) v += t->w[q] * (double)t->p[t->off[q] + c];
    return v;
}

static inline void tri_get(const Tri *t, int c0, int n, double *out) {
    for (int c = 0; c < n; c++) out[c] = tri_get1(t, c0 + c);
}

/* out = exp(-x) per channel; one exp when the three are equal (grey media). */
static inline void exp3(const double x[3], double out[3]) {
    if (x[0] == x[1] && x[1] == x[2]) {
        out[0] = out[1] = out[2] = exp(-x[0]);
    } else {
        for (int a = 0; a < 3; a++) out[a] = exp(-x[a]);
    }
}

static inline void to_index(const Grid *g, const double x[3], double idx[3]) {
    for (int r = 0; r < 3; r++)
        idx[r] = g->w2i[4 * r] * x[0] + g->w2i[4 * r + 1] * x[1] + g->w2i[4 * r + 2] * x[2] + g->w2i[4 * r + 3];
}

/* floor(v) clamped to [lo, hi] (lo for NaN): a safe index from any double. */
static inline Py_ssize_t floor_clamp(double v, Py_ssize_t lo, Py_ssize_t hi) {
    double f = floor(v);
    if (!(f > (double)lo)) return lo;
    if (f > (double)hi) return hi;
    return (Py_ssize_t)f;
}

/* Parse parallel lists of grids, (3,4) maps and RGB coefficients. `nchan` = channels per voxel
 * (grids are (X,Y,Z) when nchan == 0, else (X,Y,Z,nchan) with nchan >= 1 accepted as any). */
static int parse_grids(PyObject *grids, PyObject *w2is, PyObject *sigs, PyObject *thrs, Grid *out,
                       Buf *bufs, int *n_out, int four_d) {
    if (!PyList_Check(grids) || !PyList_Check(w2is) || !PyList_Check(sigs) || !PyList_Check(thrs)) {
        PyErr_SetString(PyExc_ValueError, "grids, w2is, sigmas and thresholds must be lists");
        return -1;
    }
    Py_ssize_t n = PyList_GET_SIZE(grids);
    if (n != PyList_GET_SIZE(w2is) || n != PyList_GET_SIZE(sigs) || n != PyList_GET_SIZE(thrs) ||
        n > MAX_MEDIA) {
        PyErr_SetString(PyExc_ValueError, "grids, w2is and sigmas must have the same length (<= 64)");
        return -1;
    }
    *n_out = 0;
    for (Py_ssize_t m = 0; m < n; m++) {
        Py_ssize_t sh[4] = {-1, -1, -1, -1};
        if (get_buf(PyList_GET_ITEM(grids, m), &bufs[m], 'f', four_d ? 4 : 3, sh, "grid") < 0) return -1;
        *n_out = (int)m + 1;
        if (sh[0] < 2 || sh[1] < 2 || sh[2] < 2 || (four_d && sh[3] < 1)) {
            PyErr_SetString(PyExc_ValueError, "grid: every extent must be >= 2 (padded grid)");
            return -1;
        }
        out[m].data = (const float *)bufs[m].view.buf;
        out[m].nx = sh[0]; out[m].ny = sh[1]; out[m].nz = sh[2]; out[m].nc = four_d ? sh[3] : 1;
        Buf wb, sb;
        Py_ssize_t s34[2] = {3, 4}, s3[1] = {3};
        if (get_buf(PyList_GET_ITEM(w2is, m), &wb, 'd', 2, s34, "w2i") < 0) return -1;
        memcpy(out[m].w2i, wb.view.buf, 12 * sizeof(double));
        buf_release(&wb);
        if (get_buf(PyList_GET_ITEM(sigs, m), &sb, 'd', 1, s3, "sigma") < 0) return -1;
        memcpy(out[m].sig, sb.view.buf, 3 * sizeof(double));
        buf_release(&sb);
        out[m].thr = PyFloat_AsDouble(PyList_GET_ITEM(thrs, m));
        if (out[m].thr == -1.0 && PyErr_Occurred()) return -1;
        for (int q = 0; q < 12; q++) if (!isfinite(out[m].w2i[q])) {
            PyErr_SetString(PyExc_ValueError, "w2i: non-finite transform");
            return -1;
        }
    }
    return 0;
}

/* Channel 0 of grid g, trilinear at index coordinates idx (0 outside the grid). */
static inline double tri0(const Grid *g, const double idx[3]) {
    double fx, fy, fz;
    if (!cell_floor(idx, g, &fx, &fy, &fz))
        return 0.0;
    Py_ssize_t sz = g->nc, sy = g->nz * sz, sx = g->ny * sy;
    const float *p = g->data + (Py_ssize_t)fx * sx + (Py_ssize_t)fy * sy + (Py_ssize_t)fz * sz;
    double tx = idx[0] - fx, ty = idx[1] - fy, tz = idx[2] - fz;
    double c00 = p[0] * (1.0 - tz) + p[sz] * tz, c01 = p[sy] * (1.0 - tz) + p[sy + sz] * tz;
    double c10 = p[sx] * (1.0 - tz) + p[sx + sz] * tz;
    double c11 = p[sx + sy] * (1.0 - tz) + p[sx + sy + sz] * tz;
    return (1.0 - tx) * ((1.0 - ty) * c00 + ty * c01) + tx * ((1.0 - ty) * c10 + ty * c11);
}

/* Channel 0 of grid g at o + s v, a line in its index coordinates. */
static inline double line_at(const Grid *g, const double o[3], const double v[3], double s) {
    double idx[3] = {o[0] + v[0] * s, o[1] + v[1] * s, o[2] + v[2] * s};
    return tri0(g, idx);
}

/* The ray p + s d (world) as a line o + s v in grid g's index coordinates. */
static inline void ray_to_index(const Grid *g, const double p[3], const double d[3], double o[3],
                                double v[3]) {
    to_index(g, p, o);
    for (int r = 0; r < 3; r++)
        v[r] = g->w2i[4 * r] * d[0] + g->w2i[4 * r + 1] * d[1] + g->w2i[4 * r + 2] * d[2];
}

/* Channel 0 of grid g, trilinear, at world point x. */
static inline double fetch0(const Grid *g, const double x[3]) {
    double idx[3];
    to_index(g, x, idx);
    return tri0(g, idx);
}

#define CROSSING_HALVINGS 6

/* Twin of kernels_np.inside_fraction: the part of the segment [sa, sb] of the line o + s v
 * (grid g's index coordinates) with occupancy >= thr, given the occupancy va, vb at its ends;
 * a crossing is bracketed by CROSSING_HALVINGS bisections, then interpolated linearly. */
static inline double inside_fraction(const Grid *g, const double o[3], const double v[3], double sa,
                                     double sb, double va, double vb, double thr) {
    int ia = va >= thr, ib = vb >= thr;
    if (ia && ib) return 1.0;
    if (!ia && !ib) return 0.0;
    double lo = sa, hi = sb, vlo = va, vhi = vb;
    for (int it = 0; it < CROSSING_HALVINGS; it++) {
        double mid = 0.5 * (lo + hi), vm = line_at(g, o, v, mid);
        if ((vm >= thr) == (vlo >= thr)) { lo = mid; vlo = vm; }
        else { hi = mid; vhi = vm; }
    }
    double f = (thr - vlo) / (vhi - vlo);
    if (!isfinite(f)) f = 0.5;
    f = f < 0.0 ? 0.0 : (f > 1.0 ? 1.0 : f);
    double cross = lo + f * (hi - lo), len = sb - sa > 1e-300 ? sb - sa : 1e-300;
    return (ia ? cross - sa : sb - cross) / len;
}

/* ---- Empty and constant space (twin of kernels_np.Walk) ----
 * Per medium an optional coarse grid of density bounds (media.brick_bounds): brick b covers
 * the index cells [b B, (b + 1) B] and holds [least, largest] density of its points. */
typedef struct {
    const float *data;   /* (n[0], n[1], n[2], 2) or NULL: no bricks, the box is "varying" */
    Py_ssize_t n[3];
    double size;         /* B, cells per brick edge */
} Bricks;

#define EMPTY_MAX_BRICKS 100000  /* DDA steps per call at most (a bounded loop) */
#define KIND_EMPTY 0
#define KIND_CONST 1
#define KIND_VARYING 2

/* Parse `list` (None, or one float32 (bx, by, bz, 2) per grid with b = ceil((n - 1) / brick)). */
static int parse_bricks(PyObject *list, int brick, const Grid *g, int ng, Bricks *out, Buf *bufs,
                        int *nheld) {
    *nheld = 0;
    for (int m = 0; m < ng; m++) { out[m].data = NULL; out[m].size = 1.0; }
    if (list == NULL || list == Py_None) return 0;
    if (!PyList_Check(list) || PyList_GET_SIZE(list) != ng || brick < 1 || brick > 4096) {
        PyErr_SetString(PyExc_ValueError, "bricks: one array per medium and 1 <= brick <= 4096");
        return -1;
    }
    for (int m = 0; m < ng; m++) {
        Py_ssize_t dims[3] = {g[m].nx, g[m].ny, g[m].nz}, sh[4];
        for (int a = 0; a < 3; a++) {
            Py_ssize_t nb = (dims[a] - 1 + brick - 1) / brick;
            sh[a] = nb < 1 ? 1 : nb;
        }
        sh[3] = 2;
        if (get_buf(PyList_GET_ITEM(list, m), &bufs[m], 'f', 4, sh, "bricks") < 0) return -1;
        *nheld = m + 1;
        out[m].data = (const float *)bufs[m].view.buf;
        for (int a = 0; a < 3; a++) out[m].n[a] = sh[a];
        out[m].size = (double)brick;
    }
    return 0;
}

/* A walk along the line o + s v (s increasing) of one grid's index coordinates through its
 * bricks: it cuts the line into stretches of whole bricks that surely hold no density
 * (empty), hold one constant density (const: every brick's least = largest = value) or may
 * vary.  A brick's far face is computed afresh from its index, (face - o) * (1 / v), so both
 * twins find the same s. */
typedef struct {
    const Bricks *b;
    double o[3], inv[3];
    int dir[3];
    double sa, sb;          /* the line's interval inside the padded box (sa > sb: misses) */
    Py_ssize_t idx[3];      /* the brick just past the current stretch */
    double end;             /* where the current stretch ends */
    int kind;               /* the current stretch's kind */
    double value;           /* its density when const */
    int state;              /* 0 not started, 1 walking, 2 past the box */
} Walk;

static void walk_init(Walk *w, const Grid *g, const Bricks *b, const double o[3], const double v[3]) {
    double dims[3] = {(double)(g->nx - 1), (double)(g->ny - 1), (double)(g->nz - 1)};
    w->b = b;
    w->sa = -INFINITY;
    w->sb = INFINITY;
    w->state = 0;
    w->end = -INFINITY;
    w->kind = KIND_VARYING;
    w->value = 0.0;
    for (int a = 0; a < 3; a++) {
        w->o[a] = o[a];
        w->dir[a] = v[a] > 1e-300 ? 1 : (v[a] < -1e-300 ? -1 : 0);
        w->inv[a] = w->dir[a] ? 1.0 / v[a] : 0.0;
        if (!w->dir[a]) {
            if (!(o[a] >= 0.0 && o[a] <= dims[a])) { w->sa = INFINITY; w->sb = -INFINITY; }
            continue;
        }
        double t0 = (0.0 - o[a]) * w->inv[a], t1 = (dims[a] - o[a]) * w->inv[a];
        if (t0 > t1) { double t = t0; t0 = t1; t1 = t; }
        if (t0 > w->sa) w->sa = t0;
        if (t1 < w->sb) w->sb = t1;
    }
    if (!(w->sa <= w->sb)) { w->sa = INFINITY; w->sb = -INFINITY; }
}

/* s at which the walk leaves brick idx (its nearest face ahead) and the axis crossed. */
static inline double brick_exit(const Walk *w, const Py_ssize_t idx[3], int *axis) {
    double best = INFINITY;
    *axis = -1;
    for (int a = 0; a < 3; a++) {
        if (!w->dir[a]) continue;
        double face = (double)(w->dir[a] > 0 ? idx[a] + 1 : idx[a]) * w->b->size;
        double t = (face - w->o[a]) * w->inv[a];
        if (t < best) { best = t; *axis = a; }
    }
    return best;
}

static inline int brick_kind(const Bricks *b, const Py_ssize_t idx[3], double *value) {
    const float *e = b->data + ((idx[0] * b->n[1] + idx[1]) * b->n[2] + idx[2]) * 2;
    *value = (double)e[1];
    if (!(e[1] > 0.0f)) return KIND_EMPTY;
    return e[0] == e[1] ? KIND_CONST : KIND_VARYING;
}

/* The next stretch of the walk from brick w->idx (entered at `from`): a run of bricks of the
 * same kind (and value, when const); past the box everything is empty. */
static void walk_next(Walk *w, double from) {
    const Bricks *b = w->b;
    if (w->state == 2) { w->kind = KIND_EMPTY; w->value = 0.0; w->end = INFINITY; return; }
    w->kind = brick_kind(b, w->idx, &w->value);
    double e = from;
    for (int it = 0; it < EMPTY_MAX_BRICKS; it++) {
        int ax;
        double x = brick_exit(w, w->idx, &ax), val;
        e = x > e ? x : e;
        if (ax < 0 || !(e < w->sb)) { w->state = 2; break; }
        w->idx[ax] += w->dir[ax];
        if (w->idx[ax] < 0 || w->idx[ax] >= b->n[ax]) { w->state = 2; break; }
        int k = brick_kind(b, w->idx, &val);
        if (k != w->kind || (k == KIND_CONST && val != w->value)) break;
    }
    if (w->state == 2) w->end = (w->kind == KIND_EMPTY) ? INFINITY : (e < w->sb ? e : w->sb);
    else w->end = e;
}

/* The kind of the stretch holding s (calls come with non-decreasing s); *end: where it ends
 * (INFINITY: empty from there on), *value: its density when const. */
static int walk_at(Walk *w, double s, double *end, double *value) {
    *value = 0.0;
    if (!(s < w->sb)) { *end = INFINITY; return KIND_EMPTY; }
    if (s < w->sa) { *end = w->sa; return KIND_EMPTY; }
    if (!w->b->data) { *end = w->sb; return KIND_VARYING; }
    if (w->state == 0) {
        for (int a = 0; a < 3; a++) {
            double v = w->dir[a] ? 1.0 / w->inv[a] : 0.0;
            w->idx[a] = floor_clamp((w->o[a] + s * v) / w->b->size, 0, w->b->n[a] - 1);
        }
        w->state = 1;
        walk_next(w, s);
    }
    for (int it = 0; it < EMPTY_MAX_BRICKS && !(s < w->end); it++) walk_next(w, w->end);
    if (!(s < w->end)) { *end = INFINITY; return KIND_EMPTY; }
    *end = w->end;
    *value = w->value;
    return w->kind;
}

/* The largest density (brick bound) on the segment [s_a, s_b] of the line o + s v of a grid's
 * index coordinates: the largest bound among the bricks its bounding box touches (0 when it
 * lies wholly outside the grid).  Twin of kernels_np.segment_majorant. */
static double segment_majorant(const Grid *g, const Bricks *b, const double o[3], const double v[3],
                               double s_a, double s_b) {
    double dims[3] = {(double)(g->nx - 1), (double)(g->ny - 1), (double)(g->nz - 1)};
    Py_ssize_t lo[3], hi[3];
    double mn[3], mx[3];
    for (int a = 0; a < 3; a++) {
        double p0 = o[a] + s_a * v[a], p1 = o[a] + s_b * v[a];
        mn[a] = p0 < p1 ? p0 : p1;
        mx[a] = p0 < p1 ? p1 : p0;
        if (isnan(mn[a]) || isnan(mx[a])) return INFINITY;
    }
    for (int a = 0; a < 3; a++) {
        if (mx[a] < 0.0 || mn[a] > dims[a]) return 0.0;  /* wholly outside the grid */
        lo[a] = floor_clamp(mn[a] / b->size, 0, b->n[a] - 1);
        hi[a] = floor_clamp(mx[a] / b->size, 0, b->n[a] - 1);
    }
    float best = 0.0f;
    for (Py_ssize_t i = lo[0]; i <= hi[0]; i++)
        for (Py_ssize_t j = lo[1]; j <= hi[1]; j++)
            for (Py_ssize_t k = lo[2]; k <= hi[2]; k++) {
                float e = b->data[((i * b->n[1] + j) * b->n[2] + k) * 2 + 1];
                if (e > best) best = e;
            }
    return (double)best;
}

/* Where the ray p + s d leaves the last of the media's padded boxes it crosses (the far end of
 * the union of their intervals, as media.union_interval), capped at t_max; 0 when it meets
 * none ahead.  Twin of kernels_np.media_exit. */
static double media_exit(const Grid *g, int ng, const double p[3], const double d[3], double t_max) {
    double far = -INFINITY;
    for (int m = 0; m < ng; m++) {
        double o[3], v[3], lo = -INFINITY, hi = INFINITY;
        ray_to_index(&g[m], p, d, o, v);
        double dims[3] = {(double)(g[m].nx - 1), (double)(g[m].ny - 1), (double)(g[m].nz - 1)};
        for (int a = 0; a < 3; a++) {
            if (fabs(v[a]) < 1e-300) {
                if (!(o[a] >= 0.0 && o[a] <= dims[a])) { lo = INFINITY; hi = -INFINITY; }
                continue;
            }
            double inv = 1.0 / v[a], ta = -o[a] * inv, tb = (dims[a] - o[a]) * inv;
            double t0 = ta < tb ? ta : tb, t1 = ta < tb ? tb : ta;
            if (t0 > lo) lo = t0;
            if (t1 < hi) hi = t1;
        }
        if (hi > lo && hi > far) far = hi;
    }
    double t = far < t_max ? far : t_max;
    return t > 0.0 ? t : 0.0;
}

static const char optical_depth_doc[] =
    "optical_depth(points, dirs, t_max, grids, w2is, sigma_ts, thresholds, step, offset[, bricks, brick,\n"
    "              clip]) -> (N,3) float64; clip: first cut t_max at the media's far side (media_exit)\n"
    "  -> (N,3) float64\n"
    "Twin of kernels_np.optical_depth; with bricks (media.brick_bounds per grid) the steps that lie\n"
    "wholly in empty or constant bricks are added in one go.";

static PyObject *optical_depth(PyObject *self, PyObject *args) {
    PyObject *po, *pd, *pt, *grids, *w2is, *sigs, *thrs, *pbk = Py_None;
    double step, offset;
    int brick = 4, clip = 0;
    if (!PyArg_ParseTuple(args, "OOOOOOOdd|Oip", &po, &pd, &pt, &grids, &w2is, &sigs, &thrs, &step,
                          &offset, &pbk, &brick, &clip))
        return NULL;
    if (!(step > 0.0) || !isfinite(step) || !(offset >= 0.0 && offset <= 1.0)) {
        PyErr_SetString(PyExc_ValueError, "step must be > 0 and offset in [0, 1]");
        return NULL;
    }
    Buf bp = {0}, bd = {0}, bt = {0}, gb[MAX_MEDIA], kb[MAX_MEDIA];
    Grid g[MAX_MEDIA];
    Bricks bk[MAX_MEDIA];
    int ng = 0, nkb = 0;
    PyObject *result = NULL, *outobj = NULL;
    Py_ssize_t s_p[2] = {-1, 3};
    if (get_buf(po, &bp, 'd', 2, s_p, "points") < 0) goto done;
    Py_ssize_t n = s_p[0];
    Py_ssize_t s_d[2] = {n, 3}, s_t[1] = {n};
    if (get_buf(pd, &bd, 'd', 2, s_d, "dirs") < 0) goto done;
    if (get_buf(pt, &bt, 'd', 1, s_t, "t_max") < 0) goto done;
    if (parse_grids(grids, w2is, sigs, thrs, g, gb, &ng, 0) < 0) goto done;
    if (parse_bricks(pbk, brick, g, ng, bk, kb, &nkb) < 0) goto done;
    int skip = pbk != Py_None;
    outobj = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * 3 * sizeof(double)));
    if (!outobj) goto done;
    double *out = (double *)PyByteArray_AS_STRING(outobj);
    const double *P = (const double *)bp.view.buf, *D = (const double *)bd.view.buf,
                 *TM = (const double *)bt.view.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t r = 0; r < n; r++) {
        double tau[3] = {0, 0, 0};
        double tm = TM[r];
        if (clip) tm = media_exit(g, ng, P + 3 * r, D + 3 * r, tm);
        if (isfinite(tm) && tm > 0.0) {
            double cnt = ceil(tm / step);
            if (cnt > 1e6) cnt = 1e6;  /* a bounded loop whatever the caller passes */
            long ns = (long)cnt;
            double h = tm / (double)ns;
            double prev[MAX_MEDIA], lo[MAX_MEDIA][3], lv[MAX_MEDIA][3];
            for (int m = 0; m < ng; m++) {
                ray_to_index(&g[m], P + 3 * r, D + 3 * r, lo[m], lv[m]);
                /* sharp grids: occupancy at the segment's start */
                if (g[m].thr >= 0.0) prev[m] = line_at(&g[m], lo[m], lv[m], 0.0);
            }
            /* Where every medium is empty or constant over whole steps (their bricks) the
             * steps add rate * length in one go; elsewhere they are marched. */
            double busy = -INFINITY;
            Walk wk[MAX_MEDIA];
            if (skip)
                for (int m = 0; m < ng; m++) walk_init(&wk[m], &g[m], &bk[m], lo[m], lv[m]);
            for (long j = 0; j < ns; j++) {
                if (skip && (double)j * h >= busy) {
                    double s0 = (double)j * h, run = INFINITY, vary = s0, rate[3] = {0, 0, 0};
                    for (int m = 0; m < ng; m++) {
                        double e, val;
                        int kd = walk_at(&wk[m], s0, &e, &val);
                        if (kd == KIND_VARYING) { if (e > vary) vary = e; run = -1.0; continue; }
                        if (e < run) run = e;
                        for (int c = 0; c < 3; c++) rate[c] += val * g[m].sig[c];
                    }
                    if (run < 0.0) {
                        busy = vary;
                    } else {
                        long jump = run >= tm ? ns - j : (long)floor((run - s0) / h);
                        if (jump > 0) {
                            for (int c = 0; c < 3; c++) tau[c] += rate[c] * ((double)jump * h);
                            j += jump;
                            if (j >= ns) break;
                            for (int m = 0; m < ng; m++)
                                if (g[m].thr >= 0.0) prev[m] = line_at(&g[m], lo[m], lv[m], (double)j * h);
                            j--;
                            continue;
                        }
                        busy = run;
                    }
                }
                double s = ((double)j + offset) * h;
                for (int m = 0; m < ng; m++) {
                    double rho;
                    if (g[m].thr >= 0.0) {
                        double vb = line_at(&g[m], lo[m], lv[m], (double)(j + 1) * h);
                        rho = inside_fraction(&g[m], lo[m], lv[m], (double)j * h,
                                              (double)(j + 1) * h, prev[m], vb, g[m].thr);
                        prev[m] = vb;
                    } else {
                        rho = line_at(&g[m], lo[m], lv[m], s);
                    }
                    for (int c = 0; c < 3; c++) tau[c] += rho * g[m].sig[c] * h;
                }
            }
        }
        for (int c = 0; c < 3; c++) out[3 * r + c] = tau[c];
    }
    Py_END_ALLOW_THREADS
    result = outobj;
    outobj = NULL;
done:
    Py_XDECREF(outobj);
    buf_release(&bp); buf_release(&bd); buf_release(&bt);
    for (int m = 0; m < ng; m++) buf_release(&gb[m]);
    for (int m = 0; m < nkb; m++) buf_release(&kb[m]);
    return result;
}


/* ------------------------------------------------------------------------------------------
 * Light sweep (twin of kernels_np.light_sweep): optical depth towards a light for every voxel
 * of one medium's grid, integrated along "columns" (rays from the light) slab by slab.
 */
#define SWEEP_MAX_SUB 10000


/* Index-space position (in the target grid) of column (p, q) on slab i. */
static inline void column_index(int axis, int bax, int cax, const double *cf, double i, double p,
                                double q, double idx[3]) {
    double b = cf[4] + i * cf[5];
    idx[axis] = i;
    idx[bax] = cf[0] + i * cf[2] + b * p;
    idx[cax] = cf[1] + i * cf[3] + b * q;
}

static inline void index_to_world(const double *a2w, const double idx[3], double x[3]) {
    for (int r = 0; r < 3; r++)
        x[r] = a2w[4 * r] * idx[0] + a2w[4 * r + 1] * idx[1] + a2w[4 * r + 2] * idx[2] + a2w[4 * r + 3];
}

/* Optical depth (added to tau) of a column's segment from slab i0 to slab i0 + dir through every
 * medium, cut into n_sub equal pieces of `len` metres: Simpson's rule on smooth grids (exact
 * for the cubic that trilinear interpolation is along a line within a cell), the inside
 * fraction on sharp ones.  line[6 m .. 6 m + 5]: the column in medium m's index coordinates,
 * o + i v.  vprev[m]: channel 0 of medium m at the segment's start on entry, at its end on
 * return. */
static void segment_tau(const Grid *g, int ng, const double *line, double i0, double dir,
                        int n_sub, double len, double *vprev, double tau[3]) {
    for (int u = 0; u < n_sub; u++) {
        double sa = (double)u / n_sub, sb = (double)(u + 1) / n_sub;
        for (int m = 0; m < ng; m++) {
            const double *lo = line + 6 * m, *lv = lo + 3;
            double o[3] = {lo[0] + i0 * lv[0], lo[1] + i0 * lv[1], lo[2] + i0 * lv[2]};
            double v[3] = {dir * lv[0], dir * lv[1], dir * lv[2]};
            double va = vprev[m], vb = line_at(&g[m], o, v, sb), rho;
            if (g[m].thr >= 0.0) {
                rho = inside_fraction(&g[m], o, v, sa, sb, va, vb, g[m].thr);
            } else {
                double vm = line_at(&g[m], o, v, 0.5 * (sa + sb));
                rho = (va + 4.0 * vm + vb) / 6.0;
            }
            for (int c = 0; c < 3; c++) tau[c] += rho * g[m].sig[c] * len;
            vprev[m] = vb;
        }
    }
}

/* Slab coordinates [lo, hi] (in i, any order of travel) where the line idx(i) = o + i v of the
 * target grid's index space, mapped to world by a2w, lies inside the padded box of any medium
 * (hull of the per-medium ranges); lo > hi when it misses them all. */
static void column_box_range(const Grid *g, int ng, const double *a2w, const double o[3],
                             const double v[3], double *lo, double *hi) {
    double X0[3], X1[3];
    index_to_world(a2w, o, X0);
    for (int r = 0; r < 3; r++)
        X1[r] = a2w[4 * r] * v[0] + a2w[4 * r + 1] * v[1] + a2w[4 * r + 2] * v[2];
    *lo = INFINITY;
    *hi = -INFINITY;
    for (int m = 0; m < ng; m++) {
        double a = -INFINITY, b = INFINITY, n[3] = {(double)g[m].nx - 1, (double)g[m].ny - 1,
                                                   (double)g[m].nz - 1};
        for (int r = 0; r < 3; r++) {
            const double *w = g[m].w2i + 4 * r;
            double p0 = w[0] * X0[0] + w[1] * X0[1] + w[2] * X0[2] + w[3];
            double dv = w[0] * X1[0] + w[1] * X1[1] + w[2] * X1[2];
            if (fabs(dv) < 1e-300) {
                if (!(p0 >= 0.0 && p0 <= n[r])) { a = INFINITY; b = -INFINITY; }
                continue;
            }
            double t0 = (0.0 - p0) / dv, t1 = (n[r] - p0) / dv;
            if (t0 > t1) { double t = t0; t0 = t1; t1 = t; }
            if (t0 > a) a = t0;
            if (t1 < b) b = t1;
        }
        if (a <= b) {
            if (a < *lo) *lo = a;
            if (b > *hi) *hi = b;
        }
    }
}

static const char light_sweep_doc[] =
    "light_sweep(out, channel, a2w, axis, sign, i_first, i_last, coef, light_index, cone, init,\n"
    "            p_lo, p_hi, n_sub, grids, w2is, sigma_ts, thresholds) -> None\n"
    "Twin of kernels_np.light_sweep: writes out[..., channel:channel+3] of the voxels it owns.";

static PyObject *light_sweep(PyObject *self, PyObject *args) {
    PyObject *pout, *pa2w, *pcoef, *plight, *pinit, *grids, *w2is, *sigs, *thrs;
    int channel, axis, sign, i_first, i_last, cone, p_lo, p_hi, n_sub;
    if (!PyArg_ParseTuple(args, "OiOiiiiOOiOiiiOOOO", &pout, &channel, &pa2w, &axis, &sign,
                          &i_first, &i_last, &pcoef, &plight, &cone, &pinit, &p_lo, &p_hi,
                          &n_sub, &grids, &w2is, &sigs, &thrs))
        return NULL;
    Buf bo = {0}, ba = {0}, bc = {0}, bl = {0}, bi = {0}, gb[MAX_MEDIA];
    Grid g[MAX_MEDIA];
    int ng = 0, ok = 0;
    double *tau = NULL, *vprev = NULL, *brange = NULL, *lines = NULL;
    Py_ssize_t so[4] = {-1, -1, -1, -1}, s34[2] = {3, 4}, s6[1] = {6}, s3[1] = {3};
    Py_ssize_t si[3] = {-1, -1, 3};
    if (get_buf_ex(pout, &bo, 'f', 4, so, "out", PyBUF_WRITABLE) < 0) goto done;
    if (get_buf(pa2w, &ba, 'd', 2, s34, "a2w") < 0) goto done;
    if (get_buf(pcoef, &bc, 'd', 1, s6, "coef") < 0) goto done;
    if (get_buf(plight, &bl, 'd', 1, s3, "light_index") < 0) goto done;
    if (get_buf(pinit, &bi, 'd', 3, si, "init") < 0) goto done;
    if (parse_grids(grids, w2is, sigs, thrs, g, gb, &ng, 0) < 0) goto done;
    Py_ssize_t dims[3] = {so[0], so[1], so[2]}, nch = so[3], NP = si[0], NQ = si[1];
    const double *A2W = (const double *)ba.view.buf, *CF = (const double *)bc.view.buf,
                 *LI = (const double *)bl.view.buf, *INIT = (const double *)bi.view.buf;
    if (axis < 0 || axis > 2 || (sign != 1 && sign != -1) || channel < 0 || channel + 3 > nch ||
        dims[0] < 1 || dims[1] < 1 || dims[2] < 1) {
        PyErr_SetString(PyExc_ValueError, "light_sweep: bad axis, sign or channel");
        goto done;
    }
    if (i_first < 0 || i_first >= dims[axis] || i_last < 0 || i_last >= dims[axis] ||
        sign * (i_last - i_first) < 0) {
        PyErr_SetString(PyExc_ValueError, "light_sweep: slab range outside the grid or against the sign");
        goto done;
    }
    if (NP < 2 || NQ < 2 || p_lo < 0 || p_hi <= p_lo || p_hi > NP - 1 || n_sub < 1 || n_sub > SWEEP_MAX_SUB) {
        PyErr_SetString(PyExc_ValueError, "light_sweep: bad column range or n_sub");
        goto done;
    }
    for (int q = 0; q < 12; q++)
        if (!isfinite(A2W[q])) { PyErr_SetString(PyExc_ValueError, "light_sweep: non-finite a2w"); goto done; }
    for (int q = 0; q < 6; q++)
        if (!isfinite(CF[q])) { PyErr_SetString(PyExc_ValueError, "light_sweep: non-finite coef"); goto done; }
    for (int q = 0; q < 3; q++)
        if (!isfinite(LI[q])) { PyErr_SetString(PyExc_ValueError, "light_sweep: non-finite light"); goto done; }
    /* the column spacing B(i) = coef[4] + i coef[5] must stay positive over the slabs (linear
     * in i: checking both ends suffices) */
    if (!(CF[4] + i_first * CF[5] > 0.0) || !(CF[4] + i_last * CF[5] > 0.0)) {
        PyErr_SetString(PyExc_ValueError, "light_sweep: column spacing must be positive");
        goto done;
    }
    for (Py_ssize_t r = 0; r < NP * NQ; r++) {
        for (int c = 0; c < 3; c++)
            if (!isfinite(INIT[3 * r + c])) {
                PyErr_SetString(PyExc_ValueError, "light_sweep: non-finite init");
                goto done;
            }
    }
    Py_ssize_t ncp = (Py_ssize_t)(p_hi - p_lo + 1), ncol = ncp * NQ;
    int ngs = ng > 0 ? ng : 1;
    brange = (double *)malloc((size_t)ncol * 3 * sizeof(double));
    tau = (double *)malloc((size_t)ncol * 3 * sizeof(double));
    vprev = (double *)malloc((size_t)ncol * ngs * sizeof(double));
    lines = (double *)malloc((size_t)ncol * ngs * 6 * sizeof(double));
    if (!tau || !vprev || !brange || !lines) { PyErr_NoMemory(); goto done; }
    float *OUT = (float *)bo.view.buf;
    int bax = axis == 0 ? 1 : 0, cax = axis == 2 ? 1 : 2;
    Py_ssize_t st[3] = {dims[1] * dims[2] * nch, dims[2] * nch, nch};
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t pc = 0; pc < ncp; pc++)
        for (Py_ssize_t q = 0; q < NQ; q++) {
            Py_ssize_t col = pc * NQ + q, src = (p_lo + pc) * NQ + q;
            double o[3], i1[3], v[3], X0[3], X1[3], W1[3];
            for (int c = 0; c < 3; c++) tau[3 * col + c] = INIT[3 * src + c];
            /* the column is a straight line, world X0 + i X1 in the slab coordinate i */
            column_index(axis, bax, cax, CF, 0.0, (double)(p_lo + pc), (double)q, o);
            column_index(axis, bax, cax, CF, 1.0, (double)(p_lo + pc), (double)q, i1);
            for (int a = 0; a < 3; a++) v[a] = i1[a] - o[a];
            index_to_world(A2W, o, X0);
            for (int r = 0; r < 3; r++)
                X1[r] = A2W[4 * r] * v[0] + A2W[4 * r + 1] * v[1] + A2W[4 * r + 2] * v[2];
            for (int m = 0; m < ng; m++) {
                double *ln = lines + (col * ngs + m) * 6;
                ray_to_index(&g[m], X0, X1, ln, ln + 3);
                vprev[col * ngs + m] = line_at(&g[m], ln, ln + 3, (double)i_first);
            }
            for (int r = 0; r < 3; r++) W1[r] = X1[r];
            brange[3 * col + 2] = sqrt(W1[0] * W1[0] + W1[1] * W1[1] + W1[2] * W1[2]) / n_sub;
            /* segments wholly outside every medium's box add nothing: skipped below (their
             * ends read 0, so vprev stays right) */
            column_box_range(g, ng, A2W, o, v, &brange[3 * col], &brange[3 * col + 1]);
            brange[3 * col] -= 1.0;
            brange[3 * col + 1] += 1.0;
        }
    for (int i = i_first;; i += sign) {
        for (Py_ssize_t pc = 0; pc < ncp; pc++)
            for (Py_ssize_t q = 0; q < NQ; q++) {
                Py_ssize_t col = pc * NQ + q;
                double slo = (double)(sign > 0 ? i - 1 : i), shi = slo + 1.0;
                if (i != i_first && shi >= brange[3 * col] && slo <= brange[3 * col + 1])
                    segment_tau(g, ng, lines + col * ngs * 6, (double)(i - sign), (double)sign,
                                n_sub, brange[3 * col + 2], vprev + col * ngs, tau + 3 * col);
            }
        /* gather: every voxel of slab i in this chunk's cells takes the bilinear mean of the
         * four columns around it */
        double Bi = CF[4] + i * CF[5], Ab = CF[0] + i * CF[2], Ac = CF[1] + i * CF[3], iB = 1.0 / Bi;
        Py_ssize_t j0 = floor_clamp(Ab + Bi * p_lo - 1.0, 0, dims[bax] - 1);
        Py_ssize_t j1 = floor_clamp(Ab + Bi * p_hi + 2.0, -1, dims[bax] - 1);
        if (p_lo == 0) j0 = 0;                      /* voxels clamped into the first or last */
        if (p_hi == NP - 1) j1 = dims[bax] - 1;     /* cell (none when the lattice covers) */
        double da = (double)i - LI[axis];
        if (cone && !((double)sign * da > 0.0)) j1 = -1;  /* the light's own slab: no voxel */
        for (Py_ssize_t j = j0; j <= j1; j++) {
            if (cone) {
                double db = (double)j - LI[bax];
                if (bax < axis ? !(fabs(da) > fabs(db)) : !(fabs(da) >= fabs(db))) continue;
            }
            double p = ((double)j - Ab) * iB;
            Py_ssize_t pcell = floor_clamp(p, 0, NP - 2);
            if (pcell < p_lo || pcell >= p_hi) continue;
            double fp = p - (double)pcell;
            fp = fp < 0.0 ? 0.0 : (fp > 1.0 ? 1.0 : fp);
            Py_ssize_t c0 = (pcell - p_lo) * NQ;
            for (Py_ssize_t k = 0; k < dims[cax]; k++) {
                if (cone) {
                    double dc = (double)k - LI[cax];
                    if (cax < axis ? !(fabs(da) > fabs(dc)) : !(fabs(da) >= fabs(dc))) continue;
                }
                double qv = ((double)k - Ac) * iB;
                Py_ssize_t qcell = floor_clamp(qv, 0, NQ - 2);
                double fq = qv - (double)qcell;
                fq = fq < 0.0 ? 0.0 : (fq > 1.0 ? 1.0 : fq);
                const double *t00 = tau + 3 * (c0 + qcell), *t01 = t00 + 3, *t10 = t00 + 3 * NQ,
                             *t11 = t10 + 3;
                Py_ssize_t vox[3];
                vox[axis] = i; vox[bax] = j; vox[cax] = k;
                float *o = OUT + vox[0] * st[0] + vox[1] * st[1] + vox[2] * st[2] + channel;
                for (int c = 0; c < 3; c++)
                    o[c] = (float)((1.0 - fp) * ((1.0 - fq) * t00[c] + fq * t01[c]) +
                                   fp * ((1.0 - fq) * t10[c] + fq * t11[c]));
            }
        }
        if (i == i_last) break;
    }
    Py_END_ALLOW_THREADS
    ok = 1;
done:
    free(brange); free(tau); free(vprev); free(lines);
    buf_release(&bo); buf_release(&ba); buf_release(&bc); buf_release(&bl); buf_release(&bi);
    for (int m = 0; m < ng; m++) buf_release(&gb[m]);
    if (!ok) return NULL;
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------------------------------
 * Lattice upsampling (twin of kernels_np.upsample_into).
 */
static const char upsample_into_doc[] =
    "upsample_into(field, channel, lattice, stride, flat) -> None\n"
    "Twin of kernels_np.upsample_into: trilinear values of the lattice (point j at fine index\n"
    "j * stride) written into field[..., channel:channel + C] at the flat voxel indices.";

static PyObject *upsample_into(PyObject *self, PyObject *args) {
    PyObject *pf, *pl, *pflat;
    int channel, stride;
    if (!PyArg_ParseTuple(args, "OiOiO", &pf, &channel, &pl, &stride, &pflat)) return NULL;
    Buf bf = {0}, bl = {0}, bx = {0};
    int ok = 0;
    Py_ssize_t sf[4] = {-1, -1, -1, -1}, sl[4] = {-1, -1, -1, -1}, sx[1] = {-1};
    if (get_buf_ex(pf, &bf, 'f', 4, sf, "field", PyBUF_WRITABLE) < 0) goto done;
    if (get_buf(pl, &bl, 'f', 4, sl, "lattice") < 0) goto done;
    if (PyObject_GetBuffer(pflat, &bx.view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | PyBUF_ND) < 0) {
        PyErr_Clear();
        PyErr_SetString(PyExc_ValueError, "flat: expected a C-contiguous int64 array");
        goto done;
    }
    bx.held = 1;
    {
        const char *fm = bx.view.format ? bx.view.format : "B";
        if (fm[0] == '<' || fm[0] == '=' || fm[0] == '@') fm++;
        if (bx.view.ndim != 1 || bx.view.itemsize != 8 || (fm[0] != 'q' && fm[0] != 'l') || fm[1]) {
            PyErr_SetString(PyExc_ValueError, "flat: expected a 1-D int64 array");
            goto done;
        }
        sx[0] = bx.view.shape[0];
    }
    Py_ssize_t nc = sl[3];
    if (stride < 1 || nc < 1 || channel < 0 || channel + nc > sf[3] || sl[0] < 1 || sl[1] < 1 ||
        sl[2] < 1) {
        PyErr_SetString(PyExc_ValueError, "upsample_into: bad stride, channel or lattice");
        goto done;
    }
    const int64_t *FL = (const int64_t *)bx.view.buf;
    Py_ssize_t nvox = sf[0] * sf[1] * sf[2];
    for (Py_ssize_t q = 0; q < sx[0]; q++)
        if (FL[q] < 0 || FL[q] >= nvox) {
            PyErr_SetString(PyExc_ValueError, "flat: index outside the field");
            goto done;
        }
    float *F = (float *)bf.view.buf;
    const float *LT = (const float *)bl.view.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t q = 0; q < sx[0]; q++) {
        Py_ssize_t f = (Py_ssize_t)FL[q], ijk[3] = {f / (sf[1] * sf[2]), (f / sf[2]) % sf[1], f % sf[2]};
        Py_ssize_t lo[3], hi[3];
        double t[3];
        for (int a = 0; a < 3; a++) {
            lo[a] = ijk[a] / stride;
            if (lo[a] > sl[a] - 1) lo[a] = sl[a] - 1;
            hi[a] = lo[a] + 1 > sl[a] - 1 ? sl[a] - 1 : lo[a] + 1;
            t[a] = (double)(ijk[a] - lo[a] * stride) / (double)stride;
        }
        for (Py_ssize_t c = 0; c < nc; c++) {
            double v = 0.0;
            for (int cx = 0; cx < 2; cx++)
                for (int cy = 0; cy < 2; cy++)
                    for (int cz = 0; cz < 2; cz++) {
                        double w = (cx ? t[0] : 1.0 - t[0]) * (cy ? t[1] : 1.0 - t[1]) *
                                   (cz ? t[2] : 1.0 - t[2]);
                        Py_ssize_t i = cx ? hi[0] : lo[0], j = cy ? hi[1] : lo[1], k = cz ? hi[2] : lo[2];
                        v += w * (double)LT[((i * sl[1] + j) * sl[2] + k) * nc + c];
                    }
            F[f * sf[3] + channel + c] = (float)v;
        }
    }
    Py_END_ALLOW_THREADS
    ok = 1;
done:
    buf_release(&bf); buf_release(&bl); buf_release(&bx);
    if (!ok) return NULL;
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------------------------------
 * The camera-ray march (twin of kernels_np.march).  Layout constants mirror kernels_np.
 */
#define MAX_LIGHTS 64
#define MAX_CH 256
#define LIGHT_FIELDS 40
#define L_KIND 0
#define L_STRENGTH 1
#define L_POS 4
#define L_DIR 7
#define L_INV 10
#define L_COSHALF 19
#define L_BLEND 20
#define L_RADIUS 21
#define L_AX 22
#define L_AY 25
#define L_AREA 28
#define L_NORMAL 29
#define L_NORMALIZE 32
#define L_ROUND 33
#define L_CHANNEL 34
#define KIND_POINT 0
#define KIND_SPOT 1
#define KIND_SUN 2
#define KIND_AREA 3
#define DIM_JITTER 1000
#define SPOT_DISC_POINTS 8  /* kernels_np.SPOT_DISC_POINTS */
#define SPOT_DISC_PHI 0.6180339887498949
#define SPOT_GATE_MARGIN 1.05
#define L_COND 35
#define L_BEAM 36   /* the channel of the forward peak's light (W/m^2), < 1: none */
#define L_INDIRECT 37  /* 1: scattered light (a surface's bounce): its single scattering is multiple */
#define REFINE_STEPS 8
#define EDGE_EPS 1e-6
#define T_MIN 1e-6
#define MAX_STEPS 1000000L  /* per ray: a 256^3 grid needs ~1000 */
#define SUPER 4             /* steps per super-step (kernels_np.SUPER) */

static inline uint32_t hash32(uint32_t x) {
    x ^= x >> 16; x *= 0x7FEB352Du; x ^= x >> 15; x *= 0x846CA68Bu; x ^= x >> 16;
    return x;
}

static inline double uniform01(uint32_t key, long step, long dim) {
    uint32_t salt = hash32((uint32_t)((uint64_t)step * 0x9E3779B1u + (uint64_t)dim * 0x85EBCA77u));
    return (double)(hash32(key ^ salt) >> 8) * (1.0 / 16777216.0);
}

static inline void disc_map(double u1, double u2, int round_shape, double *pa, double *pb) {
    double a = 2.0 * u1 - 1.0, b = 2.0 * u2 - 1.0;
    if (!round_shape) { *pa = a; *pb = b; return; }
    int big = fabs(a) > fabs(b);
    double r = big ? a : b, phi;
    if (a == 0.0 && b == 0.0) phi = 0.0;
    else if (big) phi = (M_PI / 4) * b / (a == 0.0 ? 1.0 : a);
    else phi = M_PI / 2 - (M_PI / 4) * a / (b == 0.0 ? 1.0 : b);
    *pa = r * cos(phi); *pb = r * sin(phi);
}

static inline void basis(const double n[3], double t1[3], double t2[3]) {
    double sign = n[2] >= 0.0 ? 1.0 : -1.0;
    double a = -1.0 / (sign + n[2]);
    double b = n[0] * n[1] * a;
    t1[0] = 1.0 + sign * n[0] * n[0] * a; t1[1] = sign * b; t1[2] = -sign * n[0];
    t2[0] = b; t2[1] = sign + n[1] * n[1] * a; t2[2] = -n[1];
}

/* Cosine between the spot's axis and the propagation direction v (world), measured in the
 * light's local frame (its inverse matrix L_INV: non-uniform scale included). */
static inline double spot_cos(const double *L, const double v[3]) {
    const double *M = L + L_INV;
    double loc[3];
    for (int r = 0; r < 3; r++) loc[r] = M[3 * r] * v[0] + M[3 * r + 1] * v[1] + M[3 * r + 2] * v[2];
    double ln = sqrt(loc[0] * loc[0] + loc[1] * loc[1] + loc[2] * loc[2]);
    return -loc[2] / (ln > 1e-30 ? ln : 1e-30);
}

/* Light record `L` at point x: propagation direction d, irradiance e, unit direction to the
 * centre wc and its distance dc (INFINITY for the sun), and ds, the distance to the emitting
 * point(s) sampled (their irradiance-weighted mean; dc for a point without radius). */
static void light_sample(const double *L, const double x[3], double u1, double u2,
                         double d[3], double e[3], double wc[3], double *dc, double *ds) {
    int kind = (int)L[L_KIND];
    if (kind == KIND_SUN) {
        for (int a = 0; a < 3; a++) { d[a] = L[L_DIR + a]; e[a] = L[L_STRENGTH + a]; wc[a] = -d[a]; }
        *dc = INFINITY;
        *ds = INFINITY;
        return;
    }
    const double *c = L + L_POS;
    double vc[3] = {c[0] - x[0], c[1] - x[1], c[2] - x[2]};
    double dcc = sqrt(vc[0] * vc[0] + vc[1] * vc[1] + vc[2] * vc[2]);
    double inv_dc = 1.0 / (dcc > 1e-30 ? dcc : 1e-30);
    for (int a = 0; a < 3; a++) wc[a] = vc[a] * inv_dc;
    *dc = dcc;
    double pa, pb;
    disc_map(u1, u2, kind != KIND_AREA || L[L_ROUND] > 0, &pa, &pb);
    if (kind == KIND_POINT || kind == KIND_SPOT) {
        double radius = L[L_RADIUS], t1[3] = {0, 0, 0}, t2[3] = {0, 0, 0};
        if (radius > 0.0) {
            double nn[3] = {-wc[0], -wc[1], -wc[2]};
            basis(nn, t1, t2);
        }
        /* a spot with a radius averages its cone over SPOT_DISC_POINTS points of the disc:
         * (u1, u2) shifts a fixed lattice (Cranley-Patterson), so each point is uniform and
         * the mean irradiance unbiased; one random point would light x or not (noise) */
        int n_pts = (kind == KIND_SPOT && radius > 0.0) ? SPOT_DISC_POINTS : 1;
        if (n_pts > 1 && radius < dcc) {
            /* one point where the cone is the same over the whole disc: the disc's directions
             * lie within alpha of the centre's (wider in the light's frame by L_COND) */
            double out[3] = {-wc[0], -wc[1], -wc[2]};
            double cc = spot_cos(L, out);
            cc = cc < -1.0 ? -1.0 : (cc > 1.0 ? 1.0 : cc);
            double th = acos(cc), spread = SPOT_GATE_MARGIN * L[L_COND] * asin(radius / dcc);
            double ch = L[L_COSHALF], bl = L[L_BLEND];
            double th_out = acos(ch), cin = ch + (1.0 - ch) * bl;
            double th_in = bl > 0.0 ? acos(cin < 1.0 ? cin : 1.0) : th_out;
            if (th - spread > th_out || th + spread < th_in) n_pts = 1;
        }
        double rmin = 1e-4, esum = 0.0, dsum[3] = {0, 0, 0}, lsum = 0.0;
        /* 1 - cos theta_max of the disc's cone, without cancellation for r << d */
        double hyp = sqrt(dcc * dcc + radius * radius);
        double omc_max = radius > 0.0 ? radius * radius / (hyp * (hyp + dcc)) : 0.0;
        double e_disc = radius > 0.0 ? 2.0 * omc_max / (radius * radius) : 0.0;
        for (int i = 0; i < n_pts; i++) {
            if (i > 0) {
                double ua = u1 + (double)i / (double)SPOT_DISC_POINTS, ub = (double)i * SPOT_DISC_PHI;
                ub = u2 + (ub - floor(ub));
                if (ua >= 1.0) ua -= 1.0;
                if (ub >= 1.0) ub -= 1.0;
                disc_map(ua, ub, 1, &pa, &pb);
            }
            double di[3], den, dist;  /* the irradiance per unit intensity is att / den */
            if (radius > 0.0) {
                /* Cycles' soft-falloff lamp: a disc of radius r facing x with radiance
                 * I / (pi r^2); the disc subtends the cone of half-angle atan(r / d) about wc,
                 * irradiance I / (pi r^2) * 2 pi (1 - cos theta_max), exact also inside r.
                 * The disc point (pa, pb) maps to a direction uniform in that solid angle. */
                double s = pa * pa + pb * pb, omc = s * omc_max;
                double cos_t = 1.0 - omc, sin_t = sqrt(omc * (2.0 - omc) > 0.0 ? omc * (2.0 - omc) : 0.0);
                double rs = s > 0.0 ? sin_t / sqrt(s) : 0.0;
                for (int a = 0; a < 3; a++) di[a] = -(wc[a] * cos_t + (t1[a] * pa + t2[a] * pb) * rs);
                den = 1.0 / e_disc;
                dist = dcc / (cos_t > 1e-12 ? cos_t : 1e-12);  /* to the disc along di */
            } else {
                double v[3] = {x[0] - c[0], x[1] - c[1], x[2] - c[2]};
                dist = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
                double id = 1.0 / (dist > 1e-30 ? dist : 1e-30);
                for (int a = 0; a < 3; a++) di[a] = v[a] * id;
                den = dist * dist > rmin * rmin ? dist * dist : rmin * rmin;
            }
            if (i == 0)
                for (int a = 0; a < 3; a++) d[a] = di[a];
            double att = 1.0;
            if (kind == KIND_SPOT) {
                double cos_t = spot_cos(L, di);
                double ch = L[L_COSHALF], bl = L[L_BLEND];
                if (bl <= 0.0) att = cos_t > ch ? 1.0 : 0.0;
                else {
                    double q = (cos_t - ch) / ((1.0 - ch) * bl);
                    q = q < 0.0 ? 0.0 : (q > 1.0 ? 1.0 : q);
                    att = q * q * (3.0 - 2.0 * q);
                }
            }
            esum += att / den;
            lsum += att / den * dist;
            for (int a = 0; a < 3; a++) dsum[a] += att / den * di[a];
        }
        *ds = (radius > 0.0 && esum > 0.0) ? lsum / esum : dcc;
        /* the direction: the irradiance-weighted mean over the points, so that the phase
         * function sees the light from the part of the disc that lights x */
        double dn = sqrt(dsum[0] * dsum[0] + dsum[1] * dsum[1] + dsum[2] * dsum[2]);
        if (n_pts > 1 && dn > 0.0)
            for (int a = 0; a < 3; a++) d[a] = dsum[a] / dn;
        for (int a = 0; a < 3; a++) e[a] = L[L_STRENGTH + a] / (4.0 * M_PI) * (esum / (double)n_pts);
        return;
    }
    /* AREA */
    double src[3], v[3];
    for (int a = 0; a < 3; a++) src[a] = c[a] + L[L_AX + a] * pa + L[L_AY + a] * pb;
    for (int a = 0; a < 3; a++) v[a] = x[a] - src[a];
    double dist2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    if (!(dist2 > 1e-8)) dist2 = 1e-8;
    double dist = sqrt(dist2);
    *ds = dist;
    for (int a = 0; a < 3; a++) d[a] = v[a] / dist;
    double cos_l = d[0] * L[L_NORMAL] + d[1] * L[L_NORMAL + 1] + d[2] * L[L_NORMAL + 2];
    if (cos_l < 0.0) cos_l = 0.0;
    double area = L[L_AREA];
    double norm = (L[L_NORMALIZE] > 0 && area > 0) ? area : 1.0;
    for (int a = 0; a < 3; a++) e[a] = L[L_STRENGTH + a] / M_PI / norm * (cos_l * area / dist2);
}

/* The optical depth to an emitting point at distance ds, from the field's depth to the light's
 * centre at distance dc: the centre's path's mean extinction times the emitting point's path
 * length, ds / dc (exact in a homogeneous medium).  Near the centre the field's trilinear
 * depth stands for at least half a voxel's path, so dc is taken as at least that. */
static inline double path_stretch(double ds, double dc, double voxel) {
    double lo = 0.5 * voxel;
    return ds / (dc > lo ? dc : lo);
}

static inline double hg_phase(double c, double g) {
    double denom = 1.0 + g * g - 2.0 * g * c;
    if (denom < 1e-12) denom = 1e-12;
    return (1.0 - g * g) / (4.0 * M_PI * denom * sqrt(denom));
}

static void refined_tau(const Grid *f, int nm, int mi, int c, const double x[3], const double w[3],
                        double dist, double delta, double tau[3]) {
    double end[3] = {x[0], x[1], x[2]};
    tau[0] = tau[1] = tau[2] = 0.0;
    for (int k = 1; k <= REFINE_STEPS; k++) {
        double seg = dist - (k - 1) * delta;
        seg = seg < 0.0 ? 0.0 : (seg > delta ? delta : seg);
        double s_mid = (k - 1) * delta + 0.5 * seg, s_end = (k - 1) * delta + seg, mid[3];
        for (int a = 0; a < 3; a++) { mid[a] = x[a] + w[a] * s_mid; end[a] = x[a] + w[a] * s_end; }
        for (int m = 0; m < nm; m++) {
            double rho = density_from(&f[m], fetch0(&f[m], mid));
            for (int a = 0; a < 3; a++) tau[a] += rho * seg * f[m].sig[a];
        }
        double occ = fetch0(&f[mi], end);
        if (occ <= EDGE_EPS || occ >= 1.0 - EDGE_EPS || seg < delta) break;
    }
    double idx[3], v[3];
    to_index(&f[mi], end, idx);
    trilinear(&f[mi], idx, c, 3, v);
    for (int a = 0; a < 3; a++) tau[a] += v[a];
}


/* ---- multiple scattering (twin of kernels_np.multiple_source) ---- */
#define MAX_LEVELS 16
typedef struct {
    int first[MAX_MEDIA][MAX_LIGHTS];   /* index of level 0 in `lv`, or -1 */
    int nlev[MAX_MEDIA][MAX_LIGHTS];
    double stride[MAX_MEDIA][MAX_LIGHTS], h[MAX_MEDIA][MAX_LIGHTS];
    const double *tab[MAX_MEDIA];       /* per medium (K, nr, 6): weight R,G,B, anisotropy R,G,B */
    int tabk[MAX_MEDIA];
    Py_ssize_t nr;
    double lr0, dlr;                    /* log density of table entry 0, spacing */
    int amb;                            /* world-light multiple channel or -1 */
} MS;

static void multiple_source_c(const MS *ms, const Grid *lv, int m, int nl, const double *cosl,
                              double rho, const double x[3], const double *w2i, double out[3]) {
    double idx_w[3];
    for (int r = 0; r < 3; r++)
        idx_w[r] = w2i[4 * r] * x[0] + w2i[4 * r + 1] * x[1] + w2i[4 * r + 2] * x[2] + w2i[4 * r + 3];
    out[0] = out[1] = out[2] = 0.0;
    double f = (log(rho > 1e-300 ? rho : 1e-300) - ms->lr0) / ms->dlr;
    double fmax = (double)(ms->nr - 1);
    f = f < 0.0 ? 0.0 : (f > fmax ? fmax : f);
    Py_ssize_t i = (Py_ssize_t)floor(f);
    if (i > ms->nr - 2) i = ms->nr - 2;
    double t = f - (double)i;
    const double *tab = ms->tab[m];
    for (int l = 0; l < nl; l++) {
        int f0 = ms->first[m][l], K = ms->nlev[m][l];
        if (f0 < 0 || K <= 0) continue;
        if (K > ms->tabk[m]) K = ms->tabk[m];
        double stride = ms->stride[m][l];
        for (int k = 0; k < K; k++) {
            const double *e0 = tab + ((Py_ssize_t)k * ms->nr + i) * 6, *e1 = e0 + 6;
            double scale = stride * ldexp(1.0, k), idx[3], q[3];
            for (int a = 0; a < 3; a++) idx[a] = idx_w[a] / scale;
            if (trilinear(&lv[f0 + k], idx, 0, 3, q)) {
                double phase = 0.0, g_prev = 0.0;
                for (int a = 0; a < 3; a++) {  /* by channel; one phase when they agree */
                    double gk = e0[3 + a] * (1.0 - t) + e1[3 + a] * t;
                    if (a == 0 || gk != g_prev) phase = hg_phase(cosl[l], gk);
                    g_prev = gk;
                    double weight = e0[a] * (1.0 - t) + e1[a] * t;
                    out[a] += q[a] * (weight * phase);
                }
            }
        }
    }
}

#define LIGHT_VARIATION 0.2  /* kernels_np.LIGHT_VARIATION */

/* Whether the light a lit local light scatters towards the camera (its irradiance at its
 * centre, before the media, times the phase function of anisotropy g) differs by more than
 * LIGHT_VARIATION between the ends of the segment [s_a, s_b] of the ray o + s d: a spot's cone
 * edge, a nearby light or a forward-scattering lobe, whose shape longer steps would miss.
 * Twin of kernels_np.light_varies. */
static int light_varies(const double *LR, Py_ssize_t nl, const int *chan, const double o[3],
                        const double d[3], double s_a, double s_b, double g) {
    double xa[3], xb[3], wi[3], e[3], wc[3], dc, ds;
    for (int q = 0; q < 3; q++) { xa[q] = o[q] + d[q] * s_a; xb[q] = o[q] + d[q] * s_b; }
    for (Py_ssize_t l = 0; l < nl; l++) {
        if (chan[l] < 0 || (int)LR[l * LIGHT_FIELDS + L_KIND] == KIND_SUN) continue;
        light_sample(LR + l * LIGHT_FIELDS, xa, 0.5, 0.5, wi, e, wc, &dc, &ds);
        double ea = (e[0] + e[1] + e[2]) * hg_phase(-(wi[0] * d[0] + wi[1] * d[1] + wi[2] * d[2]), g);
        light_sample(LR + l * LIGHT_FIELDS, xb, 0.5, 0.5, wi, e, wc, &dc, &ds);
        double eb = (e[0] + e[1] + e[2]) * hg_phase(-(wi[0] * d[0] + wi[1] * d[1] + wi[2] * d[2]), g);
        double hi = ea > eb ? ea : eb, lo = ea > eb ? eb : ea;
        if (hi > 0.0 && !(lo >= (1.0 - LIGHT_VARIATION) * hi)) return 1;
    }
    return 0;
}

static int parse_doubles(PyObject *list, Py_ssize_t n, double *out, const char *what) {
    if (!PyList_Check(list) || PyList_GET_SIZE(list) != n) {
        PyErr_Format(PyExc_ValueError, "%s: expected a list of %zd numbers", what, n);
        return -1;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        out[i] = PyFloat_AsDouble(PyList_GET_ITEM(list, i));
        if (out[i] == -1.0 && PyErr_Occurred()) return -1;
    }
    return 0;
}

static const char march_doc[] =
    "march(origins, dirs, t0, t1, axial, keys, fields, w2is, sigma_ss, sigma_ts, gs, thresholds,\n"
    "      voxels, lights, ambient, step, depth_opacity, depth_miss[, multiple, emissions, bricks, brick,\n"
    "      adapt_tau, emission_channels])\n"
    "  -> (single, T, depth, multiple, steps, emission) as bytes of float64\n"
    "Twin of kernels_np.march.";

static PyObject *march(PyObject *self, PyObject *args) {
    PyObject *po, *pd, *pt0, *pt1, *pax, *pk, *fields, *w2is, *sss, *sts, *gsl, *thrs, *vox, *plights;
    PyObject *pms = Py_None, *pem = Py_None, *pbk = Py_None, *pec = Py_None;
    int ambient, brick = 4;
    double step, depth_opacity, depth_miss, adapt_tau = 0.0;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOOOiddd|OOOidO", &po, &pd, &pt0, &pt1, &pax, &pk, &fields,
                          &w2is, &sss, &sts, &gsl, &thrs, &vox, &plights, &ambient, &step,
                          &depth_opacity, &depth_miss, &pms, &pem, &pbk, &brick, &adapt_tau, &pec))
        return NULL;
    if (!isfinite(adapt_tau)) {
        PyErr_SetString(PyExc_ValueError, "adapt_tau must be finite");
        return NULL;
    }
    if (!(step > 0.0) || !isfinite(step)) {
        PyErr_SetString(PyExc_ValueError, "step must be a positive finite length");
        return NULL;
    }
    Buf bo = {0}, bd = {0}, b0 = {0}, b1 = {0}, bax = {0}, bk = {0}, bl = {0}, gb[MAX_MEDIA];
    Buf btab = {0}, btabs[MAX_MEDIA], kb[MAX_MEDIA];
    Bricks bks[MAX_MEDIA];
    int ntabs = 0, nkb = 0;
    Buf *lvb = NULL;
    Grid *lv = NULL;
    int nlv = 0, use_ms = 0;
    MS ms;
    memset(&ms, 0, sizeof ms);
    Grid g[MAX_MEDIA];
    double sig_s[MAX_MEDIA][3], gg[MAX_MEDIA], voxel[MAX_MEDIA], emit[MAX_MEDIA][3];
    int emc[MAX_MEDIA];  /* first channel of each medium's emission grid, or -1 */
    int use_em = 0;
    int ng = 0;
    PyObject *o_s = NULL, *o_t = NULL, *o_d = NULL, *o_m = NULL, *o_k = NULL, *o_e = NULL, *result = NULL;
    Py_ssize_t s_o[2] = {-1, 3};
    if (get_buf(po, &bo, 'd', 2, s_o, "origins") < 0) goto done;
    Py_ssize_t n = s_o[0];
    Py_ssize_t s_d[2] = {n, 3}, s_n[1] = {n}, s_n2[1] = {n}, s_n3[1] = {n}, s_n4[1] = {n};
    if (get_buf(pd, &bd, 'd', 2, s_d, "dirs") < 0) goto done;
    if (get_buf(pt0, &b0, 'd', 1, s_n, "t0") < 0) goto done;
    if (get_buf(pt1, &b1, 'd', 1, s_n2, "t1") < 0) goto done;
    if (get_buf(pax, &bax, 'd', 1, s_n3, "axial") < 0) goto done;
    if (get_buf(pk, &bk, 'I', 1, s_n4, "keys") < 0) goto done;
    if (parse_grids(fields, w2is, sts, thrs, g, gb, &ng, 1) < 0) goto done;
    if (parse_bricks(pbk, brick, g, ng, bks, kb, &nkb) < 0) goto done;
    int skip = pbk != Py_None;
    if (!PyList_Check(sss) || PyList_GET_SIZE(sss) != ng) {
        PyErr_SetString(PyExc_ValueError, "sigma_ss: one RGB array per medium");
        goto done;
    }
    for (int m = 0; m < ng; m++) {
        Buf sb;
        Py_ssize_t s3[1] = {3};
        if (get_buf(PyList_GET_ITEM(sss, m), &sb, 'd', 1, s3, "sigma_s") < 0) goto done;
        memcpy(sig_s[m], sb.view.buf, 3 * sizeof(double));
        buf_release(&sb);
        if (g[m].nc > MAX_CH) {
            PyErr_SetString(PyExc_ValueError, "fields: too many channels");
            goto done;
        }
    }
    if (parse_doubles(gsl, ng, gg, "gs") < 0 || parse_doubles(vox, ng, voxel, "voxels") < 0) goto done;
    if (pem != Py_None) {
        if (!PyList_Check(pem) || PyList_GET_SIZE(pem) != ng) {
            PyErr_SetString(PyExc_ValueError, "emissions: one RGB array per medium");
            goto done;
        }
        for (int m = 0; m < ng; m++) {
            Buf eb;
            Py_ssize_t s3[1] = {3};
            if (get_buf(PyList_GET_ITEM(pem, m), &eb, 'd', 1, s3, "emission") < 0) goto done;
            memcpy(emit[m], eb.view.buf, 3 * sizeof(double));
            buf_release(&eb);
            for (int a = 0; a < 3; a++)
                if (!isfinite(emit[m][a])) {
                    PyErr_SetString(PyExc_ValueError, "emission: non-finite value");
                    goto done;
                }
        }
        use_em = 1;
    }
    for (int m = 0; m < ng; m++) emc[m] = -1;
    if (pec != Py_None) {
        if (!PyList_Check(pec) || PyList_GET_SIZE(pec) != ng) {
            PyErr_SetString(PyExc_ValueError, "emission_channels: one int per medium");
            goto done;
        }
        for (int m = 0; m < ng; m++) {
            long c = PyLong_AsLong(PyList_GET_ITEM(pec, m));
            if (c == -1 && PyErr_Occurred()) goto done;
            if (c >= 0 && (c < 1 || c + 3 > g[m].nc)) {
                PyErr_SetString(PyExc_ValueError, "emission_channels: channel outside the fields");
                goto done;
            }
            emc[m] = c < 0 ? -1 : (int)c;
        }
    }
    for (int m = 0; m < ng; m++) {
        if (!(gg[m] > -1.0 && gg[m] < 1.0) || !(voxel[m] > 0.0) || !isfinite(voxel[m])) {
            PyErr_SetString(PyExc_ValueError, "gs must lie in (-1, 1) and voxels be positive");
            goto done;
        }
    }
    Py_ssize_t s_l[2] = {-1, LIGHT_FIELDS};
    if (get_buf(plights, &bl, 'd', 2, s_l, "lights") < 0) goto done;
    Py_ssize_t nl = s_l[0];
    if (nl > MAX_LIGHTS) {
        PyErr_SetString(PyExc_ValueError, "lights: at most 64 per call");
        goto done;
    }
    const double *LR = (const double *)bl.view.buf;
    int chan[MAX_LIGHTS], beam[MAX_LIGHTS], indirect[MAX_LIGHTS];
    for (Py_ssize_t l = 0; l < nl; l++) {
        double cf = LR[l * LIGHT_FIELDS + L_CHANNEL], kf = LR[l * LIGHT_FIELDS + L_KIND];
        indirect[l] = LR[l * LIGHT_FIELDS + L_INDIRECT] > 0.5;
        double bf = LR[l * LIGHT_FIELDS + L_BEAM];
        beam[l] = (cf >= 0 && bf >= 1.0 && bf < 1e9) ? (int)bf : -1;
        for (int m = 0; m < ng; m++)
            if (beam[l] >= 0 && beam[l] + 3 > g[m].nc) {
                PyErr_SetString(PyExc_ValueError, "lights: beam channel outside the fields");
                goto done;
            }
        if (!(kf == 0 || kf == 1 || kf == 2 || kf == 3)) {
            PyErr_SetString(PyExc_ValueError, "lights: unknown kind");
            goto done;
        }
        chan[l] = cf < 0 ? -1 : (int)cf;
        for (int m = 0; m < ng; m++)
            if (chan[l] >= 0 && (chan[l] < 1 || chan[l] + 3 > g[m].nc)) {
                PyErr_SetString(PyExc_ValueError, "lights: channel outside the fields");
                goto done;
            }
    }
    for (int m = 0; m < ng; m++)
        if (ambient >= 0 && (ambient < 1 || ambient + 3 > g[m].nc)) {
            PyErr_SetString(PyExc_ValueError, "ambient channel outside the fields");
            goto done;
        }
    if (pms != Py_None) {
        /* (amb_ms, levels list, table (M, L, 4) [first, count, stride, h],
         *  per-medium level tables [(K, nr, 6)], log density of entry 0, spacing) */
        PyObject *plv, *ptab, *ptabs;
        int amb_ms;
        double lr0, dlr;
        if (!PyTuple_Check(pms) || !PyArg_ParseTuple(pms, "iOOOdd", &amb_ms, &plv, &ptab, &ptabs, &lr0, &dlr)) {
            PyErr_SetString(PyExc_ValueError, "multiple: expected (amb, levels, table, tables, lr0, dlr)");
            goto done;
        }
        if (!PyList_Check(plv) || PyList_GET_SIZE(plv) > 100000) {
            PyErr_SetString(PyExc_ValueError, "multiple: levels must be a list");
            goto done;
        }
        if (!PyList_Check(ptabs) || PyList_GET_SIZE(ptabs) != ng || !(dlr > 0.0) || !isfinite(lr0) ||
            !isfinite(dlr)) {
            PyErr_SetString(PyExc_ValueError, "multiple: one level table per medium, dlr > 0");
            goto done;
        }
        nlv = (int)PyList_GET_SIZE(plv);
        lvb = (Buf *)calloc((size_t)(nlv > 0 ? nlv : 1), sizeof(Buf));
        lv = (Grid *)calloc((size_t)(nlv > 0 ? nlv : 1), sizeof(Grid));
        if (!lvb || !lv) { PyErr_NoMemory(); goto done; }
        for (int i = 0; i < nlv; i++) {
            Py_ssize_t sh[4] = {-1, -1, -1, 3};
            if (get_buf(PyList_GET_ITEM(plv, i), &lvb[i], 'f', 4, sh, "pyramid level") < 0) goto done;
            if (sh[0] < 2 || sh[1] < 2 || sh[2] < 2) {
                PyErr_SetString(PyExc_ValueError, "pyramid level: every extent must be >= 2");
                goto done;
            }
            lv[i].data = (const float *)lvb[i].view.buf;
            lv[i].nx = sh[0]; lv[i].ny = sh[1]; lv[i].nz = sh[2]; lv[i].nc = 3;
            lv[i].thr = -1.0;
        }
        Py_ssize_t nr = -1;
        for (int m = 0; m < ng; m++) {
            Py_ssize_t st[3] = {-1, nr, 6};
            if (get_buf(PyList_GET_ITEM(ptabs, m), &btabs[m], 'd', 3, st, "level table") < 0) goto done;
            ntabs = m + 1;
            if (st[0] < 1 || st[0] > MAX_LEVELS || st[1] < 2) {
                PyErr_SetString(PyExc_ValueError, "level table: 1..16 levels and >= 2 densities");
                goto done;
            }
            nr = st[1];
            ms.tab[m] = (const double *)btabs[m].view.buf;
            ms.tabk[m] = (int)st[0];
        }
        ms.nr = nr;
        ms.lr0 = lr0;
        ms.dlr = dlr;
        Py_ssize_t s_tab[3] = {ng, nl, 4};
        if (get_buf(ptab, &btab, 'd', 3, s_tab, "multiple table") < 0) goto done;
        const double *T = (const double *)btab.view.buf;
        for (int m = 0; m < ng; m++)
            for (Py_ssize_t l = 0; l < nl; l++) {
                const double *r = T + ((Py_ssize_t)m * nl + l) * 4;
                int first = (int)r[0], cnt = (int)r[1];
                if (!(r[1] >= 1.0) || !(r[0] >= 0.0)) { ms.first[m][l] = -1; ms.nlev[m][l] = 0; continue; }
                if (cnt > MAX_LEVELS || first > nlv - cnt || !(r[2] >= 1.0) || !(r[2] < 1e9) ||
                    !(r[3] > 0.0) || !isfinite(r[3])) {
                    PyErr_SetString(PyExc_ValueError, "multiple table: bad level range, stride or h");
                    goto done;
                }
                ms.first[m][l] = first; ms.nlev[m][l] = cnt;
                ms.stride[m][l] = r[2]; ms.h[m][l] = r[3];
            }
        for (int m = 0; m < ng; m++)
            if (amb_ms >= 0 && (amb_ms < 1 || amb_ms + 3 > g[m].nc)) {
                PyErr_SetString(PyExc_ValueError, "ambient multiple channel outside the fields");
                goto done;
            }
        ms.amb = amb_ms;
        use_ms = 1;
    }
    o_s = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * 3 * sizeof(double)));
    o_t = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * 3 * sizeof(double)));
    o_d = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * sizeof(double)));
    o_m = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * 3 * sizeof(double)));
    o_k = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * sizeof(double)));
    o_e = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * 3 * sizeof(double)));
    if (!o_s || !o_t || !o_d || !o_m || !o_k || !o_e) goto done;
    double *OK = (double *)PyByteArray_AS_STRING(o_k), *OE = (double *)PyByteArray_AS_STRING(o_e);
    double *OM = (double *)PyByteArray_AS_STRING(o_m);
    double *OS = (double *)PyByteArray_AS_STRING(o_s), *OT = (double *)PyByteArray_AS_STRING(o_t),
           *OD = (double *)PyByteArray_AS_STRING(o_d);
    const double *O = (const double *)bo.view.buf, *D = (const double *)bd.view.buf,
                 *T0 = (const double *)b0.view.buf, *T1 = (const double *)b1.view.buf,
                 *AX = (const double *)bax.view.buf;
    const uint32_t *K = (const uint32_t *)bk.view.buf;
    const double thr_op = 1.0 - depth_opacity;
    double g_lobe = 0.0;  /* the most anisotropic medium's g (light_varies) */
    for (int m = 0; m < ng; m++) if (fabs(gg[m]) > fabs(g_lobe)) g_lobe = gg[m];
    double sig_max[MAX_MEDIA];  /* largest extinction per unit density, over the channels */
    for (int m = 0; m < ng; m++) {
        sig_max[m] = g[m].sig[0] > g[m].sig[1] ? g[m].sig[0] : g[m].sig[1];
        sig_max[m] = sig_max[m] > g[m].sig[2] ? sig_max[m] : g[m].sig[2];
        if (!(sig_max[m] > 0.0)) sig_max[m] = 1.0;  /* a medium that only scatters nothing still counts */
    }
    /* lights whose sample does not depend on the random pair (a sun, a point or spot without
     * radius) draw none */
    int jitter[MAX_LIGHTS];
    for (Py_ssize_t l = 0; l < nl; l++) {
        const double *L = LR + l * LIGHT_FIELDS;
        int kind = (int)L[L_KIND];
        jitter[l] = kind == KIND_AREA || ((kind == KIND_POINT || kind == KIND_SPOT) && L[L_RADIUS] > 0.0);
    }
    /* longer steps in thin media only where every lit light is sampled without jitter: the
     * jittered ones (area, sphere) average their shape over the steps' samples */
    int adapt = adapt_tau > 0.0;
    for (Py_ssize_t l = 0; l < nl; l++)
        if (chan[l] >= 0 && jitter[l]) adapt = 0;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t r = 0; r < n; r++) {
        const double *o = O + 3 * r, *d = D + 3 * r;
        double T[3] = {1, 1, 1}, S[3] = {0, 0, 0}, M3[3] = {0, 0, 0}, E3[3] = {0, 0, 0};
        double depth = depth_miss;
        double t0 = T0[r], t1 = T1[r];
        uint32_t key = K[r];
        /* Super-step K covers [t0 + SUPER K step, t0 + SUPER (K + 1) step] (the last one ends at
         * t1) and is cut into n_sub equal steps, each read at one jittered point: n_sub = SUPER
         * without bricks; with bricks, 0 where every medium is empty and, with adapt_tau > 0,
         * the fewest (at least 1) that keep the majorant's optical depth per step <= adapt_tau. */
        long taken = 0, K = 0;
        int done = 0;
        double lo[MAX_MEDIA][3], lvv[MAX_MEDIA][3];
        if (skip)
            for (int m = 0; m < ng; m++) ray_to_index(&g[m], o, d, lo[m], lvv[m]);
        while (!done && K < MAX_STEPS / SUPER) {
            double s_lo = t0 + (double)(SUPER * K) * step;
            if (!(s_lo < t1)) break;
            double s_hi = t0 + (double)(SUPER * (K + 1)) * step;
            s_hi = s_hi < t1 ? s_hi : t1;
            int n_sub = SUPER;
            if (skip) {
                double maj = 0.0;
                int sharp = 0;  /* a mesh volume's surface must keep the steps short */
                for (int m = 0; m < ng; m++) {
                    double mm = segment_majorant(&g[m], &bks[m], lo[m], lvv[m], s_lo, s_hi);
                    maj += mm * sig_max[m];
                    sharp |= g[m].thr >= 0.0 && mm > 0.0;
                }
                if (!(maj > 0.0)) { K++; continue; }  /* wholly empty: nothing to add */
                if (adapt && !sharp) {
                    double want = ceil(maj * (s_hi - s_lo) / adapt_tau);
                    n_sub = want < 1.0 ? 1 : (want > (double)SUPER ? SUPER : (int)want);
                    if (n_sub < SUPER && light_varies(LR, nl, chan, o, d, s_lo, s_hi, g_lobe)) n_sub = SUPER;
                }
            }
            double H = (double)SUPER * step / (double)n_sub;
            for (int jj = 0; jj < n_sub; jj++) {
                long k = SUPER * K + jj;
                double seg = s_lo + (double)jj * H;
                if (!(seg < t1)) break;
                double hl = t1 - seg < H ? t1 - seg : H;
                double t = seg + uniform01(key, k, DIM_JITTER) * H;
                double ts = t < seg + hl ? t : seg + hl, x[3];
                for (int q = 0; q < 3; q++) x[q] = o[q] + d[q] * ts;
                double wi[MAX_LIGHTS][3], e[MAX_LIGHTS][3], wc[MAX_LIGHTS][3], dc[MAX_LIGHTS], ds[MAX_LIGHTS];
                for (Py_ssize_t l = 0; l < nl; l++) {
                    double u1 = 0.5, u2 = 0.5;
                    if (jitter[l]) { u1 = uniform01(key, k, 2 * l); u2 = uniform01(key, k, 2 * l + 1); }
                    light_sample(LR + l * LIGHT_FIELDS, x, u1, u2, wi[l], e[l], wc[l], &dc[l], &ds[l]);
                }
                double sig_t[3] = {0, 0, 0}, src[3] = {0, 0, 0}, src_ms[3] = {0, 0, 0}, src_em[3] = {0, 0, 0};
                for (int m = 0; m < ng; m++) {
                    double idx[3], v[MAX_CH];
                    to_index(&g[m], x, idx);
                    Tri tw;
                    if (!tri_setup(&g[m], idx, &tw)) continue;
                    if (emc[m] >= 0) {  /* an emission grid shines whatever the density */
                        double ev[3];
                        tri_get(&tw, emc[m], 3, ev);
                        for (int a = 0; a < 3; a++) src_em[a] += ev[a];
                    }
                    double rho = density_from(&g[m], tri_get1(&tw, 0));  /* the density first */
                    if (!(rho > 0.0)) continue;
                    tri_get(&tw, 0, (int)g[m].nc, v);
                    for (int a = 0; a < 3; a++) sig_t[a] += rho * g[m].sig[a];
                    if (use_em)
                        for (int a = 0; a < 3; a++) src_em[a] += emit[m][a];
                    int edge = g[m].thr >= 0.0 && v[0] > EDGE_EPS && v[0] < 1.0 - EDGE_EPS;
                    double inc[3] = {0, 0, 0}, beam_inc[3] = {0, 0, 0}, ind_inc[3] = {0, 0, 0};
                    for (Py_ssize_t l = 0; l < nl; l++) {
                        int c = chan[l];
                        if (c < 0) continue;
                        double tau[3] = {v[c], v[c + 1], v[c + 2]};
                        if (edge) refined_tau(g, ng, m, c, x, wc[l], dc[l], 0.5 * voxel[m], tau);
                        if (ds[l] != dc[l])  /* light from an emitter point off the centre */
                            for (int a = 0; a < 3; a++) tau[a] *= path_stretch(ds[l], dc[l], voxel[m]);
                        int cb = use_ms ? beam[l] : -1;
                        double cs = -(wi[l][0] * d[0] + wi[l][1] * d[1] + wi[l][2] * d[2]);
                        double p = hg_phase(cs, gg[m]);
                        exp3(tau, tau);
                        double *to = indirect[l] ? ind_inc : inc;  /* a bounce's light: multiple */
                        for (int a = 0; a < 3; a++) to[a] += p * e[l][a] * tau[a];
                        if (cb >= 0)  /* the forward peak's light (precompute.peak_light) */
                            for (int a = 0; a < 3; a++)
                                beam_inc[a] += p * (v[cb + a] > 0.0 ? v[cb + a] : 0.0);
                    }
                    if (ambient >= 0)
                        for (int a = 0; a < 3; a++) inc[a] += v[ambient + a];
                    for (int a = 0; a < 3; a++) src[a] += rho * sig_s[m][a] * inc[a];
                    for (int a = 0; a < 3; a++) src_ms[a] += rho * sig_s[m][a] * ind_inc[a];
                    if (use_ms) {
                        double cosl[MAX_LIGHTS], msi[3];
                        for (Py_ssize_t l = 0; l < nl; l++)
                            cosl[l] = -(wi[l][0] * d[0] + wi[l][1] * d[1] + wi[l][2] * d[2]);
                        multiple_source_c(&ms, lv, m, (int)nl, cosl, rho, x, g[m].w2i, msi);
                        if (ms.amb >= 0)
                            for (int a = 0; a < 3; a++) msi[a] += v[ms.amb + a];
                        for (int a = 0; a < 3; a++) src_ms[a] += rho * sig_s[m][a] * (msi[a] + beam_inc[a]);
                    }
                }
                taken++;
                double Tb[3] = {T[0], T[1], T[2]}, xt[3], att[3];
                for (int a = 0; a < 3; a++) xt[a] = sig_t[a] * hl;
                exp3(xt, att);
                int grey = xt[0] == xt[1] && xt[1] == xt[2];
                double frac0 = xt[0] > 1e-7 ? -expm1(-xt[0]) / xt[0] : 1.0 - 0.5 * xt[0];
                for (int a = 0; a < 3; a++) {
                    double frac = grey ? frac0 : (xt[a] > 1e-7 ? -expm1(-xt[a]) / xt[a] : 1.0 - 0.5 * xt[a]);
                    S[a] += Tb[a] * src[a] * (frac * hl);
                    M3[a] += Tb[a] * src_ms[a] * (frac * hl);
                    E3[a] += Tb[a] * src_em[a] * (frac * hl);
                    T[a] = Tb[a] * att[a];
                }
                double tb = (Tb[0] + Tb[1] + Tb[2]) / 3.0, ta = (T[0] + T[1] + T[2]) / 3.0;
                if (depth >= depth_miss && ta <= thr_op && tb > thr_op) {
                    double fr = log(tb / thr_op) / log(tb / (ta > 1e-300 ? ta : 1e-300));
                    fr = fr < 0.0 ? 0.0 : (fr > 1.0 ? 1.0 : fr);
                    depth = (seg + fr * hl) * AX[r];
                }
                double tmax = T[0] > T[1] ? T[0] : T[1];
                tmax = tmax > T[2] ? tmax : T[2];
                /* opaque enough, or a step that no longer advances t: stop */
                if (!(tmax > T_MIN) || !(seg + H > seg)) { done = 1; break; }
            }
            K++;
        }
        for (int a = 0; a < 3; a++) { OS[3 * r + a] = S[a]; OT[3 * r + a] = T[a]; OM[3 * r + a] = M3[a]; }
        OK[r] = (double)taken;
        for (int a = 0; a < 3; a++) OE[3 * r + a] = E3[a];
        OD[r] = depth;
    }
    Py_END_ALLOW_THREADS
    result = PyTuple_Pack(6, o_s, o_t, o_d, o_m, o_k, o_e);
done:
    Py_XDECREF(o_s); Py_XDECREF(o_t); Py_XDECREF(o_d); Py_XDECREF(o_m); Py_XDECREF(o_k);
    Py_XDECREF(o_e);
    buf_release(&btab);
    for (int m = 0; m < ntabs; m++) buf_release(&btabs[m]);
    if (lvb) for (int i = 0; i < nlv; i++) buf_release(&lvb[i]);
    free(lvb); free(lv);
    buf_release(&bo); buf_release(&bd); buf_release(&b0); buf_release(&b1); buf_release(&bax);
    buf_release(&bk); buf_release(&bl);
    for (int m = 0; m < ng; m++) buf_release(&gb[m]);
    for (int m = 0; m < nkb; m++) buf_release(&kb[m]);
    return result;
}

/* ------------------------------------------------------------------------------------------
 * Trilinear interpolation at many points (twin of media.trilinear).
 */
static const char trilinear_doc[] =
    "trilinear(grid, idx) -> bytes\n"
    "Twin of media.trilinear: grid (X,Y,Z,C) float32, idx (N,3) float64 index coordinates;\n"
    "(N,C) float64 as bytes: the trilinear value where 0 <= idx < extent - 1 on every axis,\n"
    "0 elsewhere (also for non-finite coordinates).";

static PyObject *py_trilinear(PyObject *self, PyObject *args) {
    PyObject *pg, *pi;
    if (!PyArg_ParseTuple(args, "OO", &pg, &pi)) return NULL;
    Buf bg = {0}, bi = {0};
    PyObject *result = NULL;
    Py_ssize_t sg[4] = {-1, -1, -1, -1}, si[2] = {-1, 3};
    if (get_buf(pg, &bg, 'f', 4, sg, "grid") < 0) goto done;
    if (get_buf(pi, &bi, 'd', 2, si, "idx") < 0) goto done;
    Py_ssize_t n = si[0], nc = sg[3];
    if (nc < 1 || nc > INT32_MAX || (n > 0 && nc > PY_SSIZE_T_MAX / (Py_ssize_t)sizeof(double) / n)) {
        PyErr_SetString(PyExc_ValueError, "trilinear: bad channel count");
        goto done;
    }
    result = PyBytes_FromStringAndSize(NULL, n * nc * (Py_ssize_t)sizeof(double));
    if (!result) goto done;
    {
        double *out = (double *)PyBytes_AS_STRING(result);
        const double *I = (const double *)bi.view.buf;
        Grid g;
        memset(&g, 0, sizeof g);
        g.data = (const float *)bg.view.buf;
        g.nx = sg[0]; g.ny = sg[1]; g.nz = sg[2]; g.nc = nc;
        g.thr = -1.0;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t q = 0; q < n; q++)  /* zeros outside [0, extent - 1) and for NaN */
            trilinear(&g, I + 3 * q, 0, (int)nc, out + q * nc);
        Py_END_ALLOW_THREADS
    }
done:
    buf_release(&bg); buf_release(&bi);
    return result;
}

static PyMethodDef methods[] = {
    {"march", march, METH_VARARGS, march_doc},
    {"optical_depth", optical_depth, METH_VARARGS, optical_depth_doc},
    {"light_sweep", light_sweep, METH_VARARGS, light_sweep_doc},
    {"upsample_into", upsample_into, METH_VARARGS, upsample_into_doc},
    {"trilinear", py_trilinear, METH_VARARGS, trilinear_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moduledef = {PyModuleDef_HEAD_INIT, "_kernels",
                                       "Compiled twins of mpp_render.kernels_np.", -1, methods,
                                       NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&moduledef); }
