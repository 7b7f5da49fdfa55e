/* Masked row sums equal to the bit to numpy's np.sum of each row's selected values
 * (controllers/rowsum.py is the numpy reference and says why the order matters).
 *
 * numpy sums a contiguous run of doubles pairwise (numpy/_core/src/umath/loops_utils.h.src,
 * pairwise_sum): a run of at most 128 values in eight partial sums over blocks of eight,
 * combined as ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7)), the rest (fewer than eight
 * values) added one by one; a longer run split in two halves, the first a multiple of eight
 * long, summed the same way and added. A sum starts from numpy's identity, +0.0. Built with
 * the kernels' flags (no -ffast-math, no contraction): every addition as written. */
#include <stdint.h>

#include "pairwise.h"

#define EXPORT __attribute__((visibility("default")))

EXPORT int controller_rowsum_abi(void) { return 1; }

/* out[i] = np.sum(values[i][mask[i]]) for rows x width row-major values and mask (one
 * byte per value, nonzero: selected); scratch holds width doubles. */
EXPORT void controller_masked_row_sums(int64_t rows, int64_t width, const double *values,
                                  const uint8_t *mask, double *scratch, double *out)
{
    for (int64_t i = 0; i < rows; i++) {
        const double *v = values + i * width;
        const uint8_t *m = mask + i * width;
        int64_t n = 0;
        for (int64_t j = 0; j < width; j++)
            if (m[j])
                scratch[n++] = v[j];
        out[i] = 0.0 + pairwise(scratch, n);
    }
}
