/* Rays against triangles, shared by the light paths (paths.c) and the surfaces' ray casts
 * (intersect.c, the twin of surfaces.intersect_np).  A triangle is 9 float64: its corner v0
 * and two edges e1, e2 (m); consecutive TRI_CHUNK triangles share a culling box.
 */
#ifndef MPP_TRIANGLES_H
#define MPP_TRIANGLES_H

#include "common.h"

#define TRI_CHUNK 64   /* triangles per culling box */

/* The culling boxes (n_box = ceil(n_tri / TRI_CHUNK), 6 float64 each: lo, hi) of n_tri
 * triangles, a little wider than the triangles so that a grazing ray still tests them. */
static inline void tri_chunk_boxes(const double *tri, Py_ssize_t n_tri, double *boxes) {
    Py_ssize_t n_box = (n_tri + TRI_CHUNK - 1) / TRI_CHUNK;
    for (Py_ssize_t bx = 0; bx < n_box; bx++) {
        double *B = boxes + 6 * bx;
        for (int a = 0; a < 3; a++) { B[a] = INFINITY; B[3 + a] = -INFINITY; }
        Py_ssize_t end = (bx + 1) * TRI_CHUNK < n_tri ? (bx + 1) * TRI_CHUNK : n_tri;
        for (Py_ssize_t k = bx * TRI_CHUNK; k < end; k++) {
            const double *v = tri + 9 * k;
            for (int corner = 0; corner < 3; corner++)
                for (int a = 0; a < 3; a++) {
                    double x = v[a] + (corner ? v[3 * corner + a] : 0.0);
                    if (x < B[a]) B[a] = x;
                    if (x > B[3 + a]) B[3 + a] = x;
                }
        }
        for (int a = 0; a < 3; a++) {
            double pad = 1e-9 * (1.0 + fabs(B[a]) + fabs(B[3 + a]));
            B[a] -= pad;
            B[3 + a] += pad;
        }
    }
}

/* The nearest of the n_tri triangles hit by o + t d for t in (tmin, tmax), other than
 * `skip` (-1: none), its t in *t_hit (tmax when none); -1 when none.  Moller-Trumbore; the
 * first triangle in order wins a tie. */
static inline Py_ssize_t tri_hit(const double *tri, Py_ssize_t n_tri, const double *box,
                                 const double o[3], const double d[3], double tmin,
                                 double tmax, Py_ssize_t skip, double *t_hit) {
    Py_ssize_t found = -1, n_box = (n_tri + TRI_CHUNK - 1) / TRI_CHUNK;
    double best = tmax;
    for (Py_ssize_t bi = 0; bi < n_box; bi++) {
        const double *B = box + 6 * bi;
        double t0 = 0.0, t1 = best;
        int miss = 0;
        for (int a = 0; a < 3 && !miss; a++) {
            if (d[a] == 0.0) {
                if (o[a] < B[a] || o[a] > B[3 + a]) miss = 1;
                continue;
            }
            double ta = (B[a] - o[a]) / d[a], tb = (B[3 + a] - o[a]) / d[a];
            if (ta > tb) { double x = ta; ta = tb; tb = x; }
            if (ta > t0) t0 = ta;
            if (tb < t1) t1 = tb;
            if (t1 < t0) miss = 1;
        }
        if (miss) continue;
        Py_ssize_t end = (bi + 1) * TRI_CHUNK < n_tri ? (bi + 1) * TRI_CHUNK : n_tri;
        for (Py_ssize_t k = bi * TRI_CHUNK; k < end; k++) {
            if (k == skip) continue;
            const double *v0 = tri + 9 * k, *e1 = v0 + 3, *e2 = v0 + 6;
            double p[3] = {d[1] * e2[2] - d[2] * e2[1], d[2] * e2[0] - d[0] * e2[2],
                           d[0] * e2[1] - d[1] * e2[0]};
            double det = p[0] * e1[0] + p[1] * e1[1] + p[2] * e1[2];
            if (!(fabs(det) > 1e-300)) continue;
            double inv = 1.0 / det;
            double s[3] = {o[0] - v0[0], o[1] - v0[1], o[2] - v0[2]};
            double u = (s[0] * p[0] + s[1] * p[1] + s[2] * p[2]) * inv;
            if (!(u >= 0.0 && u <= 1.0)) continue;
            double q[3] = {s[1] * e1[2] - s[2] * e1[1], s[2] * e1[0] - s[0] * e1[2],
                           s[0] * e1[1] - s[1] * e1[0]};
            double v = (d[0] * q[0] + d[1] * q[1] + d[2] * q[2]) * inv;
            if (!(v >= 0.0 && u + v <= 1.0)) continue;
            double t = (e2[0] * q[0] + e2[1] * q[1] + e2[2] * q[2]) * inv;
            if (t > tmin && t < best) {
                best = t;
                found = k;
            }
        }
    }
    *t_hit = best;
    return found;
}

#endif
