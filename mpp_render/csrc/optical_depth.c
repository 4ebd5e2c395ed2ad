/* Optical depth along rays through the media (twin of kernels_np.optical_depth). */
#include "bricks.h"
#include "kernels.h"

const char optical_depth_doc[] =
    "optical_depth(points, dirs, t_max, grids, w2is, sigma_ts, thresholds, step, offset[, bricks, brick,\n"
    "              clip]) -> (N,3) float64; clip: first cut t_max at the media's far side (media_exit)\n"
    "  -> (N,3) float64\n"
    "Twin of kernels_np.optical_depth; with bricks (media.brick_bounds per grid) the steps that lie\n"
    "wholly in empty or constant bricks are added in one go.";

PyObject *optical_depth(PyObject *self, PyObject *args) {
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

