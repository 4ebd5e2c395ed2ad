/* The local-linear fit of the traced paths' deposits to their lobe (twin of
 * kernels_np.lobe_ratio; precompute/lobefit.py says why).  The same sums in the same order as
 * the twin (its cumulative sums along each axis, its Cramer's rule): the same bits. */
#include "kernels.h"

#define LOBE_SUMS 14   /* u d (1, x) and u m (1, x) (1, x)^T's upper triangle */
/* standard deviations of the window's weighted spread beyond which its line is an
 * extrapolation (kernels_np.LOBE_REACH) */
#define LOBE_REACH 3.0

const char lobe_ratio_doc[] =
    "lobe_ratio(md, mc, u, r, channels) -> bytearray\n"
    "Twin of kernels_np.lobe_ratio: md, mc (X,Y,Z,3) float64 the deposits and the lobe, u\n"
    "(X,Y,Z) float64 the weights, r >= 1 the window's radius (lattice points), channels 1 (a\n"
    "grey medium: channel 0 fitted, copied to 1 and 2) or 3.  (X,Y,Z,3) float64 as a\n"
    "bytearray: M_r = M_c a, a the local-linear fit of M_d / M_c over each window (the\n"
    "window's weighted mean ratio beyond LOBE_REACH standard deviations of its spread).";

/* In place along one axis of a C-order (X,Y,Z) array: each value the sum of the 2r+1 around
 * it (0 beyond), as the difference of the running sums S(min(i+r, n-1)) - S(i-r-1), the
 * twin's cumulative sums over the zero-padded line. */
static void box_axis(double *a, const Py_ssize_t n3[3], int axis, int r, double *pre) {
    Py_ssize_t n = n3[axis], stride = axis == 0 ? n3[1] * n3[2] : (axis == 1 ? n3[2] : 1);
    Py_ssize_t outer = n3[0] * n3[1] * n3[2] / n;
    for (Py_ssize_t o = 0; o < outer; o++) {
        /* the line's first element: o runs over the other two axes in C order */
        Py_ssize_t base;
        if (axis == 0) base = o;
        else if (axis == 1) base = (o / n3[2]) * n3[1] * n3[2] + o % n3[2];
        else base = o * n3[2];
        double s = 0.0;
        for (Py_ssize_t i = 0; i < n; i++) {
            s += a[base + i * stride];
            pre[i] = s;
        }
        for (Py_ssize_t i = 0; i < n; i++) {
            Py_ssize_t hi = i + r < n - 1 ? i + r : n - 1, lo = i - r - 1;
            a[base + i * stride] = pre[hi] - (lo >= 0 ? pre[lo] : 0.0);
        }
    }
}

/* x = C^-1 b for symmetric C by Cramer's rule on its upper triangle, 0 where det is 0: the
 * twin's lobefit._solve3, term for term. */
static void cramer3(double c00, double c01, double c02, double c11, double c12, double c22,
                    const double b[3], double x[3]) {
    double a00 = c11 * c22 - c12 * c12, a01 = c02 * c12 - c01 * c22,
           a02 = c01 * c12 - c02 * c11, a11 = c00 * c22 - c02 * c02,
           a12 = c01 * c02 - c00 * c12, a22 = c00 * c11 - c01 * c01;
    double det = c00 * a00 + c01 * a01 + c02 * a02;
    double inv = det != 0.0 ? 1.0 / det : 0.0;
    x[0] = (a00 * b[0] + a01 * b[1] + a02 * b[2]) * inv;
    x[1] = (a01 * b[0] + a11 * b[1] + a12 * b[2]) * inv;
    x[2] = (a02 * b[0] + a12 * b[1] + a22 * b[2]) * inv;
}

PyObject *lobe_ratio(PyObject *self, PyObject *args) {
    PyObject *pd, *pc, *pu;
    int r, channels;
    if (!PyArg_ParseTuple(args, "OOOii", &pd, &pc, &pu, &r, &channels)) return NULL;
    Buf bd = {0}, bc = {0}, bu = {0};
    PyObject *result = NULL;
    double *work = NULL;
    Py_ssize_t sd[4] = {-1, -1, -1, 3};
    if (get_buf(pd, &bd, 'd', 4, sd, "md") < 0) goto done;
    {
        Py_ssize_t sc[4] = {sd[0], sd[1], sd[2], 3}, su[3] = {sd[0], sd[1], sd[2]};
        if (get_buf(pc, &bc, 'd', 4, sc, "mc") < 0 || get_buf(pu, &bu, 'd', 3, su, "u") < 0)
            goto done;
    }
    if (r < 1 || (channels != 1 && channels != 3)) {
        PyErr_SetString(PyExc_ValueError, "lobe_ratio: r >= 1, channels 1 or 3");
        goto done;
    }
    const Py_ssize_t n3[3] = {sd[0], sd[1], sd[2]};
    Py_ssize_t pts = n3[0] * n3[1] * n3[2], longest = n3[0];
    if (n3[1] > longest) longest = n3[1];
    if (n3[2] > longest) longest = n3[2];
    if (n3[0] > 0 && n3[1] > 0 && n3[2] > 0 &&
        (pts / n3[0] / n3[1] != n3[2] ||
         pts > PY_SSIZE_T_MAX / (Py_ssize_t)((LOBE_SUMS + 1) * sizeof(double)))) {
        PyErr_SetString(PyExc_ValueError, "lobe_ratio: lattice too large");
        goto done;
    }
    result = PyByteArray_FromStringAndSize(NULL, pts * 3 * (Py_ssize_t)sizeof(double));
    if (!result) goto done;
    work = (double *)malloc(((size_t)LOBE_SUMS * (size_t)pts + (size_t)longest + 1) *
                            sizeof(double));
    if (!work) {
        Py_CLEAR(result);
        PyErr_NoMemory();
        goto done;
    }
    {
        double *out = (double *)PyByteArray_AS_STRING(result);
        const double *MD = (const double *)bd.view.buf, *MC = (const double *)bc.view.buf,
                     *U = (const double *)bu.view.buf;
        double *S = work, *pre = work + (size_t)LOBE_SUMS * (size_t)pts;
        Py_BEGIN_ALLOW_THREADS
        memcpy(out, MD, (size_t)pts * 3 * sizeof(double));
        for (int c = 0; c < channels; c++) {
            /* the normal equations' sums at each point, f = (1, x, y, z): u d f_i and
             * u m f_i f_j (i <= j), with the twin's products' order */
            for (Py_ssize_t i = 0; i < n3[0]; i++)
                for (Py_ssize_t j = 0; j < n3[1]; j++)
                    for (Py_ssize_t k = 0; k < n3[2]; k++) {
                        Py_ssize_t p = (i * n3[1] + j) * n3[2] + k;
                        double m = MC[3 * p + c], d = MD[3 * p + c];
                        double w = m > 0.0 ? U[p] : 0.0, wd = w * d, wm = w * m;
                        double f[4] = {1.0, (double)i, (double)j, (double)k};
                        for (int a = 0; a < 4; a++) S[a * pts + p] = wd * f[a];
                        int q = 4;
                        for (int a = 0; a < 4; a++)
                            for (int b = a; b < 4; b++) S[(q++) * pts + p] = wm * f[a] * f[b];
                    }
            for (int q = 0; q < LOBE_SUMS; q++)
                for (int axis = 0; axis < 3; axis++)
                    box_axis(S + q * pts, n3, axis, r, pre);
            for (Py_ssize_t i = 0; i < n3[0]; i++)
                for (Py_ssize_t j = 0; j < n3[1]; j++)
                    for (Py_ssize_t k = 0; k < n3[2]; k++) {
                        Py_ssize_t p = (i * n3[1] + j) * n3[2] + k;
                        double m = MC[3 * p + c];
                        /* A's upper triangle in S[4..13]: (0,0) (0,1) (0,2) (0,3) (1,1)
                         * (1,2) (1,3) (2,2) (2,3) (3,3) */
                        double A00 = S[4 * pts + p];
                        double A0[3] = {S[5 * pts + p], S[6 * pts + p], S[7 * pts + p]};
                        double rhs0 = S[p], rhs[3] = {S[pts + p], S[2 * pts + p], S[3 * pts + p]};
                        int ok = A00 > 0.0;
                        if (!(ok && m > 0.0)) { out[3 * p + c] = MD[3 * p + c]; continue; }
                        double mu[3] = {A0[0] / A00, A0[1] / A00, A0[2] / A00};
                        double Ax[3][3] = {{S[8 * pts + p], S[9 * pts + p], S[10 * pts + p]},
                                           {S[9 * pts + p], S[11 * pts + p], S[12 * pts + p]},
                                           {S[10 * pts + p], S[12 * pts + p], S[13 * pts + p]}};
                        double C[3][3];
                        for (int a = 0; a < 3; a++)
                            for (int b = 0; b < 3; b++) C[a][b] = Ax[a][b] - A00 * mu[a] * mu[b];
                        double ridge = 1e-9 * ((C[0][0] + C[1][1] + C[2][2]) / 3.0 + A00);
                        for (int a = 0; a < 3; a++) C[a][a] = C[a][a] + ridge;
                        double rc[3] = {rhs[0] - mu[0] * rhs0, rhs[1] - mu[1] * rhs0,
                                        rhs[2] - mu[2] * rhs0}, s[3];
                        cramer3(C[0][0], C[0][1], C[0][2], C[1][1], C[1][2], C[2][2], rc, s);
                        double a0 = (rhs0 - (s[0] * A0[0] + s[1] * A0[1] + s[2] * A0[2])) / A00;
                        /* beyond LOBE_REACH of the window's spread the window's mean ratio */
                        double delta[3] = {(double)i - mu[0], (double)j - mu[1],
                                           (double)k - mu[2]}, xd[3];
                        cramer3(C[0][0], C[0][1], C[0][2], C[1][1], C[1][2], C[2][2], delta, xd);
                        double far = A00 * (delta[0] * xd[0] + delta[1] * xd[1] + delta[2] * xd[2]);
                        double a = far > LOBE_REACH * LOBE_REACH ? rhs0 / A00 :
                                   a0 + (s[0] * (double)i + s[1] * (double)j + s[2] * (double)k);
                        out[3 * p + c] = m * a;
                    }
        }
        if (channels == 1)   /* one fit serves the three equal channels */
            for (Py_ssize_t p = 0; p < pts; p++) out[3 * p + 1] = out[3 * p + 2] = out[3 * p];
        Py_END_ALLOW_THREADS
    }
done:
    free(work);
    buf_release(&bd); buf_release(&bc); buf_release(&bu);
    return result;
}
