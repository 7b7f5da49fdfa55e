/* The kinematic world's control tick (plant/kinematic.py): every robot of one world, or of
 * a batch of copies of one world, moved along the exact arc of its wheel speeds unless its
 * footprint would come closer to a wall, a low static object or another robot of its world
 * within the footprint's radius.
 *
 * plant/kinematic.py's reference_step is the same arithmetic in numpy, element by element;
 * here it is operation by operation and in the same order, in IEEE doubles: no fused
 * multiply-adds (-ffp-contract=off, plant/kernels/build.py), libm's sin, cos and hypot
 * (numpy's ufuncs give the same values here: tests/plant/test_kernels.py compares the two to the
 * bit), and numpy's minimum and maximum, which keep a NaN. The footprint test computes a
 * clearance exactly only where it can be below the footprint's radius (clearance_below),
 * which is all its comparisons need: it decides as the reference, which computes them all.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "npmath.h"

#define EXPORT __attribute__((visibility("default")))

EXPORT int plant_kinematic_abi(void) { return 2; }

/* The static world as the footprint test sees it (plant.footprint.Footprints); tol and
 * cull as cull_setup sets them. */
typedef struct {
    int64_t nbox, ncirc;
    const double *box_c, *box_cos, *box_sin, *box_half, *circ_c, *circ_r, *half;
    double tol;         /* the rounding allowance of clearance_below's bounds */
    int cull;           /* whether clearance_below may leave shapes out (all finite) */
} Statics;

/* Footprints.clearances of one point: the floor's walls, then the boxes, then the circles,
 * each reduced with np.minimum.reduce (a NaN anywhere is the result). */
static double clearance(const Statics *s, double cx, double cy)
{
    double out = np_min(s->half[0] - fabs(cx), s->half[1] - fabs(cy));
    if (s->nbox) {
        double least = 0.0;
        for (int64_t b = 0; b < s->nbox; b++) {
            double dx = cx - s->box_c[2 * b], dy = cy - s->box_c[2 * b + 1];
            double qx = np_max(fabs(dx * s->box_cos[b] + dy * s->box_sin[b])
                               - s->box_half[2 * b], 0.0);
            double qy = np_max(fabs(-dx * s->box_sin[b] + dy * s->box_cos[b])
                               - s->box_half[2 * b + 1], 0.0);
            double h = hypot(qx, qy);
            least = b ? np_min(least, h) : h;
        }
        out = np_min(out, least);
    }
    if (s->ncirc) {
        double least = 0.0;
        for (int64_t c = 0; c < s->ncirc; c++) {
            double d = hypot(cx - s->circ_c[2 * c], cy - s->circ_c[2 * c + 1]) - s->circ_r[c];
            d = np_max(d, 0.0);
            least = c ? np_min(least, d) : d;
        }
        out = np_min(out, least);
    }
    return out;
}

/* clearance_below's set-up for the call: it leaves shapes out only if every number of the
 * static world is finite (then, for a finite point, so is every shape's clearance) and each
 * box's (cos, sin) is a unit vector; tol, the allowance its bounds keep for rounding, is
 * 1e-9 of the world's scale, far above the few ulps of it that the clearances and the
 * bounds can each be off by. */
static void cull_setup(Statics *s)
{
    double scale = 1.0 + fabs(s->half[0]) + fabs(s->half[1]), big = 0.0, all = scale;
    int unit = 1;      /* the boxes' bounding squares below need cos^2 + sin^2 = 1 */
    for (int64_t b = 0; b < s->nbox; b++) {
        unit &= fabs(s->box_cos[b] * s->box_cos[b] + s->box_sin[b] * s->box_sin[b] - 1.0) < 1e-9;
        double m = fabs(s->box_c[2 * b]) + fabs(s->box_c[2 * b + 1]) + fabs(s->box_cos[b])
                   + fabs(s->box_sin[b]) + fabs(s->box_half[2 * b]) + fabs(s->box_half[2 * b + 1]);
        big = m > big ? m : big;
        all += m;                               /* NaN or inf if any number is */
    }
    for (int64_t c = 0; c < s->ncirc; c++) {
        double m = fabs(s->circ_c[2 * c]) + fabs(s->circ_c[2 * c + 1]) + fabs(s->circ_r[c]);
        big = m > big ? m : big;
        all += m;
    }
    s->cull = isfinite(all) && unit;
    s->tol = 1e-9 * (scale + big);
}

/* A grid over the floor listing, per cell, the shapes whose bound (clearance_below) can
 * come within r of a point of the cell: built for a call (grid_build), so that each robot
 * tries the few shapes near it instead of all. */
#define GRID_SIDE 32            /* cells along each side, at most */
#define GRID_STACK 4096         /* entries kept on the stack; more are malloc'd */
#define GRID_CELL_R 4.0         /* a cell's side, at least, in footprint radii */
/* robots x shapes below which trying every shape costs less than building a grid
 * (measured: 48 robots and 74 shapes of the swarm world gain nothing, 96 and 146 do) */
#define GRID_MIN_WORK 8192
typedef struct {
    int64_t nx, ny;             /* 0: no grid, every shape is tried */
    double x0, y0, inv;         /* a point's cell: floor((x - x0) * inv), clamped */
    int32_t start[GRID_SIDE * GRID_SIDE + 1];   /* cell c's shapes: idx[start[c]..start[c+1]) */
    int32_t *idx;               /* shape j: a box if j < nbox, else circle j - nbox */
    int32_t here[GRID_STACK];
} Grid;

/* The column (or row) of coordinate x: floor((x - x0) * inv) clamped to [0, n): a
 * non-decreasing function of x, in floating point too. */
static inline int64_t grid_at(double x, double x0, double inv, int64_t n)
{
    double f = floor((x - x0) * inv);
    return f < 0.0 ? 0 : f >= (double)n ? n - 1 : (int64_t)f;
}

/* Shape j's clearance from (cx, cy) into *out if lower, unless its bound shows it is above
 * *cut (then it is not the minimum below r); *cut follows *out. */
static inline void shape_below(const Statics *s, int64_t j, double cx, double cy, double r,
                               double *out, double *cut)
{
    double d;
    if (j < s->nbox) {
        double dx = cx - s->box_c[2 * j], dy = cy - s->box_c[2 * j + 1];
        double reach = s->box_half[2 * j] + s->box_half[2 * j + 1];
        if (fabs(dx) - reach > *cut || fabs(dy) - reach > *cut)
            return;
        double qx = np_max(fabs(dx * s->box_cos[j] + dy * s->box_sin[j])
                           - s->box_half[2 * j], 0.0);
        double qy = np_max(fabs(-dx * s->box_sin[j] + dy * s->box_cos[j])
                           - s->box_half[2 * j + 1], 0.0);
        d = hypot(qx, qy);
    } else {
        int64_t c = j - s->nbox;
        double dx = cx - s->circ_c[2 * c], dy = cy - s->circ_c[2 * c + 1];
        if (fabs(dx) - s->circ_r[c] > *cut || fabs(dy) - s->circ_r[c] > *cut)
            return;
        d = np_max(hypot(dx, dy) - s->circ_r[c], 0.0);
    }
    if (d < *out) {
        *out = d;
        *cut = (d < r ? d : r) + s->tol;
    }
}

/* The footprint test needs a clearance exactly only where it is below the footprint's
 * radius r: clearance_below(s, g, cx, cy, r) equals clearance(s, cx, cy) whenever that is
 * below r, and is at least r otherwise. It leaves out the shapes that cannot come that
 * close: a box's clearance is at least the point's distance to the box's bounding square
 * (half side hx + hy round its centre), at least max(|dx|, |dy|) - (hx + hy); a circle's at
 * least max(|dx|, |dy|) - radius (hypot is at least either side). A shape whose bound
 * exceeds r, or the least clearance found so far, by more than tol is not the minimum; g
 * (if it has cells) lists the shapes that can pass that test in the point's cell. The walls
 * come first: where they are at or below 0 (on or beyond a wall) no shape (clearance >= 0)
 * is lower. A point that is not finite, or a world with a number that is not, takes the
 * whole clearance (its NaNs and infinities as they are). Only the value matters to the
 * caller, which compares it: a zero's sign may differ. */
static double clearance_below(const Statics *s, const Grid *g, double cx, double cy, double r)
{
    if (!s->cull || !isfinite(cx) || !isfinite(cy) || !isfinite(r))
        return clearance(s, cx, cy);
    double out = np_min(s->half[0] - fabs(cx), s->half[1] - fabs(cy));
    if (!(out > 0.0))
        return out;
    double cut = (out < r ? out : r) + s->tol;
    if (g->nx) {
        int64_t c = grid_at(cy, g->y0, g->inv, g->ny) * g->nx + grid_at(cx, g->x0, g->inv, g->nx);
        for (int32_t k = g->start[c]; k < g->start[c + 1]; k++)
            shape_below(s, g->idx[k], cx, cy, r, &out, &cut);
    } else {
        for (int64_t j = 0; j < s->nbox + s->ncirc; j++)
            shape_below(s, j, cx, cy, r, &out, &cut);
    }
    return out;
}

/* Fills g for the call, or leaves it without cells (every shape tried) where a grid cannot
 * pay (few robots or shapes), for a world clearance_below does not cull, or without memory.
 * Cells of at least GRID_CELL_R r, at most GRID_SIDE a side, over the floor. A shape is
 * listed in the cells from those of its centre -/+ (its bound's reach + r + 2 tol) along x
 * and y: a point whose shape bound is within r + tol has its coordinates within those,
 * so (grid_at being non-decreasing) its cell among them. Pass 0 counts each cell's shapes,
 * pass 1 lists them in shape order. */
static void grid_build(Grid *g, const Statics *s, double r, int64_t robots)
{
    int64_t shapes = s->nbox + s->ncirc;
    g->nx = g->ny = 0;
    g->idx = g->here;
    if (!s->cull || !isfinite(r) || r < 0.0 || shapes > INT32_MAX
        || (double)robots * (double)shapes < GRID_MIN_WORK)
        return;
    double w = 2.0 * fabs(s->half[0]), h = 2.0 * fabs(s->half[1]);
    double side = fmax(fmax(w, h) / GRID_SIDE, GRID_CELL_R * r);
    if (!(side > 0.0))
        return;
    double x0 = -fabs(s->half[0]), y0 = -fabs(s->half[1]), inv = 1.0 / side;
    int64_t nx = (int64_t)fmin(fmax(ceil(w * inv), 1.0), GRID_SIDE);
    int64_t ny = (int64_t)fmin(fmax(ceil(h * inv), 1.0), GRID_SIDE);
    int64_t cells = nx * ny;
    double margin = r * (1.0 + 1e-9) + 2.0 * s->tol;     /* (r's own rounding too) */
    int32_t *count = g->start;          /* pass 0: count[c + 1] the shapes of cell c */
    for (int64_t c = 0; c <= cells; c++)
        count[c] = 0;
    int32_t *idx = NULL;
    for (int pass = 0; pass < 2; pass++) {
        for (int64_t j = 0; j < shapes; j++) {
            int64_t k = j - s->nbox;
            double x = j < s->nbox ? s->box_c[2 * j] : s->circ_c[2 * k];
            double y = j < s->nbox ? s->box_c[2 * j + 1] : s->circ_c[2 * k + 1];
            double reach = j < s->nbox ? s->box_half[2 * j] + s->box_half[2 * j + 1]
                                       : s->circ_r[k];
            int64_t ax = grid_at(x - reach - margin, x0, inv, nx);
            int64_t bx = grid_at(x + reach + margin, x0, inv, nx);
            int64_t ay = grid_at(y - reach - margin, y0, inv, ny);
            int64_t by = grid_at(y + reach + margin, y0, inv, ny);
            for (int64_t iy = ay; iy <= by; iy++)
                for (int64_t ix = ax; ix <= bx; ix++) {
                    int64_t c = iy * nx + ix;
                    if (pass == 0)
                        count[c + 1]++;
                    else
                        idx[count[c]++] = (int32_t)j;
                }
        }
        if (pass == 0) {
            for (int64_t c = 0; c < cells; c++) {   /* count[c]: cell c's first entry */
                if (count[c + 1] > INT32_MAX - count[c])
                    return;
                count[c + 1] += count[c];
            }
            idx = count[cells] <= GRID_STACK ? g->here : malloc((size_t)count[cells] * 4);
            if (!idx)
                return;
        }
    }
    /* pass 1 left count[c] at cell c's end, the next cell's start: shift back by one */
    for (int64_t c = cells; c > 0; c--)
        count[c] = count[c - 1];
    count[0] = 0;
    g->nx = nx;
    g->ny = ny;
    g->x0 = x0;
    g->y0 = y0;
    g->inv = inv;
    g->idx = idx;
}

static void grid_free(Grid *g)
{
    if (g->idx != g->here)
        free(g->idx);
}

/* Footprints.clearances of n points pts (n, 2) into out (n). */
EXPORT void plant_clearances(int64_t n, const double *pts, int64_t nbox, const double *box_c,
                             const double *box_cos, const double *box_sin,
                             const double *box_half, int64_t ncirc, const double *circ_c,
                             const double *circ_r, const double *half, double *out)
{
    Statics s = {nbox, ncirc, box_c, box_cos, box_sin, box_half, circ_c, circ_r, half, 0.0, 0};
    for (int64_t i = 0; i < n; i++)
        out[i] = clearance(&s, pts[2 * i], pts[2 * i + 1]);
}

/* Up to this many robots a call's scratch is on the stack (~32 kB), more are malloc'd. */
#define STACK_ROBOTS 256

/* A robot of the sort below: its world, its new footprint centre's x, its index. */
typedef struct {
    int64_t world;
    double x;
    int64_t i;
} Near;

static int near_before(const Near *a, const Near *b)
{
    if (a->world != b->world)
        return a->world < b->world;
    if (a->x != b->x)
        return a->x < b->x;
    return a->i < b->i;
}

/* Sorts e[0..k) by near_before (a strict total order: the indices differ), a bottom-up merge
 * sort through tmp (k entries): qsort would malloc its own scratch for a crowd. Returns the
 * array holding the result (e or tmp). */
static Near *sort_near(Near *e, Near *tmp, int64_t k)
{
    for (int64_t w = 1; w < k; w *= 2) {
        for (int64_t lo = 0; lo < k; lo += 2 * w) {
            int64_t mid = lo + w < k ? lo + w : k, hi = lo + 2 * w < k ? lo + 2 * w : k;
            int64_t a = lo, b = mid, o = lo;
            while (a < mid && b < hi)
                tmp[o++] = near_before(&e[b], &e[a]) ? e[b++] : e[a++];
            while (a < mid)
                tmp[o++] = e[a++];
            while (b < hi)
                tmp[o++] = e[b++];
        }
        Near *t = e;
        e = tmp;
        tmp = t;
    }
    return e;
}

/* The robot-robot test: robot i (not already blocked, m[10 i + 9]) is blocked if another
 * robot of its world has a new footprint centre closer than two_r to i's new one, and closer
 * than their old centres were. Whether it is blocked is an OR over the others, so the order
 * they are tried in is free; and only robots whose new centres' x differ by less than two_r
 * can be that close (hypot(dx, dy) >= |dx| in IEEE arithmetic, and x_j - x_i grows with
 * x_j). So the robots are sorted by world and new centre x, and each tries its neighbours
 * in that order until the x gap reaches two_r: the answer of testing every pair, in
 * O(n log n + close pairs). A centre whose x is NaN is never that close (its distances are
 * NaN or inf) and is left out. Returns 0, or -1 if out of memory. */
static int robot_pairs(int64_t n, double *m, const int64_t *world, double two_r)
{
    Near here[2 * STACK_ROBOTS];
    Near *held = n <= STACK_ROBOTS ? here : malloc((size_t)n * 2 * sizeof(Near));
    if (!held)
        return -1;
    Near *e = held;
    int64_t k = 0;
    for (int64_t i = 0; i < n; i++) {
        if (isnan(m[10 * i + 7]))
            continue;
        e[k].world = world[i];
        e[k].x = m[10 * i + 7];
        e[k].i = i;
        k++;
    }
    e = sort_near(e, held + n, k);
    for (int64_t p = 0; p < k; p++) {
        double *a = m + 10 * e[p].i;
        if (a[9] != 0.0)
            continue;
        for (int dir = -1; dir <= 1 && a[9] == 0.0; dir += 2) {
            for (int64_t q = p + dir; q >= 0 && q < k && e[q].world == e[p].world; q += dir) {
                if (!((dir > 0 ? e[q].x - e[p].x : e[p].x - e[q].x) < two_r))
                    break;
                double *b = m + 10 * e[q].i;
                double d_old = hypot(a[5] - b[5], a[6] - b[6]);
                double d_new = hypot(a[7] - b[7], a[8] - b[8]);
                if (d_new < two_r && d_new < d_old) {
                    a[9] = 1.0;
                    break;
                }
            }
        }
    }
    if (held != here)
        free(held);
    return 0;
}

/* One tick of n robots. targets (n, 2) wheel-speed targets (rad/s, left, right); radius,
 * separation (n); world (n) each robot's world (robots of one world next to each other);
 * pose (n, 3), wheels (n, 2), speeds (n, 2), vel (n, 2) updated in place; T the tick (s);
 * foot_r the footprint's radius, centre_x its centre along the heading; pairs: 0 when no
 * world has two robots (no robot-robot test: robot_pairs). Returns 0, or -1 if out of memory. */
EXPORT int plant_kinematic_step(int64_t n, double T, const double *targets,
                                const double *radius, const double *separation,
                                const int64_t *world, double *pose, double *wheels,
                                double *speeds, double *vel, int64_t nbox, const double *box_c,
                                const double *box_cos, const double *box_sin,
                                const double *box_half, int64_t ncirc, const double *circ_c,
                                const double *circ_r, const double *half, double foot_r,
                                double centre_x, int64_t pairs)
{
    Statics s = {nbox, ncirc, box_c, box_cos, box_sin, box_half, circ_c, circ_r, half, 0.0, 0};
    cull_setup(&s);
    Grid g;
    grid_build(&g, &s, foot_r, n);
    /* per robot: v, w, nx, ny, nyaw, old centre (x, y), new centre (x, y), blocked */
    double here[STACK_ROBOTS * 10];
    double *m = n <= STACK_ROBOTS ? here : malloc((size_t)n * 10 * sizeof(double));
    if (!m)
        return -1;
    for (int64_t i = 0; i < n; i++) {
        double *q = m + 10 * i;
        double wl = targets[2 * i], wr = targets[2 * i + 1], r = radius[i];
        double v = r * (wr + wl) / 2.0;
        double w = r * (wr - wl) / separation[i];
        double x = pose[3 * i], y = pose[3 * i + 1], yaw = pose[3 * i + 2];
        double h = w * (T / 2.0);
        double chord = v * T * (h != 0.0 ? sin(h) / h : 1.0);    /* the arc's chord */
        double mid = yaw + h;
        double nx = x + chord * cos(mid);
        double ny = y + chord * sin(mid);
        double nyaw = yaw + 2.0 * h;
        q[0] = v;
        q[1] = w;
        q[2] = nx;
        q[3] = ny;
        q[4] = nyaw;
        q[5] = x + centre_x * cos(yaw);          /* footprint_centres */
        q[6] = y + centre_x * sin(yaw);
        q[7] = nx + centre_x * cos(nyaw);
        q[8] = ny + centre_x * sin(nyaw);
        /* blocked by the room: (c_new < foot_r) && (c_new < c_old), c_old only wanted when
         * c_new < foot_r; where c_old >= foot_r, clearance_below's value (also >= foot_r)
         * answers the same */
        double c_new = clearance_below(&s, &g, q[7], q[8], foot_r);
        q[9] = (c_new < foot_r) && (c_new < clearance_below(&s, &g, q[5], q[6], foot_r));
    }
    grid_free(&g);
    if (pairs && n > 1 && robot_pairs(n, m, world, 2 * foot_r) != 0) {
        if (m != here)
            free(m);
        return -1;
    }
    for (int64_t i = 0; i < n; i++) {
        double *q = m + 10 * i;
        int blocked = q[9] != 0.0;
        if (!blocked) {
            pose[3 * i] = q[2];
            pose[3 * i + 1] = q[3];
            pose[3 * i + 2] = q[4];
        }
        vel[2 * i] = blocked ? 0.0 : q[0];
        vel[2 * i + 1] = blocked ? 0.0 : q[1];
        for (int k = 0; k < 2; k++) {
            wheels[2 * i + k] = wheels[2 * i + k] + targets[2 * i + k] * T;
            speeds[2 * i + k] = targets[2 * i + k];
        }
    }
    if (m != here)
        free(m);
    return 0;
}
