/* Control ticks of a batch of worlds of R robots each, per call (diffbot/envs/kinbatch.py:
 * an Avoid step's ticks, the batched env's and the single env's; a swarm's worlds).
 *
 * Each tick is what the plant's tick does for such a world: the commands through the drive
 * limiters and the motion noise of the robots that move (plant_drive_commands, as a
 * plant's tick runs them), the kinematic step
 * (plant_kinematic_step), the encoders' noise (plant_noise_values, as the plant's sensors
 * draw it: sense.c), the dead reckoning (plant_odometry) and the worlds' clocks. The same
 * operations in the same order as its Python, so the same bits
 * (tests/envs/test_envs_vector.py runs the message path beside it, every noise on;
 * tests/envs/test_envs_identity.py a plant over the bus). Every noise is drawn here from
 * its stream's key and the world's tick: the motion noise by plant_drive_commands, the
 * encoders' by plant_noise_values.
 *
 * The calls stop after a tick at which some world's lidar is due (its scan is cast in
 * Python before the next tick moves the robot): the number of ticks made is returned.
 * A DART world is stepped in Python between the two halves of a tick (plant_tick_part).
 */
#include <math.h>
#include <stdint.h>

#define EXPORT __attribute__((visibility("default")))

EXPORT int plant_ticks_abi(void) { return 7; }

void plant_drive_commands(int64_t worlds, int64_t n, const int64_t *tick,
                          const double *limits, const double *std, const uint64_t *keys,
                          int64_t *kind, const double *cmd, double *v, double *w,
                          double *wheels, double *targets);
void plant_noise_values(const double *law, uint64_t key, int64_t tick, int64_t n,
                        const double *x, double *y);
void plant_lidar_noise(int64_t g, int64_t n, const double *exact, const uint64_t *keys,
                       const double *laws, int64_t tick, double lo, double hi, double q,
                       double *work, float *out);
void plant_odometry(int64_t n, const double *pos, const double *t, double *pose, double *vel,
                    double *last, double *last_t, const double *r, const double *d);
int plant_kinematic_step(int64_t n, double T, const double *targets, const double *radius,
                         const double *separation, const int64_t *world, double *pose,
                         double *wheels, double *speeds, double *vel, int64_t nbox,
                         const double *box_c, const double *box_cos, const double *box_sin,
                         const double *box_half, int64_t ncirc, const double *circ_c,
                         const double *circ_r, const double *half, double foot_r,
                         double centre_x, int64_t pairs);

/* The slots of the call's int64 block (addresses and counts; kinbatch._TickPlan fills it
 * in this order), most of them pointing into the core's data (plant/core/data.py): n rows,
 * a robot each, world after world, R (A_ROBOTS) robots a world, so row j is world j / R's
 * robot j % R. A row's arrays (n, ...): the limiters, the commands, the targets, the noise
 * keys, the dead reckoning, the scans. A world's (n / R): its tick, steps, time, due. A
 * robot's (R, ...), the model's: the drive limits (R, 8) and motion noise std (R), the
 * noise laws (R, 4) (std, mean, bias, resolution; the encoders' may be 0: none). The
 * commands: plant_drive_commands' arrays (cmd (n, 2) each robot's twist; kind (n) and the
 * worlds' ticks set here each tick). */
enum {
    A_V, A_W, A_LIM_WHEELS, A_KIND, A_CMD, A_TARGETS,            /* drive limiters */
    A_LIMITS, A_STD, A_KEYS, A_TICK,                               /* and motion noise */
    A_RADIUS, A_SEPARATION, A_WORLD, A_POSE, A_WHEELS, A_SPEEDS, A_VEL, A_PAIRS, /* robots */
    A_NBOX, A_BOX_C, A_BOX_COS, A_BOX_SIN, A_BOX_HALF, A_NCIRC, A_CIRC_C, A_CIRC_R, A_HALF,
    A_ENC_KEYS, A_ENC_LAWS,                                        /* encoder noise (0: none) */
    A_ODO_POSE, A_ODO_VEL, A_LAST, A_LAST_T, A_ODO_R, A_ODO_D, A_POS, A_T, /* dead reckoning */
    A_STEPS, A_T_NS, A_DUE, A_SUB, A_STEP_NS, A_TICK_NS, A_PERIOD, /* clocks, lidar due */
    A_LID_KEYS, A_LID_LAWS, A_LID_WORK, A_RAW, A_SCANS, A_NEW_SCAN, A_RAYS, /* the scans */
    A_ROBOTS,                                                      /* robots a world */
    A_COUNT
};
/* ... and of its double block */
enum {
    P_TICK_S, P_FOOT_R, P_CENTRE_X,                /* the kinematic step's */
    P_LID_LO, P_LID_HI, P_LID_Q, P_SCAN_MAX,       /* the lidar's range, step; the scan's bound */
    P_COUNT
};

/* The blocks' sizes (A_COUNT * 1000 + P_COUNT): the caller checks its layout against it. */
EXPORT int64_t plant_ticks_count(void) { return A_COUNT * 1000 + P_COUNT; }

#define PTR(type, slot) ((type *)(intptr_t)a[slot])

/* A tick's commands: Tick.drive's twist of every robot, run as a plant's tick runs them
 * (plant_drive_commands: the limiter, then the motion noise of a robot that moves, at its
 * world's tick) into targets (n, 2). */
static void commands(int64_t n, const int64_t *a)
{
    int64_t *kind = PTR(int64_t, A_KIND), *tick = PTR(int64_t, A_TICK);
    const int64_t *steps = PTR(const int64_t, A_STEPS);
    const int64_t sub = a[A_SUB], R = a[A_ROBOTS];
    for (int64_t i = 0; i < n; i++)
        kind[i] = 1;                                            /* a twist */
    for (int64_t k = 0; k < n / R; k++)
        tick[k] = steps[k] / sub;
    plant_drive_commands(n / R, R, tick, PTR(const double, A_LIMITS), PTR(const double, A_STD),
                         PTR(const uint64_t, A_KEYS), kind, PTR(const double, A_CMD),
                         PTR(double, A_V), PTR(double, A_W), PTR(double, A_LIM_WHEELS),
                         PTR(double, A_TARGETS));
}

/* What follows a tick's step: the worlds' clocks, the encoders (the wheel angles in
 * wheels (n, 2), with the encoders' noise at the world's new tick), the dead reckoning, and
 * due (n / R): whose worlds' lidars are due now. Whether any is. */
static int after(int64_t n, const int64_t *a)
{
    const double *wheels = PTR(const double, A_WHEELS);
    const uint64_t *enc_keys = PTR(const uint64_t, A_ENC_KEYS);
    const double *enc_laws = PTR(const double, A_ENC_LAWS);
    double *pos = PTR(double, A_POS), *t = PTR(double, A_T);
    int64_t *steps = PTR(int64_t, A_STEPS), *t_ns = PTR(int64_t, A_T_NS);
    int64_t *due = PTR(int64_t, A_DUE), *tick = PTR(int64_t, A_TICK);
    const int64_t sub = a[A_SUB], step_ns = a[A_STEP_NS], R = a[A_ROBOTS];
    const int64_t tick_ns = a[A_TICK_NS], period = a[A_PERIOD];
    int any_due = 0;
    for (int64_t k = 0; k < n / R; k++) {
        steps[k] += sub;
        t_ns[k] = steps[k] * step_ns;
        tick[k] = steps[k] / sub;
        due[k] = (t_ns[k] / tick_ns) % period == 0;
        any_due |= (int)due[k];
    }
    for (int64_t i = 0; i < n; i++) {
        const int64_t k = i / R;
        t[i] = (double)t_ns[k] * 1e-9;
        if (enc_laws)
            plant_noise_values(enc_laws + 4 * (i % R), enc_keys[i], steps[k] / sub, 2,
                               wheels + 2 * i, pos + 2 * i);
        else {
            pos[2 * i] = wheels[2 * i];
            pos[2 * i + 1] = wheels[2 * i + 1];
        }
    }
    plant_odometry(n, pos, t, PTR(double, A_ODO_POSE), PTR(double, A_ODO_VEL),
                   PTR(double, A_LAST), PTR(double, A_LAST_T), PTR(const double, A_ODO_R),
                   PTR(const double, A_ODO_D));
    return any_due;
}

/* Up to `ticks` control ticks of n robots in kinematic worlds (the commands, the kinematic
 * step, what follows it); returns the ticks made (fewer when a lidar came due: due
 * (n / R, int64) marks the worlds whose lidars are due after the last one), or -1 if out
 * of memory. */
EXPORT int64_t plant_ticks(int64_t n, int64_t ticks, const int64_t *a, const double *p)
{
    for (int64_t k = 0; k < ticks; k++) {
        commands(n, a);
        if (plant_kinematic_step(n, p[P_TICK_S], PTR(const double, A_TARGETS),
                                 PTR(const double, A_RADIUS), PTR(const double, A_SEPARATION),
                                 PTR(const int64_t, A_WORLD), PTR(double, A_POSE),
                                 PTR(double, A_WHEELS), PTR(double, A_SPEEDS),
                                 PTR(double, A_VEL), a[A_NBOX], PTR(const double, A_BOX_C),
                                 PTR(const double, A_BOX_COS), PTR(const double, A_BOX_SIN),
                                 PTR(const double, A_BOX_HALF), a[A_NCIRC],
                                 PTR(const double, A_CIRC_C), PTR(const double, A_CIRC_R),
                                 PTR(const double, A_HALF), p[P_FOOT_R], p[P_CENTRE_X],
                                 a[A_PAIRS]))
            return -1;
        if (after(n, a))
            return k + 1;
    }
    return ticks;
}

/* One tick's half, for n robots in worlds another engine steps (DART): part 0 the commands (into
 * targets), part 1 what follows the step (the engine's wheel angles put in wheels first).
 * Part 1 returns whether some world's lidar is due. */
EXPORT int64_t plant_tick_part(int64_t n, int64_t part, const int64_t *a, const double *p)
{
    (void)p;                                  /* (its parameters: the step's own) */
    if (part == 0) {
        commands(n, a);
        return 0;
    }
    return after(n, a);
}

/* The scans of the g robots rows[0 .. g) whose lidar is due, from their exact ranges exact
 * (g, rays) float64: each row's reported ranges (raw, (n, rays) float32) with its lidar's
 * noise (keys (n), laws (R, 4)) at its own world's tick (plant_lidar_noise, as the plant's
 * tick draws it), and its observation's scan (scans, (n, rays) float32): each finite
 * reading clipped to [0, max] as np.minimum(np.maximum(r, 0), max) does, max where it is
 * not finite (controllers.learned.AvoidObserver); new_scan (n, bool) marks the rows. */
EXPORT void plant_ticks_scans(int64_t g, const int64_t *rows, const double *exact,
                              const int64_t *a, const double *p)
{
    const int64_t rays = a[A_RAYS], tick_ns = a[A_TICK_NS], R = a[A_ROBOTS];
    const int64_t *t_ns = PTR(const int64_t, A_T_NS);
    const uint64_t *keys = PTR(const uint64_t, A_LID_KEYS);
    const double *laws = PTR(const double, A_LID_LAWS);
    double *work = PTR(double, A_LID_WORK);
    float *raw = PTR(float, A_RAW), *scans = PTR(float, A_SCANS);
    uint8_t *new_scan = PTR(uint8_t, A_NEW_SCAN);
    const float top = (float)p[P_SCAN_MAX];
    for (int64_t k = 0; k < g; k++) {
        const int64_t r = rows[k];
        float *y = raw + r * rays, *s = scans + r * rays;
        plant_lidar_noise(1, rays, exact + k * rays, keys + r, laws + 4 * (r % R),
                          t_ns[r / R] / tick_ns,
                          p[P_LID_LO], p[P_LID_HI], p[P_LID_Q], work, y);
        for (int64_t i = 0; i < rays; i++) {
            float v = y[i];
            if (isfinite(v)) {
                v = (v > 0.0f) ? v : 0.0f;        /* np.maximum(v, 0): 0 at a tie (-0.0) */
                v = (v < top) ? v : top;          /* np.minimum(v, max): max at a tie */
            } else
                v = top;
            s[i] = v;
        }
        new_scan[r] = 1;
    }
}

/* The true (x, y, yaw) (n, 3) of kinematic robots at pose (n, 3), as their ground_truth
 * messages give them back (diffbot/envs/obsmath.py's truths): the rotation of the yaw
 * (plant/sim.py's kin_state: cos, sin), its quaternion (rotation_to_quaternion, both of
 * its branches: the trace's, or the largest diagonal element's, m22 = 1), and the yaw of
 * that (bus/codec.py's yaw_of: atan2, which Python's math.atan2 calls for finite values). */
EXPORT void plant_ticks_truths(int64_t n, const double *pose, double *out)
{
    for (int64_t i = 0; i < n; i++) {
        const double yaw = pose[3 * i + 2], c = cos(yaw), s = sin(yaw);
        const double tr = c + c + 1.0;
        double qx, qy, qz, qw;
        if (tr > 0) {
            const double s1 = sqrt(tr + 1.0) * 2;
            qx = qy = 0.0 / s1;
            qz = (s - -s) / s1;
            qw = 0.25 * s1;
        } else {
            const double s2 = sqrt(1.0 + 1.0 - c - c) * 2;
            qx = qy = 0.0 / s2;
            qz = 0.25 * s2;
            qw = (s - -s) / s2;
        }
        out[3 * i] = pose[3 * i];
        out[3 * i + 1] = pose[3 * i + 1];
        out[3 * i + 2] = atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz));
    }
}

/* x % m as Python's float % (and numpy's) gives it: fmod, moved to m's sign */
static double py_mod(double x, double m)
{
    double r = fmod(x, m);
    if (r != 0.0) {
        if ((m < 0) != (r < 0))
            r += m;
    } else
        r = copysign(0.0, m);
    return r;
}

/* np.minimum(np.maximum(v, lo), hi) of float32s (a NaN stays one; at a tie the bound) */
static float clip32(float v, float lo, float hi)
{
    if (v != v)
        return v;
    v = v > lo ? v : lo;
    return v < hi ? v : hi;
}

/* The odometry and goal parts of n robots' Avoid observations (diffbot/envs/obsmath.py's
 * observation; controllers/learned.py's AvoidObserver, robot by robot, in Python floats):
 * odom (n, 5) float32 = (x, y, wrap(yaw), v, w) of the dead-reckoned pose (n, 3) and
 * velocity vel (n, 2), clipped to +-odom_high (5); goal_out (n, 2) float32 = goal (n, 2)
 * (in the odometry's frame) in the robot's frame, clipped to +-goal_limit. libm's cos and
 * sin, which Python's math calls. */
EXPORT void plant_ticks_observe(int64_t n, const double *pose, const double *vel,
                                const double *goal, const float *odom_high, double goal_limit,
                                float *odom, float *goal_out)
{
    const double pi = 3.141592653589793;
    const float gl = (float)goal_limit;
    for (int64_t i = 0; i < n; i++) {
        const double x = pose[3 * i], y = pose[3 * i + 1], th = pose[3 * i + 2];
        const double c = cos(th), s = sin(th);
        const double dx = goal[2 * i] - x, dy = goal[2 * i + 1] - y;
        const double v[5] = {x, y, py_mod(th + pi, 2 * pi) - pi, vel[2 * i], vel[2 * i + 1]};
        for (int k = 0; k < 5; k++)
            odom[5 * i + k] = clip32((float)v[k], -odom_high[k], odom_high[k]);
        goal_out[2 * i] = clip32((float)(dx * c + dy * s), -gl, gl);
        goal_out[2 * i + 1] = clip32((float)(-dx * s + dy * c), -gl, gl);
    }
}
