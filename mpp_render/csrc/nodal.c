/* The traced paths' lattice values moved from their tents' centroids to the lattice points
 * (twin of kernels_np.nodal_fit; precompute/nodal.py says why). */
#include "kernels.h"

#define NODAL_MAX_CHANNELS 64

const char nodal_fit_doc[] =
    "nodal_fit(mean, offsets, mass, signed, ridge) -> bytearray\n"
    "Twin of kernels_np.nodal_fit: mean (X,Y,Z,C) float32 tent means, offsets (X,Y,Z,3)\n"
    "float64 (each tent's centroid less its point, lattice steps), mass (X,Y,Z) float64, the\n"
    "last `signed` of the C channels left below 0, ridge > 0 (lattice steps^2).  (X,Y,Z,C)\n"
    "float32 as a bytearray: each point with mass and an offset moved along the gradient\n"
    "fitted to its 26 neighbours, the rest as they came.";

/* x = A^-1 b for a symmetric 3 x 3 A (row-major) and `nc` right-hand sides b (3, nc), by the
 * adjugate of A scaled to its largest element (no overflow for a huge ridge); 0 where A is
 * singular or not finite (the ridge keeps it from being singular). */
static void solve3(const double A0[9], const double *b, int nc, double *x) {
    double big = 0.0, A[9];
    for (int i = 0; i < 9; i++) big = fmax(big, fabs(A0[i]));
    if (!(big > 0.0) || !isfinite(big)) {
        for (int i = 0; i < 3 * nc; i++) x[i] = 0.0;
        return;
    }
    for (int i = 0; i < 9; i++) A[i] = A0[i] / big;
    double c00 = A[4] * A[8] - A[5] * A[7], c01 = A[5] * A[6] - A[3] * A[8],
           c02 = A[3] * A[7] - A[4] * A[6];
    double det = A[0] * c00 + A[1] * c01 + A[2] * c02;
    if (!(fabs(det) > 1e-300)) {
        for (int i = 0; i < 3 * nc; i++) x[i] = 0.0;
        return;
    }
    double inv[9] = {c00, A[2] * A[7] - A[1] * A[8], A[1] * A[5] - A[2] * A[4],
                     c01, A[0] * A[8] - A[2] * A[6], A[2] * A[3] - A[0] * A[5],
                     c02, A[1] * A[6] - A[0] * A[7], A[0] * A[4] - A[1] * A[3]};
    for (int i = 0; i < 9; i++) inv[i] /= det * big;
    for (int a = 0; a < 3; a++)
        for (int c = 0; c < nc; c++)
            x[a * nc + c] = inv[3 * a] * b[c] + inv[3 * a + 1] * b[nc + c] + inv[3 * a + 2] * b[2 * nc + c];
}

PyObject *nodal_fit(PyObject *self, PyObject *args) {
    PyObject *pm, *pd, *pw;
    int sgn;
    double ridge;
    if (!PyArg_ParseTuple(args, "OOOid", &pm, &pd, &pw, &sgn, &ridge)) return NULL;
    Buf bm = {0}, bd = {0}, bw = {0};
    PyObject *result = NULL;
    Py_ssize_t sm[4] = {-1, -1, -1, -1};
    if (get_buf(pm, &bm, 'f', 4, sm, "mean") < 0) goto done;
    {
        Py_ssize_t sd[4] = {sm[0], sm[1], sm[2], 3}, sw[3] = {sm[0], sm[1], sm[2]};
        if (get_buf(pd, &bd, 'd', 4, sd, "offsets") < 0 || get_buf(pw, &bw, 'd', 3, sw, "mass") < 0)
            goto done;
    }
    if (sm[3] < 1 || sm[3] > NODAL_MAX_CHANNELS || sgn < 0 || sgn > sm[3] || !(ridge > 0.0) ||
        !isfinite(ridge)) {
        PyErr_SetString(PyExc_ValueError, "nodal_fit: 1-64 channels, 0 <= signed <= channels, ridge > 0");
        goto done;
    }
    const Py_ssize_t X = sm[0], Y = sm[1], Z = sm[2];
    const int C = (int)sm[3];
    Py_ssize_t pts = X * Y * Z;
    if (X > 0 && Y > 0 && Z > 0 &&
        (pts / X / Y != Z || pts > PY_SSIZE_T_MAX / (Py_ssize_t)(C * sizeof(float)))) {
        PyErr_SetString(PyExc_ValueError, "nodal_fit: lattice too large");
        goto done;
    }
    result = PyByteArray_FromStringAndSize(NULL, pts * C * (Py_ssize_t)sizeof(float));
    if (!result) goto done;
    {
        float *out = (float *)PyByteArray_AS_STRING(result);
        const float *M = (const float *)bm.view.buf;
        const double *D = (const double *)bd.view.buf, *W = (const double *)bw.view.buf;
        memcpy(out, M, (size_t)pts * (size_t)C * sizeof(float));
        Py_BEGIN_ALLOW_THREADS
        double b[3 * NODAL_MAX_CHANNELS], grad[3 * NODAL_MAX_CHANNELS];
        for (Py_ssize_t i = 0; i < X; i++)
            for (Py_ssize_t j = 0; j < Y; j++)
                for (Py_ssize_t k = 0; k < Z; k++) {
                    Py_ssize_t p = (i * Y + j) * Z + k;
                    double w0 = W[p];
                    const double *d0 = D + 3 * p;
                    double dmax = fmax(fabs(d0[0]), fmax(fabs(d0[1]), fabs(d0[2])));
                    if (!(w0 > 0.0) || !(dmax > 1e-6)) continue;
                    double A[9] = {ridge, 0, 0, 0, ridge, 0, 0, 0, ridge};
                    for (int q = 0; q < 3 * C; q++) b[q] = 0.0;
                    const float *m0 = M + p * C;
                    /* the neighbours in the twin's order: offsets -1..1 per axis, C order */
                    for (int di = -1; di <= 1; di++)
                        for (int dj = -1; dj <= 1; dj++)
                            for (int dk = -1; dk <= 1; dk++) {
                                if (!di && !dj && !dk) continue;
                                Py_ssize_t ni = i + di, nj = j + dj, nk = k + dk;
                                if (ni < 0 || nj < 0 || nk < 0 || ni >= X || nj >= Y || nk >= Z)
                                    continue;   /* beyond the lattice: no mass */
                                Py_ssize_t q = (ni * Y + nj) * Z + nk;
                                double wz = W[q];
                                if (!(wz > 0.0)) continue;
                                double wt = wz / (wz + w0);
                                const double *dq = D + 3 * q;
                                double dc[3] = {di + dq[0] - d0[0], dj + dq[1] - d0[1],
                                                dk + dq[2] - d0[2]};
                                for (int a = 0; a < 3; a++) {
                                    double wa = wt * dc[a];
                                    for (int e = 0; e < 3; e++) A[3 * a + e] += wa * dc[e];
                                    const float *mq = M + q * C;
                                    for (int c = 0; c < C; c++)
                                        b[a * C + c] += wa * ((double)mq[c] - (double)m0[c]);
                                }
                            }
                    solve3(A, b, C, grad);
                    for (int c = 0; c < C; c++) {
                        double v = (double)m0[c] - (d0[0] * grad[c] + d0[1] * grad[C + c] +
                                                    d0[2] * grad[2 * C + c]);
                        if (c < C - sgn && v < 0.0) v = 0.0;   /* light: never below 0 (NaN as the twin) */
                        out[p * C + c] = (float)v;
                    }
                }
        Py_END_ALLOW_THREADS
    }
done:
    buf_release(&bm); buf_release(&bd); buf_release(&bw);
    return result;
}
