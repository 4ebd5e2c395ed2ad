/* Empty and constant space (twin of kernels_np.Walk): the walk through a medium's bricks. */
#include "bricks.h"

int parse_bricks(PyObject *list, int brick, const Grid *g, int ng, Bricks *out, Buf *bufs,
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

void walk_init(Walk *w, const Grid *g, const Bricks *b, const double o[3], const double v[3]) {
    const double *dims = g->last;
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
int walk_at(Walk *w, double s, double *end, double *value) {
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
double segment_majorant(const Grid *g, const Bricks *b, const double o[3], const double v[3],
                        double s_a, double s_b) {
    return segment_bounds(g, b, o, v, s_a, s_b, NULL);
}

double segment_bounds(const Grid *g, const Bricks *b, const double o[3], const double v[3],
                      double s_a, double s_b, double *least) {
    const double *dims = g->last;
    Py_ssize_t lo[3], hi[3];
    double mn[3], mx[3];
    int partly = 0;  /* the segment leaves the grid: its least density is 0 */
    if (least) *least = 0.0;
    for (int a = 0; a < 3; a++) {
        double p0 = o[a] + s_a * v[a], p1 = o[a] + s_b * v[a];
        mn[a] = p0 < p1 ? p0 : p1;
        mx[a] = p0 < p1 ? p1 : p0;
        if (isnan(mn[a]) || isnan(mx[a])) return INFINITY;
    }
    for (int a = 0; a < 3; a++) {
        if (mx[a] < 0.0 || mn[a] > dims[a]) return 0.0;  /* wholly outside the grid */
        partly |= mn[a] < 0.0 || mx[a] > dims[a];
        lo[a] = floor_clamp(mn[a] / b->size, 0, b->n[a] - 1);
        hi[a] = floor_clamp(mx[a] / b->size, 0, b->n[a] - 1);
    }
    float best = 0.0f, worst = INFINITY;
    for (Py_ssize_t i = lo[0]; i <= hi[0]; i++)
        for (Py_ssize_t j = lo[1]; j <= hi[1]; j++)
            for (Py_ssize_t k = lo[2]; k <= hi[2]; k++) {
                const float *e = b->data + ((i * b->n[1] + j) * b->n[2] + k) * 2;
                if (e[1] > best) best = e[1];
                if (e[0] < worst) worst = e[0];
            }
    if (least && !partly) *least = (double)worst;
    return (double)best;
}

/* Where the ray p + s d leaves the last of the media's padded boxes it crosses (the far end of
 * the union of their intervals, as media.union_interval), capped at t_max; 0 when it meets
 * none ahead.  Twin of kernels_np.media_exit. */
void box_interval(const double o[3], const double v[3], const double last[3], double *lo,
                  double *hi) {
    double a0 = -INFINITY, a1 = INFINITY;
    for (int a = 0; a < 3; a++) {
        double t0, t1;
        if (fabs(v[a]) < 1e-300) {   /* parallel to the slab: all of it or none */
            int in = o[a] >= 0.0 && o[a] <= last[a];
            t0 = in ? -INFINITY : INFINITY;
            t1 = in ? INFINITY : -INFINITY;
        } else {
            double inv = 1.0 / v[a], ta = -o[a] * inv, tb = (last[a] - o[a]) * inv;
            t0 = fmin(ta, tb);
            t1 = fmax(ta, tb);
        }
        a0 = (t0 > a0 || t0 != t0) ? t0 : a0;
        a1 = (t1 < a1 || t1 != t1) ? t1 : a1;
    }
    *lo = a0;
    *hi = a1;
}

double media_exit(const Grid *g, int ng, const double p[3], const double d[3], double t_max) {
    double far = -INFINITY;
    for (int m = 0; m < ng; m++) {
        double o[3], v[3], lo, hi;
        ray_to_index(&g[m], p, d, o, v);
        box_interval(o, v, g[m].last, &lo, &hi);
        if (hi > lo && hi > far) far = hi;
    }
    double t = far < t_max ? far : t_max;
    return t > 0.0 ? t : 0.0;
}
