/* The Python entry points of mpp_render._kernels, one file each; module.c lists them. */
#ifndef MPP_KERNELS_H
#define MPP_KERNELS_H

#include "common.h"

#define STOP_EVERY 16  /* paths traced between reads of the stop flag (trace_paths) */

extern const char optical_depth_doc[], light_sweep_doc[], upsample_into_doc[], march_doc[],
    trilinear_doc[], light_layout_doc[], trace_paths_doc[], intersect_doc[],
    union_interval_doc[], walk_depth_doc[], nodal_fit_doc[], lobe_ratio_doc[],
    light_samples_doc[], emitter_transmittance_doc[];
PyObject *optical_depth(PyObject *self, PyObject *args);
PyObject *light_sweep(PyObject *self, PyObject *args);
PyObject *upsample_into(PyObject *self, PyObject *args);
PyObject *march(PyObject *self, PyObject *args);
PyObject *py_trilinear(PyObject *self, PyObject *args);
PyObject *light_layout(PyObject *self, PyObject *noargs);
PyObject *trace_paths(PyObject *self, PyObject *args);
PyObject *intersect(PyObject *self, PyObject *args);
PyObject *union_interval(PyObject *self, PyObject *args);
PyObject *walk_depth(PyObject *self, PyObject *args);
PyObject *nodal_fit(PyObject *self, PyObject *args);
PyObject *lobe_ratio(PyObject *self, PyObject *args);
PyObject *light_samples(PyObject *self, PyObject *args);
PyObject *emitter_transmittance(PyObject *self, PyObject *args);

#endif
