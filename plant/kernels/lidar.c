/* The lidar's sweep in C: every ray of G fans against the primitives of a scene, in one
 * call (plant/kernels/__init__.py loads it, plant/lidar.py calls it).
 *
 * The arithmetic of each (ray, shape) element is plant/raycast.py's cast_sectors written
 * out in double, operation for operation and in the same order, so a range is the same
 * bits as the numpy reference's (built with -ffp-contract=off: no fused multiply-adds).
 * The max / min of a NaN follow numpy's np.maximum / np.minimum (the NaN wins) and
 * np.fmin / np.fmax (the number wins).
 *
 * Shapes (S of them, arrays row-major): centre c (S x 3), rotation R shape -> world
 * (S x 9, R[j][k] at 3j + k), half extents h (S x 3), quadric q (S x 3: 0 for a box,
 * (1, 1, 0) a cylinder, (1, 1, 1) a sphere), rr (S: radius^2, 1 for a box), bounding
 * radius (S), owner id (S). A fan g: origin (3), rotation of the sensor (9, its z axis is
 * the scan plane's normal), n ray directions (n x 3), the owner id it skips (-1: none),
 * the range of shapes [first, last) it sees (several worlds may share one call).
 */
#define _GNU_SOURCE                  /* pthread_setname_np, pthread_sigmask under -std=c99 */
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdint.h>

#include "npmath.h"

#define EXPORT __attribute__((visibility("default")))
#define PI 3.14159265358979323846

/* The rays lo..hi of one fan against one shape (cast_sectors' elements): ray i from the
 * origin at ol (in the shape's frame) along (dx[i], dy[i], dz[i]) (world frame), the
 * nearest entering hit kept in row[i]. Branch-free, for the compiler to vectorise (each
 * lane does the scalar operations, so the bits are the same); ``round_`` is a constant
 * at each call below, so each kind of shape gets a loop of its own. */
static inline __attribute__((always_inline)) void rays_vs(
    const double *ol, const double *dx, const double *dy, const double *dz, int64_t lo,
    int64_t hi, const double *R, const double *h, const double *q, double rr,
    const int round_, double max_range, double *restrict row)
{
    const double ax = -h[0] - ol[0], bx = h[0] - ol[0];
    const double ay = -h[1] - ol[1], by = h[1] - ol[1];
    const double az = -h[2] - ol[2], bz = h[2] - ol[2];
    const double q0 = q[0], q1 = q[1], q2 = q[2];
    const double o0 = ol[0], o1 = ol[1], o2 = ol[2];
    const double R0 = R[0], R1 = R[1], R2 = R[2], R3 = R[3], R4 = R[4], R5 = R[5],
                 R6 = R[6], R7 = R[7], R8 = R[8];
    const double c = q0 * o0 * o0 + q1 * o1 * o1 + q2 * o2 * o2 - rr;
    const double flat0 = c < 0.0 ? -INFINITY : NAN, flat1 = c < 0.0 ? INFINITY : NAN;
    for (int64_t i = lo; i <= hi; i++) {
        const double d0 = dx[i], d1 = dy[i], d2 = dz[i];
        const double l0 = d0 * R0 + d1 * R3 + d2 * R6;
        const double l1 = d0 * R1 + d1 * R4 + d2 * R7;
        const double l2 = d0 * R2 + d1 * R5 + d2 * R8;
        double inv = 1.0 / l0, t1 = ax * inv, t2 = bx * inv;
        double tn = np_fmin(t1, t2), tf = np_fmax(t1, t2);
        inv = 1.0 / l1; t1 = ay * inv; t2 = by * inv;
        tn = np_max(tn, np_fmin(t1, t2));
        tf = np_min(tf, np_fmax(t1, t2));
        inv = 1.0 / l2; t1 = az * inv; t2 = bz * inv;
        tn = np_max(tn, np_fmin(t1, t2));
        tf = np_min(tf, np_fmax(t1, t2));
        if (round_) {
            const double a = q0 * l0 * l0 + q1 * l1 * l1 + q2 * l2 * l2;
            const double b = q0 * l0 * o0 + q1 * l1 * o1 + q2 * l2 * o2;
            /* raycast.quadratic_roots; a == 0: along a cylinder's axis */
            const double sq = sqrt(b * b - a * c);
            const double qq = -(b + copysign(sq, b));
            const double x1 = qq / a, x2 = c / qq;
            const double m0 = np_min(x1, x2), m1 = np_max(x1, x2);
            const double r0 = (a == 0.0) ? flat0 : m0;
            const double r1 = (a == 0.0) ? flat1 : m1;
            tn = np_max(tn, r0);
            tf = np_min(tf, r1);
        }
        /* hit: tn <= tf, 0 <= tn <= max_range, nearer than what the ray has */
        const double old = row[i];
        double v = (tn <= tf) ? tn : old;
        v = (tn >= 0.0) ? v : old;
        v = (tn <= max_range) ? v : old;
        row[i] = (tn < old) ? v : old;
    }
}

static void rays_vs_box(const double *ol, const double *dx, const double *dy,
                        const double *dz, int64_t lo, int64_t hi, const double *R,
                        const double *h, const double *q, double rr, double max_range,
                        double *restrict row)
{
    rays_vs(ol, dx, dy, dz, lo, hi, R, h, q, rr, 0, max_range, row);
}

static void rays_vs_round(const double *ol, const double *dx, const double *dy,
                          const double *dz, int64_t lo, int64_t hi, const double *R,
                          const double *h, const double *q, double rr, double max_range,
                          double *restrict row)
{
    rays_vs(ol, dx, dy, dz, lo, hi, R, h, q, rr, 1, max_range, row);
}

EXPORT int plant_lidar_abi(void) { return 4; }

/* atan2 to within 2e-5 rad (a minimax polynomial for atan on [0, 1]; the culls below
 * widen every angle they take from it by SLACK, so they stay conservative) */
#define SLACK 1e-3
static inline double atan2_approx(double y, double x)
{
    double ax = fabs(x), ay = fabs(y);
    double mx_ = ax > ay ? ax : ay, mn_ = ax > ay ? ay : ax;
    if (mx_ == 0.0)
        return 0.0;
    double z = mn_ / mx_, z2 = z * z;
    double a = z * (0.9998660 + z2 * (-0.3302995 + z2 * (0.1801410 + z2 * (-0.0851330
                                                                      + z2 * 0.0208351))));
    if (ay > ax) a = 0.5 * PI - a;
    if (x < 0.0) a = PI - a;
    return y < 0.0 ? -a : a;
}

/* The rays [*lo, *hi] of a fan that may meet shape s (0 if none may): its bounding box
 * must cross the scan plane, lie within range, and cover their bearings. Conservative:
 * every angle it takes is widened by more than its own error (SLACK), so a ray it leaves
 * out misses the shape's bounding sphere (or the box's corners' span) by at least SLACK
 * and testing the rays it keeps finds what testing every ray would. o: the sensor's origin
 * minus the shape's centre (world frame); P: the sensor's pose (its axes: columns of the
 * rotation); R: the shape's rotation. What it needs of the shape in the sensor's frame
 * (the centre rel, the shape's axes A[3k + i]: component i of axis k) is computed as it
 * goes: most shapes are left out, or found narrow, from the normal's row alone. */
static int sector(const double *o, const double *P, const double *R, const double *h,
                  double radius, int64_t n, double a0, double inc, double max_range,
                  int64_t *lo, int64_t *hi)
{
    double rel[3], A[9];
    rel[2] = -(o[0] * P[2] + o[1] * P[6] + o[2] * P[10]);
    for (int k = 0; k < 3; k++)
        A[3 * k + 2] = R[k] * P[2] + R[3 + k] * P[6] + R[6 + k] * P[10];
    double extent = fabs(A[2]) * h[0] + fabs(A[5]) * h[1] + fabs(A[8]) * h[2];
    double hz = fabs(rel[2]);
    if (hz > extent * (1.0 + 1e-9) + 1e-9)
        return 0;                                 /* wholly above or below the plane */
    for (int i = 0; i < 2; i++)
        rel[i] = -(o[0] * P[i] + o[1] * P[4 + i] + o[2] * P[8 + i]);
    double r = radius * (1.0 + 1e-9) + 1e-9;
    double rp = hz < r ? sqrt(r * r - hz * hz) : 0.0;
    /* rho to a few ulps (sqrt of the sum, not hypot: the margins are far wider) */
    double rho = sqrt(rel[0] * rel[0] + rel[1] * rel[1]);
    if (rho - rp > max_range * (1.0 + 1e-9) + 1e-9)
        return 0;                                 /* out of range */
    *lo = 0;
    *hi = n - 1;
    if (n < 2 || rho <= 1e-9)
        return 1;
    double bearing = atan2_approx(rel[1], rel[0]), dmin, dmax;
    /* the sphere's half angle asin(rp / rho) (pi: the sensor inside it), bounded above by
     * its tangent first (cheaper, within a part in 1e3 of it for the narrow sectors it is
     * kept for) */
    double half = rho > rp ? rp / sqrt((rho - rp) * (rho + rp)) : PI;
    if (half * 2.0 > 8.0 * inc) {
        half = rho > rp ? asin(rp / rho) : PI;
        /* a wide sector: the bearings of the bounding box's corners projected on the
         * plane, relative to the centre's; if they span less than pi the sensor is
         * outside the box's shadow and they bound it */
        for (int i = 0; i < 2; i++)
            for (int k = 0; k < 3; k++)
                A[3 * k + i] = R[k] * P[i] + R[3 + k] * P[4 + i] + R[6 + k] * P[8 + i];
        dmin = 0.0;
        dmax = 0.0;
        for (int c = 0; c < 8; c++) {
            double x = rel[0], y = rel[1];
            for (int k = 0; k < 3; k++) {
                double e = (c >> k & 1) ? h[k] : -h[k];
                x += e * A[3 * k];
                y += e * A[3 * k + 1];
            }
            double d = atan2_approx(y, x) - bearing;
            if (d > PI) d -= 2.0 * PI;
            if (d < -PI) d += 2.0 * PI;
            if (d < dmin) dmin = d;
            if (d > dmax) dmax = d;
        }
        if (dmax - dmin >= PI - 4.0 * SLACK) {
            if (half >= PI)
                return 1;                         /* around the sensor: every ray */
            dmin = -half;
            dmax = half;
        } else if (half < PI) {
            dmin = dmin > -half ? dmin : -half;
            dmax = dmax < half ? dmax : half;
        }
    } else {
        dmin = -half;
        dmax = half;
    }
    dmin -= 2.0 * SLACK;                          /* the bearing's error and the corners' */
    dmax += 2.0 * SLACK;
    if (fabs(bearing) + (dmax > -dmin ? dmax : -dmin) >= PI - 1e-6)
        return 1;                                 /* across the +-pi seam: every ray */
    /* the rays whose angles a0 + i inc lie in the widened sector (none: the sector falls
     * between two rays or outside the field of view, or a number is NaN: no ray hits) */
    double f = ceil((bearing + dmin - a0) / inc);
    double l = floor((bearing + dmax - a0) / inc);
    if (!(l >= f) || l < 0.0 || f > (double)(n - 1))
        return 0;
    *lo = f < 0.0 ? 0 : (int64_t)f;
    *hi = l > (double)(n - 1) ? n - 1 : (int64_t)l;
    return 1;
}

/* The scene and the fans of one call (plant_lidar_scan's arguments). */
typedef struct {
    const double *centers, *rot, *halves, *quad, *rr, *radii;
    const int64_t *owner;
    int64_t n_shapes, n;
    const double *poses, *dirs;
    const int64_t *skip_owner, *first_shape, *last_shape;
    double a0, inc, min_range, max_range;
    double *out;
} Fans;

/* Fans g0 .. g1 - 1 of ``a`` (each fan's row of ``out`` is its own: fans split over
 * threads give the bits they give in one). work: room for 3 n doubles. */
static void scan_fans(const Fans *a, int64_t g0, int64_t g1, double *work)
{
    const int64_t n = a->n;
    double *dx = work, *dy = work + n, *dz = work + 2 * n;
    for (int64_t g = g0; g < g1; g++) {
        double *row = a->out + g * n;
        for (int64_t i = 0; i < n; i++)
            row[i] = INFINITY;
        const double *P = a->poses + 16 * g;
        const double org[3] = {P[3], P[7], P[11]};
        const double *fd = a->dirs + 3 * n * g;
        for (int64_t i = 0; i < n; i++) {          /* the rays as columns (SoA) */
            dx[i] = fd[3 * i];
            dy[i] = fd[3 * i + 1];
            dz[i] = fd[3 * i + 2];
        }
        int64_t s0 = a->first_shape ? a->first_shape[g] : 0;
        int64_t s1 = a->last_shape ? a->last_shape[g] : a->n_shapes;
        for (int64_t s = s0; s < s1; s++) {
            if (a->owner[s] == a->skip_owner[g])
                continue;
            const double *c = a->centers + 3 * s, *R = a->rot + 9 * s, *h = a->halves + 3 * s;
            double o[3] = {org[0] - c[0], org[1] - c[1], org[2] - c[2]};
            /* Beyond reach, before the cull below: every point of the shape lies in its
             * bounding sphere (radius |h|, the box its rays are clipped to), so a centre
             * further than max_range + radius (with a margin far above rounding) has no
             * hit within range on any ray, and sector() would say so too. In a large world
             * most shapes are out of a sensor's reach; this test costs a few flops. */
            const double reach = (a->max_range + a->radii[s]) * (1.0 + 1e-6) + 1e-6;
            if (o[0] * o[0] + o[1] * o[1] + o[2] * o[2] > reach * reach)
                continue;
            int64_t lo, hi;
            if (!sector(o, P, R, h, a->radii[s], n, a->a0, a->inc, a->max_range, &lo, &hi))
                continue;
            /* the origin in the shape's frame, as cast_sectors computes it per pair */
            double ol[3];
            for (int k = 0; k < 3; k++)
                ol[k] = o[0] * R[k] + o[1] * R[3 + k] + o[2] * R[6 + k];
            const double *q = a->quad + 3 * s;
            if (q[0] > 0.0)
                rays_vs_round(ol, dx, dy, dz, lo, hi, R, h, q, a->rr[s], a->max_range, row);
            else
                rays_vs_box(ol, dx, dy, dz, lo, hi, R, h, q, a->rr[s], a->max_range, row);
        }
        for (int64_t i = 0; i < n; i++)
            if (row[i] < a->min_range)
                row[i] = INFINITY;
    }
}

typedef struct {
    const Fans *fans;
    int64_t g0, g1;
    double *work;
} Part;

#define MAX_THREADS 64
#define MIN_FANS_PER_THREAD 8        /* a waking worker costs about what a few scans do */

/* The workers, kept between calls: starting a thread per part on every call cost more
 * CPU than the part it cast. Worker w (0-based) casts part w + 1 of each call whose
 * generation it has not seen yet and that has that part; it parks on ``go`` between
 * calls. One call at a time owns the pool (``owner``, taken with trylock: a call that
 * finds it busy, from another thread, casts all its fans on its own thread: the same
 * bits). The workers are never joined; they block every signal (the interpreter's
 * handlers run on its own threads) and die with the process. A forked child has none of
 * them: the atfork handler empties the pool there, and the first call re-creates it. */
typedef struct {
    pthread_mutex_t owner;           /* held by the call using the pool */
    pthread_mutex_t lock;            /* guards the fields below */
    pthread_cond_t go, done;
    int64_t n_workers;               /* started so far */
    uint64_t generation;             /* one per call that hands out parts */
    int64_t n_parts;                 /* parts of the current call (its own is part 0) */
    int64_t pending;                 /* worker parts of the current call not yet cast */
    uint64_t born[MAX_THREADS];      /* the generation before worker w's first call */
    Part parts[MAX_THREADS];
} Pool;

static Pool pool = {.owner = PTHREAD_MUTEX_INITIALIZER, .lock = PTHREAD_MUTEX_INITIALIZER,
                    .go = PTHREAD_COND_INITIALIZER, .done = PTHREAD_COND_INITIALIZER};
static pthread_once_t pool_once = PTHREAD_ONCE_INIT;

static void pool_after_fork(void)
{
    /* only the forking thread lives on in the child: no workers, nothing held */
    pthread_mutex_init(&pool.owner, NULL);
    pthread_mutex_init(&pool.lock, NULL);
    pthread_cond_init(&pool.go, NULL);
    pthread_cond_init(&pool.done, NULL);
    pool.n_workers = 0;
    pool.n_parts = 0;
    pool.pending = 0;
}

static void pool_register(void) { pthread_atfork(NULL, NULL, pool_after_fork); }

static void *pool_worker(void *arg)
{
    const int64_t w = (int64_t)(intptr_t)arg, part = w + 1;
    pthread_setname_np(pthread_self(), "lidar-cast");   /* for top -H, py-spy, the tests */
    pthread_mutex_lock(&pool.lock);
    uint64_t seen = pool.born[w];           /* the call that started it is its first */
    for (;;) {
        while (pool.generation == seen)
            pthread_cond_wait(&pool.go, &pool.lock);
        seen = pool.generation;
        if (part >= pool.n_parts)
            continue;                       /* this call has fewer parts */
        const Part p = pool.parts[part];
        pthread_mutex_unlock(&pool.lock);
        scan_fans(p.fans, p.g0, p.g1, p.work);
        pthread_mutex_lock(&pool.lock);
        if (--pool.pending == 0)
            pthread_cond_signal(&pool.done);
    }
    return NULL;
}

/* Start workers until there are ``want`` (pool.lock held); returns how many there are. */
static int64_t pool_grow(int64_t want)
{
    if (pool.n_workers >= want)
        return pool.n_workers;
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old);    /* the workers inherit: no signals */
    pthread_attr_t attr;
    pthread_attr_init(&attr);
    pthread_attr_setdetachstate(&attr, PTHREAD_CREATE_DETACHED);
    while (pool.n_workers < want) {
        pthread_t t;
        pool.born[pool.n_workers] = pool.generation;
        if (pthread_create(&t, &attr, pool_worker, (void *)(intptr_t)pool.n_workers) != 0)
            break;
        pool.n_workers++;
    }
    pthread_attr_destroy(&attr);
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    return pool.n_workers;
}

/* Cast ``parts[0 .. t_n)``: parts 1.. on the pool's workers, part 0 (and any part no
 * worker could take) here. Returns 0 when the pool is busy (nothing cast). */
static int pool_cast(Part *parts, int64_t t_n)
{
    pthread_once(&pool_once, pool_register);
    if (pthread_mutex_trylock(&pool.owner) != 0)
        return 0;
    pthread_mutex_lock(&pool.lock);
    int64_t handed = pool_grow(t_n - 1);
    if (handed > t_n - 1)
        handed = t_n - 1;
    for (int64_t t = 0; t <= handed; t++)
        pool.parts[t] = parts[t];
    pool.n_parts = handed + 1;
    pool.pending = handed;
    pool.generation++;
    if (handed > 0)
        pthread_cond_broadcast(&pool.go);
    pthread_mutex_unlock(&pool.lock);
    scan_fans(parts[0].fans, parts[0].g0, parts[0].g1, parts[0].work);
    for (int64_t t = handed + 1; t < t_n; t++)   /* workers that could not be started */
        scan_fans(parts[t].fans, parts[t].g0, parts[t].g1, parts[t].work);
    pthread_mutex_lock(&pool.lock);
    while (pool.pending > 0)
        pthread_cond_wait(&pool.done, &pool.lock);
    pool.n_parts = 0;
    pthread_mutex_unlock(&pool.lock);
    pthread_mutex_unlock(&pool.owner);
    return 1;
}

/* Nearest entering hit of every ray of every fan: out (G x n), +inf where none, and a
 * hit nearer than min_range reported as +inf (it still occludes what lies behind).
 * poses: the sensors' world poses (G x 16, row-major 4x4); ray i of a fan points at
 * a0 + i inc in its sensor's plane (used only to skip the rays outside a shape's bearing
 * sector). first_shape / last_shape: the shapes [first, last) fan g sees (NULL: all).
 * n_threads: at most that many threads (this one and the pool's workers), each with a
 * contiguous part of at least MIN_FANS_PER_THREAD fans (a worker that cannot be started
 * leaves its part to this one; a pool busy with another thread's call leaves it all);
 * work: room for 3 n doubles per thread. The result does not depend on n_threads. */
EXPORT void plant_lidar_scan(
    const double *centers, const double *rot, const double *halves, const double *quad,
    const double *rr, const double *radii, const int64_t *owner, int64_t n_shapes,
    int64_t n_fans, int64_t n, const double *poses, const double *dirs,
    const int64_t *skip_owner, const int64_t *first_shape, const int64_t *last_shape,
    double a0, double inc, double min_range, double max_range, double *out, double *work,
    int64_t n_threads)
{
    const Fans fans = {centers, rot, halves, quad, rr, radii, owner, n_shapes, n, poses, dirs,
                       skip_owner, first_shape, last_shape, a0, inc, min_range, max_range, out};
    int64_t t_n = n_threads < 1 ? 1 : (n_threads > MAX_THREADS ? MAX_THREADS : n_threads);
    if (t_n > n_fans / MIN_FANS_PER_THREAD)
        t_n = n_fans / MIN_FANS_PER_THREAD < 1 ? 1 : n_fans / MIN_FANS_PER_THREAD;
    if (t_n == 1) {
        scan_fans(&fans, 0, n_fans, work);
        return;
    }
    Part parts[MAX_THREADS];
    for (int64_t t = 0; t < t_n; t++)
        parts[t] = (Part){&fans, n_fans * t / t_n, n_fans * (t + 1) / t_n, work + 3 * n * t};
    if (!pool_cast(parts, t_n))
        scan_fans(&fans, 0, n_fans, work);      /* another thread's call has the pool */
}
