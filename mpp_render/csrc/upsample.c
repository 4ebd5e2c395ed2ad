/* Lattice upsampling (twin of kernels_np.upsample_into). */
#include "kernels.h"

#define GEO_FLOOR 1e-30   /* the logarithm's floor (twin: kernels_np.GEO_FLOOR); a corner of
                             weight 0 may hold 0 */

const char upsample_into_doc[] =
    "upsample_into(field, channel, lattice, stride, flat[, inside]) -> None\n"
    "Twin of kernels_np.upsample_into: trilinear values of the lattice (point j at fine index\n"
    "j * stride) written into field[..., channel:channel + C] at the flat voxel indices (None:\n"
    "every voxel).  inside: None, or uint8 (cx,cy,cz) the lattice points inside the medium:\n"
    "where every point a voxel's value weighs is inside and above 0 in a channel, that\n"
    "channel's logarithm is interpolated (geometric: exact for an exponential fall).";

PyObject *upsample_into(PyObject *self, PyObject *args) {
    PyObject *pf, *pl, *pflat, *pin = Py_None;
    int channel, stride;
    if (!PyArg_ParseTuple(args, "OiOiO|O", &pf, &channel, &pl, &stride, &pflat, &pin))
        return NULL;
    Buf bf = {0}, bl = {0}, bx = {0}, bi = {0};
    double *LG = NULL;   /* with inside: each lattice value's logarithm, taken once */
    int ok = 0;
    Py_ssize_t sf[4] = {-1, -1, -1, -1}, sl[4] = {-1, -1, -1, -1}, sx[1] = {-1};
    if (get_buf_ex(pf, &bf, 'f', 4, sf, "field", PyBUF_WRITABLE) < 0) goto done;
    if (get_buf(pl, &bl, 'f', 4, sl, "lattice") < 0) goto done;
    int every = pflat == Py_None;   /* None: every voxel of the field */
    if (!every && PyObject_GetBuffer(pflat, &bx.view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | PyBUF_ND) < 0) {
        PyErr_Clear();
        PyErr_SetString(PyExc_ValueError, "flat: expected a C-contiguous int64 array");
        goto done;
    }
    bx.held = !every;
    if (!every) {
        const char *fm = bx.view.format ? bx.view.format : "B";
        if (fm[0] == '<' || fm[0] == '=' || fm[0] == '@') fm++;
        if (bx.view.ndim != 1 || bx.view.itemsize != 8 || (fm[0] != 'q' && fm[0] != 'l') || fm[1]) {
            PyErr_SetString(PyExc_ValueError, "flat: expected a 1-D int64 array");
            goto done;
        }
        sx[0] = bx.view.shape[0];
    }
    Py_ssize_t nc = sl[3];
    if (stride < 1 || nc < 1 || channel < 0 || channel + nc > sf[3] || sl[0] < 1 || sl[1] < 1 ||
        sl[2] < 1) {
        PyErr_SetString(PyExc_ValueError, "upsample_into: bad stride, channel or lattice");
        goto done;
    }
    const unsigned char *IN = NULL;
    if (pin != Py_None) {
        Py_ssize_t si[3] = {sl[0], sl[1], sl[2]};
        if (get_buf(pin, &bi, 'B', 3, si, "inside") < 0) goto done;
        IN = (const unsigned char *)bi.view.buf;
    }
    const int64_t *FL = every ? NULL : (const int64_t *)bx.view.buf;
    Py_ssize_t nvox = sf[0] * sf[1] * sf[2];
    if (every) sx[0] = nvox;
    for (Py_ssize_t q = 0; FL && q < sx[0]; q++)
        if (FL[q] < 0 || FL[q] >= nvox) {
            PyErr_SetString(PyExc_ValueError, "flat: index outside the field");
            goto done;
        }
    float *F = (float *)bf.view.buf;
    const float *LT = (const float *)bl.view.buf;
    Py_ssize_t nlat = sl[0] * sl[1] * sl[2] * nc;
    if (IN) {
        LG = (double *)malloc((size_t)nlat * sizeof(double));
        if (!LG) { PyErr_NoMemory(); goto done; }
        for (Py_ssize_t q = 0; q < nlat; q++) {
            double x = (double)LT[q];
            LG[q] = log(x > GEO_FLOOR ? x : GEO_FLOOR);
        }
    }
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t q = 0; q < sx[0]; q++) {
        Py_ssize_t f = FL ? (Py_ssize_t)FL[q] : q, ijk[3] = {f / (sf[1] * sf[2]), (f / sf[2]) % sf[1], f % sf[2]};
        Py_ssize_t lo[3], hi[3];
        double t[3];
        for (int a = 0; a < 3; a++) {
            lo[a] = ijk[a] / stride;
            if (lo[a] > sl[a] - 1) lo[a] = sl[a] - 1;
            hi[a] = lo[a] + 1 > sl[a] - 1 ? sl[a] - 1 : lo[a] + 1;
            t[a] = (double)(ijk[a] - lo[a] * stride) / (double)stride;
        }
        /* the 8 corners' weights and lattice points, n = 4 cx + 2 cy + cz; with inside,
         * whether every point of weight > 0 lies inside the medium */
        double w[8];
        Py_ssize_t pt[8];
        int geo = IN != NULL;
        for (int n = 0; n < 8; n++) {
            int cx = n >> 2, cy = (n >> 1) & 1, cz = n & 1;
            w[n] = (cx ? t[0] : 1.0 - t[0]) * (cy ? t[1] : 1.0 - t[1]) * (cz ? t[2] : 1.0 - t[2]);
            pt[n] = ((cx ? hi[0] : lo[0]) * sl[1] + (cy ? hi[1] : lo[1])) * sl[2] + (cz ? hi[2] : lo[2]);
            if (geo && w[n] > 0.0 && !IN[pt[n]]) geo = 0;
        }
        for (Py_ssize_t c = 0; c < nc; c++) {
            double v = 0.0, lv = 0.0;
            int pos = geo;
            for (int n = 0; n < 8; n++) {
                Py_ssize_t at = pt[n] * nc + c;
                double x = (double)LT[at];
                v += w[n] * x;
                if (geo) {
                    if (w[n] > 0.0 && !(x > 0.0)) pos = 0;
                    lv += w[n] * LG[at];
                }
            }
            F[f * sf[3] + channel + c] = (float)(pos ? exp(lv) : v);
        }
    }
    Py_END_ALLOW_THREADS
    ok = 1;
done:
    free(LG);
    buf_release(&bf); buf_release(&bl); buf_release(&bx); buf_release(&bi);
    if (!ok) return NULL;
    Py_RETURN_NONE;
}
