/* Empty and constant space: per medium a coarse grid of density bounds (bricks.c). */
#ifndef MPP_BRICKS_H
#define MPP_BRICKS_H

#include "common.h"

/* ---- Empty and constant space (twin of kernels_np.Walk) ----
 * Per medium an optional coarse grid of density bounds (media.brick_bounds): brick b covers
 * the index cells [b B, (b + 1) B] and holds [least, largest] density of its points. */
typedef struct {
    const float *data;   /* (n[0], n[1], n[2], 2) or NULL: no bricks, the box is "varying" */
    Py_ssize_t n[3];
    double size;         /* B, cells per brick edge */
} Bricks;

#define EMPTY_MAX_BRICKS 100000  /* DDA steps per call at most (a bounded loop) */
#define KIND_EMPTY 0
#define KIND_CONST 1
#define KIND_VARYING 2


/* Parse `list` (None, or one float32 (bx, by, bz, 2) per grid with b = ceil((n - 1) / brick)). */
int parse_bricks(PyObject *list, int brick, const Grid *g, int ng, Bricks *out, Buf *bufs,
                 int *nheld);

/* A walk along the line o + s v (s increasing) of one grid's index coordinates through its
 * bricks: it cuts the line into stretches of whole bricks that surely hold no density
 * (empty), hold one constant density (const: every brick's least = largest = value) or may
 * vary.  A brick's far face is computed afresh from its index, (face - o) * (1 / v), so both
 * twins find the same s. */
typedef struct {
    const Bricks *b;
    double o[3], inv[3];
    int dir[3];
    double sa, sb;          /* the line's interval inside the padded box (sa > sb: misses) */
    Py_ssize_t idx[3];      /* the brick just past the current stretch */
    double end;             /* where the current stretch ends */
    int kind;               /* the current stretch's kind */
    double value;           /* its density when const */
    int state;              /* 0 not started, 1 walking, 2 past the box */
} Walk;

void walk_init(Walk *w, const Grid *g, const Bricks *b, const double o[3], const double v[3]);
/* The kind of the stretch holding s (calls come with non-decreasing s); *end: where it ends
 * (INFINITY: empty from there on), *value: its density when const. */
int walk_at(Walk *w, double s, double *end, double *value);
/* The largest density (brick bound) on the segment [s_a, s_b] of the line o + s v of a grid's
 * index coordinates (0 when it lies wholly outside the grid).  Twin of
 * kernels_np.segment_majorant. */
double segment_majorant(const Grid *g, const Bricks *b, const double o[3], const double v[3],
                        double s_a, double s_b);
/* segment_majorant, and with `least` non-NULL the least density bound on the segment there
 * (0 where the segment leaves the grid or its coordinates are not finite), from the same walk
 * over the bricks.  Twin of kernels_np.segment_majorant (least=). */
double segment_bounds(const Grid *g, const Bricks *b, const double o[3], const double v[3],
                      double s_a, double s_b, double *least);
/* The interval [*lo, *hi] of the index-space ray o + s v inside the box [0, last] (*lo > *hi
 * where it misses; a ray parallel to a slab is wholly in or out of it).  As numpy's maximum
 * and minimum, a NaN stays NaN, and the ray then misses.  Twin of media.ray_box. */
void box_interval(const double o[3], const double v[3], const double last[3], double *lo,
                  double *hi);
/* Where the ray p + s d leaves the last of the media's padded boxes it crosses, capped at
 * t_max; 0 when it meets none ahead.  Twin of kernels_np.media_exit. */
double media_exit(const Grid *g, int ng, const double p[3], const double d[3], double t_max);

#endif
