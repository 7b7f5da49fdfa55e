/* The ball follower's per-frame noise estimate (controllers/ball_follower.py,
 * image_noise_std): the median of neighbouring pixels' differences, numpy's median to the
 * bit (integers only; tests/controllers/test_ball_follower.py compares them). */
#include <stdint.h>
#include <string.h>

#define EXPORT __attribute__((visibility("default")))

EXPORT int controller_vision_abi(void) { return 1; }

/* Twice the median (numpy's: the middle value, or the two middle ones' sum, of an even
 * count) of |p[r][c + 1] - p[r][c]| over rows 0, step, 2 step, ... of an h x w plane of
 * bytes whose pixel (r, c) is at p[r * row_stride + c * px_stride]; w >= 2, h >= 1.
 * out[0] = twice the median, out[1] = the number of differences. */
EXPORT void controller_diff_median(const uint8_t *p, int64_t h, int64_t w, int64_t row_stride,
                                   int64_t px_stride, int64_t step, int64_t *out)
{
    int64_t hist[256];
    memset(hist, 0, sizeof hist);
    int64_t n = 0;
    for (int64_t r = 0; r < h; r += step) {
        const uint8_t *row = p + r * row_stride;
        int prev = row[0];
        for (int64_t c = 1; c < w; c++) {
            int v = row[c * px_stride], d = v - prev;
            hist[d < 0 ? -d : d]++;
            prev = v;
        }
        n += w - 1;
    }
    /* the value at sorted position k: the first whose cumulative count exceeds k */
    int64_t hi = n / 2, lo = n % 2 ? hi : hi - 1, acc = 0, a = -1, b = -1;
    for (int v = 0; v < 256 && b < 0; v++) {
        acc += hist[v];
        if (a < 0 && acc > lo)
            a = v;
        if (acc > hi)
            b = v;
    }
    out[0] = a + b;
    out[1] = n;
}
