/* A batch of robots' drive limiters and dead reckoning, one control tick each call: the
 * commands of a world's robots (plant_drive_commands: plant/core/drive.py, every host's
 * tick) or of the worlds an environment steps (plant/kernels/ticks.c, which also calls
 * plant_odometry).
 *
 * Both are Python code elsewhere, run with Python floats: plant/drive.py's DriveLimiter
 * (from_twist, from_wheels), plant/sim.py's motion noise (plant/core/drive.py's
 * reference_commands) and controllers/odometry.py's Odometry.update (arc_step). Here is the same
 * arithmetic, operation by operation and in the same order, in IEEE doubles: no fused
 * multiply-adds (-ffp-contract=off, plant/kernels/build.py) and libm's sin and cos, which
 * are what Python's math module calls, so every value is the Python code's to the bit
 * (tests/envs/test_envs_vector.py compares them through a batch against the message path).
 */
#include <math.h>
#include <stdint.h>

#include "normals.h"

#define EXPORT __attribute__((visibility("default")))

EXPORT int plant_drive_abi(void) { return 2; }

/* Python's max(-lim, min(lim, x)): min(a, b) is a unless b < a; max(a, b) a unless b > a */
static inline double clamp(double x, double lim)
{
    double m = (x < lim) ? x : lim;
    return (m > -lim) ? m : -lim;
}

/* DriveLimiter._wheel_limits: the wheel speeds (wl, wr) scaled together to the speed
 * limit m (the path's curvature kept), then each ramped from wh (2, updated) by at most a */
static inline void wheel_limits(double wl, double wr, double m, double a, double *wh)
{
    double al = fabs(wl), ar = fabs(wr);
    double peak = (ar > al) ? ar : al;          /* Python's max(al, ar) */
    if (peak > m) {
        wl = wl * m / peak;
        wr = wr * m / peak;
    }
    wh[0] = wh[0] + clamp(wl - wh[0], a);       /* _ramp */
    wh[1] = wh[1] + clamp(wr - wh[1], a);
}

/* DriveLimiter.from_twist after the targets' clamp: v, w ramped toward (vt, wt) by at most
 * (dv, dw), turned into wheel speeds (inverse) and limited into wh (2) */
static inline void twist_row(double *v, double *w, double *wh, double vt, double wt,
                             double dv, double dw, double r, double d, double m, double a)
{
    *v = *v + clamp(vt - *v, dv);                                /* _ramp */
    *w = *w + clamp(wt - *w, dw);
    wheel_limits((*v - *w * d / 2.0) / r, (*v + *w * d / 2.0) / r, m, a, wh);   /* inverse */
}

/* The columns of plant_drive_commands' limits (n, DRIVE_COLUMNS), a robot a row
 * (plant/core/drive.py's limits_of lays them out) */
enum { L_V, L_W, L_DV, L_DW, L_R, L_D, L_M, L_A, DRIVE_COLUMNS };

/* A tick's commands of n robots in each of `worlds` worlds (row j = world k's robot i, at
 * k n + i), each as Simulation.command_twist / command_wheels / _set_targets did robot by
 * robot: kind[j] 1 a twist (cmd[j] = v m/s, w rad/s: clamped to the speed limits, ramped by
 * the accelerations, turned into wheel speeds, limited), 2 wheel speeds (cmd[j] = left,
 * right rad/s: limited; v, w then the body speeds of the limited wheels, as forward gives
 * them), 0 no command (the limiter and the targets as they were). A commanded robot's
 * targets[j] (2) are its limited wheel speeds plus its motion noise: the two standard
 * normals of keys[j] at tick[k] (normals.h) times std[i], none where std[i] is 0 or the
 * wheels are (0, 0) (a robot told to stand). Every kind[j] is 0 after the call. */
EXPORT void plant_drive_commands(int64_t worlds, int64_t n, const int64_t *tick,
                                 const double *limits, const double *std,
                                 const uint64_t *keys, int64_t *kind, const double *cmd,
                                 double *v, double *w, double *wheels, double *targets)
{
    for (int64_t k = 0; k < worlds; k++) {
        for (int64_t i = 0; i < n; i++) {
            const int64_t j = k * n + i;
            if (kind[j] == 0)
                continue;
            const double *L = limits + DRIVE_COLUMNS * i, *c = cmd + 2 * j;
            double *wh = wheels + 2 * j, *o = targets + 2 * j;
            if (kind[j] == 1) {
                twist_row(v + j, w + j, wh, clamp(c[0], L[L_V]), clamp(c[1], L[L_W]),
                          L[L_DV], L[L_DW], L[L_R], L[L_D], L[L_M], L[L_A]);
            } else {
                wheel_limits(c[0], c[1], L[L_M], L[L_A], wh);
                v[j] = L[L_R] * (wh[1] + wh[0]) / 2.0;                   /* forward */
                w[j] = L[L_R] * (wh[1] - wh[0]) / L[L_D];
            }
            kind[j] = 0;
            double t0 = wh[0], t1 = wh[1];
            if (std[i] > 0.0 && !(t0 == 0.0 && t1 == 0.0)) {
                double z[2];
                row_normals(row_seed(keys[j], (uint64_t)tick[k]), 2, z);
                t0 = t0 + z[0] * std[i];
                t1 = t1 + z[1] * std[i];
            }
            o[0] = t0;
            o[1] = t1;
        }
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
