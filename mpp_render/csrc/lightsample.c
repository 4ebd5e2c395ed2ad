/* A packed light sampled at many points (twin of lights.light_sample without surface
 * normals): what the surfaces' shading and the world fog's tail beyond its grid ask of every
 * lamp at every sample, which numpy worked out in a dozen passes over the points. */
#include "kernels.h"
#include "light.h"

const char light_samples_doc[] =
    "light_samples(rec, x, u1, u2) -> bytes\n"
    "Twin of lights.light_sample without surface normals: rec (LIGHT_FIELDS,) float64 one\n"
    "packed light (mpp_render.lightrecord), x (N,3) float64 points (m), u1, u2 (N,) float64\n"
    "its jitter in [0, 1).  (N,11) float64 as bytes: per point the propagation direction (3),\n"
    "the irradiance (3, W/m^2), the unit direction to the light's centre (3), the centre's\n"
    "distance and the sampled emitter point's (m; inf for a sun).  The GIL is released.";

PyObject *light_samples(PyObject *self, PyObject *args) {
    PyObject *pr, *px, *pu, *pv;
    if (!PyArg_ParseTuple(args, "OOOO", &pr, &px, &pu, &pv)) return NULL;
    Buf br = {0}, bx = {0}, bu = {0}, bv = {0};
    PyObject *result = NULL;
    Py_ssize_t sr[1] = {LIGHT_FIELDS}, sx[2] = {-1, 3}, su[1] = {-1}, sv[1] = {-1};
    if (get_buf(pr, &br, 'd', 1, sr, "rec") < 0 || get_buf(px, &bx, 'd', 2, sx, "x") < 0)
        goto done;
    su[0] = sv[0] = sx[0];   /* one jitter pair per point */
    if (get_buf(pu, &bu, 'd', 1, su, "u1") < 0 || get_buf(pv, &bv, 'd', 1, sv, "u2") < 0)
        goto done;
    const double *L = (const double *)br.view.buf;
    if (!light_kind_known(L[L_KIND])) {
        PyErr_SetString(PyExc_ValueError, "light_samples: unknown kind");
        goto done;
    }
    Py_ssize_t n = sx[0];
    if (n > PY_SSIZE_T_MAX / (11 * (Py_ssize_t)sizeof(double))) {
        PyErr_SetString(PyExc_ValueError, "light_samples: too many points");
        goto done;
    }
    result = PyBytes_FromStringAndSize(NULL, n * 11 * (Py_ssize_t)sizeof(double));
    if (!result) goto done;
    {
        double *out = (double *)PyBytes_AS_STRING(result);
        const double *X = (const double *)bx.view.buf, *U = (const double *)bu.view.buf,
                     *V = (const double *)bv.view.buf;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t q = 0; q < n; q++) {
            double *o = out + 11 * q;
            light_sample(L, X + 3 * q, U[q], V[q], o, o + 3, o + 6, o + 9, o + 10);
        }
        Py_END_ALLOW_THREADS
    }
done:
    buf_release(&br); buf_release(&bx); buf_release(&bu); buf_release(&bv);
    return result;
}
