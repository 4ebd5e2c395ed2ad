/* The light record (one float64 row of LIGHT_FIELDS per light) and light_sample.
 *
 * The layout (L_* offsets, KIND_* kinds) is mpp_render/lightrecord.py's; module.c exports these
 * values as _kernels.light_layout() and tests/test_kernels.py holds them to the Python module.
 */
#ifndef MPP_LIGHT_H
#define MPP_LIGHT_H

#include "common.h"

#define LIGHT_FIELDS 41
#define L_KIND 0
#define L_STRENGTH 1
#define L_POS 4
#define L_DIR 7
#define L_INV 10
#define L_COSHALF 19
#define L_BLEND 20
#define L_RADIUS 21
#define L_AX 22
#define L_AY 25
#define L_AREA 28
#define L_NORMAL 29
#define L_NORMALIZE 32
#define L_ROUND 33
#define L_CHANNEL 34
#define L_COND 35
#define L_BEAM 36      /* the channel of the forward peak's light (W/m^2), < 1: none */
#define L_INDIRECT 37  /* 1: scattered light (a surface's bounce): its single scattering is multiple */
#define L_DISC 38      /* the channel of its disc's depth change beyond the reach, < 1: none */
#define L_ANGLES 39    /* a spot's half angle and its blend's inner angle (rad) */
#define KIND_POINT 0
#define KIND_SPOT 1
#define KIND_SUN 2
#define KIND_AREA 3

/* Whether a record's L_KIND is one of the kinds above (the kernels refuse any other). */
static inline int light_kind_known(double kf) {
    return kf == KIND_POINT || kf == KIND_SPOT || kf == KIND_SUN || kf == KIND_AREA;
}
#define SPOT_DISC_POINTS 8  /* kernels_np.SPOT_DISC_POINTS */
#define SPOT_DISC_PHI 0.6180339887498949
#define SPOT_GATE_MARGIN 1.05

/* cos and sin of 2 pi frac(i SPOT_DISC_PHI), i = 0..7: the turn of the disc lattice's i-th
 * azimuth from its first (lights.LAMP_DISC_TURN, which tests/test_light_samples.py holds to
 * the formula) */
static const double LAMP_DISC_TURN[SPOT_DISC_POINTS][2] = {
    {1.0, 0.0},
    {-0.7373688780783199, -0.6754902942615236},
    {0.08742572471695967, 0.9961710408648278},
    {0.6084388609788622, -0.7936007512916963},
    {-0.9847134853154288, 0.17418195037931125},
    {0.8437552948123968, 0.5367280526263234},
    {-0.2596043049014893, -0.9657150743757781},
    {-0.4609070247133709, 0.8874484292452537},
};

static inline void disc_map(double u1, double u2, int round_shape, double *pa, double *pb) {
    double a = 2.0 * u1 - 1.0, b = 2.0 * u2 - 1.0;
    if (!round_shape) { *pa = a; *pb = b; return; }
    int big = fabs(a) > fabs(b);
    double r = big ? a : b, phi;
    if (a == 0.0 && b == 0.0) phi = 0.0;
    else if (big) phi = (M_PI / 4) * b / (a == 0.0 ? 1.0 : a);
    else phi = M_PI / 2 - (M_PI / 4) * a / (b == 0.0 ? 1.0 : b);
    *pa = r * cos(phi); *pb = r * sin(phi);
}

static inline void basis(const double n[3], double t1[3], double t2[3]) {
    double sign = n[2] >= 0.0 ? 1.0 : -1.0;
    double a = -1.0 / (sign + n[2]);
    double b = n[0] * n[1] * a;
    t1[0] = 1.0 + sign * n[0] * n[0] * a; t1[1] = sign * b; t1[2] = -sign * n[0];
    t2[0] = b; t2[1] = sign + n[1] * n[1] * a; t2[2] = -n[1];
}

/* Cosine between the spot's axis and the propagation direction v (world), measured in the
 * light's local frame (its inverse matrix L_INV: non-uniform scale included). */
static inline double spot_cos(const double *L, const double v[3]) {
    const double *M = L + L_INV;
    double loc[3];
    for (int r = 0; r < 3; r++) loc[r] = M[3 * r] * v[0] + M[3 * r + 1] * v[1] + M[3 * r + 2] * v[2];
    double ln = sqrt(loc[0] * loc[0] + loc[1] * loc[1] + loc[2] * loc[2]);
    return -loc[2] / (ln > 1e-30 ? ln : 1e-30);
}

/* A point of a rectangular area light uniform in the solid angle it subtends at x (Urena,
 * Fajardo and King 2013, "An Area-Preserving Parametrization for Spherical Rectangles"):
 * writes it to src and returns that solid angle (sr); -1 where the rectangle is skewed
 * (edges not at right angles), x lies in its plane or behind it (it lights nothing there),
 * or x is so far (dc over RECT_FAR times its diagonal) that a point uniform over the area
 * has no noise to lose.  kernels_np / lights.rect_solid_angle_sample is the twin. */
#define RECT_FAR 64.0
static inline double rect_solid_angle_sample(const double *L, const double x[3], double dc,
                                             double u, double v, double src[3]) {
    const double *ax = L + L_AX, *ay = L + L_AY, *c = L + L_POS, *nl = L + L_NORMAL;
    double la = sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2]);
    double lb = sqrt(ay[0] * ay[0] + ay[1] * ay[1] + ay[2] * ay[2]);
    if (!(la > 0.0 && lb > 0.0)) return -1.0;
    if (dc > RECT_FAR * 2.0 * sqrt(la * la + lb * lb)) return -1.0;
    double ex[3], ey[3], ez[3];
    for (int a = 0; a < 3; a++) { ex[a] = ax[a] / la; ey[a] = ay[a] / lb; }
    if (fabs(ex[0] * ey[0] + ex[1] * ey[1] + ex[2] * ey[2]) > 1e-6) return -1.0;
    ez[0] = ex[1] * ey[2] - ex[2] * ey[1];
    ez[1] = ex[2] * ey[0] - ex[0] * ey[2];
    ez[2] = ex[0] * ey[1] - ex[1] * ey[0];
    double rel[3], dd[3];
    for (int a = 0; a < 3; a++) { rel[a] = x[a] - c[a]; dd[a] = c[a] - ax[a] - ay[a] - x[a]; }
    double front = rel[0] * nl[0] + rel[1] * nl[1] + rel[2] * nl[2];
    double x0 = dd[0] * ex[0] + dd[1] * ex[1] + dd[2] * ex[2];
    double y0 = dd[0] * ey[0] + dd[1] * ey[1] + dd[2] * ey[2];
    double z0 = dd[0] * ez[0] + dd[1] * ez[1] + dd[2] * ez[2];
    if (!(front > 1e-9 * (la + lb)) || !(fabs(z0) > 1e-9 * (la + lb))) return -1.0;
    if (z0 > 0.0) { z0 = -z0; for (int a = 0; a < 3; a++) ez[a] = -ez[a]; }
    double x1 = x0 + 2.0 * la, y1 = y0 + 2.0 * lb, z2 = z0 * z0;
    /* the z components of the unit normals of the planes through x and each edge (n0, n2
     * have no x component, n1, n3 no y one, so neighbours' dot products are these alone),
     * and the spherical rectangle's inner angles */
    double n0z = -y0 / sqrt(z2 + y0 * y0), n1z = x1 / sqrt(z2 + x1 * x1);
    double n2z = y1 / sqrt(z2 + y1 * y1), n3z = -x0 / sqrt(z2 + x0 * x0);
    double g0 = acos(max_d(-1.0, min_d(1.0, -n0z * n1z)));
    double g1 = acos(max_d(-1.0, min_d(1.0, -n1z * n2z)));
    double g2 = acos(max_d(-1.0, min_d(1.0, -n2z * n3z)));
    double g3 = acos(max_d(-1.0, min_d(1.0, -n3z * n0z)));
    double b0 = n0z, b1 = n2z, k = 2.0 * M_PI - g2 - g3, S = g0 + g1 - k;
    if (!(S > 0.0)) return -1.0;
    /* u: the angle swept from the first edge; v: the height along the chosen column */
    double au = u * S + k;
    double sa = sin(au);
    double fu = (cos(au) * b0 - b1) / (fabs(sa) > 1e-300 ? sa : 1e-300);
    double cu = (fu > 0.0 ? 1.0 : -1.0) / sqrt(fu * fu + b0 * b0);
    cu = max_d(-1.0, min_d(1.0, cu));
    double xu = -(cu * z0) / sqrt(max_d(1.0 - cu * cu, 1e-300));
    xu = max_d(x0, min_d(x1, xu));
    double dist = sqrt(xu * xu + z2);
    double h0 = y0 / sqrt(dist * dist + y0 * y0), h1 = y1 / sqrt(dist * dist + y1 * y1);
    double hv = h0 + v * (h1 - h0), hv2 = hv * hv;
    double yv = hv2 < 1.0 - 1e-12 ? hv * dist / sqrt(1.0 - hv2) : y1;
    yv = max_d(y0, min_d(y1, yv));
    for (int a = 0; a < 3; a++) src[a] = x[a] + xu * ex[a] + yv * ey[a] + z0 * ez[a];
    return S;
}

/* Light record `L` at point x: propagation direction d, irradiance e, unit direction to the
 * centre wc and its distance dc (INFINITY for the sun), and ds, the distance to the emitting
 * point(s) sampled (their irradiance-weighted mean; dc for a point without radius). */
static inline void light_sample(const double *L, const double x[3], double u1, double u2,
                         double d[3], double e[3], double wc[3], double *dc, double *ds) {
    int kind = (int)L[L_KIND];
    if (kind == KIND_SUN) {
        for (int a = 0; a < 3; a++) { d[a] = L[L_DIR + a]; e[a] = L[L_STRENGTH + a]; wc[a] = -d[a]; }
        *dc = INFINITY;
        *ds = INFINITY;
        return;
    }
    const double *c = L + L_POS;
    double vc[3] = {c[0] - x[0], c[1] - x[1], c[2] - x[2]};
    double dcc = sqrt(vc[0] * vc[0] + vc[1] * vc[1] + vc[2] * vc[2]);
    double inv_dc = 1.0 / (dcc > 1e-30 ? dcc : 1e-30);
    for (int a = 0; a < 3; a++) wc[a] = vc[a] * inv_dc;
    *dc = dcc;
    if (kind == KIND_POINT || kind == KIND_SPOT) {
        double radius = L[L_RADIUS], t1[3] = {0, 0, 0}, t2[3] = {0, 0, 0};
        if (radius > 0.0) {
            double nn[3] = {-wc[0], -wc[1], -wc[2]};
            basis(nn, t1, t2);
        }
        /* a spot with a radius averages its cone over SPOT_DISC_POINTS points of the disc:
         * (u1, u2) shifts a fixed lattice (Cranley-Patterson), so each point is uniform and
         * the mean irradiance unbiased; one random point would light x or not (noise) */
        int n_pts = (kind == KIND_SPOT && radius > 0.0) ? SPOT_DISC_POINTS : 1;
        if (n_pts > 1 && radius < dcc) {
            /* one point where the cone is the same over the whole disc: the disc's directions
             * lie within alpha of the centre's (wider in the light's frame by L_COND) */
            double out[3] = {-wc[0], -wc[1], -wc[2]};
            double cc = spot_cos(L, out);
            cc = cc < -1.0 ? -1.0 : (cc > 1.0 ? 1.0 : cc);
            double th = acos(cc), spread = SPOT_GATE_MARGIN * L[L_COND] * asin(radius / dcc);
            if (th - spread > L[L_ANGLES] || th + spread < L[L_ANGLES + 1]) n_pts = 1;
        }
        /* one disc point: (u1, u2) by the concentric map, (0.5, 0.5) the centre (the callers'
         * unjittered sample).  Several (a spot's): the lattice (1/2 + i / SPOT_DISC_POINTS,
         * frac(i SPOT_DISC_PHI)) shifted by (u1, u2) (Cranley-Patterson) modulo 1 in polar
         * coordinates on the unit disc, the squared radius and the azimuth over 2 pi, each
         * point uniform over the disc: the azimuths' cosines and sines are one sincos turned
         * by LAMP_DISC_TURN, where the concentric map took a sincos per point */
        double pa = 0.0, pb = 0.0, c0 = 1.0, s0 = 0.0;
        if (radius > 0.0 && n_pts == 1) disc_map(u1, u2, 1, &pa, &pb);
        if (n_pts > 1) {
            c0 = cos(2.0 * M_PI * u2);
            s0 = sin(2.0 * M_PI * u2);
        }
        double rmin = 1e-4, esum = 0.0, dsum[3] = {0, 0, 0}, lsum = 0.0;
        /* 1 - cos theta_max of the disc's cone, without cancellation for r << d */
        double hyp = sqrt(dcc * dcc + radius * radius);
        double omc_max = radius > 0.0 ? radius * radius / (hyp * (hyp + dcc)) : 0.0;
        double e_disc = radius > 0.0 ? 2.0 * omc_max / (radius * radius) : 0.0;
        for (int i = 0; i < n_pts; i++) {
            double di[3], den, dist;  /* the irradiance per unit intensity is att / den */
            if (radius > 0.0) {
                /* Cycles' soft-falloff lamp: a disc of radius r facing x with radiance
                 * I / (pi r^2); the disc subtends the cone of half-angle atan(r / d) about wc,
                 * irradiance I / (pi r^2) * 2 pi (1 - cos theta_max), exact also inside r.
                 * The disc point (s, azimuth) maps to a direction uniform in that solid angle:
                 * 1 - cos theta = s (1 - cos theta_max). */
                /* s: the point's squared radius on the unit disc; (ca, sa): the point itself
                 * (the concentric map's), or its azimuth's cosine and sine (the lattice's);
                 * rs scales them to sin theta */
                double s, ca, sa;
                if (n_pts == 1) {
                    s = pa * pa + pb * pb;
                    ca = pa;
                    sa = pb;
                } else {
                    s = u1 + 0.5 + (double)i / (double)SPOT_DISC_POINTS;
                    if (s >= 1.0) s -= 1.0;
                    if (s >= 1.0) s -= 1.0;
                    ca = c0 * LAMP_DISC_TURN[i][0] - s0 * LAMP_DISC_TURN[i][1];
                    sa = s0 * LAMP_DISC_TURN[i][0] + c0 * LAMP_DISC_TURN[i][1];
                }
                double omc = s * omc_max;
                double cos_t = 1.0 - omc, sin_t = sqrt(omc * (2.0 - omc) > 0.0 ? omc * (2.0 - omc) : 0.0);
                double rs = n_pts > 1 ? sin_t : (s > 0.0 ? sin_t / sqrt(s) : 0.0);
                for (int a = 0; a < 3; a++) di[a] = -(wc[a] * cos_t + (t1[a] * ca + t2[a] * sa) * rs);
                den = 1.0 / e_disc;
                dist = dcc / (cos_t > 1e-12 ? cos_t : 1e-12);  /* to the disc along di */
            } else {
                double v[3] = {x[0] - c[0], x[1] - c[1], x[2] - c[2]};
                dist = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
                double id = 1.0 / (dist > 1e-30 ? dist : 1e-30);
                for (int a = 0; a < 3; a++) di[a] = v[a] * id;
                den = dist * dist > rmin * rmin ? dist * dist : rmin * rmin;
            }
            if (i == 0)
                for (int a = 0; a < 3; a++) d[a] = di[a];
            double att = 1.0;
            if (kind == KIND_SPOT) {
                double cos_t = spot_cos(L, di);
                double ch = L[L_COSHALF], bl = L[L_BLEND];
                if (bl <= 0.0) att = cos_t > ch ? 1.0 : 0.0;
                else {
                    double q = (cos_t - ch) / ((1.0 - ch) * bl);
                    q = q < 0.0 ? 0.0 : (q > 1.0 ? 1.0 : q);
                    att = q * q * (3.0 - 2.0 * q);
                }
            }
            esum += att / den;
            lsum += att / den * dist;
            for (int a = 0; a < 3; a++) dsum[a] += att / den * di[a];
        }
        *ds = (radius > 0.0 && esum > 0.0) ? lsum / esum : dcc;
        /* the direction: the irradiance-weighted mean over the points, so that the phase
         * function sees the light from the part of the disc that lights x */
        double dn = sqrt(dsum[0] * dsum[0] + dsum[1] * dsum[1] + dsum[2] * dsum[2]);
        if (n_pts > 1 && dn > 0.0)
            for (int a = 0; a < 3; a++) d[a] = dsum[a] / dn;
        for (int a = 0; a < 3; a++) e[a] = L[L_STRENGTH + a] / (4.0 * M_PI) * (esum / (double)n_pts);
        return;
    }
    /* AREA */
    double src[3], v[3], omega = -1.0, pa, pb;
    disc_map(u1, u2, L[L_ROUND] > 0, &pa, &pb);
    if (!(L[L_ROUND] > 0))
        omega = rect_solid_angle_sample(L, x, dcc, u1, u2, src);
    if (omega < 0.0)  /* round, far, skewed or in its plane: a point uniform over the area */
        for (int a = 0; a < 3; a++) src[a] = c[a] + L[L_AX + a] * pa + L[L_AY + a] * pb;
    for (int a = 0; a < 3; a++) v[a] = x[a] - src[a];
    double dist2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    if (!(dist2 > 1e-8)) dist2 = 1e-8;
    double dist = sqrt(dist2);
    *ds = dist;
    for (int a = 0; a < 3; a++) d[a] = v[a] / dist;
    double cos_l = d[0] * L[L_NORMAL] + d[1] * L[L_NORMAL + 1] + d[2] * L[L_NORMAL + 2];
    if (cos_l < 0.0) cos_l = 0.0;
    double area = L[L_AREA];
    double norm = (L[L_NORMALIZE] > 0 && area > 0) ? area : 1.0;
    /* the radiance times the solid angle per sample: omega (the pdf 1 / omega), or
     * cos A / r^2 (the pdf 1 / A) */
    double w = omega >= 0.0 ? (cos_l > 0.0 ? omega : 0.0) : cos_l * area / dist2;
    for (int a = 0; a < 3; a++) e[a] = L[L_STRENGTH + a] / M_PI / norm * w;
}

/* The optical depth to an emitting point at distance ds, from the field's depth to the light's
 * centre at distance dc: the centre's path's mean extinction times the emitting point's path
 * length, ds / dc (exact in a homogeneous medium).  Near the centre the field's trilinear
 * depth stands for at least half a voxel's path, so dc is taken as at least that. */
static inline double path_stretch(double ds, double dc, double voxel) {
    double lo = 0.5 * voxel;
    return ds / (dc > lo ? dc : lo);
}


#endif
