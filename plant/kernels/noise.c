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
#include "wide.h"

#define EXPORT __attribute__((visibility("default")))

EXPORT int plant_noise_abi(void) { return 3; }

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

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define WIDE_NOISE 1
#include <immintrin.h>

/* -1: eight elements at a time where the processor has AVX2; 0: two, always (the tests
 * compare the two) */
static int wide_mode = -1;

#define AVX2 __attribute__((target("avx2")))

/* a * b's low 64 bits in four lanes, b given as its 32-bit halves (AVX2 multiplies 32 by
 * 32 bits only): a_lo b_lo + ((a_hi b_lo + a_lo b_hi) << 32) */
AVX2 static inline __m256i mul64(__m256i a, __m256i b_lo, __m256i b_hi)
{
    const __m256i cross = _mm256_add_epi64(_mm256_mul_epu32(_mm256_srli_epi64(a, 32), b_lo),
                                           _mm256_mul_epu32(a, b_hi));
    return _mm256_add_epi64(_mm256_mul_epu32(a, b_lo), _mm256_slli_epi64(cross, 32));
}

/* noisy()'s D + 255 of the 32-bit uniforms in the low halves of u's four lanes: the
 * column j = (u k) >> 32 read in one 64-bit load from tab (thr[j], then vals[2 j] and
 * vals[2 j + 1] as 16-bit fields at bits 32 and 48), its own value where f < thr[j] */
AVX2 static inline __m256i pick4(__m256i u, __m256i kv, const uint64_t *tab)
{
    const __m256i low32 = _mm256_set1_epi64x(0xFFFFFFFFLL);
    const __m256i uk = _mm256_mul_epu32(u, kv);
    const __m256i t = _mm256_i64gather_epi64((const long long *)tab, _mm256_srli_epi64(uk, 32), 8);
    const __m256i own = _mm256_cmpgt_epi64(_mm256_and_si256(t, low32), _mm256_and_si256(uk, low32));
    const __m256i shift = _mm256_blendv_epi8(_mm256_set1_epi64x(32), _mm256_set1_epi64x(48), own);
    return _mm256_and_si256(_mm256_srlv_epi64(t, shift), _mm256_set1_epi64x(0xFFFF));
}

/* plant_image_noise's elements 0 .. 8 m - 1 (m the most whole groups of eight in n), the
 * same numbers four of the frame's at a time: the lanes' low halves give the even
 * elements, their high halves the odd ones; clip(x + D, 0, 255) by 16-bit arithmetic and
 * an unsigned saturating pack. Returns the elements done. */
AVX2 static int64_t noise8(const uint8_t *img, int64_t n, uint64_t seed, int64_t k,
                           const uint32_t *thr, const uint16_t *vals, uint8_t *out)
{
    uint64_t tab[512];
    if (k > 512)                       /* (D takes at most 511 values: never) */
        return 0;
    for (int64_t j = 0; j < k; j++)
        tab[j] = thr[j] | (uint64_t)vals[2 * j] << 32 | (uint64_t)vals[2 * j + 1] << 48;
    const __m256i c1l = _mm256_set1_epi64x((int64_t)(0xBF58476D1CE4E5B9ULL & 0xFFFFFFFFULL));
    const __m256i c1h = _mm256_set1_epi64x((int64_t)(0xBF58476D1CE4E5B9ULL >> 32));
    const __m256i c2l = _mm256_set1_epi64x((int64_t)(0x94D049BB133111EBULL & 0xFFFFFFFFULL));
    const __m256i c2h = _mm256_set1_epi64x((int64_t)(0x94D049BB133111EBULL >> 32));
    const __m256i kv = _mm256_set1_epi64x(k);
    const __m256i step = _mm256_set1_epi64x((int64_t)(4 * GOLDEN));
    const __m128i off = _mm_set1_epi16(255);
    __m256i s = _mm256_set_epi64x((int64_t)(seed + 4 * GOLDEN), (int64_t)(seed + 3 * GOLDEN),
                                  (int64_t)(seed + 2 * GOLDEN), (int64_t)(seed + GOLDEN));
    int64_t i = 0;
    for (; i + 8 <= n; i += 8) {
        __m256i z = s;                 /* mix(), four numbers */
        s = _mm256_add_epi64(s, step);
        z = mul64(_mm256_xor_si256(z, _mm256_srli_epi64(z, 30)), c1l, c1h);
        z = mul64(_mm256_xor_si256(z, _mm256_srli_epi64(z, 27)), c2l, c2h);
        z = _mm256_xor_si256(z, _mm256_srli_epi64(z, 31));
        const __m256i even = pick4(z, kv, tab), odd = pick4(_mm256_srli_epi64(z, 32), kv, tab);
        /* (even, odd) pairs as 32-bit lanes in the elements' order, then 16-bit */
        const __m256i d32 = _mm256_or_si256(even, _mm256_slli_epi64(odd, 32));
        const __m128i d = _mm_packus_epi32(_mm256_castsi256_si128(d32),
                                           _mm256_extracti128_si256(d32, 1));
        const __m128i x = _mm_cvtepu8_epi16(_mm_loadl_epi64((const __m128i *)(img + i)));
        const __m128i y = _mm_sub_epi16(_mm_add_epi16(x, d), off);
        _mm_storel_epi64((__m128i *)(out + i), _mm_packus_epi16(y, y));
    }
    return i;
}
#endif

/* Set the eight-at-a-time mode of plant_image_noise (-1 or 0; other values leave it) and
 * say whether it is used: the same bytes either way. */
EXPORT int plant_noise_wide(int mode)
{
#ifdef WIDE_NOISE
    return wide_switch(&wide_mode, mode);
#else
    (void)mode;
    return 0;
#endif
}

/* Element 2m takes the low half of the frame's m-th number, element 2m + 1 its high half. */
EXPORT void plant_image_noise(const uint8_t *img, int64_t n, uint64_t seed, int64_t k,
                              const uint32_t *thr, const uint16_t *vals, uint8_t *out)
{
    uint64_t s = seed;
    int64_t i = 0;
    if (sat[510] != 255)
        fill_sat();
#ifdef WIDE_NOISE
    if (plant_noise_wide(1)) {         /* the first whole groups of eight, then the rest */
        i = noise8(img, n, seed, k, thr, vals, out);
        s = seed + (uint64_t)(i / 2) * GOLDEN;
    }
#endif
    for (; i + 1 < n; i += 2) {
        s += GOLDEN;
        uint64_t r = mix(s);
        out[i] = noisy(img[i], (uint32_t)r, (uint64_t)k, thr, vals);
        out[i + 1] = noisy(img[i + 1], (uint32_t)(r >> 32), (uint64_t)k, thr, vals);
    }
    if (i < n)
        out[i] = noisy(img[i], (uint32_t)mix(s + GOLDEN), (uint64_t)k, thr, vals);
}
