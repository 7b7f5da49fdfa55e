/* The plant's noise, counter-based: every number a pure function of its stream's key, the
 * tick and its index, so any number of rows is drawn in one call, in any order.
 *
 * Standard normals (plant_normals): row r's element i, for the row's key and tick:
 *   s = mix(key + mix(tick + GOLDEN))                      the row's seed
 *   a = mix(s + (2 j + 1) GOLDEN), b = mix(s + (2 j + 2) GOLDEN)  for the pair j = i / 2
 *   u1 = ((a >> 11) + 1) 2^-53 in (0, 1], u2 = (b >> 11) 2^-53 in [0, 1)
 *   element 2 j = sqrt(-2 log u1) cos(2 pi u2), element 2 j + 1 = sqrt(-2 log u1) sin(2 pi u2)
 * (Box and Muller 1958), with libm's log, sqrt, cos and sin: plant/noise.py's
 * normals_reference is the same arithmetic with Python's math module (which calls the same
 * libm), the bits the tests compare.
 *
 * Camera image noise (plant/noise.py calls it): out = clip(img + D, 0, 255) per channel,
 * D drawn from the law of rint(offset + N(0, std)) (tails lumped at -255 and 255, past
 * which every pixel clips alike) by Walker's alias method, one 64-bit number a channel.
 *
 * Why this gives the model's image: for a whole grey level x, rint(x + offset + n) =
 * x + rint(offset + n) except on ties (probability 0), so the noisy image is x plus an
 * integer whose law depends on the offset and the std only. plant/image_law.py builds
 * that law's alias table once per (std, offset).
 *
 * The numbers: SplitMix64 as a counter-based generator, the k-th number of a frame
 * mix(seed + (k + 1) * GOLDEN) (Steele, Lea and Flood 2014; the frame's seed is
 * plant/noise.py's frame_seed of the camera stream's key and the tick), each giving two
 * channels a 32-bit uniform. plant/image_law.py's image_noise_reference is this
 * arithmetic in numpy, the bytes the tests compare.
 */
#include <math.h>
#include <stdint.h>

#include "normals.h"

#define EXPORT __attribute__((visibility("default")))

EXPORT int plant_noise_abi(void) { return 2; }

/* out (k, n): row r's n normals for keys[r] and ticks[r * tick_stride] (tick_stride 0: one
 * tick for every row). */
EXPORT void plant_normals(int64_t k, const uint64_t *keys, const int64_t *ticks,
                          int64_t tick_stride, int64_t n, double *out)
{
    for (int64_t r = 0; r < k; r++)
        row_normals(row_seed(keys[r], (uint64_t)ticks[r * tick_stride]), n, out + r * n);
}

/* clip(y, 0, 255) for y = x + D in [-255, 510], by table */
static uint8_t sat[766];
static void fill_sat(void)
{
    for (int y = -255; y <= 510; y++)
        sat[y + 255] = (uint8_t)(y < 0 ? 0 : (y > 255 ? 255 : y));
}

/* D + 255 for the 32-bit uniform u: u k = j 2^32 + f picks column j, which gives its own
 * value (vals[2 j + 1]) when f < thr[j], else its alias (vals[2 j]). Each value's
 * probability is thus a whole number of u's 2^32 values. No branch: the comparison is
 * random. */
static inline uint8_t noisy(uint8_t x, uint32_t u, uint64_t k, const uint32_t *thr,
                            const uint16_t *vals)
{
    uint64_t uk = (uint64_t)u * k;
    uint32_t j = (uint32_t)(uk >> 32);
    return sat[x + vals[2 * j + ((uint32_t)uk < thr[j])]];
}

/* Element 2m takes the low half of the frame's m-th number, element 2m + 1 its high half. */
EXPORT void plant_image_noise(const uint8_t *img, int64_t n, uint64_t seed, int64_t k,
                              const uint32_t *thr, const uint16_t *vals, uint8_t *out)
{
    uint64_t s = seed;
    int64_t i = 0;
    if (sat[510] != 255)
        fill_sat();
    for (; i + 1 < n; i += 2) {
        s += GOLDEN;
        uint64_t r = mix(s);
        out[i] = noisy(img[i], (uint32_t)r, (uint64_t)k, thr, vals);
        out[i + 1] = noisy(img[i + 1], (uint32_t)(r >> 32), (uint64_t)k, thr, vals);
    }
    if (i < n)
        out[i] = noisy(img[i], (uint32_t)mix(s + GOLDEN), (uint64_t)k, thr, vals);
}
