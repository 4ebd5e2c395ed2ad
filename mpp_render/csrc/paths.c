/* Light paths through a medium for multiple scattering (twin of mpp_render.paths.trace_paths_np,
 * which documents the estimate).  Every size is checked against the buffers, every voxel and
 * lattice index is bounds-checked, and each path's events are capped, so no input reads out
 * of bounds or loops without end.  The loop runs without the GIL.
 */
#include "kernels.h"
#include "light.h"   /* basis: the orthonormal frame of phase.orthonormal_basis */

const char trace_paths_doc[] =
    "trace_paths(out, density, w2i, i2w, sigma_s, sigma_t, g, stride, towards, starts, weights,\n"
    "            dirs, cdf, rate, path_lo, path_hi, n_paths, seed, max_collisions, roulette)\n"
    "Twin of mpp_render.paths.trace_paths_np: adds to out (LX,LY,LZ,3) float64 the deposits\n"
    "of paths path_lo..path_hi-1 of n_paths.";

#define MAX_EVENTS 1000000L   /* tentative collisions per path, whatever the medium */
#define MAX_RATE_SPAN 1e6    /* rate x the grid's diagonal (m): tentative points across it */
#define D_PICK 0
#define D_JIT 1
#define D_DIR 7
#define D_FLY 10
#define D_HIT 11
#define D_TURN 12
#define D_RR 14

static inline void turn(double u1, double u2, double g, const double axis[3], double out[3]) {
    double c;
    if (fabs(g) < 1e-4) {
        c = 1.0 - 2.0 * u1;
    } else {
        double s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u1);
        c = (1.0 + g * g - s * s) / (2.0 * g);
    }
    if (c < -1.0) c = -1.0;
    if (c > 1.0) c = 1.0;
    double st = sqrt(fmax(0.0, 1.0 - c * c)), phi = 2.0 * M_PI * u2;
    double t1[3], t2[3];
    basis(axis, t1, t2);
    double cp = st * cos(phi), sp = st * sin(phi), len2 = 0.0;
    for (int a = 0; a < 3; a++) {
        out[a] = t1[a] * cp + t2[a] * sp + axis[a] * c;
        len2 += out[a] * out[a];
    }
    double len = sqrt(len2);
    for (int a = 0; a < 3; a++) out[a] /= len;
}

typedef struct {
    const float *dens;
    Py_ssize_t n[3];
    double w2i[12], i2w[9], ss[3], st[3], st_max, g, mu, roulette;
    long stride, max_hits;
    const double *tw;
    Py_ssize_t ls[3];
    double *out;
} Tracer;

static void trace_one(const Tracer *T, uint32_t key, const double *start, const double *w_start,
                      const double *dir, double inv_n) {
    double pos[3], d[3], w[3], off[3], w0 = 0.0;
    for (int a = 0; a < 3; a++)
        off[a] = (uniform01(key, 0, D_JIT + 2 * a) + uniform01(key, 0, D_JIT + 2 * a + 1) - 1.0) *
                 (double)T->stride;
    for (int a = 0; a < 3; a++)
        pos[a] = start[a] + T->i2w[3 * a] * off[0] + T->i2w[3 * a + 1] * off[1] +
                 T->i2w[3 * a + 2] * off[2];
    turn(uniform01(key, 0, D_DIR), uniform01(key, 0, D_DIR + 1), T->g, dir, d);
    for (int c = 0; c < 3; c++) {
        w[c] = w_start[c] * inv_n;
        if (w[c] > w0) w0 = w[c];
    }
    long hits = 0;
    for (long ev = 1; ev <= MAX_EVENTS; ev++) {
        double t = -log(1.0 - uniform01(key, ev, D_FLY)) / T->mu, idx[3];
        for (int a = 0; a < 3; a++) pos[a] += t * d[a];
        for (int r = 0; r < 3; r++)
            idx[r] = T->w2i[4 * r] * pos[0] + T->w2i[4 * r + 1] * pos[1] +
                     T->w2i[4 * r + 2] * pos[2] + T->w2i[4 * r + 3];
        Py_ssize_t v[3];
        for (int a = 0; a < 3; a++) {
            double f = floor(idx[a] + 0.5);
            if (!(f >= 0.0 && f < (double)T->n[a])) return;   /* left the grid (or NaN) */
            v[a] = (Py_ssize_t)f;
        }
        double rho = (double)T->dens[(v[0] * T->n[1] + v[1]) * T->n[2] + v[2]];
        if (!(rho >= 0.0)) rho = 0.0;   /* NaN or negative density: empty */
        /* deposit, weighted by the density, on the 8 lattice points round the point */
        double lat[3], fr[3];
        Py_ssize_t b[3];
        for (int a = 0; a < 3; a++) {
            lat[a] = idx[a] / (double)T->stride;
            double fl = floor(lat[a]);
            b[a] = (Py_ssize_t)fl;
            fr[a] = lat[a] - fl;
        }
        for (int corner = 0; corner < 8; corner++) {
            int o[3] = {(corner >> 2) & 1, (corner >> 1) & 1, corner & 1};
            Py_ssize_t cc[3];
            double share = 1.0;
            int ok = 1;
            for (int a = 0; a < 3; a++) {
                cc[a] = b[a] + o[a];
                if (cc[a] < 0 || cc[a] >= T->ls[a]) ok = 0;
                share *= o[a] ? fr[a] : 1.0 - fr[a];
            }
            if (!ok) continue;
            Py_ssize_t flat = (cc[0] * T->ls[1] + cc[1]) * T->ls[2] + cc[2];
            const double *tv = T->tw + 3 * flat;
            double ph = hg_phase(d[0] * tv[0] + d[1] * tv[1] + d[2] * tv[2], T->g);
            for (int c = 0; c < 3; c++) T->out[3 * flat + c] += (w[c] / T->mu) * rho * share * ph;
        }
        double p_hit = rho * T->st_max / T->mu;
        if (p_hit > 1.0) p_hit = 1.0;
        int hit = uniform01(key, ev, D_HIT) < p_hit;
        if (!hit) {
            double den = fmax(1.0 - p_hit, 1e-12);
            for (int c = 0; c < 3; c++) w[c] *= (1.0 - rho * T->st[c] / T->mu) / den;
        } else {
            for (int c = 0; c < 3; c++) w[c] *= T->ss[c] / T->st_max;
            double nd[3];
            turn(uniform01(key, ev, D_TURN), uniform01(key, ev, D_TURN + 1), T->g, d, nd);
            for (int a = 0; a < 3; a++) d[a] = nd[a];
            hits++;
        }
        double m = fmax(w[0], fmax(w[1], w[2])) / fmax(w0, 1e-300);
        double q = (hit && m < T->roulette) ? m / T->roulette : 1.0;
        int survive = uniform01(key, ev, D_RR) < q;
        for (int c = 0; c < 3; c++) w[c] /= fmax(q, 1e-300);
        if (!survive || hits >= T->max_hits || !(fmax(w[0], fmax(w[1], w[2])) > 0.0)) return;
    }
}

PyObject *trace_paths(PyObject *self, PyObject *args) {
    PyObject *po, *pd, *pw2i, *pi2w, *pss, *pst, *ptw, *pstarts, *pws, *pdirs, *pcdf;
    double g, rate, roulette;
    long stride, lo, hi, n_paths, max_hits;
    unsigned long seed;
    if (!PyArg_ParseTuple(args, "OOOOOOdlOOOOOdlllkld", &po, &pd, &pw2i, &pi2w, &pss, &pst, &g,
                          &stride, &ptw, &pstarts, &pws, &pdirs, &pcdf, &rate, &lo, &hi,
                          &n_paths, &seed, &max_hits, &roulette))
        return NULL;
    Buf bo = {0}, bd = {0}, bw = {0}, bi = {0}, bss = {0}, bst = {0}, btw = {0}, bs = {0},
        bws = {0}, bdir = {0}, bc = {0};
    int ok = 0;
    Py_ssize_t so[4] = {-1, -1, -1, 3}, sd[3] = {-1, -1, -1}, sw[2] = {3, 4}, si[2] = {3, 3},
               s3[1] = {3}, stw[4] = {-1, -1, -1, 3}, sn[2] = {-1, 3}, sc[1] = {-1};
    if (get_buf_ex(po, &bo, 'd', 4, so, "out", PyBUF_WRITABLE) < 0) goto done;
    if (get_buf(pd, &bd, 'f', 3, sd, "density") < 0) goto done;
    if (get_buf(pw2i, &bw, 'd', 2, sw, "w2i") < 0) goto done;
    if (get_buf(pi2w, &bi, 'd', 2, si, "i2w") < 0) goto done;
    if (get_buf(pss, &bss, 'd', 1, s3, "sigma_s") < 0) goto done;
    s3[0] = 3;
    if (get_buf(pst, &bst, 'd', 1, s3, "sigma_t") < 0) goto done;
    stw[0] = so[0]; stw[1] = so[1]; stw[2] = so[2];
    if (get_buf(ptw, &btw, 'd', 4, stw, "towards") < 0) goto done;
    if (get_buf(pstarts, &bs, 'd', 2, sn, "starts") < 0) goto done;
    if (get_buf(pws, &bws, 'd', 2, sn, "weights") < 0) goto done;
    if (get_buf(pdirs, &bdir, 'd', 2, sn, "dirs") < 0) goto done;
    sc[0] = sn[0];
    if (get_buf(pcdf, &bc, 'd', 1, sc, "cdf") < 0) goto done;
    if (stride < 1 || !(rate > 0.0) || !isfinite(rate) || !isfinite(g) ||
        n_paths < 1 || lo < 0 || hi < lo || hi > n_paths || max_hits < 1 || !(roulette >= 0.0) ||
        sn[0] < 1) {
        PyErr_SetString(PyExc_ValueError, "trace_paths: bad stride, rate, g, path range or caps");
        goto done;
    }
    {
        /* the grid's diagonal in metres bounds the tentative points a crossing takes */
        const double *M = (const double *)bi.view.buf;
        double diag2 = 0.0;
        for (int r = 0; r < 3; r++) {
            double e = M[3 * r] * (double)sd[0] + M[3 * r + 1] * (double)sd[1] +
                       M[3 * r + 2] * (double)sd[2];
            diag2 += e * e;
        }
        double span = rate * sqrt(diag2);
        if (!(span <= MAX_RATE_SPAN)) {
            PyErr_SetString(PyExc_ValueError,
                            "trace_paths: the rate of tentative collisions is too high for the "
                            "grid (or the grid's size is not finite)");
            goto done;
        }
    }
    Tracer T;
    T.dens = (const float *)bd.view.buf;
    for (int a = 0; a < 3; a++) { T.n[a] = sd[a]; T.ls[a] = so[a]; }
    memcpy(T.w2i, bw.view.buf, sizeof T.w2i);
    memcpy(T.i2w, bi.view.buf, sizeof T.i2w);
    memcpy(T.ss, bss.view.buf, sizeof T.ss);
    memcpy(T.st, bst.view.buf, sizeof T.st);
    T.st_max = fmax(T.st[0], fmax(T.st[1], T.st[2]));
    if (!(T.st_max > 0.0) || !isfinite(T.st_max)) {
        PyErr_SetString(PyExc_ValueError, "trace_paths: sigma_t must be positive and finite");
        goto done;
    }
    T.g = g > 0.999 ? 0.999 : (g < -0.999 ? -0.999 : g);
    T.mu = rate;
    T.roulette = roulette;
    T.stride = stride;
    T.max_hits = max_hits;
    T.tw = (const double *)btw.view.buf;
    T.out = (double *)bo.view.buf;
    const double *S = (const double *)bs.view.buf, *W = (const double *)bws.view.buf,
                 *D = (const double *)bdir.view.buf, *C = (const double *)bc.view.buf;
    Py_ssize_t n_starts = sn[0];
    Py_BEGIN_ALLOW_THREADS
    uint32_t base = hash32((uint32_t)((uint64_t)seed * 0x27D4EB2Fu + 0x165667B1u));
    for (long i = lo; i < hi; i++) {
        uint32_t key = hash32((uint32_t)i ^ base);
        double u = uniform01(key, 0, D_PICK);
        /* searchsorted(cdf, u, side="right"), clamped to the last start */
        Py_ssize_t a = 0, b = n_starts;
        while (a < b) {
            Py_ssize_t mid = a + (b - a) / 2;
            if (C[mid] <= u) a = mid + 1; else b = mid;
        }
        if (a > n_starts - 1) a = n_starts - 1;
        trace_one(&T, key, S + 3 * a, W + 3 * a, D + 3 * a, 1.0 / (double)n_paths);
    }
    Py_END_ALLOW_THREADS
    ok = 1;
done:
    buf_release(&bo); buf_release(&bd); buf_release(&bw); buf_release(&bi); buf_release(&bss);
    buf_release(&bst); buf_release(&btw); buf_release(&bs); buf_release(&bws);
    buf_release(&bdir); buf_release(&bc);
    if (!ok) return NULL;
    Py_RETURN_NONE;
}
