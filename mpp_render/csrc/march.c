/* The camera-ray march (twin of kernels_np.march). */
#include "bricks.h"
#include "kernels.h"
#include "light.h"

#define MAX_LIGHTS 64
#define MAX_CH 256
#define DIM_JITTER 1000
#define DIM_STRATUM 1002  /* the steps' strata's shuffle (kernels_np.DIM_STRATUM) */
#define DIM_ROULETTE 1001   /* kernels_np.DIM_ROULETTE */
#define REFINE_STEPS 8
#define EDGE_EPS 1e-6
#define T_MIN 1e-6
#define MAX_STEPS 1000000L  /* per ray: a 256^3 grid needs ~1000 */
#define SUPER 4             /* steps per super-step (kernels_np.SUPER) */
#define DISC_STEPS_MAX 4096 /* kernels_np.DISC_STEPS_MAX */
#define DISC_STEP_VOXELS 2.0 /* kernels_np.DISC_STEP_VOXELS */

/* Medium m's extinction (1/m, RGB) at world point x, added to out: its density
 * (density_from) times sig, or with an extinction channel xc >= 0 channel a of its
 * extinction density times sig[a] (twin of kernels_np._extinction). */
static inline void extinction_at(const Grid *f, int xc, const double x[3], double scale,
                                 double out[3]) {
    if (xc >= 0) {
        double idx[3], v[3];
        to_index(f, x, idx);
        trilinear(f, idx, xc, 3, v);
        for (int a = 0; a < 3; a++) out[a] += scale * v[a] * f->sig[a];
    } else {
        double rho = density_from(f, fetch0(f, x));
        for (int a = 0; a < 3; a++) out[a] += scale * rho * f->sig[a];
    }
}

static void refined_tau(const Grid *f, const int *xcs, int nm, int mi, int c, const double x[3],
                        const double w[3], double dist, double delta, double tau[3]) {
    double end[3] = {x[0], x[1], x[2]};
    tau[0] = tau[1] = tau[2] = 0.0;
    for (int k = 1; k <= REFINE_STEPS; k++) {
        double seg = dist - (k - 1) * delta;
        seg = seg < 0.0 ? 0.0 : (seg > delta ? delta : seg);
        double s_mid = (k - 1) * delta + 0.5 * seg, s_end = (k - 1) * delta + seg, mid[3];
        for (int a = 0; a < 3; a++) { mid[a] = x[a] + w[a] * s_mid; end[a] = x[a] + w[a] * s_end; }
        for (int m = 0; m < nm; m++) extinction_at(&f[m], xcs[m], mid, seg, tau);
        double occ = fetch0(&f[mi], end);
        if (occ <= EDGE_EPS || occ >= 1.0 - EDGE_EPS || seg < delta) break;
    }
    double idx[3], v[3];
    to_index(&f[mi], end, idx);
    trilinear(&f[mi], idx, c, 3, v);
    for (int a = 0; a < 3; a++) tau[a] += v[a];
}

/* a lamp within this many voxel steps of a plane of centres: the depth there is a cone about
 * the lamp, which a bilinear read on the plane would cut (walk_tau stops before) */
#define LAMP_PLANES 1.25

/* The optical depth (RGB) from x towards a light (unit direction w, its centre dist metres
 * away) in a density grid f[mi] (no sharp surface), for a sample whose cell is optically
 * thick: the field's channel c (its depth at the voxel centres) read where the light's path
 * from x crosses the next plane of voxel centres along the index axis that path runs most
 * along (bilinearly: no fraction along that axis), plus the extinction of every medium over
 * the segment from x to that plane (read at its midpoint).  Read trilinearly at x, the depth
 * between the centres is linear along the light, but in a cell of optical depth d it bends
 * with the density: where the light enters a dense voxel from an empty one it rises as the
 * square of the way in, and the straight line over it darkens the cell's light by up to a
 * fifth at d = 2.5 (docs/method.md, "Light in an optically thick voxel").  Leaves tau as it is
 * (the trilinear read) where the plane lies outside the grid or a lamp lies within
 * LAMP_PLANES steps along the axis beyond it (about a lamp the depth is a cone, which the
 * plane's bilinear read would cut).  Returns whether it wrote tau.  Twin of
 * kernels_np._plane_tau. */
#define PLANE_EPS 1e-9
#define WALK_IN 1e-6   /* walk_tau tests the cell beyond a plane this many voxels into it;
                        * plane_tau reads a plane this near as its own */
static int plane_tau(const Grid *f, const int *xcs, int nm, int mi, int c, const double x[3],
                      const double w[3], double dist, double tau[3]) {
    const Grid *g = &f[mi];
    double idx[3], u[3];
    ray_to_index(g, x, w, idx, u);
    int a = 0;
    for (int r = 1; r < 3; r++)
        if (fabs(u[r]) > fabs(u[a])) a = r;
    if (!(fabs(u[a]) > 0.0) || !(fabs(idx[a]) < 4.0e15)) return 0;
    /* a point within WALK_IN of a plane (where walk_tau ends) reads that plane itself */
    double kp = u[a] > 0.0 ? -floor_within(-(idx[a] - WALK_IN)) : floor_within(idx[a] + WALK_IN);
    double t = (kp - idx[a]) / u[a];
    if (t < 0.0) t = 0.0;
    /* a lamp within LAMP_PLANES voxel steps beyond the plane (the depth's cone about it is no
     * plane there) or before it: the trilinear read */
    if (!(t >= 0.0 && (dist - t) * fabs(u[a]) > LAMP_PLANES)) return 0;
    double ip[3], v[3], fx, fy, fz;
    for (int r = 0; r < 3; r++) ip[r] = idx[r] + u[r] * t;
    /* the grid's last plane (its padding, or a density reaching its face) read from the cell
     * below it */
    ip[a] = kp < g->last[a] ? kp : g->last[a] - PLANE_EPS;
    if (!cell_floor(ip, g, &fx, &fy, &fz)) return 0;
    trilinear(g, ip, c, 3, v);
    double mid[3], seg[3] = {0.0, 0.0, 0.0};
    if (t > 0.0) {   /* (none from a point on the plane: where walk_tau ends on it) */
        for (int q = 0; q < 3; q++) mid[q] = x[q] + w[q] * (0.5 * t);
        for (int m = 0; m < nm; m++) extinction_at(&f[m], xcs[m], mid, t, seg);
    }
    for (int q = 0; q < 3; q++) tau[q] = v[q] + seg[q];
    return 1;
}

/* The largest extinction (1/m) of one corner's voxel pq of grid g: its density times
 * sig_max, or with an extinction channel xc >= 0 its channels times g's coefficients. */
static inline double corner_extinction(const Grid *g, const float *pq, int xc, double sig_max) {
    if (xc < 0) return (double)pq[0] * sig_max;
    double top = (double)pq[xc] * g->sig[0];
    for (int a = 1; a < 3; a++) {
        double r = (double)pq[xc + a] * g->sig[a];
        if (r > top) top = r;
    }
    return top;
}

/* Whether the cell of grid g whose stencil is t has its most extinguishing corner
 * (corner_extinction) at least cell_tau deep across the voxel size (twin:
 * kernels_np._corner_max). */
static int thick_tri(const Grid *g, const Tri *t, int xc, double sig_max, double voxel,
                     double cell_tau) {
    double top = 0.0;
    for (int q = 0; q < 8; q++) {
        double r = corner_extinction(g, t->p + t->off[q], xc, sig_max);
        if (r > top) top = r;
    }
    return top * voxel >= cell_tau;
}

/* One cell of a density grid as walk_tau reads it: its corners' density (or with an
 * extinction channel its three channels) loaded once, for the thickness test and for the
 * extinction at any point of the cell, its faces included. */
typedef struct {
    double v[8][3];   /* corner q's density (v[q][0]) or extinction channels, as stored */
    double base[3];   /* the index coordinates of its first corner */
} WalkCell;

/* Loads the cell of grid g holding index coordinates idx (xc: g's extinction channel, or < 0)
 * into wc and returns whether its most extinguishing corner is at least cell_tau deep (as
 * thick_tri); -1 where the cell lies outside the grid. */
static int walk_cell(const Grid *g, int xc, double sig_max, double voxel, double cell_tau,
                     const double idx[3], WalkCell *wc) {
    double fx, fy, fz;
    if (!cell_floor(idx, g, &fx, &fy, &fz)) return -1;
    Py_ssize_t off[8];
    grid_offsets(g, off);
    const float *p = g->data + (Py_ssize_t)fx * off[4] + (Py_ssize_t)fy * off[2] + (Py_ssize_t)fz * off[1];
    wc->base[0] = fx; wc->base[1] = fy; wc->base[2] = fz;
    double top = 0.0;
    for (int q = 0; q < 8; q++) {
        const float *pq = p + off[q];
        for (int a = 0; a < (xc >= 0 ? 3 : 1); a++) wc->v[q][a] = (double)pq[xc >= 0 ? xc + a : 0];
        double r = corner_extinction(g, pq, xc, sig_max);
        if (r > top) top = r;
    }
    return top * voxel >= cell_tau;
}

/* The extinction (1/m, RGB) of grid g (xc as walk_cell) at index coordinates idx within the
 * loaded cell wc (trilinear from its corners; on its faces as well), added to out. */
static inline void walk_cell_ext(const Grid *g, int xc, const WalkCell *wc, const double idx[3],
                                 double out[3]) {
    double tx = idx[0] - wc->base[0], ty = idx[1] - wc->base[1], tz = idx[2] - wc->base[2];
    /* nested interpolation: along z, then y, then x (corner q = 4 x + 2 y + z) */
    for (int a = 0; a < (xc >= 0 ? 3 : 1); a++) {
        double z0 = wc->v[0][a] + tz * (wc->v[1][a] - wc->v[0][a]);
        double z1 = wc->v[2][a] + tz * (wc->v[3][a] - wc->v[2][a]);
        double z2 = wc->v[4][a] + tz * (wc->v[5][a] - wc->v[4][a]);
        double z3 = wc->v[6][a] + tz * (wc->v[7][a] - wc->v[6][a]);
        double y0 = z0 + ty * (z1 - z0), y1 = z2 + ty * (z3 - z2);
        double v = y0 + tx * (y1 - y0);
        if (xc >= 0) out[a] += v * g->sig[a];
        else
            for (int b = 0; b < 3; b++) out[b] += v * g->sig[b];
    }
}

/* The optical depth (RGB) from x towards a light (unit direction w, its centre dist metres
 * away) for a sample in an optically thick cell of density grid f[mi]: the light's path
 * followed cell by cell through grid mi's cells (their faces are the planes of voxel centres,
 * where an index crosses a whole number), each piece integrated by Simpson's rule over every
 * medium (within one cell the trilinear density along a line is a cubic: exact for this
 * medium), for at most `cells` pieces and while the cells entered stay thick (tested
 * WALK_IN voxels past each plane, so that rounding on the plane cannot pick the cell left);
 * then from where it ends plane_tau (the next plane of centres along the axis the light
 * runs most along: a plane crossed last along another axis would read the depth's bend
 * along the light again).  Where the path would leave the grid's cells, or a lamp lies
 * within LAMP_PLANES voxel steps of the next plane, it ends at the last plane reached.  Each
 * cell's corners are read once (walk_cell): its thickness and grid mi's extinction at the
 * piece's middle and end come from them.  Twin of kernels_np._walk_tau. */
static void walk_tau(const Grid *f, const int *xcs, int nm, int mi, int c, const double x[3],
                     const double w[3], double dist, double sig_max, double voxel,
                     double cell_tau, int cells, double tau[3]) {
    const Grid *g = &f[mi];
    double i0[3], u[3], kk[3], umax = 0.0;
    ray_to_index(g, x, w, i0, u);
    for (int r = 0; r < 3; r++) {
        if (fabs(u[r]) > umax) umax = fabs(u[r]);
        if (!(fabs(i0[r]) < 4.0e15)) return;
        /* the next plane of centres ahead along each axis */
        kk[r] = u[r] > 0.0 ? floor_within(i0[r]) + 1.0 : -floor_within(-i0[r]) - 1.0;
    }
    if (!(umax > 0.0)) return;
    double iu[3];   /* 1 / u: the distance from one plane of centres to the next along each axis */
    for (int r = 0; r < 3; r++) iu[r] = u[r] != 0.0 ? 1.0 / u[r] : 0.0;
    int xm_c = xcs[mi];
    WalkCell cell;
    /* the sample's own cell (thick: the caller tested it); outside the grid's cells no piece */
    if (walk_cell(g, xm_c, sig_max, voxel, cell_tau, i0, &cell) < 0) {
        plane_tau(f, xcs, nm, mi, c, x, w, dist, tau);
        return;
    }
    double s = 0.0, acc[3] = {0.0, 0.0, 0.0}, ea[3] = {0.0, 0.0, 0.0}, pin[3];
    int moved = 0;
    walk_cell_ext(g, xm_c, &cell, i0, ea);
    for (int m = 0; m < nm; m++)
        if (m != mi) extinction_at(&f[m], xcs[m], x, 1.0, ea);
    for (int k = 0; k < cells; k++) {
        if (k > 0) {  /* the cell entered at the last plane: thick? (in the grid: tested there) */
            if (walk_cell(g, xm_c, sig_max, voxel, cell_tau, pin, &cell) != 1) break;
        }
        double sn = INFINITY, sr[3] = {INFINITY, INFINITY, INFINITY};
        for (int r = 0; r < 3; r++)
            if (u[r] != 0.0) {
                sr[r] = (kk[r] - i0[r]) * iu[r];
                if (sr[r] < sn) sn = sr[r];
            }
        if (!((dist - sn) * umax > LAMP_PLANES)) break;
        /* the cell beyond that plane, a millionth of a voxel in: in the grid's cells? */
        double fx, fy, fz;
        for (int r = 0; r < 3; r++) pin[r] = i0[r] + u[r] * (sn + WALK_IN / umax);
        if (!cell_floor(pin, g, &fx, &fy, &fz)) break;
        double xe[3], xm[3], im[3], ie[3], em[3] = {0.0, 0.0, 0.0}, ee[3] = {0.0, 0.0, 0.0};
        double sm = 0.5 * (s + sn);
        for (int q = 0; q < 3; q++) {
            im[q] = i0[q] + u[q] * sm;
            ie[q] = i0[q] + u[q] * sn;
        }
        walk_cell_ext(g, xm_c, &cell, im, em);
        walk_cell_ext(g, xm_c, &cell, ie, ee);
        if (nm > 1) {
            for (int q = 0; q < 3; q++) {
                xm[q] = x[q] + w[q] * sm;
                xe[q] = x[q] + w[q] * sn;
            }
            for (int m = 0; m < nm; m++)
                if (m != mi) {
                    extinction_at(&f[m], xcs[m], xm, 1.0, em);
                    extinction_at(&f[m], xcs[m], xe, 1.0, ee);
                }
        }
        for (int q = 0; q < 3; q++) {
            acc[q] += (sn - s) / 6.0 * (ea[q] + 4.0 * em[q] + ee[q]);
            ea[q] = ee[q];
        }
        for (int r = 0; r < 3; r++)   /* every axis whose plane lies there */
            if (sr[r] <= sn) kk[r] += u[r] > 0.0 ? 1.0 : -1.0;
        s = sn;
        moved = 1;
    }
    if (!moved) {
        plane_tau(f, xcs, nm, mi, c, x, w, dist, tau);
        return;
    }
    double pe[3], xe[3];
    for (int r = 0; r < 3; r++) pe[r] = i0[r] + u[r] * s;
    for (int q = 0; q < 3; q++) xe[q] = x[q] + w[q] * s;
    /* on along the light's main axis; where that cannot be read, the field where it ends */
    if (!plane_tau(f, xcs, nm, mi, c, xe, w, dist - s, tau)) trilinear(g, pe, c, 3, tau);
    for (int q = 0; q < 3; q++) tau[q] += acc[q];
}

/* Optical depth (RGB) over every medium from x to a lamp's disc point or an area light's
 * emitter point (unit direction wd, distance ds) minus `stretch` times that to its centre (wc,
 * dc): what the field's stretched depth to the centre misses in a medium that is not
 * homogeneous across the disc or emitter.  Both paths
 * take n = ceil(dc / step) steps, each read at its midpoint.  Twin of
 * kernels_np.disc_correction. */
static void disc_correction(const Grid *f, const int *xcs, int nm, const double x[3],
                            const double wc[3], double dc,
                            const double wd[3], double ds, double stretch, double step,
                            double out[3]) {
    double nf = ceil(dc / step);
    int n = nf < 1.0 ? 1 : (nf > DISC_STEPS_MAX ? DISC_STEPS_MAX : (int)nf);
    double hc = dc / n, hd = ds / n, tc[3] = {0, 0, 0}, td[3] = {0, 0, 0};
    for (int k = 0; k < n; k++) {
        double pc[3], pd[3];
        for (int a = 0; a < 3; a++) {
            pc[a] = x[a] + wc[a] * (k + 0.5) * hc;
            pd[a] = x[a] + wd[a] * (k + 0.5) * hd;
        }
        for (int m = 0; m < nm; m++) {
            extinction_at(&f[m], xcs[m], pc, 1.0, tc);
            extinction_at(&f[m], xcs[m], pd, 1.0, td);
        }
    }
    for (int a = 0; a < 3; a++) out[a] = td[a] * hd - stretch * tc[a] * hc;
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
    int flat[MAX_MEDIA];                /* the table is one level, the same at every density and
                                         * isotropic (march.FLAT_TABLE): weight x phase is flat_w */
    double flat_w[MAX_MEDIA][3];
} MS;

/* A level of 12 channels holds the traced paths' moments (paths.py, "Moments"): M0 (RGB),
 * then M1 along x, y, z (RGB each); the radiance towards v = -d is, per channel,
 * 4 pi M0 HG(v . G / |G|; |G|) with G = M1 / M0.  A level of 3 channels is read as it is.
 * Twin of kernels_np.read_level. */
static int read_level(const Grid *lv, const double idx[3], const double d[3], double q[3]) {
    double m[12], G_prev[3] = {0.0, 0.0, 0.0}, p_prev = -1.0;
    int nc = (int)lv->nc;
    if (!trilinear(lv, idx, 0, nc, m)) return 0;
    for (int a = 0; a < 3; a++) {
        q[a] = m[a];
        if (nc != 12) continue;
        if (!(m[a] > 0.0)) { q[a] = 0.0; continue; }
        double G[3] = {m[3 + a] / m[a], m[6 + a] / m[a], m[9 + a] / m[a]}, p;
        if (p_prev >= 0.0 && G[0] == G_prev[0] && G[1] == G_prev[1] && G[2] == G_prev[2]) {
            p = p_prev;   /* the channels' lobes agree (a grey medium): one phase */
        } else {
            double gl = sqrt(G[0] * G[0] + G[1] * G[1] + G[2] * G[2]);
            double cs = gl > 0.0 ? -(G[0] * d[0] + G[1] * d[1] + G[2] * d[2]) / gl : 0.0;
            p = hg_phase(cs, gl < G_LIMIT ? gl : G_LIMIT);
            G_prev[0] = G[0]; G_prev[1] = G[1]; G_prev[2] = G[2];
            p_prev = p;
        }
        q[a] = 4.0 * M_PI * m[a] * p;
    }
    return 1;
}

/* Medium m's multiply scattered radiance towards -d at the point of index coordinates idx_w
 * (its field's) and density rho, from the levels lv of each of the nl lights (cosl: the cosines
 * from their directions to -d). */
static void multiple_source_c(const MS *ms, const Grid *lv, int m, int nl, const double *cosl,
                              double rho, const double idx_w[3], const double d[3],
                              double out[3]) {
    out[0] = out[1] = out[2] = 0.0;
    const int flat = ms->flat[m];
    Py_ssize_t i = 0;
    double t = 0.0;
    if (!flat) {  /* the table's row by the density's logarithm */
        double f = (log(rho > 1e-300 ? rho : 1e-300) - ms->lr0) / ms->dlr;
        double fmax = (double)(ms->nr - 1);
        f = f < 0.0 ? 0.0 : (f > fmax ? fmax : f);
        i = (Py_ssize_t)floor(f);
        if (i > ms->nr - 2) i = ms->nr - 2;
        t = f - (double)i;
    }
    const double *tab = ms->tab[m];
    for (int l = 0; l < nl; l++) {
        int f0 = ms->first[m][l], K = ms->nlev[m][l];
        if (f0 < 0 || K <= 0) continue;
        if (K > ms->tabk[m]) K = ms->tabk[m];
        double stride = ms->stride[m][l];
        for (int k = 0; k < K; k++) {
            const double *e0 = tab + ((Py_ssize_t)k * ms->nr + i) * 6, *e1 = e0 + 6;
            double scale = stride * (double)(1L << k), idx[3], q[3];
            for (int a = 0; a < 3; a++) idx[a] = idx_w[a] / scale;
            if (read_level(&lv[f0 + k], idx, d, q)) {
                if (flat) {
                    for (int a = 0; a < 3; a++) out[a] += q[a] * ms->flat_w[m][a];
                    continue;
                }
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

/* The light one light scatters towards the camera at a point of a ray, as light_varies weighs
 * it, kept by the ray's distance s where it was last worked out (NaN: not yet): consecutive
 * super-steps share an end. */
typedef struct {
    double s[MAX_LIGHTS], e[MAX_LIGHTS];
} VaryMemo;

/* The solid angle (sr) that a rectangular (or parallelogram) area light's emitter subtends
 * at x, from its emitting side (0 behind it): Van Oosterom and Strackee's formula on its two
 * triangles, two atan2 where the draw of the spherical rectangle takes four acos and a sincos.
 * Twin: kernels_np.area_omega. */
static double area_omega(const double *L, const double x[3]) {
    const double *c = L + L_POS, *ax = L + L_AX, *ay = L + L_AY, *nl = L + L_NORMAL;
    double front = (x[0] - c[0]) * nl[0] + (x[1] - c[1]) * nl[1] + (x[2] - c[2]) * nl[2];
    if (!(front > 0.0)) return 0.0;
    static const double SX[4] = {-1.0, 1.0, 1.0, -1.0}, SY[4] = {-1.0, -1.0, 1.0, 1.0};
    double r[4][3], ln[4];
    for (int k = 0; k < 4; k++) {
        for (int a = 0; a < 3; a++) r[k][a] = c[a] + SX[k] * ax[a] + SY[k] * ay[a] - x[a];
        ln[k] = sqrt(r[k][0] * r[k][0] + r[k][1] * r[k][1] + r[k][2] * r[k][2]);
        if (!(ln[k] > 1e-300)) ln[k] = 1e-300;
    }
    double omega = 0.0;
    for (int i = 1; i < 3; i++) {
        const double *a = r[0], *b = r[i], *q = r[i + 1];
        double cr[3] = {b[1] * q[2] - b[2] * q[1], b[2] * q[0] - b[0] * q[2], b[0] * q[1] - b[1] * q[0]};
        double num = fabs(a[0] * cr[0] + a[1] * cr[1] + a[2] * cr[2]);
        double ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        double aq = a[0] * q[0] + a[1] * q[1] + a[2] * q[2];
        double bq = b[0] * q[0] + b[1] * q[1] + b[2] * q[2];
        double den = ln[0] * ln[i] * ln[i + 1] + ab * ln[i + 1] + aq * ln[i] + bq * ln[0];
        omega += 2.0 * atan2(num, den);
    }
    return omega;
}

/* What light_varies weighs for one light at x, for a ray along d in a medium of anisotropy g:
 * the irradiance summed over the channels times the phase function.  A rectangular area
 * light: its emitter's exact irradiance L_e Omega (area_omega), seen along the direction from
 * its centre; any other light: light_sample at the middle of its draw. */
static double varies_value(const double *L, const double x[3], const double d[3], double g) {
    if ((int)L[L_KIND] == KIND_AREA && !(L[L_ROUND] > 0)) {
        const double *c = L + L_POS;
        double v[3] = {x[0] - c[0], x[1] - c[1], x[2] - c[2]};
        double dist = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        double inv = 1.0 / (dist > 1e-30 ? dist : 1e-30);
        double area = L[L_AREA];
        double norm = (L[L_NORMALIZE] > 0 && area > 0) ? area : 1.0;
        double e = (L[L_STRENGTH] + L[L_STRENGTH + 1] + L[L_STRENGTH + 2]) / M_PI / norm *
                   area_omega(L, x);
        return e * hg_phase(-(v[0] * d[0] + v[1] * d[1] + v[2] * d[2]) * inv, g);
    }
    double wi[3], e[3], wc[3], dc, ds;
    light_sample(L, x, 0.5, 0.5, wi, e, wc, &dc, &ds);
    return (e[0] + e[1] + e[2]) * hg_phase(-(wi[0] * d[0] + wi[1] * d[1] + wi[2] * d[2]), g);
}

/* Whether the light a lit local light scatters towards the camera (its irradiance at its
 * centre, before the media, times the phase function of anisotropy g) differs by more than
 * LIGHT_VARIATION between the ends of the segment [s_a, s_b] of the ray o + s d: a spot's cone
 * edge, a nearby light or a forward-scattering lobe, whose shape longer steps would miss.
 * `memo` keeps the ray's last end's values.  Twin of kernels_np.light_varies. */
static int light_varies(const double *LR, Py_ssize_t nl, const int *chan, const double o[3],
                        const double d[3], double s_a, double s_b, double g, VaryMemo *memo) {
    double xa[3], xb[3];
    for (int q = 0; q < 3; q++) { xa[q] = o[q] + d[q] * s_a; xb[q] = o[q] + d[q] * s_b; }
    for (Py_ssize_t l = 0; l < nl; l++) {
        if (chan[l] < 0 || (int)LR[l * LIGHT_FIELDS + L_KIND] == KIND_SUN) continue;
        const double *L = LR + l * LIGHT_FIELDS;
        double ea = memo->s[l] == s_a ? memo->e[l] : varies_value(L, xa, d, g);
        double eb = varies_value(L, xb, d, g);
        memo->s[l] = s_b;
        memo->e[l] = eb;
        double hi = ea > eb ? ea : eb, lo = ea > eb ? eb : ea;
        if (hi > 0.0 && !(lo >= (1.0 - LIGHT_VARIATION) * hi)) return 1;
    }
    return 0;
}

/* ---- the march's inputs ---- */

/* Everything march() was given, parsed and checked (march_parse), and the buffers holding it
 * (march_release).  The loops read it without the GIL. */
typedef struct {
    Py_ssize_t n;                          /* rays */
    const double *O, *D, *T0, *T1, *AX;    /* origins, dirs (n, 3); t0, t1, axial (n) */
    const uint32_t *K;                     /* each ray's random key */
    const uint32_t *JB;                    /* each ray's jitter stratum (0 .. nj - 1), or NULL */
    const uint32_t *JK;                    /* each ray's pixel's key (the steps' shuffles) */
    int nj;                                /* the strata (1 without) */
    double jw;                             /* a stratum's width 1 / nj */
    int ng, skip;                          /* media; skip: brick bounds were given */
    Grid g[MAX_MEDIA];
    Bricks bks[MAX_MEDIA];
    double sig_s[MAX_MEDIA][3], gg[MAX_MEDIA], voxel[MAX_MEDIA], emit[MAX_MEDIA][3];
    int emc[MAX_MEDIA];                    /* first channel of each medium's emission grid, or -1 */
    int scc[MAX_MEDIA];                    /* first channel of each medium's scatter colour grid
                                            * (its factor on sig_s), or -1 */
    int xc[MAX_MEDIA];                     /* first channel of each medium's extinction density
                                            * (sig[a] times channel a), or -1: the density's */
    int use_em;
    const double *LR;                      /* light records (nl, LIGHT_FIELDS) */
    Py_ssize_t nl;
    int chan[MAX_LIGHTS], beam[MAX_LIGHTS], indirect[MAX_LIGHTS], jitter[MAX_LIGHTS];
    int disc[MAX_LIGHTS];   /* the channel of its disc's depth change beyond the reach, or -1 */
    int ambient;
    double step, depth_opacity, depth_miss, adapt_tau, thr_op;
    double roulette;                       /* Russian roulette below this transmittance; 0: off */
    double cell_tau;                       /* a density grid's cell of at least this optical
                                            * depth across follows the light's path cell by
                                            * cell (walk_tau); 0: off */
    int cell_walk;                         /* walk_tau's cells at most; 0: the next plane alone */
    double disc_step;                      /* disc_correction's step: DISC_STEP_VOXELS finest
                                            * voxels (m) */
    double disc_reach[MAX_LIGHTS];         /* per light, the distance (m) within which a disc
                                            * or emitter point's depth is corrected
                                            * (disc_correction); 0 for lights that draw no
                                            * point (jitter) */
    int use_ms;                            /* multiple scattering from the pyramid levels lv */
    MS ms;
    Grid *lv;
    int on[MAX_MEDIA];                     /* the medium's flat level lies on its field's voxels */
    Grid onf[MAX_MEDIA];                   /* that level (3 channels), read with the field's
                                            * stencil at the corner offsets onoff */
    Py_ssize_t onoff[MAX_MEDIA][8];
    Buf onb[MAX_MEDIA];
    double sig_max[MAX_MEDIA];             /* largest extinction per unit density, over channels */
    double g_lobe;                         /* the most anisotropic medium's g (light_varies) */
    int adapt;                             /* longer steps in thin media */
    Buf bo, bd, b0, b1, bax, bk, bjb, bjk, bl, btab, gb[MAX_MEDIA], btabs[MAX_MEDIA], kb[MAX_MEDIA];
    int ntabs, nkb, nlv;
    Buf *lvb;
    int sun[MAX_LIGHTS];                   /* a sun: the same light at every point */
} March;

static void march_release(March *c) {
    buf_release(&c->btab);
    for (int m = 0; m < c->ntabs; m++) buf_release(&c->btabs[m]);
    for (int m = 0; m < c->ng; m++) buf_release(&c->onb[m]);
    if (c->lvb) for (int i = 0; i < c->nlv; i++) buf_release(&c->lvb[i]);
    free(c->lvb); free(c->lv);
    buf_release(&c->bo); buf_release(&c->bd); buf_release(&c->b0); buf_release(&c->b1);
    buf_release(&c->bax); buf_release(&c->bk); buf_release(&c->bjb); buf_release(&c->bjk); buf_release(&c->bl);
    for (int m = 0; m < c->ng; m++) buf_release(&c->gb[m]);
    for (int m = 0; m < c->nkb; m++) buf_release(&c->kb[m]);
}

/* A list of `ng` float64 RGB arrays into out[m][0..2]; `list_msg` names what the list must
 * be, `what` each array (the messages of a bad call). */
static int parse_rgb_list(PyObject *list, int ng, double (*out)[3], const char *list_msg,
                          const char *what) {
    if (!PyList_Check(list) || PyList_GET_SIZE(list) != ng) {
        PyErr_SetString(PyExc_ValueError, list_msg);
        return -1;
    }
    for (int m = 0; m < ng; m++) {
        Buf b;
        Py_ssize_t s3[1] = {3};
        if (get_buf(PyList_GET_ITEM(list, m), &b, 'd', 1, s3, what) < 0) return -1;
        memcpy(out[m], b.view.buf, 3 * sizeof(double));
        buf_release(&b);
    }
    return 0;
}

/* Per medium the first of 3 field channels of one of its grids (`what` in messages), or -1,
 * from None (all -1) or a list of ints; each range must lie after the density and inside the
 * medium's fields. */
static int parse_channels(const March *c, PyObject *list, int *out, const char *what) {
    for (int m = 0; m < c->ng; m++) out[m] = -1;
    if (list == Py_None) return 0;
    if (!PyList_Check(list) || PyList_GET_SIZE(list) != c->ng) {
        PyErr_Format(PyExc_ValueError, "%s: one int per medium", what);
        return -1;
    }
    for (int m = 0; m < c->ng; m++) {
        long ch = PyLong_AsLong(PyList_GET_ITEM(list, m));
        if (ch == -1 && PyErr_Occurred()) return -1;
        if (ch >= 0 && (ch < 1 || ch + 3 > c->g[m].nc)) {
            PyErr_Format(PyExc_ValueError, "%s: channel outside the fields", what);
            return -1;
        }
        out[m] = ch < 0 ? -1 : (int)ch;
    }
    return 0;
}

/* The per-medium lists: scattering coefficients, anisotropies, voxel sizes, emissions,
 * emission channels and scatter colour channels. */
static int parse_media(March *c, PyObject *sss, PyObject *gsl, PyObject *vox, PyObject *pem,
                       PyObject *pec, PyObject *psc, PyObject *pxc) {
    int ng = c->ng;
    if (parse_rgb_list(sss, ng, c->sig_s, "sigma_ss: one RGB array per medium", "sigma_s") < 0)
        return -1;
    for (int m = 0; m < ng; m++) {
        if (c->g[m].nc > MAX_CH) {
            PyErr_SetString(PyExc_ValueError, "fields: too many channels");
            return -1;
        }
    }
    if (parse_doubles(gsl, ng, c->gg, "gs") < 0 || parse_doubles(vox, ng, c->voxel, "voxels") < 0)
        return -1;
    if (pem != Py_None) {
        if (parse_rgb_list(pem, ng, c->emit, "emissions: one RGB array per medium", "emission") < 0)
            return -1;
        for (int m = 0; m < ng; m++) {
            for (int a = 0; a < 3; a++)
                if (!isfinite(c->emit[m][a])) {
                    PyErr_SetString(PyExc_ValueError, "emission: non-finite value");
                    return -1;
                }
        }
        c->use_em = 1;
    }
    if (parse_channels(c, pec, c->emc, "emission_channels") < 0 ||
        parse_channels(c, psc, c->scc, "scatter_channels") < 0 ||
        parse_channels(c, pxc, c->xc, "extinction_channels") < 0)
        return -1;
    for (int m = 0; m < ng; m++) {
        if (!(c->gg[m] > -1.0 && c->gg[m] < 1.0) || !(c->voxel[m] > 0.0) || !isfinite(c->voxel[m])) {
            PyErr_SetString(PyExc_ValueError, "gs must lie in (-1, 1) and voxels be positive");
            return -1;
        }
    }
    return 0;
}

/* A light record's optional 3-channel field (the forward peak's light, the disc's change) for
 * a light lit at channel `cf` (>= 0): the channel `v`, -1 for none (below 1), or -2 with
 * `msg` raised where it lies outside a medium's field. */
static int optional_channel(const March *c, double cf, double v, const char *msg) {
    int ch = (cf >= 0 && v >= 1.0 && v < 1e9) ? (int)v : -1;
    for (int m = 0; m < c->ng; m++)
        if (ch >= 0 && ch + 3 > c->g[m].nc) {
            PyErr_SetString(PyExc_ValueError, msg);
            return -2;
        }
    return ch;
}

/* The light records (their kinds and channels checked against the fields) and the ambient
 * channel. */
static int parse_lights(March *c, PyObject *plights) {
    Py_ssize_t s_l[2] = {-1, LIGHT_FIELDS};
    if (get_buf(plights, &c->bl, 'd', 2, s_l, "lights") < 0) return -1;
    Py_ssize_t nl = s_l[0];
    if (nl > MAX_LIGHTS) {
        PyErr_SetString(PyExc_ValueError, "lights: at most 64 per call");
        return -1;
    }
    c->nl = nl;
    const double *LR = c->LR = (const double *)c->bl.view.buf;
    for (Py_ssize_t l = 0; l < nl; l++) {
        double cf = LR[l * LIGHT_FIELDS + L_CHANNEL], kf = LR[l * LIGHT_FIELDS + L_KIND];
        c->indirect[l] = LR[l * LIGHT_FIELDS + L_INDIRECT] > 0.5;
        c->beam[l] = optional_channel(c, cf, LR[l * LIGHT_FIELDS + L_BEAM],
                                      "lights: beam channel outside the fields");
        if (c->beam[l] < -1) return -1;
        c->disc[l] = optional_channel(c, cf, LR[l * LIGHT_FIELDS + L_DISC],
                                      "lights: disc channel outside the fields");
        if (c->disc[l] < -1) return -1;
        if (!light_kind_known(kf)) {
            PyErr_SetString(PyExc_ValueError, "lights: unknown kind");
            return -1;
        }
        c->chan[l] = cf < 0 ? -1 : (int)cf;
        for (int m = 0; m < c->ng; m++)
            if (c->chan[l] >= 0 && (c->chan[l] < 1 || c->chan[l] + 3 > c->g[m].nc)) {
                PyErr_SetString(PyExc_ValueError, "lights: channel outside the fields");
                return -1;
            }
    }
    for (int m = 0; m < c->ng; m++)
        if (c->ambient >= 0 && (c->ambient < 1 || c->ambient + 3 > c->g[m].nc)) {
            PyErr_SetString(PyExc_ValueError, "ambient channel outside the fields");
            return -1;
        }
    return 0;
}

/* The multiple-scattering pack (amb_ms, levels list, table (M, L, 4) [first, count, stride, h],
 * per-medium level tables [(K, nr, 6)], log density of entry 0, spacing). */
static int parse_multiple(March *c, PyObject *pms) {
    PyObject *plv, *ptab, *ptabs, *pon = Py_None;
    int amb_ms, ng = c->ng;
    Py_ssize_t nl = c->nl;
    double lr0, dlr;
    MS *ms = &c->ms;
    if (!PyTuple_Check(pms) || !PyArg_ParseTuple(pms, "iOOOdd|O", &amb_ms, &plv, &ptab, &ptabs, &lr0,
                                                 &dlr, &pon)) {
        PyErr_SetString(PyExc_ValueError, "multiple: expected (amb, levels, table, tables, lr0, dlr"
                        "[, on_field])");
        return -1;
    }
    if (pon != Py_None && (!PyList_Check(pon) || PyList_GET_SIZE(pon) != ng)) {
        PyErr_SetString(PyExc_ValueError, "multiple: on_field must be a list, one per medium");
        return -1;
    }
    if (!PyList_Check(plv) || PyList_GET_SIZE(plv) > 100000) {
        PyErr_SetString(PyExc_ValueError, "multiple: levels must be a list");
        return -1;
    }
    if (!PyList_Check(ptabs) || PyList_GET_SIZE(ptabs) != ng || !(dlr > 0.0) || !isfinite(lr0) ||
        !isfinite(dlr)) {
        PyErr_SetString(PyExc_ValueError, "multiple: one level table per medium, dlr > 0");
        return -1;
    }
    int nlv = c->nlv = (int)PyList_GET_SIZE(plv);
    c->lvb = (Buf *)calloc((size_t)(nlv > 0 ? nlv : 1), sizeof(Buf));
    c->lv = (Grid *)calloc((size_t)(nlv > 0 ? nlv : 1), sizeof(Grid));
    if (!c->lvb || !c->lv) { PyErr_NoMemory(); return -1; }
    for (int i = 0; i < nlv; i++) {
        Py_ssize_t sh[4] = {-1, -1, -1, -1};
        if (get_buf(PyList_GET_ITEM(plv, i), &c->lvb[i], 'f', 4, sh, "pyramid level") < 0) return -1;
        if (sh[0] < 2 || sh[1] < 2 || sh[2] < 2 || (sh[3] != 3 && sh[3] != 12)) {
            PyErr_SetString(PyExc_ValueError, "pyramid level: every extent must be >= 2 and "
                            "the channels 3 (or 12, moments)");
            return -1;
        }
        Grid *lv = &c->lv[i];
        lv->data = (const float *)c->lvb[i].view.buf;
        grid_shape(lv, sh[0], sh[1], sh[2], sh[3]);
        lv->thr = -1.0;
    }
    Py_ssize_t nr = -1;
    for (int m = 0; m < ng; m++) {
        Py_ssize_t st[3] = {-1, nr, 6};
        if (get_buf(PyList_GET_ITEM(ptabs, m), &c->btabs[m], 'd', 3, st, "level table") < 0) return -1;
        c->ntabs = m + 1;
        if (st[0] < 1 || st[0] > MAX_LEVELS || st[1] < 2) {
            PyErr_SetString(PyExc_ValueError, "level table: 1..16 levels and >= 2 densities");
            return -1;
        }
        nr = st[1];
        const double *tab = ms->tab[m] = (const double *)c->btabs[m].view.buf;
        ms->tabk[m] = (int)st[0];
        int flat = st[0] == 1;
        for (Py_ssize_t r = 1; flat && r < nr; r++)
            for (int a = 0; a < 6; a++) flat &= tab[6 * r + a] == tab[a];
        for (int a = 3; flat && a < 6; a++) flat &= tab[a] == 0.0;
        ms->flat[m] = flat;
        for (int a = 0; a < 3; a++) ms->flat_w[m][a] = flat ? tab[a] * hg_phase(0.0, 0.0) : 0.0;
        PyObject *po = pon == Py_None ? Py_None : PyList_GET_ITEM(pon, m);
        if (po != Py_None) {  /* the flat level on the field's voxels */
            const Grid *g = &c->g[m];
            Py_ssize_t sh[4] = {g->nx, g->ny, g->nz, 3};
            if (get_buf(po, &c->onb[m], 'f', 4, sh, "on_field level") < 0) return -1;
            if (!flat) {
                PyErr_SetString(PyExc_ValueError, "on_field level: its medium's table must be flat");
                return -1;
            }
            c->on[m] = 1;
            c->onf[m].data = (const float *)c->onb[m].view.buf;
            grid_shape(&c->onf[m], g->nx, g->ny, g->nz, 3);
            grid_offsets(&c->onf[m], c->onoff[m]);
        }
    }
    ms->nr = nr;
    ms->lr0 = lr0;
    ms->dlr = dlr;
    Py_ssize_t s_tab[3] = {ng, nl, 4};
    if (get_buf(ptab, &c->btab, 'd', 3, s_tab, "multiple table") < 0) return -1;
    const double *T = (const double *)c->btab.view.buf;
    for (int m = 0; m < ng; m++)
        for (Py_ssize_t l = 0; l < nl; l++) {
            const double *r = T + ((Py_ssize_t)m * nl + l) * 4;
            int first = (int)r[0], cnt = (int)r[1];
            if (!(r[1] >= 1.0) || !(r[0] >= 0.0)) { ms->first[m][l] = -1; ms->nlev[m][l] = 0; continue; }
            if (cnt > MAX_LEVELS || first > nlv - cnt || !(r[2] >= 1.0) || !(r[2] < 1e9) ||
                !(r[3] > 0.0) || !isfinite(r[3])) {
                PyErr_SetString(PyExc_ValueError, "multiple table: bad level range, stride or h");
                return -1;
            }
            ms->first[m][l] = first; ms->nlev[m][l] = cnt;
            ms->stride[m][l] = r[2]; ms->h[m][l] = r[3];
        }
    for (int m = 0; m < ng; m++)
        if (amb_ms >= 0 && (amb_ms < 1 || amb_ms + 3 > c->g[m].nc)) {
            PyErr_SetString(PyExc_ValueError, "ambient multiple channel outside the fields");
            return -1;
        }
    ms->amb = amb_ms;
    c->use_ms = 1;
    return 0;
}

/* Parse and check march()'s arguments into c (the caller releases it whatever the outcome). */
static int march_parse(March *c, PyObject *args) {
    PyObject *po, *pd, *pt0, *pt1, *pax, *pk, *fields, *w2is, *sss, *sts, *gsl, *thrs, *vox, *plights;
    PyObject *pms = Py_None, *pem = Py_None, *pbk = Py_None, *pec = Py_None, *pdr = Py_None;
    PyObject *psc = Py_None, *pxc = Py_None, *pjb = Py_None, *pjk = Py_None;
    int brick = 4, nj = 1;
    c->adapt_tau = 0.0;
    c->roulette = 0.0;
    c->cell_tau = 0.0;
    c->cell_walk = 0;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOOOiddd|OOOidOdOOOdiOiO", &po, &pd, &pt0, &pt1, &pax, &pk, &fields,
                          &w2is, &sss, &sts, &gsl, &thrs, &vox, &plights, &c->ambient, &c->step,
                          &c->depth_opacity, &c->depth_miss, &pms, &pem, &pbk, &brick, &c->adapt_tau,
                          &pec, &c->roulette, &pdr, &psc, &pxc, &c->cell_tau, &c->cell_walk,
                          &pjb, &nj, &pjk))
        return -1;
    if (!(c->cell_tau >= 0.0) || c->cell_walk < 0 || c->cell_walk > 4096) {
        PyErr_SetString(PyExc_ValueError, "cell_tau must be >= 0 and cell_walk in [0, 4096]");
        return -1;
    }
    if (!(c->roulette >= 0.0 && c->roulette < 1.0)) {
        PyErr_SetString(PyExc_ValueError, "roulette must be in [0, 1)");
        return -1;
    }
    if (!isfinite(c->adapt_tau)) {
        PyErr_SetString(PyExc_ValueError, "adapt_tau must be finite");
        return -1;
    }
    if (!(c->step > 0.0) || !isfinite(c->step)) {
        PyErr_SetString(PyExc_ValueError, "step must be a positive finite length");
        return -1;
    }
    Py_ssize_t s_o[2] = {-1, 3};
    if (get_buf(po, &c->bo, 'd', 2, s_o, "origins") < 0) return -1;
    Py_ssize_t n = c->n = s_o[0];
    Py_ssize_t s_d[2] = {n, 3}, s_n[1] = {n}, s_n2[1] = {n}, s_n3[1] = {n}, s_n4[1] = {n};
    if (get_buf(pd, &c->bd, 'd', 2, s_d, "dirs") < 0) return -1;
    if (get_buf(pt0, &c->b0, 'd', 1, s_n, "t0") < 0) return -1;
    if (get_buf(pt1, &c->b1, 'd', 1, s_n2, "t1") < 0) return -1;
    if (get_buf(pax, &c->bax, 'd', 1, s_n3, "axial") < 0) return -1;
    if (get_buf(pk, &c->bk, 'I', 1, s_n4, "keys") < 0) return -1;
    c->JB = c->JK = NULL;
    c->nj = 1;
    c->jw = 1.0;
    if (pjb != Py_None) {
        Py_ssize_t s_n5[1] = {n}, s_n6[1] = {n};
        if (nj < 1 || nj > (1 << 24)) {
            PyErr_SetString(PyExc_ValueError, "jitter_count must be in [1, 2^24]");
            return -1;
        }
        if (get_buf(pjb, &c->bjb, 'I', 1, s_n5, "jitter_bands") < 0) return -1;
        if (get_buf(pjk, &c->bjk, 'I', 1, s_n6, "jitter_keys") < 0) return -1;
        c->JK = (const uint32_t *)c->bjk.view.buf;
        c->nj = nj;
        c->JB = (const uint32_t *)c->bjb.view.buf;
        for (Py_ssize_t r = 0; r < n; r++)
            if (c->JB[r] >= (uint32_t)nj) {
                PyErr_SetString(PyExc_ValueError, "jitter_bands must lie in [0, jitter_count)");
                return -1;
            }
        c->jw = 1.0 / (double)nj;
    }
    if (parse_grids(fields, w2is, sts, thrs, c->g, c->gb, &c->ng, 1) < 0) return -1;
    if (parse_bricks(pbk, brick, c->g, c->ng, c->bks, c->kb, &c->nkb) < 0) return -1;
    c->skip = pbk != Py_None;
    if (parse_media(c, sss, gsl, vox, pem, pec, psc, pxc) < 0) return -1;
    if (parse_lights(c, plights) < 0) return -1;
    for (Py_ssize_t l = 0; l < c->nl; l++) c->disc_reach[l] = 0.0;
    if (pdr != Py_None) {
        if (parse_doubles(pdr, c->nl, c->disc_reach, "disc_reach") < 0) return -1;
        for (Py_ssize_t l = 0; l < c->nl; l++)
            if (!(c->disc_reach[l] >= 0.0) || !isfinite(c->disc_reach[l])) {
                PyErr_SetString(PyExc_ValueError, "disc_reach must be finite lengths >= 0");
                return -1;
            }
    }
    if (pms != Py_None && parse_multiple(c, pms) < 0) return -1;
    c->O = (const double *)c->bo.view.buf;
    c->D = (const double *)c->bd.view.buf;
    c->T0 = (const double *)c->b0.view.buf;
    c->T1 = (const double *)c->b1.view.buf;
    c->AX = (const double *)c->bax.view.buf;
    c->K = (const uint32_t *)c->bk.view.buf;
    return 0;
}

/* What the rays share, derived from the inputs: the extinction bounds, which lights draw
 * random numbers and whether steps may lengthen. */
static void march_prepare(March *c) {
    int ng = c->ng;
    c->thr_op = 1.0 - c->depth_opacity;
    c->g_lobe = 0.0;
    for (int m = 0; m < ng; m++) if (fabs(c->gg[m]) > fabs(c->g_lobe)) c->g_lobe = c->gg[m];
    for (int m = 0; m < ng; m++) {
        const double *sig = c->g[m].sig;
        c->sig_max[m] = sig[0] > sig[1] ? sig[0] : sig[1];
        c->sig_max[m] = c->sig_max[m] > sig[2] ? c->sig_max[m] : sig[2];
        if (!(c->sig_max[m] > 0.0)) c->sig_max[m] = 1.0;  /* a medium that only scatters nothing still counts */
    }
    /* lights whose sample does not depend on the random pair (a sun, a point or spot without
     * radius) draw none */
    for (Py_ssize_t l = 0; l < c->nl; l++) {
        const double *L = c->LR + l * LIGHT_FIELDS;
        int kind = (int)L[L_KIND];
        c->sun[l] = kind == KIND_SUN;
        c->jitter[l] = kind == KIND_AREA || ((kind == KIND_POINT || kind == KIND_SPOT) && L[L_RADIUS] > 0.0);
        if (!c->jitter[l]) c->disc_reach[l] = 0.0;
    }
    c->disc_step = HUGE_VAL;
    for (int m = 0; m < ng; m++) if (c->voxel[m] < c->disc_step) c->disc_step = c->voxel[m];
    c->disc_step *= DISC_STEP_VOXELS;
    c->adapt = c->adapt_tau > 0.0;
}

/* ---- the march itself ---- */

/* The lights seen from one march sample: propagation direction wi, irradiance e, direction wc
 * and distance dc to the centre, distance ds to the emitting point(s) sampled (light_sample). */
typedef struct {
    double wi[MAX_LIGHTS][3], e[MAX_LIGHTS][3], wc[MAX_LIGHTS][3], dc[MAX_LIGHTS], ds[MAX_LIGHTS];
    /* the last phase function value of each light: at cosine pc with anisotropy pg, pp (a
     * sun's cosine is the same all along a ray); pc NaN: none yet */
    double pc[MAX_LIGHTS], pg[MAX_LIGHTS], pp[MAX_LIGHTS];
} LightsAt;

/* What the media add at one march sample: extinction, the single-scattered, multiple-scattered
 * and emitted radiance per unit length. */
typedef struct {
    double sig_t[3], src[3], src_ms[3], src_em[3];
} Sources;

/* How many steps super-step [s_lo, s_hi] of ray o + s d is cut into: SUPER without bricks;
 * with bricks 0 where every medium is empty and, with adapt, the fewest (at least 1) that keep
 * the majorant's optical depth per step <= adapt_tau.  lo, lv: the ray in each medium's index
 * coordinates. */
static int super_step_count(const March *c, const double o[3], const double d[3],
                            const double lo[][3], const double lv[][3], double s_lo, double s_hi,
                            VaryMemo *memo) {
    int n_sub = SUPER;
    if (!c->skip) return n_sub;
    double maj = 0.0;
    int sharp = 0;  /* a mesh volume's surface must keep the steps short (not its inside) */
    for (int m = 0; m < c->ng; m++) {
        /* a mesh's least bound, where its surface may lie on the super-step (below 1), only
         * where longer steps are possible */
        int mesh = c->adapt && !sharp && c->g[m].thr >= 0.0;
        double least = 1.0;
        double mm = segment_bounds(&c->g[m], &c->bks[m], lo[m], lv[m], s_lo, s_hi,
                                   mesh ? &least : NULL);
        maj += mm * c->sig_max[m];
        sharp |= mesh && mm > 0.0 && !(least >= 1.0);
    }
    if (!(maj > 0.0)) return 0;  /* wholly empty: nothing to add */
    if (c->adapt && !sharp) {
        double want = ceil(maj * (s_hi - s_lo) / c->adapt_tau);
        n_sub = want < 1.0 ? 1 : (want > (double)SUPER ? SUPER : (int)want);
        if (n_sub < SUPER && light_varies(c->LR, c->nl, c->chan, o, d, s_lo, s_hi, c->g_lobe, memo))
            n_sub = SUPER;
    }
    return n_sub;
}

/* The stratum (0 .. n - 1) of step k of a ray whose pixel's key is pk and whose stratum is
 * b: b shuffled by a bijection of the strata drawn per pixel and step (XOR with a mask when
 * n is a power of two, which keeps the adaptive rounds' first 2^m samples on distinct
 * 2^m-ths of the step; a shift modulo n otherwise), so that a pixel's samples cover every
 * stratum of each step while one ray's steps lie on unrelated strata (twin:
 * kernels_np.step_stratum). */
static inline uint32_t step_stratum(uint32_t b, uint32_t pk, long k, int n) {
    uint32_t m = (uint32_t)(uniform01(pk, k, DIM_STRATUM) * (double)n);
    if (m >= (uint32_t)n) m = (uint32_t)n - 1;
    return (n & (n - 1)) == 0 ? (b ^ m) : (uint32_t)(((uint64_t)b + m) % (uint32_t)n);
}

/* u in [0, 1) moved onto the stratum of step k of ray r, where the rays have strata
 * (else u). */
static inline double on_stratum(const March *c, Py_ssize_t r, long k, double u) {
    if (!c->JB) return u;
    return ((double)step_stratum(c->JB[r], c->JK[r], k, c->nj) + u) * c->jw;
}

/* Every light at x, march step k of the ray with random key `key`; with `again`, the ray's
 * lights sampled before, only those whose sample depends on x (all but suns). */
static void sample_lights(const March *c, const double x[3], uint32_t key, long k, int again,
                          LightsAt *la) {
    for (Py_ssize_t l = 0; l < c->nl; l++) {
        if (again && c->sun[l]) continue;
        double u1 = 0.5, u2 = 0.5;
        if (c->jitter[l]) { u1 = uniform01(key, k, 2 * l); u2 = uniform01(key, k, 2 * l + 1); }
        light_sample(c->LR + l * LIGHT_FIELDS, x, u1, u2, la->wi[l], la->e[l], la->wc[l], &la->dc[l],
                     &la->ds[l]);
    }
}

/* Medium m's part of the sources at x (seen along d), added to s. */
static void medium_sources(const March *c, int m, const double x[3], const double d[3],
                           LightsAt *la, Sources *s) {
    const Grid *g = &c->g[m];
    double idx[3], v[MAX_CH];
    to_index(g, x, idx);
    Tri tw;
    if (!tri_setup(g, idx, &tw)) return;
    if (c->emc[m] >= 0) {  /* an emission grid shines whatever the density */
        double ev[3];
        tri_get(&tw, c->emc[m], 3, ev);
        for (int a = 0; a < 3; a++) s->src_em[a] += ev[a];
    }
    v[0] = tri_get1(&tw, 0);
    double rho = density_from(g, v[0]);  /* the density first */
    if (!(rho > 0.0)) return;
    tri_get(&tw, 1, (int)g->nc - 1, v + 1);
    if (c->xc[m] >= 0)  /* the extinction's colour varies: its own density per channel */
        for (int a = 0; a < 3; a++) s->sig_t[a] += v[c->xc[m] + a] * g->sig[a];
    else
        for (int a = 0; a < 3; a++) s->sig_t[a] += rho * g->sig[a];
    if (c->use_em)
        for (int a = 0; a < 3; a++) s->src_em[a] += c->emit[m][a];
    int edge = g->thr >= 0.0 && v[0] > EDGE_EPS && v[0] < 1.0 - EDGE_EPS;
    /* a density grid's cell whose most extinguishing corner is optically thick */
    int thick = g->thr < 0.0 && c->cell_tau > 0.0 &&
                thick_tri(g, &tw, c->xc[m], c->sig_max[m], c->voxel[m], c->cell_tau);
    double inc[3] = {0, 0, 0}, beam_inc[3] = {0, 0, 0}, ind_inc[3] = {0, 0, 0};
    for (Py_ssize_t l = 0; l < c->nl; l++) {
        int ch = c->chan[l];
        if (ch < 0) continue;
        double tau[3] = {v[ch], v[ch + 1], v[ch + 2]};
        if (edge) refined_tau(c->g, c->xc, c->ng, m, ch, x, la->wc[l], la->dc[l], 0.5 * c->voxel[m], tau);
        else if (thick)
            walk_tau(c->g, c->xc, c->ng, m, ch, x, la->wc[l], la->dc[l], c->sig_max[m], c->voxel[m],
                     c->cell_tau, c->cell_walk, tau);
        if (la->ds[l] != la->dc[l]) {  /* light from an emitter point off the centre */
            double st = path_stretch(la->ds[l], la->dc[l], c->voxel[m]);
            for (int a = 0; a < 3; a++) tau[a] *= st;
            if (la->dc[l] < c->disc_reach[l]) {
                double wd[3] = {-la->wi[l][0], -la->wi[l][1], -la->wi[l][2]}, dt[3];
                disc_correction(c->g, c->xc, c->ng, x, la->wc[l], la->dc[l], wd, la->ds[l], st,
                                c->disc_step, dt);
                for (int a = 0; a < 3; a++) tau[a] = tau[a] + dt[a] > 0.0 ? tau[a] + dt[a] : 0.0;
            } else if (c->disc[l] >= 0) {  /* beyond: the disc's mean (discdepth.py) */
                const double *dd = v + c->disc[l];
                for (int a = 0; a < 3; a++) tau[a] = tau[a] + dd[a] > 0.0 ? tau[a] + dd[a] : 0.0;
            }
        }
        int cb = c->use_ms ? c->beam[l] : -1;
        const double *wi = la->wi[l];
        double cs = -(wi[0] * d[0] + wi[1] * d[1] + wi[2] * d[2]);
        if (!(cs == la->pc[l] && c->gg[m] == la->pg[l])) {
            la->pc[l] = cs; la->pg[l] = c->gg[m]; la->pp[l] = hg_phase(cs, c->gg[m]);
        }
        double p = la->pp[l];
        exp3(tau, tau);
        double *to = c->indirect[l] ? ind_inc : inc;  /* a bounce's light: multiple */
        for (int a = 0; a < 3; a++) to[a] += p * la->e[l][a] * tau[a];
        if (cb >= 0)  /* the forward peak's light (precompute.peak_light) */
            for (int a = 0; a < 3; a++)
                beam_inc[a] += p * (v[cb + a] > 0.0 ? v[cb + a] : 0.0);
    }
    if (c->ambient >= 0)
        for (int a = 0; a < 3; a++) inc[a] += v[c->ambient + a];
    double ss[3] = {rho * c->sig_s[m][0], rho * c->sig_s[m][1], rho * c->sig_s[m][2]};
    if (c->scc[m] >= 0)  /* the scattering colour of this point (Medium.scatter_grid) */
        for (int a = 0; a < 3; a++) ss[a] *= v[c->scc[m] + a] > 0.0 ? v[c->scc[m] + a] : 0.0;
    for (int a = 0; a < 3; a++) s->src[a] += ss[a] * inc[a];
    for (int a = 0; a < 3; a++) s->src_ms[a] += ss[a] * ind_inc[a];
    if (c->use_ms) {
        double cosl[MAX_LIGHTS], msi[3];
        for (Py_ssize_t l = 0; l < c->nl; l++) {
            const double *wi = la->wi[l];
            cosl[l] = -(wi[0] * d[0] + wi[1] * d[1] + wi[2] * d[2]);
        }
        if (c->on[m]) {  /* the flat level on the field's voxels: the field's stencil */
            tri_on(&tw, &c->onf[m], c->onoff[m], 3, msi);
            for (int a = 0; a < 3; a++) msi[a] *= c->ms.flat_w[m][a];
        } else {
            multiple_source_c(&c->ms, c->lv, m, (int)c->nl, cosl, rho, idx, d, msi);
        }
        if (c->ms.amb >= 0)
            for (int a = 0; a < 3; a++) msi[a] += v[c->ms.amb + a];
        /* light is never below 0: where the sky's, less its absorption's traced estimate
         * (skydeficit.py), has more noise than light, none (NaN too) */
        for (int a = 0; a < 3; a++) msi[a] = msi[a] > 0.0 ? msi[a] : 0.0;
        for (int a = 0; a < 3; a++) s->src_ms[a] += ss[a] * (msi[a] + beam_inc[a]);
    }
}

/* One ray's running sums: transmittance T, single S, multiple M and emitted E radiance, and
 * the depth where it turned opaque (depth_miss until then). */
typedef struct {
    double T[3], S[3], M[3], E[3], depth;
} RaySums;

#define FRACTION_SERIES 1e-2  /* below this optical depth step_fraction sums its series */

/* (1 - exp(-x)) / x, the mean transmittance over a step of optical depth x >= 0, given
 * att = exp(-x): from att where the cancellation costs at most 1e-14 relatively, else from
 * its series to x^4 (truncation below 2e-13); 1 - x / 2 at or below 1e-7.  The twin's
 * -expm1(-x) / x to those bounds. */
static inline double step_fraction(double x, double att) {
    if (x > FRACTION_SERIES) return (1.0 - att) / x;
    if (!(x > 1e-7)) return 1.0 - 0.5 * x;   /* as the twin, also for x < 0 */
    return 1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0 - x * (1.0 / 120.0))));
}

/* Integrates one step [seg, seg + hl] of constant sources s into the ray's sums (exactly, for
 * the exponential attenuation over the step); `axial` turns the ray's distance into depth. */
static void integrate_step(const March *c, const Sources *s, double seg, double hl, double axial,
                           RaySums *r) {
    double Tb[3] = {r->T[0], r->T[1], r->T[2]}, xt[3], att[3], fr[3];
    for (int a = 0; a < 3; a++) xt[a] = s->sig_t[a] * hl;
    exp3(xt, att);
    if (xt[0] == xt[1] && xt[1] == xt[2]) {
        fr[0] = fr[1] = fr[2] = step_fraction(xt[0], att[0]);
    } else {
        for (int a = 0; a < 3; a++) fr[a] = step_fraction(xt[a], att[a]);
    }
    for (int a = 0; a < 3; a++) {
        double frac = fr[a];
        r->S[a] += Tb[a] * s->src[a] * (frac * hl);
        r->M[a] += Tb[a] * s->src_ms[a] * (frac * hl);
        r->E[a] += Tb[a] * s->src_em[a] * (frac * hl);
        r->T[a] = Tb[a] * att[a];
    }
    double thr_op = c->thr_op;
    double tb = (Tb[0] + Tb[1] + Tb[2]) / 3.0, ta = (r->T[0] + r->T[1] + r->T[2]) / 3.0;
    if (r->depth >= c->depth_miss && ta <= thr_op && tb > thr_op) {
        double fr = log(tb / thr_op) / log(tb / (ta > 1e-300 ? ta : 1e-300));
        fr = fr < 0.0 ? 0.0 : (fr > 1.0 ? 1.0 : fr);
        r->depth = (seg + fr * hl) * axial;
    }
}

/* Marches ray r; returns the number of steps it took. */
static long march_ray(const March *c, Py_ssize_t r, RaySums *sums) {
    const double *o = c->O + 3 * r, *d = c->D + 3 * r;
    const double t0 = c->T0[r], t1 = c->T1[r], step = c->step;
    const uint32_t key = c->K[r];
    for (int a = 0; a < 3; a++) { sums->T[a] = 1.0; sums->S[a] = sums->M[a] = sums->E[a] = 0.0; }
    sums->depth = c->depth_miss;
    /* Super-step K covers [t0 + SUPER K step, t0 + SUPER (K + 1) step] (the last one ends at
     * t1) and is cut into n_sub equal steps (super_step_count), each read at one jittered
     * point. */
    long taken = 0, K = 0;
    int done = 0;
    double lo[MAX_MEDIA][3], lvv[MAX_MEDIA][3];
    if (c->skip)
        for (int m = 0; m < c->ng; m++) ray_to_index(&c->g[m], o, d, lo[m], lvv[m]);
    LightsAt la;
    int sampled = 0;
    VaryMemo memo;
    for (Py_ssize_t l = 0; l < c->nl; l++) la.pc[l] = memo.s[l] = NAN;
    while (!done && K < MAX_STEPS / SUPER) {
        double s_lo = t0 + (double)(SUPER * K) * step;
        if (!(s_lo < t1)) break;
        double s_hi = t0 + (double)(SUPER * (K + 1)) * step;
        s_hi = s_hi < t1 ? s_hi : t1;
        int n_sub = super_step_count(c, o, d, (const double (*)[3])lo, (const double (*)[3])lvv,
                                     s_lo, s_hi, &memo);
        if (n_sub == 0) { K++; continue; }
        double H = (double)SUPER * step / (double)n_sub;
        for (int jj = 0; jj < n_sub; jj++) {
            long k = SUPER * K + jj;
            double seg = s_lo + (double)jj * H;
            if (!(seg < t1)) break;
            double hl = t1 - seg < H ? t1 - seg : H;   /* the last step may end early, at t1 */
            /* uniform on it, on the ray's stratum of it where it has strata */
            double ts = seg + on_stratum(c, r, k, uniform01(key, k, DIM_JITTER)) * hl,
                   x[3];
            for (int q = 0; q < 3; q++) x[q] = o[q] + d[q] * ts;
            sample_lights(c, x, key, k, sampled, &la);
            sampled = 1;
            Sources s = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
            for (int m = 0; m < c->ng; m++) medium_sources(c, m, x, d, &la, &s);
            taken++;
            integrate_step(c, &s, seg, hl, c->AX[r], sums);
            double tmax = sums->T[0] > sums->T[1] ? sums->T[0] : sums->T[1];
            tmax = tmax > sums->T[2] ? tmax : sums->T[2];
            if (tmax < c->roulette) {  /* Russian roulette: go on with probability q, T / q */
                double q = tmax / c->roulette;
                if (uniform01(key, k, DIM_ROULETTE) < q) {
                    for (int a = 0; a < 3; a++) sums->T[a] /= q;
                    tmax = c->roulette;
                } else {
                    for (int a = 0; a < 3; a++) sums->T[a] = 0.0;
                    tmax = 0.0;
                }
            }
            /* opaque enough, or a step that no longer advances t: stop */
            if (!(tmax > T_MIN) || !(seg + H > seg)) { done = 1; break; }
        }
        K++;
    }
    return taken;
}

const char walk_depth_doc[] =
    "walk_depth(grid, w2i, sig, xc, c, x, w, dist, tau, sig_max, voxel, cell_tau, cells) -> bytes\n"
    "Twin of kernels_np._walk_tau for one density grid: grid (X,Y,Z,C) float32 (channel 0 the\n"
    "density, c..c+2 the light's depth at the voxel centres, xc..xc+2 the extinction density or\n"
    "xc -1), w2i (3,4) world to index, sig (3,) extinction per unit density (1/m); x, w (N,3)\n"
    "float64 points and unit directions towards the light, dist (N,) its centre's distance\n"
    "(inf for a sun), tau (N,3) the trilinear read at x; sig_max, voxel (m), cell_tau and cells\n"
    "as the march's.  (N,3) float64 as bytes: the optical depth from each point, walk_tau's.";

PyObject *walk_depth(PyObject *self, PyObject *args) {
    PyObject *pg, *pm, *ps, *px, *pw, *pd, *pt;
    int xc, c, cells;
    double sig_max, voxel, cell_tau;
    if (!PyArg_ParseTuple(args, "OOOiiOOOOdddi", &pg, &pm, &ps, &xc, &c, &px, &pw, &pd, &pt,
                          &sig_max, &voxel, &cell_tau, &cells))
        return NULL;
    Buf bg = {0}, bm = {0}, bs = {0}, bx = {0}, bw = {0}, bd = {0}, bt = {0};
    PyObject *result = NULL;
    Py_ssize_t sg[4] = {-1, -1, -1, -1}, sm[2] = {3, 4}, ss[1] = {3}, sx[2] = {-1, 3};
    if (get_buf(pg, &bg, 'f', 4, sg, "grid") < 0 || get_buf(pm, &bm, 'd', 2, sm, "w2i") < 0 ||
        get_buf(ps, &bs, 'd', 1, ss, "sig") < 0 || get_buf(px, &bx, 'd', 2, sx, "x") < 0)
        goto done;
    Py_ssize_t n = sx[0], sw[2] = {n, 3}, sd[1] = {n}, st[2] = {n, 3}, nc = sg[3];
    if (get_buf(pw, &bw, 'd', 2, sw, "w") < 0 || get_buf(pd, &bd, 'd', 1, sd, "dist") < 0 ||
        get_buf(pt, &bt, 'd', 2, st, "tau") < 0)
        goto done;
    if (nc < 1 || c < 0 || (Py_ssize_t)c + 3 > nc || xc < -1 || (xc >= 0 && (Py_ssize_t)xc + 3 > nc) ||
        cells < 0 || cells > (1 << 20) || !(voxel > 0.0) || !(sig_max >= 0.0)) {
        PyErr_SetString(PyExc_ValueError, "walk_depth: bad channels, cells or voxel size");
        goto done;
    }
    if (n > PY_SSIZE_T_MAX / (Py_ssize_t)(3 * sizeof(double))) {
        PyErr_SetString(PyExc_ValueError, "walk_depth: too many points");
        goto done;
    }
    result = PyBytes_FromStringAndSize(NULL, n * 3 * (Py_ssize_t)sizeof(double));
    if (!result) goto done;
    {
        double *out = (double *)PyBytes_AS_STRING(result);
        const double *X = bx.view.buf, *W = bw.view.buf, *D = bd.view.buf, *T = bt.view.buf;
        Grid g;
        memset(&g, 0, sizeof g);
        g.data = (const float *)bg.view.buf;
        grid_shape(&g, sg[0], sg[1], sg[2], nc);
        memcpy(g.w2i, bm.view.buf, sizeof g.w2i);
        memcpy(g.sig, bs.view.buf, sizeof g.sig);
        g.thr = -1.0;   /* a density grid: no sharp surface */
        int xcs[1] = {xc};
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t q = 0; q < n; q++) {
            for (int a = 0; a < 3; a++) out[3 * q + a] = T[3 * q + a];
            walk_tau(&g, xcs, 1, 0, c, X + 3 * q, W + 3 * q, D[q], sig_max, voxel, cell_tau,
                     cells, out + 3 * q);
        }
        Py_END_ALLOW_THREADS
    }
done:
    buf_release(&bg); buf_release(&bm); buf_release(&bs); buf_release(&bx);
    buf_release(&bw); buf_release(&bd); buf_release(&bt);
    return result;
}

const char march_doc[] =
    "march(origins, dirs, t0, t1, axial, keys, fields, w2is, sigma_ss, sigma_ts, gs, thresholds,\n"
    "      voxels, lights, ambient, step, depth_opacity, depth_miss[, multiple, emissions, bricks, brick,\n"
    "      adapt_tau, emission_channels, roulette, disc_reach, scatter_channels,\n"
    "      extinction_channels])\n"
    "  -> (single, T, depth, multiple, steps, emission) as bytes of float64\n"
    "Twin of kernels_np.march.";

PyObject *march(PyObject *self, PyObject *args) {
    March *c = (March *)calloc(1, sizeof(March));
    if (!c) return PyErr_NoMemory();
    PyObject *o_s = NULL, *o_t = NULL, *o_d = NULL, *o_m = NULL, *o_k = NULL, *o_e = NULL, *result = NULL;
    if (march_parse(c, args) < 0) goto done;
    Py_ssize_t n = c->n;
    o_s = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * 3 * sizeof(double)));
    o_t = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * 3 * sizeof(double)));
    o_d = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * sizeof(double)));
    o_m = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * 3 * sizeof(double)));
    o_k = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * sizeof(double)));
    o_e = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)(n * 3 * sizeof(double)));
    if (!o_s || !o_t || !o_d || !o_m || !o_k || !o_e) goto done;
    double *OS = (double *)PyByteArray_AS_STRING(o_s), *OT = (double *)PyByteArray_AS_STRING(o_t),
           *OD = (double *)PyByteArray_AS_STRING(o_d), *OM = (double *)PyByteArray_AS_STRING(o_m),
           *OK = (double *)PyByteArray_AS_STRING(o_k), *OE = (double *)PyByteArray_AS_STRING(o_e);
    march_prepare(c);
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t r = 0; r < n; r++) {
        RaySums sums;
        long taken = march_ray(c, r, &sums);
        for (int a = 0; a < 3; a++) {
            OS[3 * r + a] = sums.S[a]; OT[3 * r + a] = sums.T[a];
            OM[3 * r + a] = sums.M[a]; OE[3 * r + a] = sums.E[a];
        }
        OK[r] = (double)taken;
        OD[r] = sums.depth;
    }
    Py_END_ALLOW_THREADS
    result = PyTuple_Pack(6, o_s, o_t, o_d, o_m, o_k, o_e);
done:
    Py_XDECREF(o_s); Py_XDECREF(o_t); Py_XDECREF(o_d); Py_XDECREF(o_m); Py_XDECREF(o_k);
    Py_XDECREF(o_e);
    march_release(c);
    free(c);
    return result;
}
