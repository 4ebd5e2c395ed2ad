/* The interval of rays through the media's boxes (twin of media.union_interval). */
#include "bricks.h"
#include "kernels.h"

const char union_interval_doc[] =
    "union_interval(origins, dirs, t_lo, t_hi, w2is, last) -> (t0, t1) as bytes (float64)\n"
    "Rays origins + t dirs ((N,3) float64, any |dirs|); w2is ((M,3,4) float64) the media's\n"
    "world -> padded index maps and last ((M,3) float64) their grids' last index per axis.\n"
    "Per ray the smallest interval covering every box it crosses (t0 > t1 where it crosses\n"
    "none), clipped to [t_lo, t_hi] ((N,) float64).  Twin of mpp_render.media.union_interval\n"
    "(ray_box per medium, bricks.c's box_interval); runs without the GIL.";

PyObject *union_interval(PyObject *self, PyObject *args) {
    PyObject *po, *pd, *plo, *phi, *pw, *pl;
    if (!PyArg_ParseTuple(args, "OOOOOO", &po, &pd, &plo, &phi, &pw, &pl)) return NULL;
    Buf bo = {0}, bd = {0}, blo = {0}, bhi = {0}, bw = {0}, bl = {0};
    PyObject *o_0 = NULL, *o_1 = NULL, *result = NULL;
    Py_ssize_t sn[2] = {-1, 3}, s1[1] = {-1}, sw[3] = {-1, 3, 4}, sl[2] = {-1, 3};
    if (get_buf(po, &bo, 'd', 2, sn, "origins") < 0) goto done;
    if (get_buf(pd, &bd, 'd', 2, sn, "dirs") < 0) goto done;
    s1[0] = sn[0];
    if (get_buf(plo, &blo, 'd', 1, s1, "t_lo") < 0) goto done;
    if (get_buf(phi, &bhi, 'd', 1, s1, "t_hi") < 0) goto done;
    if (get_buf(pw, &bw, 'd', 3, sw, "w2is") < 0) goto done;
    sl[0] = sw[0];
    if (get_buf(pl, &bl, 'd', 2, sl, "last") < 0) goto done;
    Py_ssize_t n = sn[0], m = sw[0];
    o_0 = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * sizeof(double)));
    o_1 = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * sizeof(double)));
    if (!o_0 || !o_1) goto done;
    {
        const double *O = (const double *)bo.view.buf, *D = (const double *)bd.view.buf,
                     *LO = (const double *)blo.view.buf, *HI = (const double *)bhi.view.buf,
                     *W = (const double *)bw.view.buf, *L = (const double *)bl.view.buf;
        double *T0 = (double *)PyByteArray_AS_STRING(o_0), *T1 = (double *)PyByteArray_AS_STRING(o_1);
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t r = 0; r < n; r++) {
            double t0 = INFINITY, t1 = -INFINITY;
            for (Py_ssize_t k = 0; k < m; k++) {
                Grid g;   /* only its map and last index: ray_to_index, box_interval */
                memcpy(g.w2i, W + 12 * k, sizeof g.w2i);
                double o[3], v[3], a, b;
                ray_to_index(&g, O + 3 * r, D + 3 * r, o, v);
                box_interval(o, v, L + 3 * k, &a, &b);
                if (b > a) {
                    t0 = a < t0 ? a : t0;
                    t1 = b > t1 ? b : t1;
                }
            }
            T0[r] = t0 > LO[r] ? t0 : LO[r];
            T1[r] = t1 < HI[r] ? t1 : HI[r];
        }
        Py_END_ALLOW_THREADS
    }
    result = PyTuple_Pack(2, o_0, o_1);
done:
    buf_release(&bo); buf_release(&bd); buf_release(&blo); buf_release(&bhi);
    buf_release(&bw); buf_release(&bl);
    Py_XDECREF(o_0); Py_XDECREF(o_1);
    return result;
}
