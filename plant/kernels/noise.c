/* Camera image noise (plant/noise.py calls it): out = clip(img + D, 0, 255) per channel,
 * D drawn from the law of rint(offset + N(0, std)) (tails lumped at -255 and 255, past
 * which every pixel clips alike) by Walker's alias method, one 64-bit number a channel.
 *
 * Why this gives the model's image: for a whole grey level x, rint(x + offset + n) =
 * x + rint(offset + n) except on ties (probability 0), so the noisy image is x plus an
 * integer whose law depends on the offset and the std only. plant/noise.py builds that
 * law's alias table once per (std, offset).
 *
 * The numbers: SplitMix64 as a counter-based generator, the k-th number of a frame
 * mix(seed + (k + 1) * GOLDEN) (Steele, Lea and Flood 2014; the seed is one draw from the
 * sensor's numpy stream per frame), each giving two channels a 32-bit uniform. plant/noise.py's
 * image_noise_reference is this arithmetic in numpy, the bytes the tests compare.
 */
#include <stdint.h>

#define EXPORT __attribute__((visibility("default")))
#define GOLDEN 0x9E3779B97F4A7C15ULL

EXPORT int plant_noise_abi(void) { return 1; }

static inline uint64_t mix(uint64_t z)
{
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
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
