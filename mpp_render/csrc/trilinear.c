/* Trilinear interpolation at many points (twin of media.trilinear). */
#include "kernels.h"

const char trilinear_doc[] =
    "trilinear(grid, idx) -> bytes\n"
    "Twin of media.trilinear: grid (X,Y,Z,C) float32, idx (N,3) float64 index coordinates;\n"
    "(N,C) float64 as bytes: the trilinear value where 0 <= idx < extent - 1 on every axis,\n"
    "0 elsewhere (also for non-finite coordinates).";

PyObject *py_trilinear(PyObject *self, PyObject *args) {
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
        grid_shape(&g, sg[0], sg[1], sg[2], nc);
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
