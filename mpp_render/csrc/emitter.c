/* The transmittance an area light's emitter reaches points with, averaged over quadrature
 * nodes of the emitter by the solid angle each subtends (twin of
 * lights.emitter_transmittance; lights.area_transmittance picks the nodes).  numpy took
 * (N, K) arrays through a dozen passes; a ground that the walk model lights as an emitter
 * puts 256 nodes on every voxel of the medium above it. */
#include "kernels.h"

const char emitter_transmittance_doc[] =
    "emitter_transmittance(x, tau, dc, nodes, weights, normal, voxel) -> bytes\n"
    "Twin of lights.emitter_transmittance: x (N,3) float64 points (m), tau (N,3) their\n"
    "optical depth to the emitter's centre, dc (N,) their distance from it (m); nodes (K,3)\n"
    "float64 points of the emitter (m) with quadrature weights (K,), normal (3,) its unit\n"
    "emitting normal; voxel (m) > 0.  Per point the mean over the nodes, weighed by\n"
    "w_k max(v . normal, 0) / d^3 (v from node to point, d = |v|), of exp(-tau d / max(dc,\n"
    "voxel / 2)); exp(-tau) where no node faces the point.  (N,3) float64 as bytes; the GIL\n"
    "is released.";

PyObject *emitter_transmittance(PyObject *self, PyObject *args) {
    PyObject *px, *pt, *pd, *pn, *pw, *pm;
    double voxel;
    if (!PyArg_ParseTuple(args, "OOOOOOd", &px, &pt, &pd, &pn, &pw, &pm, &voxel)) return NULL;
    Buf bx = {0}, bt = {0}, bd = {0}, bn = {0}, bw = {0}, bm = {0};
    PyObject *result = NULL;
    Py_ssize_t sx[2] = {-1, 3}, sn[2] = {-1, 3}, sm[1] = {3};
    if (get_buf(px, &bx, 'd', 2, sx, "x") < 0 || get_buf(pn, &bn, 'd', 2, sn, "nodes") < 0 ||
        get_buf(pm, &bm, 'd', 1, sm, "normal") < 0)
        goto done;
    Py_ssize_t n = sx[0], k = sn[0], st[2] = {n, 3}, sd[1] = {n}, sw[1] = {k};
    if (get_buf(pt, &bt, 'd', 2, st, "tau") < 0 || get_buf(pd, &bd, 'd', 1, sd, "dc") < 0 ||
        get_buf(pw, &bw, 'd', 1, sw, "weights") < 0)
        goto done;
    if (!(voxel > 0.0) || !isfinite(voxel)) {
        PyErr_SetString(PyExc_ValueError, "emitter_transmittance: voxel must be > 0");
        goto done;
    }
    if (n > PY_SSIZE_T_MAX / (3 * (Py_ssize_t)sizeof(double))) {
        PyErr_SetString(PyExc_ValueError, "emitter_transmittance: too many points");
        goto done;
    }
    result = PyBytes_FromStringAndSize(NULL, n * 3 * (Py_ssize_t)sizeof(double));
    if (!result) goto done;
    {
        double *out = (double *)PyBytes_AS_STRING(result);
        const double *X = bx.view.buf, *T = bt.view.buf, *D = bd.view.buf, *P = bn.view.buf,
                     *W = bw.view.buf, *nl = bm.view.buf;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t q = 0; q < n; q++) {
            const double *x = X + 3 * q, *tau = T + 3 * q;
            double reach = D[q] > 0.5 * voxel ? D[q] : 0.5 * voxel;   /* path_stretch's */
            int grey = tau[0] == tau[1] && tau[1] == tau[2];
            double num[3] = {0.0, 0.0, 0.0}, den = 0.0;
            for (Py_ssize_t j = 0; j < k; j++) {
                const double *p = P + 3 * j;
                double v[3] = {x[0] - p[0], x[1] - p[1], x[2] - p[2]};
                double d = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
                d = d > 1e-9 ? d : 1e-9;
                double facing = v[0] * nl[0] + v[1] * nl[1] + v[2] * nl[2];
                double w = W[j] * (facing > 0.0 ? facing : 0.0) / (d * d * d);
                if (!(w > 0.0)) continue;
                double s = d / reach;
                den += w;
                if (grey) {
                    double e = w * exp(-tau[0] * s);
                    num[0] += e; num[1] += e; num[2] += e;
                } else {
                    for (int a = 0; a < 3; a++) num[a] += w * exp(-tau[a] * s);
                }
            }
            for (int a = 0; a < 3; a++) out[3 * q + a] = den > 0.0 ? num[a] / den : exp(-tau[a]);
        }
        Py_END_ALLOW_THREADS
    }
done:
    buf_release(&bx); buf_release(&bt); buf_release(&bd); buf_release(&bn); buf_release(&bw);
    buf_release(&bm);
    return result;
}
