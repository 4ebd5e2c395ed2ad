/* Light paths through a medium for multiple scattering (twin of mpp_render.paths.trace_paths_np,
 * which documents the estimate).  Every size is checked against the buffers, every voxel and
 * lattice index is bounds-checked, and each path's events are capped, so no input reads out
 * of bounds or loops without end.  The loop runs without the GIL.
 */
#include "kernels.h"
#include "light.h"   /* basis: the orthonormal frame of phase.orthonormal_basis */
#include "triangles.h"

const char trace_paths_doc[] =
    "trace_paths(out, density, w2i, i2w, sigma_s, sigma_t, g, stride, towards, starts, weights,\n"
    "            dirs, cdf, rate, path_lo, path_hi, n_paths, seed, max_collisions, roulette,\n"
    "            jitter, lobe, outside, reach, triangles, albedo, start_source, start_peak,\n"
    "            moments, others, threshold, cells, light, colour, extinction[, min_collisions])\n"
    "Twin of mpp_render.paths.trace_paths_np: adds to out (LX,LY,LZ,3) float64 the deposits\n"
    "of paths path_lo..path_hi-1 of n_paths towards the camera, and to moments (LX,LY,LZ,12)\n"
    "float64, unless it is empty, their moments of order 0 and 1 (paths.py, \"Moments\").\n"
    "others: a tuple of (out, moments, density, w2i, sigma_s, sigma_t, g, stride, towards,\n"
    "rate, threshold, cells, colour, extinction), the other media the paths fly through, scatter in and deposit on\n"
    "(at most 7).  threshold >= 0: the medium is the grid's trilinear value >= threshold\n"
    "(density 1, a mesh volume's sharp surface, as the march reads it), else the nearest\n"
    "voxel's density.  cells: empty, or with threshold > 0 (n0-1,n1-1,n2-1) uint8, each cell\n"
    "of 8 voxels 0 where its trilinear value is below threshold throughout, 1 where it is at\n"
    "or above it throughout, else 2 (kernels.cell_classes): a read saved, the same result.\n"
    "light: empty, or the light record (LIGHT_FIELDS float64) whose first scatterings the\n"
    "lobe-0 starts are: each path's incoming direction is drawn from its emitter at the start\n"
    "(light_sample) instead of dirs.  colour: (0,0,0,3) float32, or the density's shape x 3:\n"
    "each voxel's factor on sigma_s, applied at a real collision (the nearest voxel's).\n"
    "extinction: (0,0,0,3) float32, or the density's shape x 3: per voxel the density each\n"
    "channel's extinction reads (sigma_t[c] times channel c, the nearest voxel's; at most the\n"
    "density, so the rate still bounds it), the collisions then by spectral tracking.\n"
    "min_collisions (default 0): the real collisions and bounces a path has made before its\n"
    "deposits count (1: only the light that has scattered at least once).\n"
    "stop (default None): a writable uint8 array of at least one byte, read between paths\n"
    "while the loop runs without the GIL: once its first byte is nonzero (another thread\n"
    "sets it: Esc) the loop stops within STOP_EVERY paths and out holds a partial sum, which\n"
    "the caller discards.\n"
    "odds (default None): None, an empty float32 array, or (LX,LY,LZ) float32 in (0, 1] on\n"
    "the lattice: the camera's roulette at real collisions in the grid (paths.py, \"The\n"
    "camera's roulette\"), the nearest lattice point's odds.";

#define MAX_EVENTS 1000000L   /* tentative collisions per path, whatever the medium */
#define MAX_RATE_SPAN 1e6    /* rate x the grid's diagonal (m): tentative points across it */
#define OTHER_BUFS 10        /* buffers held per other medium (other_grid) */
#define T_MIN 1e-9           /* m: a surface closer than this along a segment is not hit */
#define FAR 1e30             /* m: how far a segment into empty space is tested */
#define D_PICK 0
#define D_JIT 1
#define D_DIR 7
#define D_FLY 10
#define D_HIT 11
#define D_TURN 12
#define D_RR 14
#define D_BOUNCE 15
#define D_RETRY 16     /* a start's offset drawn again: 6 dimensions per try (event 0) */
#define D_ACCEPT 512   /* a start's acceptance draw, one dimension per try (event 0) */
#define D_CORNER 600   /* the lattice corner a deposit's moments go to */
#define D_MEDIUM 17    /* which medium a tentative collision is in, with several (event >= 1) */
#define D_LIGHT 700    /* the emitter point a first scattering's light comes from (event 0) */
#define D_LIGHT_MORE 702   /* the other candidate emitter points, two dimensions each */
#define LIGHT_CANDIDATES 8 /* emitter points a start with a rate draws one from (trace_one) */
#define D_LIGHT_PICK (D_LIGHT_MORE + 2 * (LIGHT_CANDIDATES - 1))   /* which of them (716) */
#define D_CAMERA 800   /* the camera's roulette at a real collision (camera_roulette) */
#define START_TRIES 64 /* offsets drawn for a first scattering until one is accepted */
#define PATH_MEDIA 8    /* media one trace flies through: its own and 7 others */
#define BOX_TIE 1e-9   /* m (relative beyond 1 m): box faces this close are crossed together */
#define AIM_COSINE 0.25 /* an aimed surface start (lobe 3): the share of its paths drawn by the
                         * cosine lobe alone, the rest within the reach sphere's cone */
#define D_AIM 5        /* an aimed surface start's choice between the two (event 0) */

/* The unit direction at cosine c and azimuth 2 pi u2 about the unit vector axis. */
static inline void about(double c, double u2, const double axis[3], double out[3]) {
    double st = sqrt(max_d(0.0, 1.0 - c * c)), phi = 2.0 * M_PI * u2;
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

/* An HG-distributed direction about the propagation direction axis (phase.sample_hg). */
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
    about(c, u2, axis, out);
}

/* A cosine-distributed unit direction about the unit normal n (Lambertian reflection). */
static inline void cosine_dir(double u1, double u2, const double n[3], double out[3]) {
    about(sqrt(u1), u2, n, out);
}

/* One medium the paths fly through: its voxels, coefficients, tentative collision rate mu
 * (1/m) inside its box, and the lattice it deposits on. */
typedef struct {
    const float *dens;
    Py_ssize_t n[3];
    double w2i[12], ss[3], st[3], st_max, st_min, g, mu;
    double thr;               /* >= 0: density 1 where the trilinear value >= thr, else 0 */
    const unsigned char *cls; /* NULL, or with thr: each cell's class (0 out, 1 in, 2 read) */
    long stride;
    const double *tw;
    Py_ssize_t ls[3];
    double *out;
    double *mom;              /* NULL, or (LX,LY,LZ,12) the deposits' moments */
    const float *col;         /* NULL, or (X,Y,Z,3) each voxel's factor on ss (the scattering
                                 colour, Medium.scatter_grid) */
    const float *ext;         /* NULL, or (X,Y,Z,3) the density each channel's extinction reads
                                 (media.PreparedMedium.extinction_density) */
} PathGrid;

typedef struct {
    PathGrid m[PATH_MEDIA];        /* m[0]: the medium the paths start in; then the others */
    int nm;
    const float *src;         /* NULL, or each voxel's first-scattering source (any unit) */
    const double *peak;       /* with src: each start's largest src under its tent */
    double i2w[9], roulette, jitter, outside;
    double reach[4];          /* centre (m) and radius (m) beyond which a path outside ends */
    long max_hits;
    long min_hits;            /* real collisions and bounces before a path's deposits count */
    int lobe;                 /* 0: the first direction by the phase function, 1: cosine,
                                 2: uniform over the sphere, 3: cosine, aimed at the reach
                                 sphere (trace_one) */
    const double *tri, *alb;  /* (T,9) corner and two edges; (T,3) diffuse albedo */
    Py_ssize_t n_tri, n_box;
    const double *box;        /* (n_box,6) lo, hi of each TRI_CHUNK triangles */
    const double *light;      /* NULL, or the light record (LIGHT_FIELDS) whose first
                                 scatterings the lobe-0 starts are: the light's direction is
                                 drawn at the start from the emitter (light_sample) */
    const float *odds;        /* NULL, or (LX,LY,LZ) of m[0]'s lattice: each point's odds in
                                 (0, 1] of a path surviving there (camera_roulette) */
    const double *start_rate; /* NULL, or per start the mean extinction (1/m) along the
                                 light's path to its centre: the emitter point is drawn among
                                 LIGHT_CANDIDATES by its stretched transmittance (trace_one) */
} Tracer;

/* Where the ray o + t d (t >= 0) enters (want_exit 0) or leaves (1) the grid's box in index
 * space, [-0.5, n - 0.5] per axis (the nearest-voxel domain); INFINITY when it does not. */
static double box_cross(const PathGrid *T, const double o[3], const double d[3], int want_exit) {
    double t0 = 0.0, t1 = INFINITY;
    for (int r = 0; r < 3; r++) {
        double io = T->w2i[4 * r] * o[0] + T->w2i[4 * r + 1] * o[1] + T->w2i[4 * r + 2] * o[2] +
                    T->w2i[4 * r + 3];
        double id = T->w2i[4 * r] * d[0] + T->w2i[4 * r + 1] * d[1] + T->w2i[4 * r + 2] * d[2];
        double lo = -0.5, hi = (double)T->n[r] - 0.5;
        if (id == 0.0) {
            if (!(io >= lo && io <= hi)) return INFINITY;
            continue;
        }
        double ta = (lo - io) / id, tb = (hi - io) / id;
        if (ta > tb) { double x = ta; ta = tb; tb = x; }
        if (ta > t0) t0 = ta;
        if (tb < t1) t1 = tb;
    }
    if (!(t1 >= t0)) return INFINITY;
    return want_exit ? t1 : (t0 > 0.0 ? t0 : INFINITY);
}

/* The nearest triangle hit by o + t d for t in (T_MIN, tmax), other than ``skip`` (the one the
 * path leaves); -1 when none (triangles.h). */
static Py_ssize_t surface_hit(const Tracer *T, const double o[3], const double d[3], double tmax,
                              Py_ssize_t skip, double *t_hit) {
    return tri_hit(T->tri, T->n_tri, T->box, o, d, T_MIN, tmax, skip, t_hit);
}

/* World point p in grid G's voxel index coordinates. */
static inline void grid_index(const PathGrid *G, const double p[3], double idx[3]) {
    for (int r = 0; r < 3; r++)
        idx[r] = G->w2i[4 * r] * p[0] + G->w2i[4 * r + 1] * p[1] + G->w2i[4 * r + 2] * p[2] +
                 G->w2i[4 * r + 3];
}

/* The nearest voxel to index coordinates idx (the edge voxel on the box's face, or for NaN). */
static void nearest_voxel(const PathGrid *G, const double idx[3], Py_ssize_t v[3]) {
    for (int a = 0; a < 3; a++) {
        double f = floor_fast(idx[a] + 0.5);
        if (!(f >= 0.0)) f = 0.0;
        if (f > (double)(G->n[a] - 1)) f = (double)(G->n[a] - 1);
        v[a] = (Py_ssize_t)f;
    }
}

/* The density of grid G at index coordinates idx: with a threshold the trilinear value (0
 * outside [0, n-1] per axis, as media.trilinear) thresholded, as the march reads a mesh
 * volume; else the nearest voxel's (the edge voxel on the box's face).  0 for NaN or < 0. */
static double density_at(const PathGrid *G, const double idx[3]) {
    if (G->thr >= 0.0) {
        Py_ssize_t i0[3];
        double fr[3];
        for (int a = 0; a < 3; a++) {
            double f = floor_fast(idx[a]);
            if (!(f >= 0.0 && f < (double)(G->n[a] - 1))) return 0.0;
            i0[a] = (Py_ssize_t)f;
            fr[a] = idx[a] - f;
        }
        if (G->cls) {   /* a cell wholly in or out of the medium needs no read */
            unsigned char k = G->cls[(i0[0] * (G->n[1] - 1) + i0[1]) * (G->n[2] - 1) + i0[2]];
            if (k < 2) return (double)k;
        }
        double v = 0.0;
        for (int corner = 0; corner < 8; corner++) {
            int o[3] = {(corner >> 2) & 1, (corner >> 1) & 1, corner & 1};
            double w = 1.0;
            for (int a = 0; a < 3; a++) w *= o[a] ? fr[a] : 1.0 - fr[a];
            v += w * (double)G->dens[((i0[0] + o[0]) * G->n[1] + i0[1] + o[1]) * G->n[2] +
                                     i0[2] + o[2]];
        }
        return v >= G->thr ? 1.0 : 0.0;
    }
    Py_ssize_t v[3];
    nearest_voxel(G, idx, v);
    double rho = (double)G->dens[(v[0] * G->n[1] + v[1]) * G->n[2] + v[2]];
    return rho >= 0.0 ? rho : 0.0;   /* NaN or negative density: empty */
}

/* What a first scattering's start is weighed by at world point p: the nearest voxel's
 * source T->src, or without it 1 where the voxel's density is > 0; 0 outside the box. */
static double source_at(const Tracer *TR, const double p[3]) {
    const PathGrid *T = &TR->m[0];
    double idx[3];
    grid_index(T, p, idx);
    Py_ssize_t v[3];
    for (int r = 0; r < 3; r++) {
        double f = floor_fast(idx[r] + 0.5);
        if (!(f >= 0.0 && f < (double)T->n[r])) return 0.0;
        v[r] = (Py_ssize_t)f;
    }
    Py_ssize_t flat = (v[0] * T->n[1] + v[1]) * T->n[2] + v[2];
    if (T->thr >= 0.0) {   /* a sharp surface: only inside it, as the march reads it */
        if (!(density_at(T, idx) > 0.0)) return 0.0;
        if (!TR->src) return 1.0;
    }
    if (TR->src) {
        double q = (double)TR->src[flat];
        return q > 0.0 ? q : 0.0;
    }
    return T->dens[flat] > 0.0f ? 1.0 : 0.0;
}

/* After a real collision or a bounce: Russian roulette below T->roulette of the start weight.
 * 0 when the path ends (roulette, the collision cap, or no weight left). */
static inline int survive(const Tracer *T, uint32_t key, long ev, double w[3], double w0,
                          long hits) {
    double m = max_d(w[0], max_d(w[1], w[2])) / max_d(w0, 1e-300);
    double q = m < T->roulette ? m / T->roulette : 1.0;
    int live = uniform01(key, ev, D_RR) < q;
    for (int c = 0; c < 3; c++) w[c] /= max_d(q, 1e-300);
    return live && hits < T->max_hits && max_d(w[0], max_d(w[1], w[2])) > 0.0;
}

/* The camera's roulette at a real collision at world point p inside m[0] (paths.py, "The
 * camera's roulette"): the odds q of the lattice point nearest p; where q is below the
 * lowest odds *held the path has met, it survives with probability q / held and its weight
 * (and w0, so that the weight's own roulette sees the same path) grows by held / q.  A path
 * that reaches odds q has survived with probability q and weighs 1 / q: once per path, not
 * compounded.  0 when the path ends. */
static inline int camera_roulette(const Tracer *T, const double p[3], uint32_t key, long ev,
                                  double w[3], double *w0, double *held) {
    const PathGrid *G = &T->m[0];
    double idx[3];
    Py_ssize_t v[3];
    grid_index(G, p, idx);
    for (int a = 0; a < 3; a++) {
        double l = floor_fast(idx[a] / (double)G->stride + 0.5);
        if (!(l >= 0.0)) l = 0.0;   /* NaN too */
        if (l > (double)(G->ls[a] - 1)) l = (double)(G->ls[a] - 1);
        v[a] = (Py_ssize_t)l;
    }
    double q = (double)T->odds[(v[0] * G->ls[1] + v[1]) * G->ls[2] + v[2]];
    if (!(q < *held)) return 1;
    if (!(uniform01(key, ev, D_CAMERA) * *held < q)) return 0;
    double f = *held / q;
    for (int c = 0; c < 3; c++) w[c] *= f;
    *w0 *= f;
    *held = q;
    return 1;
}

/* Whether world point p lies in grid G's box by more than INNER_MARGIN voxels on every
 * axis: a flight that starts inside the box and ends there crosses none of its faces, and
 * the margin keeps box_cross's rounding from ever putting a face before it. */
#define INNER_MARGIN 1e-6
static inline int well_inside(const PathGrid *G, const double p[3]) {
    double idx[3];
    grid_index(G, p, idx);
    for (int r = 0; r < 3; r++)
        if (!(idx[r] > -0.5 + INNER_MARGIN && idx[r] < (double)G->n[r] - 0.5 - INNER_MARGIN))
            return 0;
    return 1;
}

/* Whether world point p lies in grid G's box (the nearest-voxel domain). */
static int in_box(const PathGrid *G, const double p[3]) {
    double idx[3];
    grid_index(G, p, idx);
    for (int r = 0; r < 3; r++) {
        double f = floor_fast(idx[r] + 0.5);
        if (!(f >= 0.0 && f < (double)G->n[r])) return 0;
    }
    return 1;
}

/* A tentative point at world pos inside grid G: its density (density_at), which it
 * returns, weighs the deposit w / mu x density x trilinear share x
 * p(d . v) on the 8 lattice points round the point (nothing where the density is 0: an
 * empty voxel adds nothing), and with G->mom the moments on one of them. */
/* A real collision's weight at pos times the scattering colour's factor there (G->col: the
 * nearest voxel's, negative or NaN read as 0); nothing without a colour grid.  Twin of
 * paths._colour_factor. */
static void apply_colour(const PathGrid *G, const double pos[3], double w[3]) {
    if (!G->col) return;
    double idx[3];
    Py_ssize_t v[3];
    grid_index(G, pos, idx);
    nearest_voxel(G, idx, v);
    const float *f = G->col + 3 * ((v[0] * G->n[1] + v[1]) * G->n[2] + v[2]);
    for (int c = 0; c < 3; c++) w[c] *= f[c] > 0.0f ? (double)f[c] : 0.0;
}

static double deposit(const PathGrid *G, const double pos[3], const double w[3], const double d[3],
                      uint32_t key, long ev) {
    double idx[3];
    grid_index(G, pos, idx);
    double rho = density_at(G, idx);
    double lat[3], fr[3];
    Py_ssize_t b[3];
    for (int a = 0; a < 3; a++) {
        lat[a] = idx[a] / (double)G->stride;
        double fl = floor_fast(lat[a]);
        if (!(fl > -2.0)) fl = -2.0;   /* NaN guard: no corner in range */
        b[a] = (Py_ssize_t)fl;
        fr[a] = lat[a] - fl;
    }
    if (rho > 0.0) {
        /* what the 8 corners share, worked out once: the weight (w / mu) rho, each axis'
         * two shares and whether each of its two lattice points lies in the lattice (the
         * products in the order of one corner's: the same bits) */
        double wr[3], sh[3][2];
        int in[3][2];
        Py_ssize_t step[3] = {G->ls[1] * G->ls[2], G->ls[2], 1};
        for (int c = 0; c < 3; c++) wr[c] = (w[c] / G->mu) * rho;
        for (int a = 0; a < 3; a++) {
            sh[a][0] = 1.0 - fr[a];
            sh[a][1] = fr[a];
            in[a][0] = b[a] >= 0 && b[a] < G->ls[a];
            in[a][1] = b[a] + 1 >= 0 && b[a] + 1 < G->ls[a];
        }
        /* the grid's fields in locals: the deposits' stores could alias them */
        const double g = G->g, *tw = G->tw, ph_iso = hg_phase(0.0, 0.0);
        /* each corner's phase function towards the camera from its lattice point (direction
         * tw) for a path going along d; an isotropic medium's needs no direction (the same
         * value: a read of tw saved, a cache miss per corner on a large lattice) */
        const int iso = g == 0.0;
        double *out = G->out;
        /* all 8 corners in the lattice (away from its faces): no test per corner */
        int all = in[0][0] && in[0][1] && in[1][0] && in[1][1] && in[2][0] && in[2][1];
        Py_ssize_t base = b[0] * step[0] + b[1] * step[1] + b[2];
#pragma GCC unroll 8   /* each corner's offsets and shares known at compile time */
        for (int corner = 0; corner < 8; corner++) {
            int o0 = (corner >> 2) & 1, o1 = (corner >> 1) & 1, o2 = corner & 1;
            if (!all && !(in[0][o0] && in[1][o1] && in[2][o2])) continue;
            double share = sh[0][o0] * sh[1][o1] * sh[2][o2];
            Py_ssize_t flat = base + o0 * step[0] + o1 * step[1] + o2;
            double ph = iso ? ph_iso : hg_phase(d[0] * tw[3 * flat] + d[1] * tw[3 * flat + 1] +
                                                 d[2] * tw[3 * flat + 2], g);
            double *o_pt = out + 3 * flat;
            for (int c = 0; c < 3; c++)
                o_pt[c] += wr[c] * share * ph;
        }
    }
    if (G->mom && rho > 0.0) {
        /* the moments, dep / (4 pi) and g d dep / (4 pi), on one corner drawn by the
         * trilinear shares with the whole weight: the same mean, an eighth of the
         * work (paths.py, "Moments"); one draw picks the corner axis by axis */
        Py_ssize_t cc[3];
        int ok = 1;
        double u = uniform01(key, ev, D_CORNER);
        for (int a = 0; a < 3; a++) {
            int up = u < fr[a];
            u = up ? u / fr[a] : (u - fr[a]) / (1.0 - fr[a]);
            cc[a] = b[a] + up;
            if (cc[a] < 0 || cc[a] >= G->ls[a]) ok = 0;
        }
        if (ok) {
            double *o_pt = G->mom + 12 * ((cc[0] * G->ls[1] + cc[1]) * G->ls[2] + cc[2]);
            for (int c = 0; c < 3; c++) {
                double m0 = (w[c] / G->mu) * rho * (1.0 / (4.0 * M_PI)), m1 = m0 * G->g;
                o_pt[c] += m0;
                for (int j = 0; j < 3; j++) o_pt[3 + 3 * j + c] += m1 * d[j];
            }
        }
    }
    return rho;
}

/* Asks the caches for what a tentative collision at world point p of grid G will read: its
 * density (with a threshold the cell's class) and the deposit's lattice points (and their
 * directions towards the camera).  The paths are bound by these reads' latency (a cloud's
 * density or a mesh's cell classes outgrow the core's cache); asked for one event ahead,
 * they arrive while the event before is worked out.  It changes no result. */
static inline void prefetch_collision(const PathGrid *G, const double p[3], uint32_t key,
                                      long ev) {
    double idx[3];
    grid_index(G, p, idx);
    Py_ssize_t v[3], b[3];
    int cell = 1;   /* with a threshold: the cell density_at reads lies in the grid */
    for (int a = 0; a < 3; a++) {
        double f = floor_fast(idx[a]);
        cell &= f >= 0.0 && f < (double)(G->n[a] - 1);   /* also NaN */
        v[a] = cell ? (Py_ssize_t)f : 0;
        double l = floor_fast(idx[a] / (double)G->stride);
        b[a] = l >= 0.0 && l < (double)(G->ls[a] - 1) ? (Py_ssize_t)l : -1;
    }
    if (G->thr < 0.0) {   /* density_at's nearest voxel */
        nearest_voxel(G, idx, v);
        PREFETCH(G->dens + (v[0] * G->n[1] + v[1]) * G->n[2] + v[2], 0);
    } else if (cell) {    /* its cell's class, or without classes its first corner */
        if (G->cls)
            PREFETCH(G->cls + (v[0] * (G->n[1] - 1) + v[1]) * (G->n[2] - 1) + v[2], 0);
        else
            PREFETCH(G->dens + (v[0] * G->n[1] + v[1]) * G->n[2] + v[2], 0);
    }
    if (b[0] < 0 || b[1] < 0 || b[2] < 0) return;
    Py_ssize_t s1 = G->ls[2], s0 = G->ls[1] * s1, base = b[0] * s0 + b[1] * s1 + b[2];
    if (G->mom) {   /* the one corner the moments go to, drawn as deposit draws it */
        double u = uniform01(key, ev, D_CORNER);
        Py_ssize_t flat = base;
        const Py_ssize_t st[3] = {s0, s1, 1};
        for (int a = 0; a < 3; a++) {
            double fr = idx[a] / (double)G->stride - (double)b[a];
            int up = u < fr;
            u = up ? u / fr : (u - fr) / (1.0 - fr);
            flat += up ? st[a] : 0;
        }
        PREFETCH(G->mom + 12 * flat, 1);
        PREFETCH(G->mom + 12 * flat + 11, 1);
    }
    const Py_ssize_t pair[4] = {0, s1, s0, s0 + s1};   /* the 4 pairs of corners along z */
    for (int q = 0; q < 4; q++) {
        const Py_ssize_t f = 3 * (base + pair[q]);
        PREFETCH(G->out + f, 1);
        PREFETCH(G->out + f + 5, 1);
        if (G->g != 0.0) {
            PREFETCH(G->tw + f, 0);
            PREFETCH(G->tw + f + 5, 0);
        }
    }
}

static int cmp_u64(const void *a, const void *b) {
    uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return (x > y) - (x < y);
}

static void trace_one(const Tracer *T, uint32_t key, const double *start, const double *w_start,
                      const double *dir, double inv_n, double peak, double lrate) {
    double pos[3], d[3], w[3], off[3], w0 = 0.0;
    if (T->lobe == 1 || T->lobe == 3) {
        /* a surface: a tent of half-width jitter metres in its plane */
        double t1[3], t2[3];
        basis(dir, t1, t2);
        for (int a = 0; a < 2; a++)
            off[a] = (uniform01(key, 0, D_JIT + 2 * a) + uniform01(key, 0, D_JIT + 2 * a + 1) -
                      1.0) * T->jitter;
        for (int a = 0; a < 3; a++) pos[a] = start[a] + t1[a] * off[0] + t2[a] * off[1];
    } else {              /* a lattice point: a tent of half-width jitter lattice steps */
        /* a first scattering (lobe 0): rejection sampling of the source within the
         * tent, so that the starts follow the voxels' source and not the tent alone (the
         * lattice point holds the voxels' power shared by the tent): a draw is accepted
         * with probability source / peak; after START_TRIES the draw with the most source
         * is kept.  An emitting voxel (lobe 2) emits where it is drawn. */
        double best[3] = {start[0], start[1], start[2]}, best_q = -1.0;
        for (int k = 0; k < START_TRIES; k++) {
            int base = k == 0 ? D_JIT : D_RETRY + 6 * (k - 1);
            for (int a = 0; a < 3; a++)
                off[a] = (uniform01(key, 0, base + 2 * a) + uniform01(key, 0, base + 2 * a + 1) -
                          1.0) * ((double)T->m[0].stride * T->jitter);
            for (int a = 0; a < 3; a++)
                pos[a] = start[a] + T->i2w[3 * a] * off[0] + T->i2w[3 * a + 1] * off[1] +
                         T->i2w[3 * a + 2] * off[2];
            if (T->lobe != 0 || T->jitter <= 0.0) break;
            double q = source_at(T, pos);
            if (uniform01(key, 0, D_ACCEPT + k) * peak < q) break;
            if (q > best_q) {
                best_q = q;
                for (int a = 0; a < 3; a++) best[a] = pos[a];
            }
            if (k == START_TRIES - 1)
                for (int a = 0; a < 3; a++) pos[a] = best[a];
        }
    }
    double din[3] = {dir[0], dir[1], dir[2]};
    if (T->lobe == 0 && T->light) {
        /* the light arriving at the start from one point of the emitter (a sphere's disc, an
         * area light's solid angle), drawn as the march draws it: near a large emitter the
         * light comes from many directions, not from its centre or along its axis alone */
        double dl[3], el[3], wc[3], dc, ds;
        light_sample(T->light, pos, uniform01(key, 0, D_LIGHT), uniform01(key, 0, D_LIGHT + 1),
                     dl, el, wc, &dc, &ds);
        if (lrate > 0.0) {
            /* through a dense medium a wide emitter's light arrives mostly along the shorter
             * paths: one of LIGHT_CANDIDATES emitter points, drawn by its light (the mean of
             * its channels) times exp(-lrate (d - d_min)) (paths.start_directions) */
            double cd[LIGHT_CANDIDATES][3], ce[LIGHT_CANDIDATES], cs[LIGHT_CANDIDATES];
            int good[LIGHT_CANDIDATES];
            double dmin = INFINITY;
            for (int j = 0; j < LIGHT_CANDIDATES; j++) {
                double e3[3], w3[3], dcj, dsj;
                if (j == 0) {
                    for (int a = 0; a < 3; a++) { cd[0][a] = dl[a]; e3[a] = el[a]; }
                    dsj = ds;
                } else {
                    light_sample(T->light, pos, uniform01(key, 0, D_LIGHT_MORE + 2 * (j - 1)),
                                 uniform01(key, 0, D_LIGHT_MORE + 2 * (j - 1) + 1), cd[j], e3,
                                 w3, &dcj, &dsj);
                }
                double m2 = cd[j][0] * cd[j][0] + cd[j][1] * cd[j][1] + cd[j][2] * cd[j][2];
                good[j] = m2 > 0.25 && m2 < 4.0 && max_d(e3[0], max_d(e3[1], e3[2])) > 0.0 &&
                          isfinite(dsj);
                ce[j] = (e3[0] + e3[1] + e3[2]) / 3.0;
                cs[j] = dsj;
                if (good[j] && dsj < dmin) dmin = dsj;
            }
            double cum[LIGHT_CANDIDATES], tot = 0.0;
            for (int j = 0; j < LIGHT_CANDIDATES; j++) {
                double gap = good[j] ? cs[j] - (isfinite(dmin) ? dmin : 0.0) : 0.0;
                tot += good[j] ? ce[j] * exp(-lrate * (gap > 0.0 ? gap : 0.0)) : 0.0;
                cum[j] = tot;
            }
            if (tot > 0.0) {
                double u = uniform01(key, 0, D_LIGHT_PICK) * tot;
                int pick = 0;
                while (pick < LIGHT_CANDIDATES - 1 && cum[pick] <= u) pick++;
                for (int a = 0; a < 3; a++) dl[a] = cd[pick][a];
                el[0] = el[1] = el[2] = 1.0;   /* a candidate that brings light */
            }
        }
        double n2 = dl[0] * dl[0] + dl[1] * dl[1] + dl[2] * dl[2];
        if (n2 > 0.25 && n2 < 4.0 && max_d(el[0], max_d(el[1], el[2])) > 0.0) {
            double inv = 1.0 / sqrt(n2);
            for (int a = 0; a < 3; a++) din[a] = dl[a] * inv;
        }
    }
    double aim = 1.0;   /* the cosine lobe's density over the one drawn from (lobe 3) */
    if (T->lobe == 1)
        cosine_dir(uniform01(key, 0, D_DIR), uniform01(key, 0, D_DIR + 1), din, d);
    else if (T->lobe == 3) {
        /* a surface aimed at the reach sphere: with probability AIM_COSINE by the cosine
         * lobe, else uniform within the cone the sphere subtends; the weight is the cosine
         * lobe's density over the mixture's (every direction keeps a density, so light that
         * reaches the medium after a bounce elsewhere is kept) */
        double axis[3], dist2 = 0.0;
        for (int a = 0; a < 3; a++) {
            axis[a] = T->reach[a] - pos[a];
            dist2 += axis[a] * axis[a];
        }
        double r2 = T->reach[3] * T->reach[3];
        if (!(dist2 > r2) || !isfinite(dist2) || !(r2 > 0.0)) {
            cosine_dir(uniform01(key, 0, D_DIR), uniform01(key, 0, D_DIR + 1), din, d);
        } else {
            double dist = sqrt(dist2), cmax = sqrt(1.0 - r2 / dist2);
            for (int a = 0; a < 3; a++) axis[a] /= dist;
            double omega = 2.0 * M_PI * (1.0 - cmax);
            if (uniform01(key, 0, D_AIM) < AIM_COSINE)
                cosine_dir(uniform01(key, 0, D_DIR), uniform01(key, 0, D_DIR + 1), din, d);
            else
                about(1.0 - uniform01(key, 0, D_DIR) * (1.0 - cmax),
                      uniform01(key, 0, D_DIR + 1), axis, d);
            double cn = d[0] * din[0] + d[1] * din[1] + d[2] * din[2];
            double ca = d[0] * axis[0] + d[1] * axis[1] + d[2] * axis[2];
            double lobe = cn > 0.0 ? cn / M_PI : 0.0;
            double mix = AIM_COSINE * lobe + (ca >= cmax && omega > 0.0 ?
                                              (1.0 - AIM_COSINE) / omega : 0.0);
            aim = mix > 0.0 ? lobe / mix : 0.0;
            if (!(aim > 0.0)) return;   /* below the surface: no light */
        }
    } else  /* lobe 2, an emitting voxel: uniform over the sphere (the phase function of g 0) */
        turn(uniform01(key, 0, D_DIR), uniform01(key, 0, D_DIR + 1),
             T->lobe == 2 ? 0.0 : T->m[0].g, din, d);
    for (int c = 0; c < 3; c++) {
        w[c] = w_start[c] * inv_n * aim;
        if (w[c] > w0) w0 = w[c];
    }
    long hits = 0;
    double held = 1.0;   /* the lowest camera odds the path has survived (camera_roulette) */
    Py_ssize_t skip = -1;
    int inside[PATH_MEDIA];
    for (int j = 0; j < T->nm; j++) inside[j] = in_box(&T->m[j], pos);
    /* the next event's flight, worked out at the end of this one for prefetch_collision:
     * its event, the rate it was drawn at and its length (the same formula: the same bits) */
    long ahead_ev = 0;
    double ahead_rate = 0.0, ahead_t = 0.0;
    for (long ev = 1; ev <= MAX_EVENTS; ev++) {
        /* with several media each keeps its own tentative collisions at its rate inside its
         * box: their sum is the rate of the whole, and a tentative point is medium j's with
         * probability mu_j over the sum */
        double tb = INFINITY, tjs[PATH_MEDIA], t_fast = -1.0;
        /* one medium, inside it: where the flight ends inside its box by INNER_MARGIN the
         * box's faces are all beyond it and its exit need not be worked out (the box is
         * convex; the same bits as with the exit: the rate and the flight are the same, and
         * min(t, exit) = t) */
        if (T->nm == 1 && inside[0] && T->m[0].mu > 0.0) {
            const double r1 = T->m[0].mu;
            double t1 = ev == ahead_ev && r1 == ahead_rate ? ahead_t
                      : -log(1.0 - uniform01(key, ev, D_FLY)) / r1;
            double q[3];
            for (int a = 0; a < 3; a++) q[a] = pos[a] + t1 * d[a];
            if (well_inside(&T->m[0], q)) {
                t_fast = t1;
                tjs[0] = INFINITY;
                goto flight;
            }
        }
        for (int j = 0; j < T->nm; j++) {
            double tj = box_cross(&T->m[j], pos, d, inside[j]);
            if (inside[j] && !(tj < INFINITY)) {
                /* no way out ahead: the path is past the box's face (rounding where boxes
                 * share a face it crossed in another's step), so it is outside */
                inside[j] = 0;
                tj = box_cross(&T->m[j], pos, d, 0);
            }
            tjs[j] = tj;
            if (tj < tb) tb = tj;
        }
    flight:;
        double rate = 0.0;
        if (T->nm == 1)
            rate = inside[0] ? T->m[0].mu : T->outside * T->m[0].st_max;
        else
            for (int j = 0; j < T->nm; j++)
                if (inside[j]) rate += T->m[j].mu;
        double t = t_fast >= 0.0 ? t_fast
                 : !(rate > 0.0) ? INFINITY
                 : ev == ahead_ev && rate == ahead_rate ? ahead_t   /* worked out the event before */
                 : -log(1.0 - uniform01(key, ev, D_FLY)) / rate;
        double tseg = min_d(t, tb);
        if (T->n_tri > 0) {
            double ts;
            Py_ssize_t k = surface_hit(T, pos, d, min_d(tseg, FAR), skip, &ts);
            if (k >= 0) {   /* a diffuse bounce off the surface, on the side the path came from */
                const double *e1 = T->tri + 9 * k + 3, *e2 = T->tri + 9 * k + 6;
                double nrm[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                                 e1[0] * e2[1] - e1[1] * e2[0]};
                double len = sqrt(nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]);
                double side = (nrm[0] * d[0] + nrm[1] * d[1] + nrm[2] * d[2]) > 0.0 ? -1.0 : 1.0;
                for (int a = 0; a < 3; a++) {
                    pos[a] += ts * d[a];
                    nrm[a] *= side / len;
                }
                for (int c = 0; c < 3; c++) w[c] *= T->alb[3 * k + c];
                cosine_dir(uniform01(key, ev, D_BOUNCE), uniform01(key, ev, D_BOUNCE + 1), nrm, d);
                hits++;
                skip = k;
                if (!survive(T, key, ev, w, w0, hits)) return;
                continue;
            }
        }
        skip = -1;
        if (!(tseg < INFINITY)) return;   /* flies off into empty space */
        if (tb <= t) {                    /* into or out of a grid: the flight starts again */
            for (int a = 0; a < 3; a++) pos[a] += tb * d[a];
            for (int j = 0; j < T->nm; j++)   /* every box whose face is there (shared faces) */
                if (tjs[j] <= tb + BOX_TIE * (1.0 + tb)) inside[j] = !inside[j];
            continue;
        }
        for (int a = 0; a < 3; a++) pos[a] += t * d[a];
        int j = 0;
        if (T->nm > 1) {   /* whose tentative point it is */
            double u = uniform01(key, ev, D_MEDIUM) * rate, cum = 0.0;
            for (int q = 0; q < T->nm; q++) {
                if (!inside[q]) continue;
                j = q;
                cum += T->m[q].mu;
                if (u < cum) break;
            }
            rate = T->m[j].mu;
        }
        const PathGrid *G = &T->m[j];
        double rho;
        if (!inside[j]) {   /* one medium, beyond its grid (the world's fog) */
            double r2 = 0.0;
            for (int a = 0; a < 3; a++) r2 += (pos[a] - T->reach[a]) * (pos[a] - T->reach[a]);
            if (!(r2 <= T->reach[3] * T->reach[3])) return;   /* too far to come back */
            rho = T->outside;
        } else if (hits >= T->min_hits) {
            rho = deposit(G, pos, w, d, key, ev);
        } else {   /* a flight whose light is not asked for: its density alone */
            double idx[3];
            grid_index(G, pos, idx);
            rho = density_at(G, idx);
        }
        /* real or null collision; chromatic media use spectral tracking (Kutz et al. 2017),
         * whose null probability stays > 0 while any channel has null density */
        double p_hit, stc[3];
        int hit, chroma = G->st_min != G->st_max || G->ext != NULL;
        if (G->ext && inside[j]) {   /* the extinction's own density per channel */
            double idx[3];
            Py_ssize_t v[3];
            grid_index(G, pos, idx);
            nearest_voxel(G, idx, v);
            const float *e = G->ext + 3 * ((v[0] * G->n[1] + v[1]) * G->n[2] + v[2]);
            for (int c = 0; c < 3; c++) stc[c] = (e[c] > 0.0f ? (double)e[c] : 0.0) * G->st[c];
        } else {
            for (int c = 0; c < 3; c++) stc[c] = rho * G->st[c];
        }
        if (!chroma) {
            p_hit = rho * G->st_max / rate;
            if (p_hit > 1.0) p_hit = 1.0;
            hit = uniform01(key, ev, D_HIT) < p_hit;
            if (!hit) {
                double den = max_d(1.0 - p_hit, 1e-12);
                for (int c = 0; c < 3; c++) w[c] *= (1.0 - stc[c] / rate) / den;
            } else {
                for (int c = 0; c < 3; c++) w[c] *= G->ss[c] / G->st_max;
            }
        } else {
            double real = max_d(stc[0], max_d(stc[1], stc[2]));
            double nul = max_d(rate - min_d(stc[0], min_d(stc[1], stc[2])), 0.0);
            p_hit = real / max_d(real + nul, 1e-300);
            hit = uniform01(key, ev, D_HIT) < p_hit;
            if (!hit) {
                for (int c = 0; c < 3; c++)
                    w[c] *= max_d(rate - stc[c], 0.0) / max_d(rate * (1.0 - p_hit), 1e-300);
            } else {
                for (int c = 0; c < 3; c++) w[c] *= rho * G->ss[c] / max_d(rate * p_hit, 1e-300);
            }
        }
        if (hit) {
            double nd[3];
            if (inside[j]) apply_colour(G, pos, w);
            turn(uniform01(key, ev, D_TURN), uniform01(key, ev, D_TURN + 1), G->g, d, nd);
            for (int a = 0; a < 3; a++) d[a] = nd[a];
            hits++;
            if (!survive(T, key, ev, w, w0, hits)) return;
            if (T->odds && j == 0 && inside[0] && !camera_roulette(T, pos, key, ev, w, &w0, &held))
                return;
        } else if (!(max_d(w[0], max_d(w[1], w[2])) > 0.0)) {
            return;
        }
        if (T->nm == 1 && inside[0]) {   /* where the next tentative collision falls, unless a
                                            face or a surface comes first */
            const double r1 = T->m[0].mu;
            ahead_ev = ev + 1;
            ahead_rate = r1;
            ahead_t = -log(1.0 - uniform01(key, ev + 1, D_FLY)) / r1;
            double q[3];
            for (int a = 0; a < 3; a++) q[a] = pos[a] + ahead_t * d[a];
            prefetch_collision(&T->m[0], q, key, ev + 1);
        }
    }
}

/* Fill grid G (moments mom or NULL); -1 with an exception for bad coefficients. */
static int set_grid(PathGrid *G, const float *dens, const Py_ssize_t n[3], const double *w2i,
                    const double *ss, const double *st, double g, double rate, long stride,
                    const double *tw, const Py_ssize_t ls[3], double *out, double *mom,
                    double thr, const unsigned char *cls) {
    if (isnan(thr) || isinf(thr)) {
        PyErr_SetString(PyExc_ValueError, "trace_paths: the threshold must be finite");
        return -1;
    }
    G->thr = thr;
    G->cls = cls;
    G->dens = dens;
    for (int a = 0; a < 3; a++) { G->n[a] = n[a]; G->ls[a] = ls[a]; }
    memcpy(G->w2i, w2i, sizeof G->w2i);
    memcpy(G->ss, ss, sizeof G->ss);
    memcpy(G->st, st, sizeof G->st);
    G->st_max = max_d(G->st[0], max_d(G->st[1], G->st[2]));
    G->st_min = min_d(G->st[0], min_d(G->st[1], G->st[2]));
    if (!(G->st_max > 0.0) || !isfinite(G->st_max)) {
        PyErr_SetString(PyExc_ValueError, "trace_paths: sigma_t must be positive and finite");
        return -1;
    }
    if (stride < 1 || !(rate > 0.0) || !isfinite(rate) || !isfinite(g)) {
        PyErr_SetString(PyExc_ValueError, "trace_paths: bad stride, rate or g");
        return -1;
    }
    G->g = g > G_LIMIT ? G_LIMIT : (g < -G_LIMIT ? -G_LIMIT : g);
    G->mu = rate;
    G->stride = stride;
    G->tw = tw;
    G->out = out;
    G->mom = mom;
    return 0;
}

/* The rate x the diagonal (m) of a grid of shape n with index steps i2w, or of w2i's inverse
 * where i2w is NULL: the tentative points a crossing takes, at most MAX_RATE_SPAN. */
static int span_ok(double rate, const Py_ssize_t n[3], const double *w2i) {
    /* the diagonal in index space mapped to metres: solve w2i[:, :3] e = n (Cramer) */
    const double *A = w2i;
    double a = A[0], b = A[1], c = A[2], d = A[4], e = A[5], f = A[6], gg = A[8], h = A[9],
           i = A[10];
    double det = a * (e * i - f * h) - b * (d * i - f * gg) + c * (d * h - e * gg);
    if (!(fabs(det) > 0.0) || !isfinite(det)) return 0;
    double y[3] = {(double)n[0], (double)n[1], (double)n[2]};
    double x0 = (y[0] * (e * i - f * h) - b * (y[1] * i - f * y[2]) +
                 c * (y[1] * h - e * y[2])) / det;
    double x1 = (a * (y[1] * i - f * y[2]) - y[0] * (d * i - f * gg) +
                 c * (d * y[2] - y[1] * gg)) / det;
    double x2 = (a * (e * y[2] - y[1] * h) - b * (d * y[2] - y[1] * gg) +
                 y[0] * (d * h - e * gg)) / det;
    double span = rate * sqrt(x0 * x0 + x1 * x1 + x2 * x2);
    return span <= MAX_RATE_SPAN;
}

/* The cells' classes (see trace_paths_doc) from obj into b: *cls NULL where obj is empty,
 * else (n0-1,n1-1,n2-1) uint8 for a grid of shape n thresholded at thr > 0; -1 with an
 * exception for any other shape, or for cells without such a threshold. */
static int cell_buf(PyObject *obj, Buf *b, const Py_ssize_t n[3], double thr,
                    const unsigned char **cls) {
    Py_ssize_t sc[3] = {-1, -1, -1};
    *cls = NULL;
    if (get_buf(obj, b, 'B', 3, sc, "cells") < 0) return -1;
    if (sc[0] * sc[1] * sc[2] == 0) return 0;
    if (!(thr > 0.0) || sc[0] != n[0] - 1 || sc[1] != n[1] - 1 || sc[2] != n[2] - 1) {
        PyErr_SetString(PyExc_ValueError, "trace_paths: cells must be empty, or the grid's "
                        "cells (one fewer per axis) with a threshold above 0");
        return -1;
    }
    *cls = (const unsigned char *)b->view.buf;
    return 0;
}

/* A medium's 3-channel grid `what` (its scatter colour or extinction density): (0,0,0,3)
 * for none (*col NULL), else the density's shape sd and 3 channels; -1 with an exception. */
static int colour_buf(PyObject *obj, Buf *b, const Py_ssize_t sd[3], const float **col,
                      const char *what) {
    Py_ssize_t s[4] = {-1, -1, -1, 3};
    *col = NULL;
    if (get_buf(obj, b, 'f', 4, s, what) < 0) return -1;
    if (s[0] * s[1] * s[2] == 0) return 0;
    if (s[0] != sd[0] || s[1] != sd[1] || s[2] != sd[2]) {
        PyErr_Format(PyExc_ValueError, "trace_paths: the %s grid must have the density's "
                     "shape (and 3 channels), or be empty", what);
        return -1;
    }
    *col = (const float *)b->view.buf;
    return 0;
}

/* One of the others: (out, moments, density, w2i, sigma_s, sigma_t, g, stride, towards,
 * rate, threshold, cells, colour, extinction), its buffers held in b[OTHER_BUFS] (released by the
 * caller); -1 with an exception. */
static int other_grid(PyObject *item, Buf b[OTHER_BUFS], PathGrid *G) {
    PyObject *po, *pm, *pd, *pw, *pss, *pst, *ptw, *pcl, *pcol, *pext;
    double g, rate, thr;
    long stride;
    if (!PyTuple_Check(item) ||
        !PyArg_ParseTuple(item, "OOOOOOdlOddOOO", &po, &pm, &pd, &pw, &pss, &pst, &g, &stride,
                          &ptw, &rate, &thr, &pcl, &pcol, &pext)) {
        if (!PyErr_Occurred())
            PyErr_SetString(PyExc_ValueError, "trace_paths: each other medium is a tuple");
        return -1;
    }
    Py_ssize_t so[4] = {-1, -1, -1, 3}, sd[3] = {-1, -1, -1}, sw[2] = {3, 4}, s3[1] = {3},
               sm[4] = {-1, -1, -1, 12};
    if (get_buf_ex(po, &b[0], 'd', 4, so, "other out", PyBUF_WRITABLE) < 0) return -1;
    if (get_buf_ex(pm, &b[1], 'd', 4, sm, "other moments", PyBUF_WRITABLE) < 0) return -1;
    if (get_buf(pd, &b[2], 'f', 3, sd, "other density") < 0) return -1;
    if (get_buf(pw, &b[3], 'd', 2, sw, "other w2i") < 0) return -1;
    if (get_buf(pss, &b[4], 'd', 1, s3, "other sigma_s") < 0) return -1;
    s3[0] = 3;
    if (get_buf(pst, &b[5], 'd', 1, s3, "other sigma_t") < 0) return -1;
    Py_ssize_t stw[4] = {so[0], so[1], so[2], 3};
    if (get_buf(ptw, &b[6], 'd', 4, stw, "other towards") < 0) return -1;
    int has_mom = sm[0] * sm[1] * sm[2] > 0;
    if (has_mom && (sm[0] != so[0] || sm[1] != so[1] || sm[2] != so[2])) {
        PyErr_SetString(PyExc_ValueError, "trace_paths: moments must have the lattice's shape");
        return -1;
    }
    if (sd[0] < 1 || sd[1] < 1 || sd[2] < 1) {
        PyErr_SetString(PyExc_ValueError, "trace_paths: an other medium's grid is empty");
        return -1;
    }
    const unsigned char *cls = NULL;
    if (cell_buf(pcl, &b[7], sd, thr, &cls) < 0) return -1;
    if (set_grid(G, (const float *)b[2].view.buf, sd, (const double *)b[3].view.buf,
                 (const double *)b[4].view.buf, (const double *)b[5].view.buf, g, rate, stride,
                 (const double *)b[6].view.buf, so, (double *)b[0].view.buf,
                 has_mom ? (double *)b[1].view.buf : NULL, thr, cls) < 0)
        return -1;
    if (colour_buf(pcol, &b[8], sd, &G->col, "scatter colour") < 0) return -1;
    if (colour_buf(pext, &b[9], sd, &G->ext, "extinction density") < 0) return -1;
    if (!span_ok(rate, sd, G->w2i)) {
        PyErr_SetString(PyExc_ValueError,
                        "trace_paths: the rate of tentative collisions is too high for the "
                        "grid (or the grid's size is not finite)");
        return -1;
    }
    return 0;
}

PyObject *trace_paths(PyObject *self, PyObject *args) {
    PyObject *po, *pd, *pw2i, *pi2w, *pss, *pst, *ptw, *pstarts, *pws, *pdirs, *pcdf, *preach,
        *ptri, *palb, *psrc, *ppeak, *pmom, *pothers, *pcells, *plight, *pcol, *pext,
        *pstop = Py_None, *podds = Py_None, *prate = Py_None;
    double g, rate, roulette, jitter, outside, thr0;
    long stride, lo, hi, n_paths, max_hits, lobe, min_hits = 0;
    unsigned long seed;
    if (!PyArg_ParseTuple(args, "OOOOOOdlOOOOOdlllklddldOOOOOOOdOOOO|lOOO", &po, &pd, &pw2i, &pi2w,
                          &pss, &pst, &g, &stride, &ptw, &pstarts, &pws, &pdirs, &pcdf, &rate,
                          &lo, &hi, &n_paths, &seed, &max_hits, &roulette, &jitter, &lobe,
                          &outside, &preach, &ptri, &palb, &psrc, &ppeak, &pmom, &pothers, &thr0,
                          &pcells, &plight, &pcol, &pext, &min_hits, &pstop, &podds, &prate))
        return NULL;
    if (!PyTuple_Check(pothers) || PyTuple_GET_SIZE(pothers) > PATH_MEDIA - 1) {
        PyErr_SetString(PyExc_ValueError, "trace_paths: others must be a tuple of at most 7 media");
        return NULL;
    }
    Buf bo = {0}, bd = {0}, bw = {0}, bi = {0}, bss = {0}, bst = {0}, btw = {0}, bs = {0},
        bws = {0}, bdir = {0}, bc = {0}, br = {0}, bt = {0}, ba = {0}, bq = {0}, bp = {0}, bm = {0},
        bcl = {0}, bli = {0}, bcol = {0}, bext = {0}, bstop = {0}, bodds = {0}, brate = {0};
    const volatile unsigned char *stop = NULL;
    /* per other medium: out, moments, density, w2i, sigma_s, sigma_t, towards, cells, colour,
     * extinction */
    Buf ob[PATH_MEDIA - 1][OTHER_BUFS];
    memset(ob, 0, sizeof ob);
    Py_ssize_t n_others = PyTuple_GET_SIZE(pothers);
    double *boxes = NULL;
    uint64_t *order = NULL;   /* the paths' (start << 32 | path - lo), in tracing order */
    int ok = 0;
    Tracer T;
    Py_ssize_t so[4] = {-1, -1, -1, 3}, sd[3] = {-1, -1, -1}, sw[2] = {3, 4}, si[2] = {3, 3},
               s3[1] = {3}, stw[4] = {-1, -1, -1, 3}, sn[2] = {-1, 3}, sc[1] = {-1};
    if (get_buf_ex(po, &bo, 'd', 4, so, "out", PyBUF_WRITABLE) < 0) goto done;
    if (pstop != Py_None) {
        Py_ssize_t sst[1] = {-1};
        if (get_buf_ex(pstop, &bstop, 'B', 1, sst, "stop", PyBUF_WRITABLE) < 0) goto done;
        if (sst[0] < 1) {
            PyErr_SetString(PyExc_ValueError, "trace_paths: stop must hold at least one byte");
            goto done;
        }
        stop = (const volatile unsigned char *)bstop.view.buf;
    }
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
    Py_ssize_t s4[1] = {4}, stri[2] = {-1, 9}, salb[2] = {-1, 3};
    if (get_buf(preach, &br, 'd', 1, s4, "reach") < 0) goto done;
    if (get_buf(ptri, &bt, 'd', 2, stri, "triangles") < 0) goto done;
    salb[0] = stri[0];
    if (get_buf(palb, &ba, 'd', 2, salb, "albedo") < 0) goto done;
    /* the starts' source: (0,0,0) and (0,) for none, else the density's shape and one peak
     * per start */
    Py_ssize_t sq[3] = {-1, -1, -1}, sp[1] = {-1};
    if (get_buf(psrc, &bq, 'f', 3, sq, "start_source") < 0) goto done;
    if (get_buf(ppeak, &bp, 'd', 1, sp, "start_peak") < 0) goto done;
    int has_src = sq[0] * sq[1] * sq[2] > 0;
    if (has_src ? (sq[0] != sd[0] || sq[1] != sd[1] || sq[2] != sd[2] || sp[0] != sn[0])
                : sp[0] != 0) {
        PyErr_SetString(PyExc_ValueError, "trace_paths: start_source must have the density's "
                        "shape and start_peak one value per start (or both be empty)");
        goto done;
    }
    /* the moments: (0,0,0,12) for none, else the lattice's shape */
    Py_ssize_t sm[4] = {-1, -1, -1, 12};
    if (get_buf_ex(pmom, &bm, 'd', 4, sm, "moments", PyBUF_WRITABLE) < 0) goto done;
    int has_mom = sm[0] * sm[1] * sm[2] > 0;
    if (has_mom && (sm[0] != so[0] || sm[1] != so[1] || sm[2] != so[2])) {
        PyErr_SetString(PyExc_ValueError, "trace_paths: moments must have the lattice's shape");
        goto done;
    }
    if (!(jitter >= 0.0) || !isfinite(jitter) || (lobe < 0 || lobe > 3) ||
        !(outside >= 0.0) || !isfinite(outside) || !(((const double *)br.view.buf)[3] >= 0.0)) {
        PyErr_SetString(PyExc_ValueError, "trace_paths: bad jitter, lobe, outside or reach");
        goto done;
    }
    if (stride < 1 || !(rate > 0.0) || !isfinite(rate) || !isfinite(g) ||
        n_paths < 1 || lo < 0 || hi < lo || hi > n_paths || hi - lo > 0xFFFFFFFFL ||
        max_hits < 1 || min_hits < 0 || !(roulette >= 0.0) ||
        sn[0] < 1 || sn[0] > 0xFFFFFFFFL) {
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
    const unsigned char *cls0 = NULL;
    if (cell_buf(pcells, &bcl, sd, thr0, &cls0) < 0) goto done;
    if (set_grid(&T.m[0], (const float *)bd.view.buf, sd, (const double *)bw.view.buf,
                 (const double *)bss.view.buf, (const double *)bst.view.buf, g, rate, stride,
                 (const double *)btw.view.buf, so, (double *)bo.view.buf, NULL, thr0, cls0) < 0)
        goto done;
    if (colour_buf(pcol, &bcol, sd, &T.m[0].col, "scatter colour") < 0) goto done;
    if (colour_buf(pext, &bext, sd, &T.m[0].ext, "extinction density") < 0) goto done;
    T.nm = 1;
    for (Py_ssize_t k = 0; k < n_others; k++) {
        if (other_grid(PyTuple_GET_ITEM(pothers, k), ob[k], &T.m[1 + k]) < 0) goto done;
        T.nm++;
    }
    {
        Py_ssize_t sl[1] = {-1};
        if (get_buf(plight, &bli, 'd', 1, sl, "light") < 0) goto done;
        if (sl[0] != 0 && sl[0] != LIGHT_FIELDS) {
            PyErr_Format(PyExc_ValueError, "trace_paths: light must be empty or hold %d values",
                         LIGHT_FIELDS);
            goto done;
        }
        T.light = sl[0] ? (const double *)bli.view.buf : NULL;
    }
    T.odds = NULL;
    if (podds != Py_None) {   /* the camera's odds: empty, or one in (0, 1] a lattice point */
        Py_ssize_t sodd[3] = {-1, -1, -1};
        if (get_buf(podds, &bodds, 'f', 3, sodd, "odds") < 0) goto done;
        Py_ssize_t n_odds = sodd[0] * sodd[1] * sodd[2];
        if (n_odds > 0) {
            if (sodd[0] != so[0] || sodd[1] != so[1] || sodd[2] != so[2]) {
                PyErr_SetString(PyExc_ValueError,
                                "trace_paths: odds must have the lattice's shape");
                goto done;
            }
            const float *q = (const float *)bodds.view.buf;
            for (Py_ssize_t k = 0; k < n_odds; k++)
                if (!(q[k] > 0.0f && q[k] <= 1.0f)) {
                    PyErr_SetString(PyExc_ValueError, "trace_paths: odds must lie in (0, 1]");
                    goto done;
                }
            T.odds = q;
        }
    }
    T.start_rate = NULL;
    if (prate != Py_None) {   /* the starts' rates: one finite value >= 0 per start */
        Py_ssize_t srt[1] = {sn[0]};
        if (get_buf(prate, &brate, 'd', 1, srt, "start_rate") < 0) goto done;
        const double *r = (const double *)brate.view.buf;
        for (Py_ssize_t k = 0; k < sn[0]; k++)
            if (!(r[k] >= 0.0) || !isfinite(r[k])) {
                PyErr_SetString(PyExc_ValueError, "trace_paths: start_rate must be finite and >= 0");
                goto done;
            }
        T.start_rate = r;
    }
    T.src = has_src ? (const float *)bq.view.buf : NULL;
    T.peak = has_src ? (const double *)bp.view.buf : NULL;
    memcpy(T.i2w, bi.view.buf, sizeof T.i2w);
    T.roulette = roulette;
    T.max_hits = max_hits;
    T.min_hits = min_hits;
    T.jitter = jitter;
    T.lobe = (int)lobe;
    T.outside = outside;
    memcpy(T.reach, br.view.buf, sizeof T.reach);
    T.tri = (const double *)bt.view.buf;
    T.alb = (const double *)ba.view.buf;
    T.n_tri = stri[0];
    T.n_box = (T.n_tri + TRI_CHUNK - 1) / TRI_CHUNK;
    if (T.n_box > 0) {
        boxes = (double *)malloc(sizeof(double) * 6 * (size_t)T.n_box);
        if (!boxes) {
            PyErr_NoMemory();
            goto done;
        }
        tri_chunk_boxes(T.tri, T.n_tri, boxes);
    }
    T.box = boxes;
    T.m[0].mom = has_mom ? (double *)bm.view.buf : NULL;
    const double *S = (const double *)bs.view.buf, *W = (const double *)bws.view.buf,
                 *D = (const double *)bdir.view.buf, *C = (const double *)bc.view.buf;
    Py_ssize_t n_starts = sn[0];
    if (hi > lo) {
        order = (uint64_t *)malloc(sizeof(uint64_t) * (size_t)(hi - lo));
        if (!order) {
            PyErr_NoMemory();
            goto done;
        }
    }
    Py_BEGIN_ALLOW_THREADS
    uint32_t base = hash32((uint32_t)((uint64_t)seed * 0x27D4EB2Fu + 0x165667B1u));
    /* each path's start (searchsorted(cdf, u, side="right"), clamped to the last start),
     * then the paths traced in the order of their starts: the starts lie in the lattice's
     * order, so paths traced one after the other start near each other and find the
     * density and the deposits' points they read in the cache (the same paths and sums;
     * only the order of the additions changes) */
    for (long i = lo; i < hi; i++) {
        uint32_t key = hash32((uint32_t)i ^ base);
        double u = uniform01(key, 0, D_PICK);
        Py_ssize_t a = 0, b = n_starts;
        while (a < b) {
            Py_ssize_t mid = a + (b - a) / 2;
            if (C[mid] <= u) a = mid + 1; else b = mid;
        }
        if (a > n_starts - 1) a = n_starts - 1;
        order[i - lo] = ((uint64_t)a << 32) | (uint64_t)(i - lo);
    }
    if (hi > lo) qsort(order, (size_t)(hi - lo), sizeof(uint64_t), cmp_u64);
    for (long q = 0; q < hi - lo; q++) {
        if (stop && q % STOP_EVERY == 0 && *stop) break;   /* Esc: the sums are discarded */
        long i = lo + (long)(order[q] & 0xFFFFFFFFu);
        Py_ssize_t a = (Py_ssize_t)(order[q] >> 32);
        uint32_t key = hash32((uint32_t)i ^ base);
        trace_one(&T, key, S + 3 * a, W + 3 * a, D + 3 * a, 1.0 / (double)n_paths,
                  T.peak ? T.peak[a] : 1.0, T.start_rate ? T.start_rate[a] : 0.0);
    }
    Py_END_ALLOW_THREADS
    ok = 1;
done:
    buf_release(&bo); buf_release(&bd); buf_release(&bw); buf_release(&bi); buf_release(&bss);
    buf_release(&bst); buf_release(&btw); buf_release(&bs); buf_release(&bws);
    buf_release(&bdir); buf_release(&bc); buf_release(&br); buf_release(&bt); buf_release(&ba);
    buf_release(&bq); buf_release(&bp); buf_release(&bm); buf_release(&bcl);
    buf_release(&bli); buf_release(&bcol); buf_release(&bext); buf_release(&bstop);
    buf_release(&bodds); buf_release(&brate);
    for (Py_ssize_t k = 0; k < n_others; k++)
        for (int q = 0; q < OTHER_BUFS; q++) buf_release(&ob[k][q]);
    free(boxes);
    free(order);
    if (!ok) return NULL;
    Py_RETURN_NONE;
}
