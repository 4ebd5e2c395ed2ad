/* Light sweep (twin of kernels_np.light_sweep): optical depth towards a light for every voxel
 * of one medium's grid, integrated along "columns" (rays from the light) slab by slab.
 */
#include "kernels.h"

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

const char light_sweep_doc[] =
    "light_sweep(out, channel, a2w, axis, sign, i_first, i_last, coef, light_index, cone, init,\n"
    "            p_lo, p_hi, n_sub, grids, w2is, sigma_ts, thresholds) -> None\n"
    "Twin of kernels_np.light_sweep: writes out[..., channel:channel+3] of the voxels it owns.";

PyObject *light_sweep(PyObject *self, PyObject *args) {
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
