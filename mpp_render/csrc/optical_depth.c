/* Optical depth along rays through the media (twin of kernels_np.optical_depth). */
#include "bricks.h"
#include "kernels.h"

const char optical_depth_doc[] =
    "optical_depth(points, dirs, t_max, grids, w2is, sigma_ts, thresholds, step, offset[, bricks, brick,\n"
    "              clip, stop, stop_depth]) -> (N,3) float64; clip: first cut t_max at the media's far\n"
    "  side (media_exit); stop (3,3) float64 or None, stop_depth: a ray ends once every channel of\n"
    "  its depth so far times stop is at least stop_depth (> 0; inf: never)\n"
    "Twin of kernels_np.optical_depth; with bricks (media.brick_bounds per grid) the steps that lie\n"
    "wholly in empty or constant bricks are added in one go (and the stop tested after them).";

/* Whether the depth so far, tau (3,) times S (3x3, row-major: channel c is sum_k tau[k]
 * S[3k + c]), is at least stop_depth in every channel. */
static inline int opaque(const double tau[3], const double S[9], double stop_depth) {
    for (int c = 0; c < 3; c++)
        if (!(tau[0] * S[c] + tau[1] * S[3 + c] + tau[2] * S[6 + c] >= stop_depth)) return 0;
    return 1;
}

PyObject *optical_depth(PyObject *self, PyObject *args) {
    PyObject *po, *pd, *pt, *grids, *w2is, *sigs, *thrs, *pbk = Py_None, *pstop = Py_None;
    double step, offset, stop_depth = INFINITY;
    int brick = 4, clip = 0;
    if (!PyArg_ParseTuple(args, "OOOOOOOdd|OipOd", &po, &pd, &pt, &grids, &w2is, &sigs, &thrs, &step,
                          &offset, &pbk, &brick, &clip, &pstop, &stop_depth))
        return NULL;
    if (!(step > 0.0) || !isfinite(step) || !(offset >= 0.0 && offset <= 1.0)) {
        PyErr_SetString(PyExc_ValueError, "step must be > 0 and offset in [0, 1]");
        return NULL;
    }
    if (!(stop_depth > 0.0)) {
        PyErr_SetString(PyExc_ValueError, "stop_depth must be > 0 (inf: never)");
        return NULL;
    }
    Buf bp = {0}, bd = {0}, bt = {0}, bs = {0}, gb[MAX_MEDIA], kb[MAX_MEDIA];
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
    double S[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    int use_stop = 0;
    if (pstop != Py_None) {
        Py_ssize_t s_s[2] = {3, 3};
        if (get_buf(pstop, &bs, 'd', 2, s_s, "stop") < 0) goto done;
        memcpy(S, bs.view.buf, sizeof S);
        for (int k = 0; k < 9; k++)
            if (!(S[k] >= 0.0) || !isfinite(S[k])) {
                PyErr_SetString(PyExc_ValueError, "stop must be finite and >= 0");
                goto done;
            }
        use_stop = isfinite(stop_depth);
    }
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
                            if (j >= ns || (use_stop && opaque(tau, S, stop_depth))) break;
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
                if (use_stop && opaque(tau, S, stop_depth)) break;
            }
        }
        for (int c = 0; c < 3; c++) out[3 * r + c] = tau[c];
    }
    Py_END_ALLOW_THREADS
    result = outobj;
    outobj = NULL;
done:
    Py_XDECREF(outobj);
    buf_release(&bp); buf_release(&bd); buf_release(&bt); buf_release(&bs);
    for (int m = 0; m < ng; m++) buf_release(&gb[m]);
    for (int m = 0; m < nkb; m++) buf_release(&kb[m]);
    return result;
}

