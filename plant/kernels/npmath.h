/* numpy's NaN rules for the plant's kernels (lidar.c, kinematic.c): np.maximum and
 * np.minimum give the NaN of either argument; np.fmax and np.fmin let a NaN give way to the
 * other. Written as selects of doubles (no ||), which gcc turns into vector blends inside a
 * loop it vectorises (lidar.c's ray loop). */
#ifndef PLANT_NPMATH_H
#define PLANT_NPMATH_H

static inline double np_max(double a, double b)
{
    double r = (a >= b) ? a : b;
    return (a != a) ? a : r;
}

static inline double np_min(double a, double b)
{
    double r = (a <= b) ? a : b;
    return (a != a) ? a : r;
}

static inline double np_fmax(double a, double b)
{
    double r = (a >= b) ? a : b;
    return (b != b) ? a : r;
}

static inline double np_fmin(double a, double b)
{
    double r = (a <= b) ? a : b;
    return (b != b) ? a : r;
}

#endif
