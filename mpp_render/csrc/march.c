/* The camera-ray march (twin of kernels_np.march). */
#include "bricks.h"
#include "kernels.h"
#include "light.h"

#define MAX_LIGHTS 64
#define MAX_CH 256
#define DIM_JITTER 1000
#define REFINE_STEPS 8
#define EDGE_EPS 1e-6
#define T_MIN 1e-6
#define MAX_STEPS 1000000L  /* per ray: a 256^3 grid needs ~1000 */
#define SUPER 4             /* steps per super-step (kernels_np.SUPER) */

static inline double hg_phase(double c, double g) {
    double denom = 1.0 + g * g - 2.0 * g * c;
    if (denom < 1e-12) denom = 1e-12;
    return (1.0 - g * g) / (4.0 * M_PI * denom * sqrt(denom));
}

static void refined_tau(const Grid *f, int nm, int mi, int c, const double x[3], const double w[3],
                        double dist, double delta, double tau[3]) {
    double end[3] = {x[0], x[1], x[2]};
    tau[0] = tau[1] = tau[2] = 0.0;
    for (int k = 1; k <= REFINE_STEPS; k++) {
        double seg = dist - (k - 1) * delta;
        seg = seg < 0.0 ? 0.0 : (seg > delta ? delta : seg);
        double s_mid = (k - 1) * delta + 0.5 * seg, s_end = (k - 1) * delta + seg, mid[3];
        for (int a = 0; a < 3; a++) { mid[a] = x[a] + w[a] * s_mid; end[a] = x[a] + w[a] * s_end; }
        for (int m = 0; m < nm; m++) {
            double rho = density_from(&f[m], fetch0(&f[m], mid));
            for (int a = 0; a < 3; a++) tau[a] += rho * seg * f[m].sig[a];
        }
        double occ = fetch0(&f[mi], end);
        if (occ <= EDGE_EPS || occ >= 1.0 - EDGE_EPS || seg < delta) break;
    }
    double idx[3], v[3];
    to_index(&f[mi], end, idx);
    trilinear(&f[mi], idx, c, 3, v);
    for (int a = 0; a < 3; a++) tau[a] += v[a];
}


/* ---- multiple scattering (twin of kernels_np.multiple_source) ---- */
#define MAX_LEVELS 16
typedef struct {
    int first[MAX_MEDIA][MAX_LIGHTS];   /* index of level 0 in `lv`, or -1 */
    int nlev[MAX_MEDIA][MAX_LIGHTS];
    double stride[MAX_MEDIA][MAX_LIGHTS], h[MAX_MEDIA][MAX_LIGHTS];
    const double *tab[MAX_MEDIA];       /* per medium (K, nr, 6): weight R,G,B, anisotropy R,G,B */
    int tabk[MAX_MEDIA];
    Py_ssize_t nr;
    double lr0, dlr;                    /* log density of table entry 0, spacing */
    int amb;                            /* world-light multiple channel or -1 */
} MS;

static void multiple_source_c(const MS *ms, const Grid *lv, int m, int nl, const double *cosl,
                              double rho, const double x[3], const double *w2i, double out[3]) {
    double idx_w[3];
    for (int r = 0; r < 3; r++)
        idx_w[r] = w2i[4 * r] * x[0] + w2i[4 * r + 1] * x[1] + w2i[4 * r + 2] * x[2] + w2i[4 * r + 3];
    out[0] = out[1] = out[2] = 0.0;
    double f = (log(rho > 1e-300 ? rho : 1e-300) - ms->lr0) / ms->dlr;
    double fmax = (double)(ms->nr - 1);
    f = f < 0.0 ? 0.0 : (f > fmax ? fmax : f);
    Py_ssize_t i = (Py_ssize_t)floor(f);
    if (i > ms->nr - 2) i = ms->nr - 2;
    double t = f - (double)i;
    const double *tab = ms->tab[m];
    for (int l = 0; l < nl; l++) {
        int f0 = ms->first[m][l], K = ms->nlev[m][l];
        if (f0 < 0 || K <= 0) continue;
        if (K > ms->tabk[m]) K = ms->tabk[m];
        double stride = ms->stride[m][l];
        for (int k = 0; k < K; k++) {
            const double *e0 = tab + ((Py_ssize_t)k * ms->nr + i) * 6, *e1 = e0 + 6;
            double scale = stride * ldexp(1.0, k), idx[3], q[3];
            for (int a = 0; a < 3; a++) idx[a] = idx_w[a] / scale;
            if (trilinear(&lv[f0 + k], idx, 0, 3, q)) {
                double phase = 0.0, g_prev = 0.0;
                for (int a = 0; a < 3; a++) {  /* by channel; one phase when they agree */
                    double gk = e0[3 + a] * (1.0 - t) + e1[3 + a] * t;
                    if (a == 0 || gk != g_prev) phase = hg_phase(cosl[l], gk);
                    g_prev = gk;
                    double weight = e0[a] * (1.0 - t) + e1[a] * t;
                    out[a] += q[a] * (weight * phase);
                }
            }
        }
    }
}

#define LIGHT_VARIATION 0.2  /* kernels_np.LIGHT_VARIATION */

/* Whether the light a lit local light scatters towards the camera (its irradiance at its
 * centre, before the media, times the phase function of anisotropy g) differs by more than
 * LIGHT_VARIATION between the ends of the segment [s_a, s_b] of the ray o + s d: a spot's cone
 * edge, a nearby light or a forward-scattering lobe, whose shape longer steps would miss.
 * Twin of kernels_np.light_varies. */
static int light_varies(const double *LR, Py_ssize_t nl, const int *chan, const double o[3],
                        const double d[3], double s_a, double s_b, double g) {
    double xa[3], xb[3], wi[3], e[3], wc[3], dc;
    for (int q = 0; q < 3; q++) { xa[q] = o[q] + d[q] * s_a; xb[q] = o[q] + d[q] * s_b; }
    for (Py_ssize_t l = 0; l < nl; l++) {
        if (chan[l] < 0 || (int)LR[l * LIGHT_FIELDS + L_KIND] == KIND_SUN) continue;
        light_sample(LR + l * LIGHT_FIELDS, xa, 0.5, 0.5, wi, e, wc, &dc);
        double ea = (e[0] + e[1] + e[2]) * hg_phase(-(wi[0] * d[0] + wi[1] * d[1] + wi[2] * d[2]), g);
        light_sample(LR + l * LIGHT_FIELDS, xb, 0.5, 0.5, wi, e, wc, &dc);
        double eb = (e[0] + e[1] + e[2]) * hg_phase(-(wi[0] * d[0] + wi[1] * d[1] + wi[2] * d[2]), g);
        double hi = ea > eb ? ea : eb, lo = ea > eb ? eb : ea;
        if (hi > 0.0 && !(lo >= (1.0 - LIGHT_VARIATION) * hi)) return 1;
    }
    return 0;
}

const char march_doc[] =
    "march(origins, dirs, t0, t1, axial, keys, fields, w2is, sigma_ss, sigma_ts, gs, thresholds,\n"
    "      voxels, lights, ambient, step, depth_opacity, depth_miss[, multiple, emissions, bricks, brick,\n"
    "      adapt_tau, emission_channels])\n"
    "  -> (single, T, depth, multiple, steps, emission) as bytes of float64\n"
    "Twin of kernels_np.march.";

PyObject *march(PyObject *self, PyObject *args) {
    PyObject *po, *pd, *pt0, *pt1, *pax, *pk, *fields, *w2is, *sss, *sts, *gsl, *thrs, *vox, *plights;
    PyObject *pms = Py_None, *pem = Py_None, *pbk = Py_None, *pec = Py_None;
    int ambient, brick = 4;
    double step, depth_opacity, depth_miss, adapt_tau = 0.0;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOOOiddd|OOOidO", &po, &pd, &pt0, &pt1, &pax, &pk, &fields,
                          &w2is, &sss, &sts, &gsl, &thrs, &vox, &plights, &ambient, &step,
                          &depth_opacity, &depth_miss, &pms, &pem, &pbk, &brick, &adapt_tau, &pec))
        return NULL;
    if (!isfinite(adapt_tau)) {
        PyErr_SetString(PyExc_ValueError, "adapt_tau must be finite");
        return NULL;
    }
    if (!(step > 0.0) || !isfinite(step)) {
        PyErr_SetString(PyExc_ValueError, "step must be a positive finite length");
        return NULL;
    }
    Buf bo = {0}, bd = {0}, b0 = {0}, b1 = {0}, bax = {0}, bk = {0}, bl = {0}, gb[MAX_MEDIA];
    Buf btab = {0}, btabs[MAX_MEDIA], kb[MAX_MEDIA];
    Bricks bks[MAX_MEDIA];
    int ntabs = 0, nkb = 0;
    Buf *lvb = NULL;
    Grid *lv = NULL;
    int nlv = 0, use_ms = 0;
    MS ms;
    memset(&ms, 0, sizeof ms);
    Grid g[MAX_MEDIA];
    double sig_s[MAX_MEDIA][3], gg[MAX_MEDIA], voxel[MAX_MEDIA], emit[MAX_MEDIA][3];
    int emc[MAX_MEDIA];  /* first channel of each medium's emission grid, or -1 */
    int use_em = 0;
    int ng = 0;
    PyObject *o_s = NULL, *o_t = NULL, *o_d = NULL, *o_m = NULL, *o_k = NULL, *o_e = NULL, *result = NULL;
    Py_ssize_t s_o[2] = {-1, 3};
    if (get_buf(po, &bo, 'd', 2, s_o, "origins") < 0) goto done;
    Py_ssize_t n = s_o[0];
    Py_ssize_t s_d[2] = {n, 3}, s_n[1] = {n}, s_n2[1] = {n}, s_n3[1] = {n}, s_n4[1] = {n};
    if (get_buf(pd, &bd, 'd', 2, s_d, "dirs") < 0) goto done;
    if (get_buf(pt0, &b0, 'd', 1, s_n, "t0") < 0) goto done;
    if (get_buf(pt1, &b1, 'd', 1, s_n2, "t1") < 0) goto done;
    if (get_buf(pax, &bax, 'd', 1, s_n3, "axial") < 0) goto done;
    if (get_buf(pk, &bk, 'I', 1, s_n4, "keys") < 0) goto done;
    if (parse_grids(fields, w2is, sts, thrs, g, gb, &ng, 1) < 0) goto done;
    if (parse_bricks(pbk, brick, g, ng, bks, kb, &nkb) < 0) goto done;
    int skip = pbk != Py_None;
    if (!PyList_Check(sss) || PyList_GET_SIZE(sss) != ng) {
        PyErr_SetString(PyExc_ValueError, "sigma_ss: one RGB array per medium");
        goto done;
    }
    for (int m = 0; m < ng; m++) {
        Buf sb;
        Py_ssize_t s3[1] = {3};
        if (get_buf(PyList_GET_ITEM(sss, m), &sb, 'd', 1, s3, "sigma_s") < 0) goto done;
        memcpy(sig_s[m], sb.view.buf, 3 * sizeof(double));
        buf_release(&sb);
        if (g[m].nc > MAX_CH) {
            PyErr_SetString(PyExc_ValueError, "fields: too many channels");
            goto done;
        }
    }
    if (parse_doubles(gsl, ng, gg, "gs") < 0 || parse_doubles(vox, ng, voxel, "voxels") < 0) goto done;
    if (pem != Py_None) {
        if (!PyList_Check(pem) || PyList_GET_SIZE(pem) != ng) {
            PyErr_SetString(PyExc_ValueError, "emissions: one RGB array per medium");
            goto done;
        }
        for (int m = 0; m < ng; m++) {
            Buf eb;
            Py_ssize_t s3[1] = {3};
            if (get_buf(PyList_GET_ITEM(pem, m), &eb, 'd', 1, s3, "emission") < 0) goto done;
            memcpy(emit[m], eb.view.buf, 3 * sizeof(double));
            buf_release(&eb);
            for (int a = 0; a < 3; a++)
                if (!isfinite(emit[m][a])) {
                    PyErr_SetString(PyExc_ValueError, "emission: non-finite value");
                    goto done;
                }
        }
        use_em = 1;
    }
    for (int m = 0; m < ng; m++) emc[m] = -1;
    if (pec != Py_None) {
        if (!PyList_Check(pec) || PyList_GET_SIZE(pec) != ng) {
            PyErr_SetString(PyExc_ValueError, "emission_channels: one int per medium");
            goto done;
        }
        for (int m = 0; m < ng; m++) {
            long c = PyLong_AsLong(PyList_GET_ITEM(pec, m));
            if (c == -1 && PyErr_Occurred()) goto done;
            if (c >= 0 && (c < 1 || c + 3 > g[m].nc)) {
                PyErr_SetString(PyExc_ValueError, "emission_channels: channel outside the fields");
                goto done;
            }
            emc[m] = c < 0 ? -1 : (int)c;
        }
    }
    for (int m = 0; m < ng; m++) {
        if (!(gg[m] > -1.0 && gg[m] < 1.0) || !(voxel[m] > 0.0) || !isfinite(voxel[m])) {
            PyErr_SetString(PyExc_ValueError, "gs must lie in (-1, 1) and voxels be positive");
            goto done;
        }
    }
    Py_ssize_t s_l[2] = {-1, LIGHT_FIELDS};
    if (get_buf(plights, &bl, 'd', 2, s_l, "lights") < 0) goto done;
    Py_ssize_t nl = s_l[0];
    if (nl > MAX_LIGHTS) {
        PyErr_SetString(PyExc_ValueError, "lights: at most 64 per call");
        goto done;
    }
    const double *LR = (const double *)bl.view.buf;
    int chan[MAX_LIGHTS], beam[MAX_LIGHTS], indirect[MAX_LIGHTS];
    for (Py_ssize_t l = 0; l < nl; l++) {
        double cf = LR[l * LIGHT_FIELDS + L_CHANNEL], kf = LR[l * LIGHT_FIELDS + L_KIND];
        indirect[l] = LR[l * LIGHT_FIELDS + L_INDIRECT] > 0.5;
        double bf = LR[l * LIGHT_FIELDS + L_BEAM];
        beam[l] = (cf >= 0 && bf >= 1.0 && bf < 1e9) ? (int)bf : -1;
        for (int m = 0; m < ng; m++)
            if (beam[l] >= 0 && beam[l] + 3 > g[m].nc) {
                PyErr_SetString(PyExc_ValueError, "lights: beam channel outside the fields");
                goto done;
            }
        if (!(kf == 0 || kf == 1 || kf == 2 || kf == 3)) {
            PyErr_SetString(PyExc_ValueError, "lights: unknown kind");
            goto done;
        }
        chan[l] = cf < 0 ? -1 : (int)cf;
        for (int m = 0; m < ng; m++)
            if (chan[l] >= 0 && (chan[l] < 1 || chan[l] + 3 > g[m].nc)) {
                PyErr_SetString(PyExc_ValueError, "lights: channel outside the fields");
                goto done;
            }
    }
    for (int m = 0; m < ng; m++)
        if (ambient >= 0 && (ambient < 1 || ambient + 3 > g[m].nc)) {
            PyErr_SetString(PyExc_ValueError, "ambient channel outside the fields");
            goto done;
        }
    if (pms != Py_None) {
        /* (amb_ms, levels list, table (M, L, 4) [first, count, stride, h],
         *  per-medium level tables [(K, nr, 6)], log density of entry 0, spacing) */
        PyObject *plv, *ptab, *ptabs;
        int amb_ms;
        double lr0, dlr;
        if (!PyTuple_Check(pms) || !PyArg_ParseTuple(pms, "iOOOdd", &amb_ms, &plv, &ptab, &ptabs, &lr0, &dlr)) {
            PyErr_SetString(PyExc_ValueError, "multiple: expected (amb, levels, table, tables, lr0, dlr)");
            goto done;
        }
        if (!PyList_Check(plv) || PyList_GET_SIZE(plv) > 100000) {
            PyErr_SetString(PyExc_ValueError, "multiple: levels must be a list");
            goto done;
        }
        if (!PyList_Check(ptabs) || PyList_GET_SIZE(ptabs) != ng || !(dlr > 0.0) || !isfinite(lr0) ||
            !isfinite(dlr)) {
            PyErr_SetString(PyExc_ValueError, "multiple: one level table per medium, dlr > 0");
            goto done;
        }
        nlv = (int)PyList_GET_SIZE(plv);
        lvb = (Buf *)calloc((size_t)(nlv > 0 ? nlv : 1), sizeof(Buf));
        lv = (Grid *)calloc((size_t)(nlv > 0 ? nlv : 1), sizeof(Grid));
        if (!lvb || !lv) { PyErr_NoMemory(); goto done; }
        for (int i = 0; i < nlv; i++) {
            Py_ssize_t sh[4] = {-1, -1, -1, 3};
            if (get_buf(PyList_GET_ITEM(plv, i), &lvb[i], 'f', 4, sh, "pyramid level") < 0) goto done;
            if (sh[0] < 2 || sh[1] < 2 || sh[2] < 2) {
                PyErr_SetString(PyExc_ValueError, "pyramid level: every extent must be >= 2");
                goto done;
            }
            lv[i].data = (const float *)lvb[i].view.buf;
            lv[i].nx = sh[0]; lv[i].ny = sh[1]; lv[i].nz = sh[2]; lv[i].nc = 3;
            lv[i].thr = -1.0;
        }
        Py_ssize_t nr = -1;
        for (int m = 0; m < ng; m++) {
            Py_ssize_t st[3] = {-1, nr, 6};
            if (get_buf(PyList_GET_ITEM(ptabs, m), &btabs[m], 'd', 3, st, "level table") < 0) goto done;
            ntabs = m + 1;
            if (st[0] < 1 || st[0] > MAX_LEVELS || st[1] < 2) {
                PyErr_SetString(PyExc_ValueError, "level table: 1..16 levels and >= 2 densities");
                goto done;
            }
            nr = st[1];
            ms.tab[m] = (const double *)btabs[m].view.buf;
            ms.tabk[m] = (int)st[0];
        }
        ms.nr = nr;
        ms.lr0 = lr0;
        ms.dlr = dlr;
        Py_ssize_t s_tab[3] = {ng, nl, 4};
        if (get_buf(ptab, &btab, 'd', 3, s_tab, "multiple table") < 0) goto done;
        const double *T = (const double *)btab.view.buf;
        for (int m = 0; m < ng; m++)
            for (Py_ssize_t l = 0; l < nl; l++) {
                const double *r = T + ((Py_ssize_t)m * nl + l) * 4;
                int first = (int)r[0], cnt = (int)r[1];
                if (!(r[1] >= 1.0) || !(r[0] >= 0.0)) { ms.first[m][l] = -1; ms.nlev[m][l] = 0; continue; }
                if (cnt > MAX_LEVELS || first > nlv - cnt || !(r[2] >= 1.0) || !(r[2] < 1e9) ||
                    !(r[3] > 0.0) || !isfinite(r[3])) {
                    PyErr_SetString(PyExc_ValueError, "multiple table: bad level range, stride or h");
                    goto done;
                }
                ms.first[m][l] = first; ms.nlev[m][l] = cnt;
                ms.stride[m][l] = r[2]; ms.h[m][l] = r[3];
            }
        for (int m = 0; m < ng; m++)
            if (amb_ms >= 0 && (amb_ms < 1 || amb_ms + 3 > g[m].nc)) {
                PyErr_SetString(PyExc_ValueError, "ambient multiple channel outside the fields");
                goto done;
            }
        ms.amb = amb_ms;
        use_ms = 1;
    }
    o_s = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * 3 * sizeof(double)));
    o_t = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * 3 * sizeof(double)));
    o_d = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * sizeof(double)));
    o_m = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * 3 * sizeof(double)));
    o_k = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * sizeof(double)));
    o_e = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * 3 * sizeof(double)));
    if (!o_s || !o_t || !o_d || !o_m || !o_k || !o_e) goto done;
    double *OK = (double *)PyByteArray_AS_STRING(o_k), *OE = (double *)PyByteArray_AS_STRING(o_e);
    double *OM = (double *)PyByteArray_AS_STRING(o_m);
    double *OS = (double *)PyByteArray_AS_STRING(o_s), *OT = (double *)PyByteArray_AS_STRING(o_t),
           *OD = (double *)PyByteArray_AS_STRING(o_d);
    const double *O = (const double *)bo.view.buf, *D = (const double *)bd.view.buf,
                 *T0 = (const double *)b0.view.buf, *T1 = (const double *)b1.view.buf,
                 *AX = (const double *)bax.view.buf;
    const uint32_t *K = (const uint32_t *)bk.view.buf;
    const double thr_op = 1.0 - depth_opacity;
    double g_lobe = 0.0;  /* the most anisotropic medium's g (light_varies) */
    for (int m = 0; m < ng; m++) if (fabs(gg[m]) > fabs(g_lobe)) g_lobe = gg[m];
    double sig_max[MAX_MEDIA];  /* largest extinction per unit density, over the channels */
    for (int m = 0; m < ng; m++) {
        sig_max[m] = g[m].sig[0] > g[m].sig[1] ? g[m].sig[0] : g[m].sig[1];
        sig_max[m] = sig_max[m] > g[m].sig[2] ? sig_max[m] : g[m].sig[2];
        if (!(sig_max[m] > 0.0)) sig_max[m] = 1.0;  /* a medium that only scatters nothing still counts */
    }
    /* lights whose sample does not depend on the random pair (a sun, a point or spot without
     * radius) draw none */
    int jitter[MAX_LIGHTS];
    for (Py_ssize_t l = 0; l < nl; l++) {
        const double *L = LR + l * LIGHT_FIELDS;
        int kind = (int)L[L_KIND];
        jitter[l] = kind == KIND_AREA || ((kind == KIND_POINT || kind == KIND_SPOT) && L[L_RADIUS] > 0.0);
    }
    /* longer steps in thin media only where every lit light is sampled without jitter: the
     * jittered ones (area, sphere) average their shape over the steps' samples */
    int adapt = adapt_tau > 0.0;
    for (Py_ssize_t l = 0; l < nl; l++)
        if (chan[l] >= 0 && jitter[l]) adapt = 0;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t r = 0; r < n; r++) {
        const double *o = O + 3 * r, *d = D + 3 * r;
        double T[3] = {1, 1, 1}, S[3] = {0, 0, 0}, M3[3] = {0, 0, 0}, E3[3] = {0, 0, 0};
        double depth = depth_miss;
        double t0 = T0[r], t1 = T1[r];
        uint32_t key = K[r];
        /* Super-step K covers [t0 + SUPER K step, t0 + SUPER (K + 1) step] (the last one ends at
         * t1) and is cut into n_sub equal steps, each read at one jittered point: n_sub = SUPER
         * without bricks; with bricks, 0 where every medium is empty and, with adapt_tau > 0,
         * the fewest (at least 1) that keep the majorant's optical depth per step <= adapt_tau. */
        long taken = 0, K = 0;
        int done = 0;
        double lo[MAX_MEDIA][3], lvv[MAX_MEDIA][3];
        if (skip)
            for (int m = 0; m < ng; m++) ray_to_index(&g[m], o, d, lo[m], lvv[m]);
        while (!done && K < MAX_STEPS / SUPER) {
            double s_lo = t0 + (double)(SUPER * K) * step;
            if (!(s_lo < t1)) break;
            double s_hi = t0 + (double)(SUPER * (K + 1)) * step;
            s_hi = s_hi < t1 ? s_hi : t1;
            int n_sub = SUPER;
            if (skip) {
                double maj = 0.0;
                int sharp = 0;  /* a mesh volume's surface must keep the steps short */
                for (int m = 0; m < ng; m++) {
                    double mm = segment_majorant(&g[m], &bks[m], lo[m], lvv[m], s_lo, s_hi);
                    maj += mm * sig_max[m];
                    sharp |= g[m].thr >= 0.0 && mm > 0.0;
                }
                if (!(maj > 0.0)) { K++; continue; }  /* wholly empty: nothing to add */
                if (adapt && !sharp) {
                    double want = ceil(maj * (s_hi - s_lo) / adapt_tau);
                    n_sub = want < 1.0 ? 1 : (want > (double)SUPER ? SUPER : (int)want);
                    if (n_sub < SUPER && light_varies(LR, nl, chan, o, d, s_lo, s_hi, g_lobe)) n_sub = SUPER;
                }
            }
            double H = (double)SUPER * step / (double)n_sub;
            for (int jj = 0; jj < n_sub; jj++) {
                long k = SUPER * K + jj;
                double seg = s_lo + (double)jj * H;
                if (!(seg < t1)) break;
                double hl = t1 - seg < H ? t1 - seg : H;
                double t = seg + uniform01(key, k, DIM_JITTER) * H;
                double ts = t < seg + hl ? t : seg + hl, x[3];
                for (int q = 0; q < 3; q++) x[q] = o[q] + d[q] * ts;
                double wi[MAX_LIGHTS][3], e[MAX_LIGHTS][3], wc[MAX_LIGHTS][3], dc[MAX_LIGHTS];
                for (Py_ssize_t l = 0; l < nl; l++) {
                    double u1 = 0.5, u2 = 0.5;
                    if (jitter[l]) { u1 = uniform01(key, k, 2 * l); u2 = uniform01(key, k, 2 * l + 1); }
                    light_sample(LR + l * LIGHT_FIELDS, x, u1, u2, wi[l], e[l], wc[l], &dc[l]);
                }
                double sig_t[3] = {0, 0, 0}, src[3] = {0, 0, 0}, src_ms[3] = {0, 0, 0}, src_em[3] = {0, 0, 0};
                for (int m = 0; m < ng; m++) {
                    double idx[3], v[MAX_CH];
                    to_index(&g[m], x, idx);
                    Tri tw;
                    if (!tri_setup(&g[m], idx, &tw)) continue;
                    if (emc[m] >= 0) {  /* an emission grid shines whatever the density */
                        double ev[3];
                        tri_get(&tw, emc[m], 3, ev);
                        for (int a = 0; a < 3; a++) src_em[a] += ev[a];
                    }
                    double rho = density_from(&g[m], tri_get1(&tw, 0));  /* the density first */
                    if (!(rho > 0.0)) continue;
                    tri_get(&tw, 0, (int)g[m].nc, v);
                    for (int a = 0; a < 3; a++) sig_t[a] += rho * g[m].sig[a];
                    if (use_em)
                        for (int a = 0; a < 3; a++) src_em[a] += emit[m][a];
                    int edge = g[m].thr >= 0.0 && v[0] > EDGE_EPS && v[0] < 1.0 - EDGE_EPS;
                    double inc[3] = {0, 0, 0}, beam_inc[3] = {0, 0, 0}, ind_inc[3] = {0, 0, 0};
                    for (Py_ssize_t l = 0; l < nl; l++) {
                        int c = chan[l];
                        if (c < 0) continue;
                        double tau[3] = {v[c], v[c + 1], v[c + 2]};
                        if (edge) refined_tau(g, ng, m, c, x, wc[l], dc[l], 0.5 * voxel[m], tau);
                        int cb = use_ms ? beam[l] : -1;
                        double cs = -(wi[l][0] * d[0] + wi[l][1] * d[1] + wi[l][2] * d[2]);
                        double p = hg_phase(cs, gg[m]);
                        exp3(tau, tau);
                        double *to = indirect[l] ? ind_inc : inc;  /* a bounce's light: multiple */
                        for (int a = 0; a < 3; a++) to[a] += p * e[l][a] * tau[a];
                        if (cb >= 0)  /* the forward peak's light (precompute.peak_light) */
                            for (int a = 0; a < 3; a++)
                                beam_inc[a] += p * (v[cb + a] > 0.0 ? v[cb + a] : 0.0);
                    }
                    if (ambient >= 0)
                        for (int a = 0; a < 3; a++) inc[a] += v[ambient + a];
                    for (int a = 0; a < 3; a++) src[a] += rho * sig_s[m][a] * inc[a];
                    for (int a = 0; a < 3; a++) src_ms[a] += rho * sig_s[m][a] * ind_inc[a];
                    if (use_ms) {
                        double cosl[MAX_LIGHTS], msi[3];
                        for (Py_ssize_t l = 0; l < nl; l++)
                            cosl[l] = -(wi[l][0] * d[0] + wi[l][1] * d[1] + wi[l][2] * d[2]);
                        multiple_source_c(&ms, lv, m, (int)nl, cosl, rho, x, g[m].w2i, msi);
                        if (ms.amb >= 0)
                            for (int a = 0; a < 3; a++) msi[a] += v[ms.amb + a];
                        for (int a = 0; a < 3; a++) src_ms[a] += rho * sig_s[m][a] * (msi[a] + beam_inc[a]);
                    }
                }
                taken++;
                double Tb[3] = {T[0], T[1], T[2]}, xt[3], att[3];
                for (int a = 0; a < 3; a++) xt[a] = sig_t[a] * hl;
                exp3(xt, att);
                int grey = xt[0] == xt[1] && xt[1] == xt[2];
                double frac0 = xt[0] > 1e-7 ? -expm1(-xt[0]) / xt[0] : 1.0 - 0.5 * xt[0];
                for (int a = 0; a < 3; a++) {
                    double frac = grey ? frac0 : (xt[a] > 1e-7 ? -expm1(-xt[a]) / xt[a] : 1.0 - 0.5 * xt[a]);
                    S[a] += Tb[a] * src[a] * (frac * hl);
                    M3[a] += Tb[a] * src_ms[a] * (frac * hl);
                    E3[a] += Tb[a] * src_em[a] * (frac * hl);
                    T[a] = Tb[a] * att[a];
                }
                double tb = (Tb[0] + Tb[1] + Tb[2]) / 3.0, ta = (T[0] + T[1] + T[2]) / 3.0;
                if (depth >= depth_miss && ta <= thr_op && tb > thr_op) {
                    double fr = log(tb / thr_op) / log(tb / (ta > 1e-300 ? ta : 1e-300));
                    fr = fr < 0.0 ? 0.0 : (fr > 1.0 ? 1.0 : fr);
                    depth = (seg + fr * hl) * AX[r];
                }
                double tmax = T[0] > T[1] ? T[0] : T[1];
                tmax = tmax > T[2] ? tmax : T[2];
                /* opaque enough, or a step that no longer advances t: stop */
                if (!(tmax > T_MIN) || !(seg + H > seg)) { done = 1; break; }
            }
            K++;
        }
        for (int a = 0; a < 3; a++) { OS[3 * r + a] = S[a]; OT[3 * r + a] = T[a]; OM[3 * r + a] = M3[a]; }
        OK[r] = (double)taken;
        for (int a = 0; a < 3; a++) OE[3 * r + a] = E3[a];
        OD[r] = depth;
    }
    Py_END_ALLOW_THREADS
    result = PyTuple_Pack(6, o_s, o_t, o_d, o_m, o_k, o_e);
done:
    Py_XDECREF(o_s); Py_XDECREF(o_t); Py_XDECREF(o_d); Py_XDECREF(o_m); Py_XDECREF(o_k);
    Py_XDECREF(o_e);
    buf_release(&btab);
    for (int m = 0; m < ntabs; m++) buf_release(&btabs[m]);
    if (lvb) for (int i = 0; i < nlv; i++) buf_release(&lvb[i]);
    free(lvb); free(lv);
    buf_release(&bo); buf_release(&bd); buf_release(&b0); buf_release(&b1); buf_release(&bax);
    buf_release(&bk); buf_release(&bl);
    for (int m = 0; m < ng; m++) buf_release(&gb[m]);
    for (int m = 0; m < nkb; m++) buf_release(&kb[m]);
    return result;
}

