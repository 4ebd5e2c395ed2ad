/* Rays against the surfaces' triangles (twin of surfaces.intersect_np). */
#include "kernels.h"
#include "triangles.h"

const char intersect_doc[] =
    "intersect(origins, dirs, tmax, triangles) -> (t, triangle) as bytes (float64, int64)\n"
    "The closest hit of each ray origins + t dirs ((N,3) float64) for t in (0, tmax) ((N,)\n"
    "float64) among the triangles ((T,9) float64: corner and two edges, m): its t and its\n"
    "index, or tmax and -1 where none is hit.  Twin of mpp_render.surfaces.intersect_np;\n"
    "runs without the GIL.";

PyObject *intersect(PyObject *self, PyObject *args) {
    PyObject *po, *pd, *pt, *ptri;
    if (!PyArg_ParseTuple(args, "OOOO", &po, &pd, &pt, &ptri)) return NULL;
    Buf bo = {0}, bd = {0}, bt = {0}, btri = {0};
    PyObject *o_t = NULL, *o_k = NULL, *result = NULL;
    double *boxes = NULL;
    Py_ssize_t sn[2] = {-1, 3}, s1[1] = {-1}, stri[2] = {-1, 9};
    if (get_buf(po, &bo, 'd', 2, sn, "origins") < 0) goto done;
    if (get_buf(pd, &bd, 'd', 2, sn, "dirs") < 0) goto done;
    s1[0] = sn[0];
    if (get_buf(pt, &bt, 'd', 1, s1, "tmax") < 0) goto done;
    if (get_buf(ptri, &btri, 'd', 2, stri, "triangles") < 0) goto done;
    Py_ssize_t n = sn[0], n_tri = stri[0], n_box = (n_tri + TRI_CHUNK - 1) / TRI_CHUNK;
    o_t = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * sizeof(double)));
    o_k = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * sizeof(int64_t)));
    if (!o_t || !o_k) goto done;
    if (n_box > 0) {
        boxes = (double *)malloc(sizeof(double) * 6 * (size_t)n_box);
        if (!boxes) {
            PyErr_NoMemory();
            goto done;
        }
    }
    {
        const double *O = (const double *)bo.view.buf, *D = (const double *)bd.view.buf,
                     *TM = (const double *)bt.view.buf, *TRI = (const double *)btri.view.buf;
        double *OT = (double *)PyByteArray_AS_STRING(o_t);
        int64_t *OK = (int64_t *)PyByteArray_AS_STRING(o_k);
        Py_BEGIN_ALLOW_THREADS
        if (n_box > 0) tri_chunk_boxes(TRI, n_tri, boxes);
        for (Py_ssize_t r = 0; r < n; r++) {
            double th = TM[r];
            Py_ssize_t k = n_box > 0 ? tri_hit(TRI, n_tri, boxes, O + 3 * r, D + 3 * r, 0.0,
                                               TM[r], -1, &th) : -1;
            OT[r] = th;
            OK[r] = (int64_t)k;
        }
        Py_END_ALLOW_THREADS
    }
    result = PyTuple_Pack(2, o_t, o_k);
done:
    buf_release(&bo); buf_release(&bd); buf_release(&bt); buf_release(&btri);
    Py_XDECREF(o_t); Py_XDECREF(o_k);
    free(boxes);
    return result;
}
