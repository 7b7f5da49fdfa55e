/* A world's per-tick sensor messages in one call: the true state of its robots (a
 * kinematic world's read from its arrays, plant_observe_kinematic; a dynamic world's
 * orientation as a quaternion, plant_quaternions), the encoder and GPS noise drawn and the
 * CDR bytes of every robot's joint_states, gps and ground_truth written (plant_sense), and
 * a lidar's reported ranges from its exact ones (plant_lidar_noise).
 *
 * plant/core/step.py calls them; the per-message path (plant/sensors.py's RobotSensors,
 * plant/noise.py's NoiseModel.apply, plant/lidar.py's apply_noise, plant/sim.py's
 * kin_state and rotation_to_quaternion) is the same arithmetic in Python, in the same
 * order, so the same bits (tests/plant/test_core.py compares them message by message):
 *
 *   noise:  y = (x + (bias + mean)) + z std   (z: the stream's normals at the tick, as
 *           plant_normals draws them; nothing drawn where std is 0), then
 *           y = rint(y / resolution) resolution where y is finite and resolution > 0; a
 *           stream whose four numbers are all 0 leaves the values as they are;
 *   lidar:  the noise, then each finite range clipped to [min, max] as np.clip does, and
 *           quantised to the lidar's resolution (then clipped again); stored as float32.
 *
 * The messages' fixed parts (encapsulation, frame ids, joint names, lengths, zero
 * covariances) are written once into the caller's buffer from bus/packed.py's templates;
 * a call writes only the stamps and the values, at the places the templates give. CDR here
 * is little endian (XCDR1, as the templates say), and so must the machine be. */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "normals.h"

#if !defined(__BYTE_ORDER__) || __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "plant/kernels/sense.c writes little-endian CDR with the machine's own byte order"
#endif

#define EXPORT __attribute__((visibility("default")))

EXPORT int plant_sense_abi(void) { return 3; }

/* a + b as numpy's float64 scalars sum them (measured): of two NaNs, b's (its sign) */
static inline double np_sum(double a, double b)
{
    return (a != a && b != b) ? b : a + b;
}

/* plant/sim.py's rotation_to_quaternion of the rotation in the 4x4 row-major m: (x, y, z, w) */
static void quaternion(const double *m, double *q)
{
    const double d[3] = {m[0], m[5], m[10]};
    const double tr = d[0] + d[1] + d[2];
    if (tr > 0) {
        const double s = sqrt(tr + 1.0) * 2;
        q[0] = (m[9] - m[6]) / s;
        q[1] = (m[2] - m[8]) / s;
        q[2] = (m[4] - m[1]) / s;
        q[3] = 0.25 * s;
        return;
    }
    /* np.argmax: the first largest, or the first NaN */
    int i = 0;
    double best = d[0];
    if (best == best)
        for (int c = 1; c < 3; c++)
            if (!(d[c] <= best)) {
                best = d[c];
                i = c;
                if (best != best)
                    break;
            }
    const int j = (i + 1) % 3, k = (i + 2) % 3;
#define M(r, c) m[4 * (r) + (c)]
    const double s = sqrt(1.0 + M(i, i) - M(j, j) - M(k, k)) * 2;
    q[i] = 0.25 * s;
    q[j] = np_sum(M(j, i), M(i, j)) / s;      /* (numpy scalars there) */
    q[k] = np_sum(M(k, i), M(i, k)) / s;
    q[3] = (M(k, j) - M(j, k)) / s;
#undef M
}

/* (n, 4, 4) transforms -> (n, 4) quaternions */
EXPORT void plant_quaternions(int64_t n, const double *tf, double *quat)
{
    for (int64_t r = 0; r < n; r++)
        quaternion(tf + 16 * r, quat + 4 * r);
}

/* A dynamic world's state rows (n, 26: plant/sim.py's Simulation.read_state: the 4x4
 * row-major pose, body linear and angular velocity, wheel angles and speeds) into the core's
 * arrays: tf (n, 4, 4), v (the forward speed), w (the yaw rate) (n,), enc_pos, enc_vel (n, 2),
 * and the orientation as quat (n, 4) (copies, and rotation_to_quaternion: the same bits). */
EXPORT void plant_observe_rows(int64_t n, const double *rows, double *tf, double *quat,
                               double *v, double *w, double *enc_pos, double *enc_vel)
{
    for (int64_t r = 0; r < n; r++) {
        const double *row = rows + 26 * r;
        memcpy(tf + 16 * r, row, 16 * sizeof *row);
        v[r] = row[16];
        w[r] = row[21];
        enc_pos[2 * r] = row[22];
        enc_pos[2 * r + 1] = row[23];
        enc_vel[2 * r] = row[24];
        enc_vel[2 * r + 1] = row[25];
        quaternion(row, quat + 4 * r);
    }
}

/* sim/poses' TFMessage of n robots into out (its template written in): at[2r] robot r's
 * header stamp (sec int32, nanosec uint32), at[2r + 1] its transform (translation x, y, z
 * from tf (n, 4, 4), rotation x, y, z, w from quat (n, 4)). */
EXPORT void plant_poses(int64_t n, const double *tf, const double *quat, const int64_t *at,
                        int64_t sec, int64_t nanosec, uint8_t *out)
{
    const int32_t s = (int32_t)sec;
    const uint32_t ns = (uint32_t)nanosec;
    for (int64_t r = 0; r < n; r++) {
        const double *m = tf + 16 * r, *q = quat + 4 * r;
        const double pose[7] = {m[3], m[7], m[11], q[0], q[1], q[2], q[3]};
        memcpy(out + at[2 * r], &s, 4);
        memcpy(out + at[2 * r] + 4, &ns, 4);
        memcpy(out + at[2 * r + 1], pose, sizeof pose);
    }
}

/* plant/sim.py's kin_state of every robot of a kinematic world (pose (n, 3) x, y, yaw;
 * vel (n, 2) v, w; wheels, speeds (n, 2); radius (n,)) into the core's arrays: tf (n, 4, 4),
 * yaw, v, w (n,), quat (n, 4), enc_pos, enc_vel (n, 2). */
EXPORT void plant_observe_kinematic(int64_t n, const double *pose, const double *vel,
                                    const double *wheels, const double *speeds,
                                    const double *radius, double *tf, double *yaw,
                                    double *quat, double *v, double *w, double *enc_pos,
                                    double *enc_vel)
{
    for (int64_t r = 0; r < n; r++) {
        const double x = pose[3 * r], y = pose[3 * r + 1], a = pose[3 * r + 2];
        const double c = cos(a), s = sin(a);
        double *m = tf + 16 * r;
        const double rows[16] = {c, -s, 0.0, x, s, c, 0.0, y, 0.0, 0.0, 1.0, radius[r],
                                 0.0, 0.0, 0.0, 1.0};
        memcpy(m, rows, sizeof rows);
        yaw[r] = (s != s || c != c) ? NAN : atan2(s, c);   /* (Python's math.atan2) */
        v[r] = vel[2 * r];
        w[r] = vel[2 * r + 1];
        enc_pos[2 * r] = wheels[2 * r];
        enc_pos[2 * r + 1] = wheels[2 * r + 1];
        enc_vel[2 * r] = speeds[2 * r];
        enc_vel[2 * r + 1] = speeds[2 * r + 1];
        quaternion(m, quat + 4 * r);
    }
}

/* y (n) = x with the noise of the law (std, mean, bias, resolution) of the stream keyed
 * `key` at `tick` (x and y may be one array). The one implementation of a stream's noise
 * law: ticks.c reads the batched envs' encoders with it too. */
void plant_noise_values(const double *law, uint64_t key, int64_t tick, int64_t n,
                        const double *x, double *y)
{
    const double std = law[0], res = law[3];
    if (std == 0 && law[1] == 0 && law[2] == 0 && res == 0) {
        if (y != x)
            memcpy(y, x, (size_t)n * sizeof *y);
        return;
    }
    const double bm = law[2] + law[1];
    if (std > 0) {
        double z[64];
        const uint64_t seed = row_seed(key, (uint64_t)tick);
        for (int64_t at = 0; at < n; at += 64) {     /* (a chunk's normals: 64 is even) */
            const int64_t m = n - at < 64 ? n - at : 64;
            row_normals(seed + (uint64_t)at * GOLDEN, m, z);  /* element at + i */
            for (int64_t i = 0; i < m; i++)
                y[at + i] = (x[at + i] + bm) + z[i] * std;
        }
    } else {
        for (int64_t i = 0; i < n; i++)
            y[i] = x[i] + bm;
    }
    if (res > 0)
        for (int64_t i = 0; i < n; i++)
            if (isfinite(y[i]))
                y[i] = nearbyint(y[i] / res) * res;
}

static inline void put_doubles(uint8_t *out, int64_t at, const double *v, int n)
{
    memcpy(out + at, v, (size_t)n * sizeof *v);
}

/* Every read message of n robots' joint_states, gps and ground_truth at the tick (stamp
 * t_ns) into out. Robot r: read[3 r + m] whether message m (joint_states, gps,
 * ground_truth) is made; at[8 r ..] the places in out of its joint_states (start,
 * position, velocity), gps (start, point) and ground_truth (start, pose, twist); the
 * encoders' and GPS's noise keys and laws (n, 4) as plant/core/data.py and model.py keep
 * them. */
EXPORT void plant_sense(int64_t n, const double *tf, const double *quat, const double *v,
                        const double *w, const double *enc_pos, const double *enc_vel,
                        const uint64_t *enc_keys, const double *enc_laws,
                        const uint64_t *gps_keys, const double *gps_laws, const int64_t *at,
                        const uint8_t *read, int64_t tick, int64_t t_ns, uint8_t *out)
{
    const int32_t sec = (int32_t)(t_ns / 1000000000);
    const uint32_t nsec = (uint32_t)(t_ns % 1000000000);
    for (int64_t r = 0; r < n; r++) {
        const int64_t *p = at + 8 * r;
        const double *m = tf + 16 * r;
        for (int k = 0; k < 3; k++)
            if (read[3 * r + k]) {
                const int64_t start = p[k == 0 ? 0 : (k == 1 ? 3 : 5)];
                memcpy(out + start + 4, &sec, 4);
                memcpy(out + start + 8, &nsec, 4);
            }
        if (read[3 * r]) {
            double pos[2];
            plant_noise_values(enc_laws + 4 * r, enc_keys[r], tick, 2, enc_pos + 2 * r, pos);
            put_doubles(out, p[1], pos, 2);
            put_doubles(out, p[2], enc_vel + 2 * r, 2);
        }
        const double xyz[3] = {m[3], m[7], m[11]};
        if (read[3 * r + 1]) {
            double g[3];
            plant_noise_values(gps_laws + 4 * r, gps_keys[r], tick, 3, xyz, g);
            put_doubles(out, p[4], g, 3);
        }
        if (read[3 * r + 2]) {
            const double *q = quat + 4 * r;
            const double pose7[7] = {xyz[0], xyz[1], xyz[2], q[0], q[1], q[2], q[3]};
            const double twist6[6] = {v[r], 0.0, 0.0, 0.0, 0.0, w[r]};
            put_doubles(out, p[6], pose7, 7);
            put_doubles(out, p[7], twist6, 6);
        }
    }
}

/* np.clip of a finite x to [lo, hi]: x stays where it equals a bound (-0.0 at 0.0) */
static inline double clip(double x, double lo, double hi)
{
    x = x < lo ? lo : x;
    return x > hi ? hi : x;
}

/* Reported ranges (g, n) float32 from exact ones (g, n) float64: row r with the noise of
 * keys[r] and laws[4 r ..] at the tick, then the lidar's [lo, hi] clip and its
 * quantisation step q (0: none). */
EXPORT void plant_lidar_noise(int64_t g, int64_t n, const double *exact, const uint64_t *keys,
                              const double *laws, int64_t tick, double lo, double hi, double q,
                              double *work, float *out)
{
    for (int64_t r = 0; r < g; r++) {
        plant_noise_values(laws + 4 * r, keys[r], tick, n, exact + r * n, work);
        float *o = out + r * n;
        for (int64_t i = 0; i < n; i++) {
            double y = work[i];
            if (isfinite(y)) {
                y = clip(y, lo, hi);
                if (q > 0.0)
                    y = clip(nearbyint(y / q) * q, lo, hi);
            }
            o[i] = (float)y;
        }
    }
}
