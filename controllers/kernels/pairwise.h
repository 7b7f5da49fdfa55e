/* numpy's pairwise sum of n contiguous doubles, its additions in its order (rowsum.c says
 * which; numpy/_core/src/umath/loops_utils.h.src, pairwise_sum). */
#ifndef PLANT_PAIRWISE_H
#define PLANT_PAIRWISE_H
#include <stdint.h>

static inline double pairwise(const double *a, int64_t n)
{
    if (n < 8) {
        double res = -0.0;              /* x + -0.0 == x for every x: adds nothing */
        for (int64_t i = 0; i < n; i++)
            res += a[i];
        return res;
    }
    if (n <= 128) {
        double r[8];
        int64_t i;
        for (int j = 0; j < 8; j++)
            r[j] = a[j];
        for (i = 8; i < n - (n % 8); i += 8)
            for (int j = 0; j < 8; j++)
                r[j] += a[i + j];
        double res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for (; i < n; i++)
            res += a[i];
        return res;
    }
    int64_t n2 = n / 2;
    n2 -= n2 % 8;
    return pairwise(a, n2) + pairwise(a + n2, n - n2);
}

#endif
