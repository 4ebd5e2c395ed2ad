/* Checked buffers from Python and the per-medium lists every kernel takes. */
#include "common.h"

void buf_release(Buf *b) {
    if (b->held) { PyBuffer_Release(&b->view); b->held = 0; }
}

/* Acquire a C-contiguous buffer of `fmt` ('d' float64, 'f' float32, 'I' uint32 or 'B' uint8)
 * with `ndim` dims.
 * shape[i] >= 0 must match; -1 accepts any extent (then written back). */
int get_buf_ex(PyObject *obj, Buf *b, char fmt, int ndim, Py_ssize_t *shape, const char *what,
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
    Py_ssize_t item = (fmt == 'd') ? 8 : (fmt == 'B' ? 1 : 4);
    if (f[0] != fmt || f[1] != '\0' || b->view.itemsize != item) {
        PyErr_Format(PyExc_ValueError, "%s: expected %s", what,
                     fmt == 'd' ? "float64" : (fmt == 'f' ? "float32" :
                                               (fmt == 'B' ? "uint8" : "uint32")));
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

int get_buf(PyObject *obj, Buf *b, char fmt, int ndim, Py_ssize_t *shape, const char *what) {
    return get_buf_ex(obj, b, fmt, ndim, shape, what, 0);
}

/* Parse parallel lists of grids, (3,4) maps and RGB coefficients. `nchan` = channels per voxel
 * (grids are (X,Y,Z) when nchan == 0, else (X,Y,Z,nchan) with nchan >= 1 accepted as any). */
int parse_grids(PyObject *grids, PyObject *w2is, PyObject *sigs, PyObject *thrs, Grid *out,
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
        grid_shape(&out[m], sh[0], sh[1], sh[2], four_d ? sh[3] : 1);
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


int parse_doubles(PyObject *list, Py_ssize_t n, double *out, const char *what) {
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
