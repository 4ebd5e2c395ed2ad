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
#include <string.h>

#define MAX_MEDIA 64

typedef struct {
    Py_buffer view;
    int held;
} Buf;

static void buf_release(Buf *b) {
    if (b->held) { PyBuffer_Release(&b->view); b->held = 0; }
}

/* Acquire a C-contiguous buffer of `fmt` ('d' float64 or 'f' float32) with `ndim` dims.
 * shape[i] >= 0 must match; -1 accepts any extent (then written back). */
static int get_buf(PyObject *obj, Buf *b, char fmt, int ndim, Py_ssize_t *shape, const char *what) {
    b->held = 0;
    if (PyObject_GetBuffer(obj, &b->view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | PyBUF_ND) < 0) {
        PyErr_Clear();
        PyErr_Format(PyExc_ValueError, "%s: expected a C-contiguous numeric array", what);
        return -1;
    }
    b->held = 1;
    const char *f = b->view.format ? b->view.format : "B";
    if (f[0] == '<' || f[0] == '=' || f[0] == '@') f++;
    Py_ssize_t item = (fmt == 'd') ? 8 : 4;
    if (f[0] != fmt || f[1] != '\0' || b->view.itemsize != item) {
        PyErr_Format(PyExc_ValueError, "%s: expected %s", what, fmt == 'd' ? "float64" : "float32");
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

/* Trilinear fetch of channel range [c0, c0+nc_out) at index coords; zeros outside. */
static inline int trilinear(const Grid *g, const double idx[3], int c0, int nc_out, double *out) {
    double fx = floor(idx[0]), fy = floor(idx[1]), fz = floor(idx[2]);
    if (!(fx >= 0.0 && fy >= 0.0 && fz >= 0.0 &&
          fx < (double)(g->nx - 1) && fy < (double)(g->ny - 1) && fz < (double)(g->nz - 1))) {
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

static inline void to_index(const Grid *g, const double x[3], double idx[3]) {
    for (int r = 0; r < 3; r++)
        idx[r] = g->w2i[4 * r] * x[0] + g->w2i[4 * r + 1] * x[1] + g->w2i[4 * r + 2] * x[2] + g->w2i[4 * r + 3];
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

static const char optical_depth_doc[] =
    "optical_depth(points, dirs, t_max, grids, w2is, sigma_ts, thresholds, step, offset) -> (N,3) float64\n"
    "Twin of kernels_np.optical_depth.";

static PyObject *optical_depth(PyObject *self, PyObject *args) {
    PyObject *po, *pd, *pt, *grids, *w2is, *sigs, *thrs;
    double step, offset;
    if (!PyArg_ParseTuple(args, "OOOOOOOdd", &po, &pd, &pt, &grids, &w2is, &sigs, &thrs, &step, &offset))
        return NULL;
    if (!(step > 0.0) || !isfinite(step) || !(offset >= 0.0 && offset <= 1.0)) {
        PyErr_SetString(PyExc_ValueError, "step must be > 0 and offset in [0, 1]");
        return NULL;
    }
    Buf bp = {0}, bd = {0}, bt = {0}, gb[MAX_MEDIA];
    Grid g[MAX_MEDIA];
    int ng = 0;
    PyObject *result = NULL, *outobj = NULL;
    Py_ssize_t s_p[2] = {-1, 3};
    if (get_buf(po, &bp, 'd', 2, s_p, "points") < 0) goto done;
    Py_ssize_t n = s_p[0];
    Py_ssize_t s_d[2] = {n, 3}, s_t[1] = {n};
    if (get_buf(pd, &bd, 'd', 2, s_d, "dirs") < 0) goto done;
    if (get_buf(pt, &bt, 'd', 1, s_t, "t_max") < 0) goto done;
    if (parse_grids(grids, w2is, sigs, thrs, g, gb, &ng, 0) < 0) goto done;
    outobj = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * 3 * sizeof(double)));
    if (!outobj) goto done;
    double *out = (double *)PyByteArray_AS_STRING(outobj);
    const double *P = (const double *)bp.view.buf, *D = (const double *)bd.view.buf,
                 *TM = (const double *)bt.view.buf;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t r = 0; r < n; r++) {
        double tau[3] = {0, 0, 0};
        double tm = TM[r];
        if (isfinite(tm) && tm > 0.0) {
            double cnt = ceil(tm / step);
            if (cnt > 1e8) cnt = 1e8;  /* a bounded loop whatever the caller passes */
            long ns = (long)cnt;
            double h = tm / (double)ns;
            for (long j = 0; j < ns; j++) {
                double s = ((double)j + offset) * h, x[3], idx[3], v;
                for (int a = 0; a < 3; a++) x[a] = P[3 * r + a] + D[3 * r + a] * s;
                for (int m = 0; m < ng; m++) {
                    to_index(&g[m], x, idx);
                    if (trilinear(&g[m], idx, 0, 1, &v)) {
                        v = density_from(&g[m], v);
                        for (int c = 0; c < 3; c++) tau[c] += v * g[m].sig[c] * h;
                    }
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
    return result;
}

static PyMethodDef methods[] = {
    {"optical_depth", optical_depth, METH_VARARGS, optical_depth_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moduledef = {PyModuleDef_HEAD_INIT, "_kernels",
                                       "Compiled twins of mpp_render.kernels_np.", -1, methods,
                                       NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&moduledef); }
