/* The avoid controller's commands for a batch of robots sharing one lidar model, in one
 * call (controllers/avoid.py, Avoid.step_many): each row the arithmetic of Avoid.command,
 * the per-robot numpy step, to the bit. Its means and sums are numpy's pairwise sums
 * (pairwise.h), its comparisons, products and quotients the same IEEE operations in the
 * same order; the rays' factors (-sign, cos) come computed by numpy. */
#include <stdint.h>

#include "pairwise.h"

#define EXPORT __attribute__((visibility("default")))

EXPORT int controller_avoid_abi(void) { return 1; }

/* The mean of the values of r where mask is set (n of them, n > 0), as numpy's mean. */
static double masked_mean(const double *r, const uint8_t *mask, int64_t width, double *scratch)
{
    int64_t n = 0;
    for (int64_t j = 0; j < width; j++)
        if (mask[j])
            scratch[n++] = r[j];
    return (0.0 + pairwise(scratch, n)) / (double)n;
}

/* rows x n ranges (row-major, read as Avoid.step_many reads them: inf, NaN and returns
 * under rmin become rmax, in place); turning: each row's side, updated; rays: n bytes a
 * ray, bit 0 ahead, 1 left (angle > 0), 2 right (< 0), 3 within +-90 deg; t0, t1: each
 * ray's push factors; p: stop, slow, v_max, w_turn, rmin, rmax; has: whether any ray is
 * ahead, left, right; scratch: n doubles; v, w: the commands. */
EXPORT void controller_avoid_commands(int64_t rows, int64_t n, double *ranges, double *turning,
                                 const uint8_t *rays, const double *t0, const double *t1,
                                 const double *p, const int64_t *has, double *scratch,
                                 double *v, double *w)
{
    const double stop = p[0], slow = p[1], v_max = p[2], w_turn = p[3];
    const double rmin = p[4], rmax = p[5];
    const double stop_slack = stop * 1.3, span = slow - stop;  /* (as Python computes them) */
    uint8_t left_mask[n > 0 ? n : 1], right_mask[n > 0 ? n : 1];
    for (int64_t j = 0; j < n; j++) {
        left_mask[j] = (rays[j] >> 1) & 1;
        right_mask[j] = (rays[j] >> 2) & 1;
    }
    for (int64_t i = 0; i < rows; i++) {
        double *r = ranges + i * n;
        for (int64_t j = 0; j < n; j++) {          /* np.fmin(r, rmax); r[r < rmin] = rmax */
            double x = r[j];
            x = (x != x || x > rmax) ? rmax : x;
            r[j] = x < rmin ? rmax : x;
        }
        double front = 0.0;
        int first = 1;
        for (int64_t j = 0; j < n; j++)
            if (!has[0] || (rays[j] & 1)) {
                if (first || r[j] < front)
                    front = r[j];
                first = 0;
            }
        double turn = turning[i];
        int blocked = front < stop || (turn != 0.0 && front < stop_slack);
        if (blocked && turn == 0.0) {
            double left = has[1] ? masked_mean(r, left_mask, n, scratch) : 0.0;
            double right = has[2] ? masked_mean(r, right_mask, n, scratch) : 0.0;
            turn = left >= right ? 1.0 : -1.0;
        }
        turning[i] = blocked ? turn : 0.0;
        if (blocked) {
            v[i] = 0.0;
            w[i] = turn * w_turn;
            continue;
        }
        double q = (front - stop) / span;
        v[i] = v_max * (q < 1.0 ? q : 1.0);
        int64_t k = 0;                                 /* the near returns' pushes, in order */
        for (int64_t j = 0; j < n; j++)
            if ((rays[j] & 8) && r[j] < slow)
                scratch[k++] = t0[j] * (slow - r[j]) / slow * t1[j];
        double push = 1.5 * (0.0 + pairwise(scratch, k));
        w[i] = push < -w_turn ? -w_turn : (push > w_turn ? w_turn : push);
    }
}
