/* The counter-based standard normals of plant/kernels/noise.c (plant_normals), as inline
 * functions for every kernel that draws them (noise.c, sense.c): the arithmetic is stated
 * in noise.c's header comment. */
#ifndef PLANT_NORMALS_H
#define PLANT_NORMALS_H

#include <math.h>
#include <stdint.h>

#define GOLDEN 0x9E3779B97F4A7C15ULL
/* 2 pi, rounded to a double as Python's 2.0 * math.pi is */
#define TWO_PI 6.283185307179586
#define TWO_M53 (1.0 / 9007199254740992.0)

static inline uint64_t mix(uint64_t z)
{
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}

static inline uint64_t row_seed(uint64_t key, uint64_t tick)
{
    return mix(key + mix(tick + GOLDEN));
}

/* o[0 .. n-1]: the n normals of the row seeded s (row_seed of its key and tick) */
static inline void row_normals(uint64_t s, int64_t n, double *o)
{
    for (int64_t i = 0; i < n; i += 2) {
        const uint64_t j = (uint64_t)i;
        const uint64_t a = mix(s + (j + 1) * GOLDEN), b = mix(s + (j + 2) * GOLDEN);
        const double u1 = (double)((a >> 11) + 1) * TWO_M53;
        const double u2 = (double)(b >> 11) * TWO_M53;
        const double rad = sqrt(-2.0 * log(u1)), t = TWO_PI * u2;
        o[i] = rad * cos(t);
        if (i + 1 < n)
            o[i + 1] = rad * sin(t);
    }
}

#endif
