/* Shared by every kernel: buffer checks, the grid record and its trilinear reads, the
 * bounds-checked index helpers and the counter-based random numbers.
 *
 * Every buffer from Python is checked for type, dimensionality, contiguity and size before
 * use (buffers.c), and every grid index is bounds-checked: a bad call raises ValueError, it
 * never reads out of bounds.  The loops run without the GIL.
 */
#ifndef MPP_COMMON_H
#define MPP_COMMON_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#if (defined(__SSE2__) || defined(_M_X64)) && !defined(MPP_NO_SIMD)
#define MPP_SIMD 1
/* SSE2: every x86-64 CPU has it (no -march flag; MSVC defines _M_X64).  MPP_NO_SIMD builds
 * the scalar code that other CPUs run, for checking it here. */
#include <emmintrin.h>
#else
#define MPP_SIMD 0
#endif

#define MAX_MEDIA 64
#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

typedef struct {
    Py_buffer view;
    int held;
} Buf;

/* buffers.c: acquire and release checked buffers, parse the per-medium lists */
void buf_release(Buf *b);
int get_buf_ex(PyObject *obj, Buf *b, char fmt, int ndim, Py_ssize_t *shape, const char *what,
               int extra);
int get_buf(PyObject *obj, Buf *b, char fmt, int ndim, Py_ssize_t *shape, const char *what);

typedef struct {
    const float *data;
    Py_ssize_t nx, ny, nz, nc;  /* nc: channels per voxel (last axis), 1 for a density grid */
    double w2i[12];             /* 3x4 world -> index */
    double sig[3];
    double thr;                 /* sharp-boundary threshold, < 0 for smooth grids */
    double last[3];             /* nx - 1, ny - 1, nz - 1: the last index per axis */
} Grid;

/* Sets grid g's shape (voxels per axis, channels per voxel) and what derives from it. */
static inline void grid_shape(Grid *g, Py_ssize_t nx, Py_ssize_t ny, Py_ssize_t nz, Py_ssize_t nc) {
    g->nx = nx; g->ny = ny; g->nz = nz; g->nc = nc;
    g->last[0] = (double)(nx - 1); g->last[1] = (double)(ny - 1); g->last[2] = (double)(nz - 1);
}

static inline double density_from(const Grid *g, double v) {
    return g->thr >= 0.0 ? (v >= g->thr ? 1.0 : 0.0) : v;
}

/* The corner (fx, fy, fz) = floor(idx) of the cell holding index coordinates idx: 1 when the
 * cell lies in grid g (0 <= idx < n - 1 per axis; NaN is outside).  Truncation is the floor
 * there, without a libm call. */
static inline int cell_floor(const double idx[3], const Grid *g, double *fx, double *fy, double *fz) {
    if (!(idx[0] >= 0.0 && idx[1] >= 0.0 && idx[2] >= 0.0 && idx[0] < g->last[0] &&
          idx[1] < g->last[1] && idx[2] < g->last[2]))
        return 0;
    *fx = (double)(Py_ssize_t)idx[0];
    *fy = (double)(Py_ssize_t)idx[1];
    *fz = (double)(Py_ssize_t)idx[2];
    return 1;
}

/* out[c] = sum over the 8 corners q, in order, of w[q] * p[off[q] + c], for c < n: each
 * channel's sum in double starting from 0, so the SSE2 path (two channels a lane pair, four
 * a load) gives the same bits as the scalar one.  Reads p[off[q] + c] for c < n only. */
static inline void corner_sums(const float *p, const Py_ssize_t off[8], const double w[8], int n,
                               double *out) {
    int c = 0;
#if MPP_SIMD
    for (; c + 4 <= n; c += 4) {
        __m128d lo = _mm_setzero_pd(), hi = _mm_setzero_pd();
        for (int q = 0; q < 8; q++) {
            __m128 f = _mm_loadu_ps(p + off[q] + c);
            __m128d wq = _mm_set1_pd(w[q]);
            lo = _mm_add_pd(lo, _mm_mul_pd(wq, _mm_cvtps_pd(f)));
            hi = _mm_add_pd(hi, _mm_mul_pd(wq, _mm_cvtps_pd(_mm_movehl_ps(f, f))));
        }
        _mm_storeu_pd(out + c, lo);
        _mm_storeu_pd(out + c + 2, hi);
    }
    for (; c + 2 <= n; c += 2) {
        __m128d acc = _mm_setzero_pd();
        for (int q = 0; q < 8; q++) {
            double two;   /* two floats, loaded as one 8-byte word wherever they lie */
            memcpy(&two, p + off[q] + c, sizeof two);
            __m128 f = _mm_castpd_ps(_mm_set_sd(two));
            acc = _mm_add_pd(acc, _mm_mul_pd(_mm_set1_pd(w[q]), _mm_cvtps_pd(f)));
        }
        _mm_storeu_pd(out + c, acc);
    }
#endif
    for (; c < n; c++) {
        double v = 0.0;
        for (int q = 0; q < 8; q++) v += w[q] * (double)p[off[q] + c];
        out[c] = v;
    }
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
    corner_sums(p, off, w, nc_out, out);
    return 1;
}

/* A trilinear stencil, set up once and read channel by channel; vox is the flat index of
 * its first corner's voxel (another grid of the same voxels reads there, tri_on). */
typedef struct {
    const float *p;
    Py_ssize_t off[8];
    double w[8];
    Py_ssize_t vox;
} Tri;

/* The stencil of grid g at index coordinates idx; 0 outside (zeros there). */
static inline int tri_setup(const Grid *g, const double idx[3], Tri *t) {
    double fx, fy, fz;
    if (!cell_floor(idx, g, &fx, &fy, &fz))
        return 0;
    double tx = idx[0] - fx, ty = idx[1] - fy, tz = idx[2] - fz;
    Py_ssize_t sz = g->nc, sy = g->nz * sz, sx = g->ny * sy;
    t->vox = ((Py_ssize_t)fx * g->ny + (Py_ssize_t)fy) * g->nz + (Py_ssize_t)fz;
    t->p = g->data + t->vox * sz;
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
    corner_sums(t->p + c0, t->off, t->w, n, out);
}

/* The n channels of grid `on`, which has the voxels of the grid that set up t and n channels
 * a voxel (its corner offsets `off`, grid_offsets), at t's point: t's weights there. */
static inline void tri_on(const Tri *t, const Grid *on, const Py_ssize_t off[8], int n,
                          double *out) {
    corner_sums(on->data + t->vox * n, off, t->w, n, out);
}

/* The 8 corner offsets (in floats) of a cell of grid g, from its first corner. */
static inline void grid_offsets(const Grid *g, Py_ssize_t off[8]) {
    Py_ssize_t sz = g->nc, sy = g->nz * sz, sx = g->ny * sy;
    Py_ssize_t o[8] = {0, sz, sy, sy + sz, sx, sx + sz, sx + sy, sx + sy + sz};
    for (int q = 0; q < 8; q++) off[q] = o[q];
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

/* floor(v) for |v| < 2^52 (the caller's bound), without a libm call (x86-64 without SSE4.1
 * has no floor instruction): truncation towards 0, one less where that rounded up. */
static inline double floor_within(double v) {
    double t = (double)(int64_t)v;
    return t > v ? t - 1.0 : t;
}

/* A hint that the cache line holding p will be read (rw 0) or written (rw 1) soon; nothing
 * where the compiler has no such hint.  It changes no result. */
#if defined(__GNUC__) || defined(__clang__)
#define PREFETCH(p, rw) __builtin_prefetch((p), (rw), 3)
#else
#define PREFETCH(p, rw) ((void)(p))
#endif

/* floor(v): floor_within where |v| < 2^52, exact there; NaN, infinities and larger values go
 * to floor itself. */
static inline double floor_fast(double v) {
    if (!(v > -4503599627370496.0 && v < 4503599627370496.0)) return floor(v);
    return floor_within(v);
}

/* fmax and fmin as glibc's x86-64 ones give them (the other argument where one is NaN; b where
 * the two are equal), inline: the compiler calls libm for fmax itself. */
static inline double max_d(double a, double b) {
    if (a != a) return b;
    if (b != b) return a;
    return a > b ? a : b;
}

static inline double min_d(double a, double b) {
    if (a != a) return b;
    if (b != b) return a;
    return a < b ? a : b;
}

/* floor(v) clamped to [lo, hi] (lo for NaN): a safe index from any double. */
static inline Py_ssize_t floor_clamp(double v, Py_ssize_t lo, Py_ssize_t hi) {
    if (!(v >= (double)lo + 1.0)) return lo;   /* floor(v) <= lo, or NaN */
    if (v >= (double)hi) return hi;            /* floor(v) >= hi */
    return (Py_ssize_t)floor_within(v);        /* |v| is within the index range here */
}

/* Parse parallel lists of grids, (3,4) maps and RGB coefficients (buffers.c). */
int parse_grids(PyObject *grids, PyObject *w2is, PyObject *sigs, PyObject *thrs, Grid *out,
                Buf *bufs, int *n_out, int four_d);
/* A list of exactly n numbers into out. */
int parse_doubles(PyObject *list, Py_ssize_t n, double *out, const char *what);

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

#define G_LIMIT 0.999   /* |g| is clamped here (phase.G_LIMIT) */

/* Henyey-Greenstein p(c) in 1/sr (twin of phase.hg; the caller clamps g to G_LIMIT): c the cosine
 * between the propagation directions before and after the scattering. */
static inline double hg_phase(double c, double g) {
    double denom = 1.0 + g * g - 2.0 * g * c;
    if (denom < 1e-12) denom = 1e-12;
    return (1.0 - g * g) / (4.0 * M_PI * denom * sqrt(denom));
}

/* Counter-based random numbers (twins of kernels_np.hash32 and kernels_np.uniform). */
static inline uint32_t hash32(uint32_t x) {
    x ^= x >> 16; x *= 0x7FEB352Du; x ^= x >> 15; x *= 0x846CA68Bu; x ^= x >> 16;
    return x;
}

static inline double uniform01(uint32_t key, long step, long dim) {
    uint32_t salt = hash32((uint32_t)((uint64_t)step * 0x9E3779B1u + (uint64_t)dim * 0x85EBCA77u));
    return (double)(hash32(key ^ salt) >> 8) * (1.0 / 16777216.0);
}

#endif
