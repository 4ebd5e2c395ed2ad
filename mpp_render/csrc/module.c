/* mpp_render._kernels: the method table.  Each kernel lives in its own file (optical_depth.c,
 * sweep.c, march.c, upsample.c, trilinear.c, paths.c, intersect.c, intervals.c, nodal.c,
 * lobefit.c, lightsample.c) over the shared headers common.h
 * (buffers, grids, trilinear reads, random numbers), bricks.h (empty space), light.h (the light
 * record) and triangles.h (rays against triangles).
 */
#include "kernels.h"
#include "light.h"

const char light_layout_doc[] =
    "light_layout() -> dict\n"
    "The light record's layout as compiled: LIGHT_FIELDS, the L_* offsets and the KIND_* kinds\n"
    "(held to mpp_render.lightrecord by the tests).";

PyObject *light_layout(PyObject *self, PyObject *noargs) {
    static const struct { const char *name; long value; } fields[] = {
        {"LIGHT_FIELDS", LIGHT_FIELDS}, {"L_KIND", L_KIND}, {"L_STRENGTH", L_STRENGTH},
        {"L_POS", L_POS}, {"L_DIR", L_DIR}, {"L_INV", L_INV}, {"L_COSHALF", L_COSHALF},
        {"L_BLEND", L_BLEND}, {"L_RADIUS", L_RADIUS}, {"L_AX", L_AX}, {"L_AY", L_AY},
        {"L_AREA", L_AREA}, {"L_NORMAL", L_NORMAL}, {"L_NORMALIZE", L_NORMALIZE},
        {"L_ROUND", L_ROUND}, {"L_CHANNEL", L_CHANNEL}, {"L_COND", L_COND}, {"L_BEAM", L_BEAM},
        {"L_INDIRECT", L_INDIRECT}, {"L_DISC", L_DISC}, {"L_ANGLES", L_ANGLES},
        {"KIND_POINT", KIND_POINT},
        {"KIND_SPOT", KIND_SPOT}, {"KIND_SUN", KIND_SUN}, {"KIND_AREA", KIND_AREA},
    };
    PyObject *d = PyDict_New();
    if (!d) return NULL;
    for (size_t i = 0; i < sizeof fields / sizeof fields[0]; i++) {
        PyObject *v = PyLong_FromLong(fields[i].value);
        if (!v || PyDict_SetItemString(d, fields[i].name, v) < 0) {
            Py_XDECREF(v);
            Py_DECREF(d);
            return NULL;
        }
        Py_DECREF(v);
    }
    return d;
}

static PyMethodDef methods[] = {
    {"march", march, METH_VARARGS, march_doc},
    {"optical_depth", optical_depth, METH_VARARGS, optical_depth_doc},
    {"light_sweep", light_sweep, METH_VARARGS, light_sweep_doc},
    {"upsample_into", upsample_into, METH_VARARGS, upsample_into_doc},
    {"trilinear", py_trilinear, METH_VARARGS, trilinear_doc},
    {"trace_paths", trace_paths, METH_VARARGS, trace_paths_doc},
    {"intersect", intersect, METH_VARARGS, intersect_doc},
    {"union_interval", union_interval, METH_VARARGS, union_interval_doc},
    {"walk_depth", walk_depth, METH_VARARGS, walk_depth_doc},
    {"nodal_fit", nodal_fit, METH_VARARGS, nodal_fit_doc},
    {"lobe_ratio", lobe_ratio, METH_VARARGS, lobe_ratio_doc},
    {"light_samples", light_samples, METH_VARARGS, light_samples_doc},
    {"emitter_transmittance", emitter_transmittance, METH_VARARGS, emitter_transmittance_doc},
    {"light_layout", light_layout, METH_NOARGS, light_layout_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef moduledef = {PyModuleDef_HEAD_INIT, "_kernels",
                                       "Compiled twins of mpp_render.kernels_np.", -1, methods,
                                       NULL, NULL, NULL, NULL};

/* SIMD: 1 where the trilinear sums run in SSE2 (common.h's corner_sums), 0 for the scalar code;
 * STOP_EVERY: the paths trace_paths traces between reads of its stop flag (Esc) */
PyMODINIT_FUNC PyInit__kernels(void) {
    PyObject *m = PyModule_Create(&moduledef);
    if (m && (PyModule_AddIntConstant(m, "SIMD", MPP_SIMD) < 0 ||
              PyModule_AddIntConstant(m, "STOP_EVERY", STOP_EVERY) < 0)) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
