/* The camera's per-pixel work in C (plant/camera.py calls it): every pixel's ray against
 * the shapes whose projected bounding box covers it, a z-buffer on the optical depth,
 * Lambert shading through the colour table, then, if given, the frame's image noise
 * (plant/kernels/noise.c's plant_image_noise, in place: one call for the noisy picture).
 *
 * Conventions are plant/camera.py's: the ray of pixel (u, v) is (xn, yn, 1) in the optical
 * frame (z forward, x right, y down), xn = (u - cx) / f, yn = (v - cy) / f without
 * distortion, or given per pixel (NaN: no preimage); a hit counts if the ray enters the
 * solid at a depth in [near, far) (back faces ignored); ties keep the lower shape index.
 * The arithmetic is double (the numpy renderer's is float32: a silhouette pixel or a grey
 * level may differ, see docs/benchmarks.md).
 */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "wide.h"

#define EXPORT __attribute__((visibility("default")))
#define LEVELS 256

EXPORT int plant_camera_abi(void) { return 3; }

/* plant/kernels/noise.c */
void plant_image_noise(const uint8_t *img, int64_t n, uint64_t seed, int64_t k,
                       const uint32_t *thr, const uint16_t *vals, uint8_t *out);

/* fmin / fmax for numbers (no NaN reaches them here but 0 * inf's, which they drop) */
static inline double mn(double a, double b) { return (a <= b || b != b) ? a : b; }
static inline double mx(double a, double b) { return (a >= b || b != b) ? a : b; }

static inline void take(double x, double y, double z, double near, double *r)
{
    double zz = z > near ? z : near, xx = x / zz, yy = y / zz;
    if (xx < r[0]) r[0] = xx;
    if (xx > r[1]) r[1] = xx;
    if (yy < r[2]) r[2] = yy;
    if (yy > r[3]) r[3] = yy;
}

/* Normalised-image rectangle r = (x0, x1, y0, y1) covering a box of half extents h whose
 * corners are, in the optical frame, p + sum_k +-h_k a_k (a_k: column k of A), clipped
 * to z >= near (camera._projected_rects); 0 if it lies wholly in front of near or
 * beyond far. */
static int rect_of(const double *p, const double *A, const double *h, double near,
                   double far, double *r)
{
    double c[8][3], zmin = INFINITY;
    for (int i = 0; i < 8; i++) {
        for (int j = 0; j < 3; j++) {
            double v = p[j];
            for (int k = 0; k < 3; k++)
                v += ((i >> k) & 1 ? h[k] : -h[k]) * A[3 * j + k];
            c[i][j] = v;
        }
        if (c[i][2] < zmin)
            zmin = c[i][2];
    }
    r[0] = INFINITY; r[1] = -INFINITY; r[2] = INFINITY; r[3] = -INFINITY;
    int any = 0;
    for (int i = 0; i < 8; i++) {
        if (c[i][2] >= near) {
            take(c[i][0], c[i][1], c[i][2], near, r);
            any = 1;
        }
        for (int b = 0; b < 3; b++) {            /* its edges crossing the near plane */
            int j = i ^ (1 << b);
            double za = c[i][2], zb = c[j][2];
            if (j > i && (za - near) * (zb - near) < 0.0) {
                double s = (near - za) / (zb - za);
                take(c[i][0] + s * (c[j][0] - c[i][0]), c[i][1] + s * (c[j][1] - c[i][1]),
                     near, near, r);
                any = 1;
            }
        }
    }
    return any && zmin <= far;
}

/* One pixel's ray d (shape frame) from o against a shape: 1 and (t, lambert) if it
 * enters at near <= t < cur. kind 0 box, 1 cylinder, 2 sphere. L: the light, shape frame. */
static inline int hit(int kind, const double *o, const double *d, const double *h,
                      const double *L, double near, double cur, double *t_out, double *lam)
{
    if (kind == 0) {
        double tn = -INFINITY, tf = INFINITY;
        int face = 0;
        for (int k = 0; k < 3; k++) {
            double inv = 1.0 / d[k];
            double t1 = (-h[k] - o[k]) * inv, t2 = (h[k] - o[k]) * inv;
            double lo = mn(t1, t2), hi = mx(t1, t2);
            if (lo > tn) { tn = lo; face = k; }
            if (hi < tf) tf = hi;
        }
        if (!(tn <= tf && tn >= near && tn < cur))
            return 0;
        *t_out = tn;
        *lam = d[face] > 0.0 ? -L[face] : L[face];
        return 1;
    }
    if (kind == 2) {
        double r = h[0];
        double a = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        double b = o[0] * d[0] + o[1] * d[1] + o[2] * d[2];
        double c = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - r * r;
        double disc = b * b - a * c;
        if (!(disc >= 0.0))
            return 0;
        double q = -(b + copysign(sqrt(disc), b));
        double r1 = q / a, r2 = c / q;
        double t = r1 < r2 ? r1 : r2;
        if (!(t >= near && t < cur))
            return 0;
        *t_out = t;
        *lam = ((o[0] + t * d[0]) * L[0] + (o[1] + t * d[1]) * L[1] + (o[2] + t * d[2]) * L[2]) / r;
        return 1;
    }
    double r = h[0], hh = h[2];
    double a = d[0] * d[0] + d[1] * d[1];
    double b = d[0] * o[0] + d[1] * o[1];
    double c = o[0] * o[0] + o[1] * o[1] - r * r;
    double s0, s1;
    if (a == 0.0) {                              /* along the axis */
        if (!(c < 0.0))
            return 0;
        s0 = -INFINITY;
        s1 = INFINITY;
    } else {
        double disc = b * b - a * c;
        if (!(disc >= 0.0))
            return 0;
        double q = -(b + copysign(sqrt(disc), b));
        double x1 = q / a, x2 = c / q;
        s0 = x1 < x2 ? x1 : x2;
        s1 = x1 < x2 ? x2 : x1;
    }
    double inv = 1.0 / d[2];
    double z1 = (-hh - o[2]) * inv, z2 = (hh - o[2]) * inv;
    double zlo = mn(z1, z2), zhi = mx(z1, z2);
    int side = s0 >= zlo;
    double tn = side ? s0 : zlo;
    double tf = s1 < zhi ? s1 : zhi;
    if (!(tn <= tf && tn >= near && tn < cur))
        return 0;
    *t_out = tn;
    *lam = side ? ((o[0] + d[0] * tn) * L[0] + (o[1] + d[1] * tn) * L[1]) / r
                : (d[2] > 0.0 ? -L[2] : L[2]);
    return 1;
}

/* Two lanes of doubles (GCC's and clang's vector extension: SSE2 on x86-64, NEON on
 * arm64), and a select on a lane mask (a comparison's all-ones or zero per lane). Each lane's
 * arithmetic is IEEE double, as the scalar code's: the same values. */
typedef double v2d __attribute__((vector_size(16)));
typedef long long v2l __attribute__((vector_size(16)));

static inline v2d sel(v2l m, v2d a, v2d b) { return (v2d)((m & (v2l)a) | (~m & (v2l)b)); }
static inline v2d splat(double x) { return (v2d){x, x}; }

/* One box-slab axis of two pixels' rays: (lo, hi) of the entry and exit along it, as mn / mx
 * (a NaN second argument gives the first) */
static inline void slab2(v2d d, double a, double b, v2d *lo, v2d *hi)
{
    v2d inv = splat(1.0) / d, t1 = splat(a) * inv, t2 = splat(b) * inv;
    v2l nan2 = t2 != t2;
    *lo = sel((t1 <= t2) | nan2, t1, t2);
    *hi = sel((t1 >= t2) | nan2, t1, t2);
}

/* Four lanes where the processor has AVX2 (x86-64, GCC or clang: the function is compiled
 * for it alone and called only after a check at run time). Per lane the same IEEE double
 * operations as the two-lane and the scalar code (no fused multiply-add: the build's
 * -ffp-contract=off), so the same values; a 256-bit division costs about what a 128-bit
 * one does, which is what the box test spends its time on. */
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define WIDE_ROWS 1
typedef double v4d __attribute__((vector_size(32)));
typedef long long v4l __attribute__((vector_size(32)));

#define SEL4(m, a, b) ((v4d)(((m) & (v4l)(a)) | (~(m) & (v4l)(b))))
#define SPLAT4(x) ((v4d){(x), (x), (x), (x)})

/* -1: four lanes where the processor has AVX2; 0: two, always (the tests compare the two) */
static int wide_mode = -1;

/* box_block's pixels u0 .. of row (y0, y1, y2: M's yn terms) four at a time, while four
 * remain up to u1; the first pixel it left */
__attribute__((target("avx2"))) static int64_t box_row4(
    const double *M, double y0, double y1, double y2, const double *ab, const double *L,
    int64_t s, double near, const double *xs, int64_t u0, int64_t u1, float *dep,
    int64_t *sd, double *lm)
{
    const v4d inf = SPLAT4(INFINITY), ninf = SPLAT4(-INFINITY), zero = SPLAT4(0.0);
    int64_t u = u0;
    for (; u + 3 <= u1; u += 4) {
        const v4d xn = {xs[u], xs[u + 1], xs[u + 2], xs[u + 3]};
        const v4d d[3] = {SPLAT4(M[0]) * xn + SPLAT4(y0) + SPLAT4(M[2]),
                          SPLAT4(M[3]) * xn + SPLAT4(y1) + SPLAT4(M[5]),
                          SPLAT4(M[6]) * xn + SPLAT4(y2) + SPLAT4(M[8])};
        v4d tn = ninf, tf = inf, lamv = zero;
        for (int k = 0; k < 3; k++) {          /* slab2 of each axis, as box_block */
            const v4d inv = SPLAT4(1.0) / d[k], t1 = SPLAT4(ab[2 * k]) * inv,
                      t2 = SPLAT4(ab[2 * k + 1]) * inv;
            const v4l nan2 = t2 != t2;
            const v4d lo = SEL4((t1 <= t2) | nan2, t1, t2), hi = SEL4((t1 >= t2) | nan2, t1, t2);
            const v4d face = SEL4(d[k] > zero, SPLAT4(-L[k]), SPLAT4(L[k]));
            if (k == 0) {
                tf = SEL4(hi < inf, hi, inf);
                tn = SEL4(lo > ninf, lo, ninf);
                lamv = face;
            } else {
                const v4l take = lo > tn;
                tn = SEL4(take, lo, tn);
                lamv = SEL4(take, face, lamv);
                tf = SEL4(hi < tf, hi, tf);
            }
        }
        const v4d cur = {(double)dep[u], (double)dep[u + 1], (double)dep[u + 2],
                         (double)dep[u + 3]};
        const v4l ok = (tn <= tf) & (tn >= SPLAT4(near)) & (tn < cur);
        for (int k = 0; k < 4; k++) {
            if (ok[k]) {
                dep[u + k] = (float)tn[k];
                sd[u + k] = s;
                lm[u + k] = lamv[k];
            }
        }
    }
    return u;
}
#endif

/* Set the four-lane mode (-1 or 0; other values leave it) and say whether renders use
 * four lanes. */
EXPORT int plant_camera_wide(int mode)
{
#ifdef WIDE_ROWS
    return wide_switch(&wide_mode, mode);
#else
    (void)mode;
    return 0;
#endif
}

/* A box over a block of pixels without distortion: hit()'s box case, the same numbers,
 * written without branches (and with its per-shape terms hoisted), two pixels at a time
 * (four with box_row4 where ``wide``). */
static void box_block(const double *M, const double *o, const double *h, const double *L,
                      int64_t s, double near, const double *xs, const double *ys, int64_t u0,
                      int64_t u1, int64_t v0, int64_t v1, int64_t W, float *depth,
                      int64_t *sid, double *lam, int wide)
{
    const double a0 = -h[0] - o[0], b0 = h[0] - o[0];
    const double a1 = -h[1] - o[1], b1 = h[1] - o[1];
    const double a2 = -h[2] - o[2], b2 = h[2] - o[2];
#ifdef WIDE_ROWS
    const double ab[6] = {a0, b0, a1, b1, a2, b2};
#else
    (void)wide;
#endif
    const v2d inf = splat(INFINITY), ninf = splat(-INFINITY), zero = splat(0.0);
    for (int64_t v = v0; v <= v1; v++) {
        const double yn = ys[v];
        const double y0 = M[1] * yn, y1 = M[4] * yn, y2 = M[7] * yn;
        float *dep = depth + v * W;
        int64_t *sd = sid + v * W;
        double *lm = lam + v * W;
        int64_t u = u0;
#ifdef WIDE_ROWS
        if (wide)
            u = box_row4(M, y0, y1, y2, ab, L, s, near, xs, u0, u1, dep, sd, lm);
#endif
        for (; u + 1 <= u1; u += 2) {
            const v2d xn = {xs[u], xs[u + 1]};
            const v2d d0 = splat(M[0]) * xn + splat(y0) + splat(M[2]);
            const v2d d1 = splat(M[3]) * xn + splat(y1) + splat(M[5]);
            const v2d d2 = splat(M[6]) * xn + splat(y2) + splat(M[8]);
            v2d lo, hi, tf, tn, lamv;
            slab2(d0, a0, b0, &lo, &hi);
            tf = sel(hi < inf, hi, inf);
            tn = sel(lo > ninf, lo, ninf);
            lamv = sel(d0 > zero, splat(-L[0]), splat(L[0]));
            slab2(d1, a1, b1, &lo, &hi);
            v2l take = lo > tn;
            tn = sel(take, lo, tn);
            lamv = sel(take, sel(d1 > zero, splat(-L[1]), splat(L[1])), lamv);
            tf = sel(hi < tf, hi, tf);
            slab2(d2, a2, b2, &lo, &hi);
            take = lo > tn;
            tn = sel(take, lo, tn);
            lamv = sel(take, sel(d2 > zero, splat(-L[2]), splat(L[2])), lamv);
            tf = sel(hi < tf, hi, tf);
            const v2d cur = {(double)dep[u], (double)dep[u + 1]};
            const v2l ok = (tn <= tf) & (tn >= splat(near)) & (tn < cur);
            for (int k = 0; k < 2; k++) {
                if (ok[k]) {
                    dep[u + k] = (float)tn[k];
                    sd[u + k] = s;
                    lm[u + k] = lamv[k];
                }
            }
        }
        for (; u <= u1; u++) {                   /* (an odd last pixel) */
            const double xn = xs[u];
            const double d0 = M[0] * xn + y0 + M[2];
            const double d1 = M[3] * xn + y1 + M[5];
            const double d2 = M[6] * xn + y2 + M[8];
            double inv = 1.0 / d0, t1 = a0 * inv, t2 = b0 * inv;
            double lo = mn(t1, t2), tf = mx(t1, t2);
            tf = tf < INFINITY ? tf : INFINITY;
            double tn = lo > -INFINITY ? lo : -INFINITY;
            double lamv = d0 > 0.0 ? -L[0] : L[0];
            inv = 1.0 / d1; t1 = a1 * inv; t2 = b1 * inv;
            lo = mn(t1, t2);
            double hi = mx(t1, t2);
            int take = lo > tn;
            tn = take ? lo : tn;
            lamv = take ? (d1 > 0.0 ? -L[1] : L[1]) : lamv;
            tf = hi < tf ? hi : tf;
            inv = 1.0 / d2; t1 = a2 * inv; t2 = b2 * inv;
            lo = mn(t1, t2);
            hi = mx(t1, t2);
            take = lo > tn;
            tn = take ? lo : tn;
            lamv = take ? (d2 > 0.0 ? -L[2] : L[2]) : lamv;
            tf = hi < tf ? hi : tf;
            const int ok = (tn <= tf) & (tn >= near) & (tn < (double)dep[u]);
            dep[u] = ok ? (float)tn : dep[u];
            sd[u] = ok ? s : sd[u];
            lm[u] = ok ? lamv : lm[u];
        }
    }
}

/* Render: rgb (H x W x 3), depth (H x W, optical depth, +inf where nothing is hit), sid
 * (H x W, shape index or -1); lam: work room for H x W + W + H doubles. todo: the n_todo shapes
 * to draw, in order. cam: the optical frame's rotation (9, row-major, optical -> world)
 * then its origin (3). light: unit vector towards the light (world). xy: NULL, or the
 * per-pixel rays (2 x H x W: xn then yn). bounds: the rays' extent (x0, x1, y0, y1).
 * lut: (n_shapes + 1) x 256 RGBA words (row n_shapes: the background). thr: NULL (no
 * noise), or the alias table (k thresholds, vals) of the image noise, drawn for the frame
 * seed ``seed`` over rgb in place (plant_image_noise's arguments). */
EXPORT void plant_camera_render(
    const double *centers, const double *rot, const double *halves, const double *quad,
    int64_t n_shapes, const int64_t *todo, int64_t n_todo, const double *cam,
    const double *light, int64_t W, int64_t H, double f, double cx, double cy,
    const double *xy, const double *bounds, double near, double far, const uint32_t *lut,
    uint8_t *rgb, float *depth, int64_t *sid, double *lam, uint64_t seed, int64_t k,
    const uint32_t *thr, const uint16_t *vals)
{
    const double *Rc = cam, *oc = cam + 9;
    const int64_t np_ = W * H;
    const int wide = plant_camera_wide(1);
    double *xs = lam + np_, *ys = xs + W;       /* the rays of the columns and rows */
    for (int64_t u = 0; u < W; u++)
        xs[u] = ((double)u - cx) / f;
    for (int64_t v = 0; v < H; v++)
        ys[v] = ((double)v - cy) / f;
    for (int64_t p = 0; p < np_; p++) {
        depth[p] = (float)far;
        sid[p] = -1;
        lam[p] = 0.0;
    }
    for (int64_t j = 0; j < n_todo; j++) {
        int64_t s = todo[j];
        const double *c = centers + 3 * s, *R = rot + 9 * s, *h = halves + 3 * s;
        int kind = quad[3 * s] == 0.0 ? 0 : (quad[3 * s + 2] == 0.0 ? 1 : 2);
        /* M = R^T Rc (optical -> shape), o = R^T (oc - c), L = R^T light; the box's
         * centre and axes in the optical frame: Rc^T (c - oc), Rc^T R */
        double M[9], o[3], L[3], p[3], A[9], w[3] = {oc[0] - c[0], oc[1] - c[1], oc[2] - c[2]};
        for (int i = 0; i < 3; i++) {
            o[i] = R[i] * w[0] + R[3 + i] * w[1] + R[6 + i] * w[2];
            L[i] = R[i] * light[0] + R[3 + i] * light[1] + R[6 + i] * light[2];
            p[i] = -(Rc[i] * w[0] + Rc[3 + i] * w[1] + Rc[6 + i] * w[2]);
            for (int k = 0; k < 3; k++) {
                M[3 * i + k] = R[i] * Rc[k] + R[3 + i] * Rc[3 + k] + R[6 + i] * Rc[6 + k];
                A[3 * i + k] = Rc[i] * R[k] + Rc[3 + i] * R[3 + k] + Rc[6 + i] * R[6 + k];
            }
        }
        double rc[4];
        if (!rect_of(p, A, h, near, far, rc))
            continue;
        if (rc[0] < bounds[0]) rc[0] = bounds[0];
        if (rc[1] > bounds[1]) rc[1] = bounds[1];
        if (rc[2] < bounds[2]) rc[2] = bounds[2];
        if (rc[3] > bounds[3]) rc[3] = bounds[3];
        if (rc[0] > rc[1] || rc[2] > rc[3])
            continue;
        int64_t u0 = 0, u1 = W - 1, v0 = 0, v1 = H - 1;
        if (!xy) {                               /* camera._RayGrid.select_block */
            double a;
            a = ceil(f * rc[0] + cx - 1e-9); u0 = a > 0.0 ? (int64_t)a : 0;
            a = floor(f * rc[1] + cx + 1e-9); u1 = a < (double)(W - 1) ? (int64_t)a : W - 1;
            a = ceil(f * rc[2] + cy - 1e-9); v0 = a > 0.0 ? (int64_t)a : 0;
            a = floor(f * rc[3] + cy + 1e-9); v1 = a < (double)(H - 1) ? (int64_t)a : H - 1;
        }
        if (kind == 0 && !xy) {
            box_block(M, o, h, L, s, near, xs, ys, u0, u1, v0, v1, W, depth, sid, lam, wide);
            continue;
        }
        for (int64_t v = v0; v <= v1; v++) {
            for (int64_t u = u0; u <= u1; u++) {
                int64_t q = v * W + u;
                double xn, yn;
                if (xy) {
                    xn = xy[q];
                    yn = xy[np_ + q];
                    if (!(xn >= rc[0] && xn <= rc[1] && yn >= rc[2] && yn <= rc[3]))
                        continue;                /* outside the rectangle, or no preimage */
                } else {
                    xn = xs[u];
                    yn = ys[v];
                }
                double d[3] = {M[0] * xn + M[1] * yn + M[2],
                               M[3] * xn + M[4] * yn + M[5],
                               M[6] * xn + M[7] * yn + M[8]};
                double t, lm;
                if (hit(kind, o, d, h, L, near, (double)depth[q], &t, &lm)) {
                    depth[q] = (float)t;
                    sid[q] = s;
                    lam[q] = lm;
                }
            }
        }
    }
    for (int64_t q = 0; q < np_; q++) {         /* shade: camera._shade's table */
        int64_t row = sid[q] < 0 ? n_shapes : sid[q];
        double l = lam[q] < 0.0 ? 0.0 : (lam[q] > 1.0 ? 1.0 : lam[q]);
        int64_t level = (int64_t)(l * (LEVELS - 1) + 0.5);
        uint32_t c = lut[row * LEVELS + level];
        /* RGBA words, little-endian bytes: all four but the last pixel's, one store (the
         * A byte is the next pixel's R, written next) */
        memcpy(rgb + 3 * q, &c, q + 1 < np_ ? 4 : 3);
        if (sid[q] < 0)
            depth[q] = INFINITY;
    }
    if (thr)
        plant_image_noise(rgb, 3 * np_, seed, k, thr, vals, rgb);
}
