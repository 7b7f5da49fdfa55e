/* A batch of robots' drive limiters and dead reckoning, one control tick each call
 * (plant/kernels/ticks.c calls them for the worlds an environment steps).
 *
 * Both are Python code elsewhere, run with Python floats: plant/drive.py's DriveLimiter
 * (from_twist) and controllers/odometry.py's Odometry.update (arc_step). Here is the same
 * arithmetic, operation by operation and in the same order, in IEEE doubles: no fused
 * multiply-adds (-ffp-contract=off, plant/kernels/build.py) and libm's sin and cos, which
 * are what Python's math module calls, so every value is the Python code's to the bit
 * (tests/envs/test_envs_vector.py compares them through a batch against the message path).
 */
#include <math.h>
#include <stdint.h>

#define EXPORT __attribute__((visibility("default")))

EXPORT int plant_drive_abi(void) { return 1; }

/* Python's max(-lim, min(lim, x)): min(a, b) is a unless b < a; max(a, b) a unless b > a */
static inline double clamp(double x, double lim)
{
    double m = (x < lim) ? x : lim;
    return (m > -lim) ? m : -lim;
}

/* DriveLimiter.from_twist for n robots of one drive: v, w (n) the ramped body speeds and
 * wheels (n, 2) the ramped wheel speeds, updated in place; v_target, w_target (n) the
 * commands clamped to the speed limits already; out (n, 2) the wheel-speed targets. */
EXPORT void plant_drive_limit(int64_t n, double *v, double *w, double *wheels,
                              const double *v_target, const double *w_target,
                              double dv, double dw, double r, double d, double m, double a,
                              double *out)
{
    for (int64_t i = 0; i < n; i++) {
        v[i] = v[i] + clamp(v_target[i] - v[i], dv);            /* _ramp */
        w[i] = w[i] + clamp(w_target[i] - w[i], dw);
        double wl = (v[i] - w[i] * d / 2.0) / r;                /* inverse */
        double wr = (v[i] + w[i] * d / 2.0) / r;
        double al = fabs(wl), ar = fabs(wr);                    /* _wheel_limits */
        double peak = (ar > al) ? ar : al;
        if (peak > m) {
            wl = wl * m / peak;
            wr = wr * m / peak;
        }
        double *wh = wheels + 2 * i;
        wh[0] = wh[0] + clamp(wl - wh[0], a);
        wh[1] = wh[1] + clamp(wr - wh[1], a);
        out[2 * i] = wh[0];
        out[2 * i + 1] = wh[1];
    }
}

/* Odometry.update of n robots with their new encoder angles pos (n, 2) at times t (n):
 * pose (n, 3) x, y, theta and vel (n, 2) v, w, last (n, 2) the last angles and last_t (n)
 * their times, all updated in place; r, d (n) wheel radius and separation. Every robot
 * has a last reading (the batch feeds t = 0 at reset) and t > last_t. */
EXPORT void plant_odometry(int64_t n, const double *pos, const double *t, double *pose,
                           double *vel, double *last, double *last_t, const double *r,
                           const double *d)
{
    for (int64_t i = 0; i < n; i++) {
        double dl = pos[2 * i] - last[2 * i], dr = pos[2 * i + 1] - last[2 * i + 1];
        double ds = r[i] * (dr + dl) / 2.0;                     /* arc_step */
        double dtheta = r[i] * (dr - dl) / d[i];
        double half = dtheta / 2.0;
        double sinc = fabs(half) < 1e-9 ? 1.0 - half * half / 6.0 : sin(half) / half;
        double chord = ds * sinc;
        double *p = pose + 3 * i;
        double x = p[0] + chord * cos(p[2] + half);
        double y = p[1] + chord * sin(p[2] + half);
        p[0] = x;
        p[1] = y;
        p[2] = p[2] + dtheta;
        double h = t[i] - last_t[i];
        if (t[i] > last_t[i]) {
            vel[2 * i] = r[i] * (dr + dl) / 2.0 / h;
            vel[2 * i + 1] = r[i] * (dr - dl) / d[i] / h;
        }
        last[2 * i] = pos[2 * i];
        last[2 * i + 1] = pos[2 * i + 1];
        last_t[i] = t[i];
    }
}
