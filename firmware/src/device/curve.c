/* Curve mode (curve.h): the keyframe buffer, the player, and the Hermite segment evaluated
 * exactly in 128-bit integers built from 32-bit operations (the Cortex-M0+ multiplies
 * 32 x 32 -> 32 bits, has no wider type, and GCC's 64-bit code there is slow).
 *
 * The exact value of a segment at e microseconds is numerator(e) / den, with
 *   numerator(e) = 1024 (d^3 p0 + (p1 - p0) e^2 (3d - 2e)) + D e (d - e) (m0 (d - e) - m1 e)
 *   den = 1024 d^3,  d = 1000 D  (hermite.hermite_position),
 * rounded to the nearest count, ties away from zero: with numerator + den/2 =
 * quotient * den + remainder (0 <= remainder < den) the value is the quotient, less one when
 * the remainder is 0 and the quotient is not positive (a tie, or an exact value, below 0).
 *
 * One evaluation (segment_evaluate) costs about 2000 cycles on the chip, too many for every
 * tick, so the player steps instead. As a polynomial in e,
 *   numerator(e) = c0 + c1 e + c2 e^2 + c3 e^3,  c0 = 1024 d^3 p0,  c1 = D m0 d^2,
 *   c2 = d (3072 (p1 - p0) - D (2 m0 + m1)),  c3 = D (m0 + m1) - 2048 (p1 - p0),
 * and the ticks of a segment advance e by the period h, so the player keeps numerator +
 * den/2 and its three forward differences, each as a quotient and a remainder by den: a
 * tick adds each difference to the one before, remainder to remainder (one carry), exactly
 * (curve_step); with den below 2^64 (segments up to 262 ms) the remainders take two words.
 * core0 prepares each keyframe's segment from the keyframe appended before it when it
 * appends it (curve_prepare_keyframe, outside the servo lock), and the tick that reaches
 * the keyframe before exactly (its value is p1) adopts those differences when the segment
 * starts where they were prepared for. A segment started unprepared (a curve's tick 0,
 * whose value is p0, or one that starts elsewhere: a curve interrupted and started again)
 * is prepared over its first ticks (curve_prepare_start, curve_warm_step), each finding
 * its value with what it needs. So no tick pays for a whole preparation. Elsewhere (a
 * keyframe reached between ticks, periods of 512 us and more, a step of 2^32 counts) the
 * player evaluates exactly and prepares from there. The tests compare every tick with the
 * Python's.
 *
 * Ranges: |p| < 2^31, |m| <= 2^15, D < 2^16, e <= d < 2^26, h <= 10^6 < 2^20. Then
 * |numerator| < 2^121 (|d^3 p0| < 2^109, |(p1 - p0) e^2 (3d - 2e)| <= 2^32 d^3 < 2^110, the
 * tangent term < 2^16 2^50 2^41 = 2^107), den < 2^88, |c1| < 2^83, |c2| < 2^72,
 * |c3| < 2^45, and every difference is below 2^123: all fit 128-bit two's complement. */
#include "curve.h"

#define WORDS 4

/* --- 128-bit integers as little-endian 32-bit words ------------------------------------ */

static inline uint32_t mul_32x32(uint32_t a, uint32_t b, uint32_t *hi) {
    return sci_mul_32x32(a, b, hi);
}

static inline void words_copy(uint32_t *out, const uint32_t *a) {
    uint32_t a0 = a[0], a1 = a[1], a2 = a[2], a3 = a[3];
    out[0] = a0;
    out[1] = a1;
    out[2] = a2;
    out[3] = a3;
}

/* out[0..n] = a[0..n-1] * b (n + 1 words); out may be a. */
static inline void words_mul(uint32_t *out, const uint32_t *a, unsigned n, uint32_t b) {
    uint32_t carry = 0;
    if (b < 0x10000u) {
        for (unsigned i = 0; i < n; i++) {
            uint32_t low = (a[i] & 0xffffu) * b;
            uint32_t middle = (a[i] >> 16) * b;
            uint32_t sum = low + (middle << 16);
            uint32_t high = (middle >> 16) + (sum < low);
            uint32_t total = sum + carry;
            out[i] = total;
            carry = high + (total < sum);
        }
    } else {
        for (unsigned i = 0; i < n; i++) {
            uint32_t high;
            uint32_t low = mul_32x32(a[i], b, &high);
            uint32_t total = low + carry;
            out[i] = total;
            carry = high + (total < low);
        }
    }
    out[n] = carry;
}

/* a *= b modulo 2^128 (two's complement: a signed a times an unsigned b). */
static inline void words_scale(uint32_t *a, uint32_t b) {
    uint32_t product[WORDS + 1];
    words_mul(product, a, WORDS, b);
    words_copy(a, product);
}

/* out = a + b modulo 2^128; out may be a or b. (The 4-word helpers are written out: GCC
 * turns loops over words into calls of memcpy.) */
static inline void words_add(uint32_t *out, const uint32_t *a, const uint32_t *b) {
    uint32_t x0 = a[0] + b[0];
    uint32_t c0 = x0 < b[0];
    uint32_t t1 = a[1] + c0;
    uint32_t x1 = t1 + b[1];
    uint32_t c1 = (t1 < c0) + (x1 < t1);
    uint32_t t2 = a[2] + c1;
    uint32_t x2 = t2 + b[2];
    uint32_t c2 = (t2 < c1) + (x2 < t2);
    out[3] = a[3] + c2 + b[3];
    out[2] = x2;
    out[1] = x1;
    out[0] = x0;
}

/* out = a - b modulo 2^128; out may be a or b. */
static inline void words_sub(uint32_t *out, const uint32_t *a, const uint32_t *b) {
    uint32_t x0 = a[0] - b[0];
    uint32_t w0 = a[0] < b[0];
    uint32_t y1 = b[1] + w0;
    uint32_t x1 = a[1] - y1;
    uint32_t w1 = (y1 < w0) | (a[1] < y1);
    uint32_t y2 = b[2] + w1;
    uint32_t x2 = a[2] - y2;
    uint32_t w2 = (y2 < w1) | (a[2] < y2);
    out[3] = a[3] - b[3] - w2;
    out[2] = x2;
    out[1] = x1;
    out[0] = x0;
}

static inline void words_negate(uint32_t *a) {
    const uint32_t zero[WORDS] = {0, 0, 0, 0};
    words_sub(a, zero, a);
}

static inline bool words_negative(const uint32_t *a) {
    return (a[WORDS - 1] >> 31) != 0;
}

static inline bool words_zero(const uint32_t *a) {
    return (a[0] | a[1] | a[2] | a[3]) == 0;
}

/* a < b, unsigned */
static inline bool words_less(const uint32_t *a, const uint32_t *b) {
    if (a[3] != b[3]) {
        return a[3] < b[3];
    }
    if (a[2] != b[2]) {
        return a[2] < b[2];
    }
    if (a[1] != b[1]) {
        return a[1] < b[1];
    }
    return a[0] < b[0];
}

/* out = value (sign-extended) */
static inline void words_from_int64(uint32_t *out, int64_t value) {
    uint64_t bits = (uint64_t)value;
    out[0] = (uint32_t)bits;
    out[1] = (uint32_t)(bits >> 32);
    out[2] = out[3] = value < 0 ? 0xffffffffu : 0u;
}

/* a << bits for 0 < bits < 32 */
static inline void words_shift_left(uint32_t *out, const uint32_t *a, unsigned bits) {
    uint32_t back = 32u - bits;
    uint32_t a0 = a[0], a1 = a[1], a2 = a[2], a3 = a[3];
    out[3] = (a3 << bits) | (a2 >> back);
    out[2] = (a2 << bits) | (a1 >> back);
    out[1] = (a1 << bits) | (a0 >> back);
    out[0] = a0 << bits;
}

/* a >> 1 */
static inline void words_half(uint32_t *out, const uint32_t *a) {
    uint32_t a0 = a[0], a1 = a[1], a2 = a[2], a3 = a[3];
    out[0] = (a0 >> 1) | (a1 << 31);
    out[1] = (a1 >> 1) | (a2 << 31);
    out[2] = (a2 >> 1) | (a3 << 31);
    out[3] = a3 >> 1;
}

static inline unsigned bit_length_32(uint32_t x) {
    unsigned bits = 0;
    if (x >= 1u << 16) {
        x >>= 16;
        bits += 16;
    }
    if (x >= 1u << 8) {
        x >>= 8;
        bits += 8;
    }
    if (x >= 1u << 4) {
        x >>= 4;
        bits += 4;
    }
    if (x >= 1u << 2) {
        x >>= 2;
        bits += 2;
    }
    if (x >= 1u << 1) {
        x >>= 1;
        bits += 1;
    }
    return bits + x;
}

/* Bits [shift, shift + 32) of a, for shift < 96. */
static inline uint32_t words_bits32(const uint32_t *a, unsigned shift) {
    unsigned word = shift / 32u;
    unsigned bit = shift % 32u;
    if (bit == 0) {
        return a[word];
    }
    uint32_t next = word + 1 < WORDS ? a[word + 1] : 0u;
    return (a[word] >> bit) | (next << (32u - bit));
}

/* (floor(n / d), n mod d) for d >= 2^40 (below 2^96) and n < 2^32 * d: one 64-by-32-bit
 * division of the operands shifted so that the divisor keeps 31 bits, then an exact
 * correction. With s the shift, D = d >> s in [2^30, 2^31) and N = n >> s < 2^63:
 * N / (D + 1) < n / d, and N / (D + 1) > (n - 2^s) / (d + 2^s) - 1 >= n / d - 6 (as
 * 2^s <= d * 2^-30 and n / d < 2^32), so at most 6 corrections. */
static uint32_t words_divide(const uint32_t *n, const uint32_t *d, uint32_t *rest) {
    unsigned top = d[2] ? 2u : 1u;
    unsigned shift = top * 32u + bit_length_32(d[top]) - 31u;
    uint64_t n_high = ((uint64_t)words_bits32(n, shift + 32u) << 32) | words_bits32(n, shift);
    uint32_t q = (uint32_t)(n_high / (words_bits32(d, shift) + 1u));
    uint32_t product[WORDS + 1];
    words_mul(product, d, 3, q);
    words_sub(rest, n, product);
    while (!words_less(rest, d)) {
        words_sub(rest, rest, d);
        q++;
    }
    return q;
}

/* --- one segment -------------------------------------------------------------------------- */

typedef struct {
    int32_t p0, p1, m0, m1;
    uint32_t duration_ms;
} segment_t;

/* den = 1024 d^3 */
static void segment_den(uint32_t d, uint32_t *den) {
    uint32_t cube[WORDS + 1];
    cube[0] = mul_32x32(d, d, &cube[1]);   /* d^2 < 2^52 */
    words_mul(cube, cube, 2, d);            /* d^3 < 2^78 */
    cube[3] = 0;
    words_shift_left(den, cube, 10);
}

/* The numerator at e (0 < e < d) as a magnitude and a sign, from the formula's terms. */
static bool segment_numerator(const segment_t *s, uint32_t e, uint32_t *magnitude) {
    uint32_t d = s->duration_ms * 1000u;
    uint32_t rest = d - e;
    uint32_t cube[WORDS + 1];
    cube[0] = mul_32x32(d, d, &cube[1]);
    words_mul(cube, cube, 2, d);
    cube[3] = 0;
    uint32_t position[WORDS + 1];
    words_mul(position, cube, 3, s->p0 < 0 ? 0u - (uint32_t)s->p0 : (uint32_t)s->p0);
    if (s->p0 < 0) {
        words_negate(position);
    }
    uint32_t dp = (uint32_t)s->p1 - (uint32_t)s->p0;   /* modulo 2^32 */
    bool dp_negative = s->p1 < s->p0;
    uint32_t blend[WORDS + 1];
    blend[0] = mul_32x32(e, e, &blend[1]);
    words_mul(blend, blend, 2, 3u * d - 2u * e);   /* e^2 (3d - 2e) <= d^3 < 2^78 */
    words_mul(blend, blend, 3, dp_negative ? 0u - dp : dp);
    if (dp_negative) {
        words_negate(blend);
    }
    words_add(position, position, blend);
    uint32_t numerator[WORDS];
    words_shift_left(numerator, position, 10);
    /* D e rest (m0 rest - m1 e): m0 rest - m1 e below 2^41, times D below 2^57 */
    int64_t slopes = (int64_t)s->m0 * rest - (int64_t)s->m1 * e;
    uint64_t slopes_magnitude = (uint64_t)(slopes < 0 ? -slopes : slopes);
    uint32_t scaled[WORDS + 1] = {(uint32_t)slopes_magnitude, (uint32_t)(slopes_magnitude >> 32),
                                  0, 0, 0};
    words_mul(scaled, scaled, 2, s->duration_ms);
    uint32_t span[WORDS + 1];
    span[0] = mul_32x32(e, rest, &span[1]);   /* < 2^50 */
    uint32_t tangents[WORDS + 1];
    words_mul(tangents, span, 2, scaled[0]);
    uint32_t high[WORDS + 1];
    high[0] = 0;
    words_mul(&high[1], span, 2, scaled[1]);   /* times 2^32 */
    tangents[3] = 0;
    words_add(tangents, tangents, high);
    if (slopes < 0) {
        words_negate(tangents);
    }
    words_add(numerator, numerator, tangents);
    bool negative = words_negative(numerator);
    if (negative) {
        words_negate(numerator);
    }
    words_copy(magnitude, numerator);
    return negative;
}

/* The rounded value at e (0 < e < d) from one exact evaluation, with the quotient and
 * remainder of numerator + den / 2 by den that the player steps from. */
static int64_t segment_evaluate(const segment_t *s, uint32_t e, const uint32_t *den,
                                int64_t *quotient, uint32_t *remainder) {
    uint32_t n[WORDS];
    bool negative = segment_numerator(s, e, n);
    uint32_t half[WORDS];
    words_half(half, den);
    words_add(n, n, half);   /* |n| + den / 2 */
    /* _round_half_away: q = (2|n| + den) // (2 den), with the sign of n */
    uint32_t rest[WORDS];
    uint32_t q = words_divide(n, den, rest);
    if (!negative) {
        *quotient = q;
        words_copy(remainder, rest);
        return q;
    }
    /* n + den/2 = den - (|n| + den/2) = (1 - q) den - rest */
    if (words_zero(rest)) {
        *quotient = 1 - (int64_t)q;
        words_copy(remainder, rest);
    } else {
        *quotient = -(int64_t)q;
        words_sub(remainder, den, rest);
    }
    return -(int64_t)q;
}

int64_t curve_hermite_position(int32_t p0, int32_t p1, int32_t m0, int32_t m1,
                               uint32_t duration_ms, uint32_t elapsed_us) {
    uint32_t d = duration_ms * 1000u;
    if (elapsed_us == 0) {
        return p0;   /* the formula's exact value at the ends */
    }
    if (elapsed_us == d) {
        return p1;
    }
    segment_t s = {p0, p1, m0, m1, duration_ms};
    uint32_t den[WORDS];
    segment_den(d, den);
    int64_t quotient;
    uint32_t remainder[WORDS];
    return segment_evaluate(&s, elapsed_us, den, &quotient, remainder);
}

/* out (4 words) = a (2 words) * b (2 words) */
static inline void words_mul_2x2(uint32_t *out, const uint32_t *a, const uint32_t *b) {
    uint32_t low[WORDS + 1];
    words_mul(low, a, 2, b[0]);
    low[3] = 0;
    uint32_t high[WORDS + 1];
    high[0] = 0;
    words_mul(&high[1], a, 2, b[1]);
    words_add(out, low, high);
}

static inline void words_from_magnitude64(uint32_t *out, uint64_t magnitude) {
    out[0] = (uint32_t)magnitude;
    out[1] = (uint32_t)(magnitude >> 32);
}

/* The numerator's polynomial coefficients (servo.h). */
typedef curve_coefficients_t coefficients_t;

/* D * x for |x| < 2^31, in 32-bit multiplies (a 64-bit multiply is a call on the M0+). */
static inline int64_t times_duration(uint32_t duration_ms, int32_t x) {
    uint32_t high;
    uint32_t low = mul_32x32(duration_ms, x < 0 ? 0u - (uint32_t)x : (uint32_t)x, &high);
    int64_t product = (int64_t)(((uint64_t)high << 32) | low);
    return x < 0 ? -product : product;
}

static int64_t segment_k2(const segment_t *s) {
    int64_t dp = (int64_t)s->p1 - s->p0;
    return (int64_t)((uint64_t)dp * 3072u) - times_duration(s->duration_ms, 2 * s->m0 + s->m1);
}

static int64_t segment_c3(const segment_t *s) {
    int64_t dp = (int64_t)s->p1 - s->p0;
    return times_duration(s->duration_ms, s->m0 + s->m1) - (int64_t)((uint64_t)dp * 2048u);
}

/* The coefficients in two halves (two phases of a warming segment's first tick): k2's and
 * m0's, then c3 and d's. */
static inline void coefficients_k2(const segment_t *s, coefficients_t *c) {
    int64_t k2 = segment_k2(s);
    c->m0 = s->m0;
    c->dm0 = s->duration_ms * (uint32_t)(s->m0 < 0 ? -s->m0 : s->m0);
    c->m0_negative = s->m0 < 0;
    c->k2_magnitude = (uint64_t)(k2 < 0 ? -k2 : k2);
    c->k2_negative = k2 < 0;
}

static inline void coefficients_c3(const segment_t *s, coefficients_t *c) {
    c->d = s->duration_ms * 1000u;
    c->d2[0] = mul_32x32(c->d, c->d, &c->d2[1]);
    c->c3 = segment_c3(s);
}

static void segment_coefficients(const segment_t *s, coefficients_t *c) {
    coefficients_k2(s, c);
    coefficients_c3(s, c);
}

/* The forward differences of the numerator at e0 = 0 for steps of h < 2^16: with
 * a_k = c_k h^k, delta1 = a1 + a2 + a3, delta2 = 2 a2 + 6 a3, delta3 = 6 a3. */
static void differences_at_start(const coefficients_t *c, uint32_t h, uint32_t delta[3][WORDS]) {
    uint32_t h2 = h * h;
    uint32_t factor[2];
    /* a1 = d^2 (D |m0| h), the factor below 2^47 */
    factor[0] = mul_32x32(c->dm0, h, &factor[1]);
    uint32_t a1[WORDS];
    words_mul_2x2(a1, c->d2, factor);
    if (c->m0_negative) {
        words_negate(a1);
    }
    /* a2 = d (|k2| h^2): below 2^45 * 2^32 * 2^26 */
    uint32_t k2[2];
    words_from_magnitude64(k2, c->k2_magnitude);
    uint32_t a2[WORDS + 1];
    words_mul(a2, k2, 2, h2);
    words_mul(a2, a2, 3, c->d);
    if (c->k2_negative) {
        words_negate(a2);
    }
    /* a3 = |c3| h^3 */
    uint32_t c3[2];
    words_from_magnitude64(c3, (uint64_t)(c->c3 < 0 ? -c->c3 : c->c3));
    uint32_t h3[2];
    h3[0] = mul_32x32(h2, h, &h3[1]);
    uint32_t a3[WORDS];
    words_mul_2x2(a3, c3, h3);
    if (c->c3 < 0) {
        words_negate(a3);
    }
    uint32_t twice[WORDS];
    words_add(twice, a3, a3);
    words_add(delta[2], twice, twice);
    words_add(delta[2], delta[2], twice);   /* 6 a3 */
    words_add(delta[1], a2, a2);
    words_add(delta[1], delta[1], delta[2]);
    words_add(delta[0], a1, a2);
    words_add(delta[0], delta[0], a3);
}

/* The forward differences at e0 for steps of h (the general case, off the common path):
 * the polynomial shifted to e0 (c2' = c2 + 3 c3 e0, c1' = c1 + e0 (c2 + c2')) and, with
 * u = c3 h, delta1 = h (c1' + h (c2' + u)), delta2 = 2 h^2 (c2' + 3u), delta3 = 6 u h^2. */
static void differences_at(const coefficients_t *c, uint32_t e0, uint32_t h,
                           uint32_t delta[3][WORDS]) {
    uint32_t c1[WORDS + 1];
    words_mul(c1, c->d2, 2, c->dm0);
    c1[3] = 0;
    if (c->m0_negative) {
        words_negate(c1);
    }
    uint32_t k2[2];
    words_from_magnitude64(k2, c->k2_magnitude);
    uint32_t c2[WORDS + 1];
    words_mul(c2, k2, 2, c->d);
    c2[3] = 0;
    if (c->k2_negative) {
        words_negate(c2);
    }
    uint32_t c3[WORDS];
    words_from_int64(c3, c->c3);
    uint32_t t[WORDS];
    words_copy(t, c3);
    words_scale(t, 3u * e0);          /* 3 c3 e0 */
    uint32_t c2_shifted[WORDS];
    words_add(c2_shifted, c2, t);
    words_add(t, c2, c2_shifted);     /* c2 + c2' */
    words_scale(t, e0);
    words_add(c1, c1, t);
    words_copy(c2, c2_shifted);
    uint32_t u[WORDS];
    words_copy(u, c3);
    words_scale(u, h);
    words_add(t, c2, u);
    words_scale(t, h);
    words_add(t, t, c1);
    words_scale(t, h);
    words_copy(delta[0], t);
    words_copy(t, u);
    words_scale(t, h);
    words_scale(t, 6u * h);
    words_copy(delta[2], t);
    words_copy(t, u);
    words_scale(t, 3u);
    words_add(t, t, c2);
    words_scale(t, h);
    words_scale(t, 2u * h);
    words_copy(delta[1], t);
}

/* Whole dens taken off (or added) one at a time before a division: differences of a curve
 * moving this many counts a tick or fewer need none. */
#define FLOOR_SUBTRACTIONS 3u

/* (floor(x / den), x mod den) for a signed x; false when the quotient is 2^32 or more in
 * magnitude. */
static bool words_floor_divide(const uint32_t *x, const uint32_t *den, int64_t *quotient,
                               uint32_t *remainder) {
    uint32_t t[WORDS];
    words_copy(t, x);
    int64_t q = 0;
    uint32_t limit[WORDS] = {0, den[0], den[1], den[2]};   /* den * 2^32 */
    if (!words_negative(t)) {
        for (unsigned i = 0; i < FLOOR_SUBTRACTIONS && !words_less(t, den); i++) {
            words_sub(t, t, den);
            q++;
        }
        if (!words_less(t, den)) {
            if (!words_less(t, limit)) {
                return false;
            }
            uint32_t rest[WORDS];
            q += words_divide(t, den, rest);
            words_copy(t, rest);
        }
    } else {
        for (unsigned i = 0; i < FLOOR_SUBTRACTIONS && words_negative(t); i++) {
            words_add(t, t, den);
            q--;
        }
        if (words_negative(t)) {
            words_negate(t);   /* the magnitude below zero */
            if (!words_less(t, limit)) {
                return false;
            }
            uint32_t rest[WORDS];
            uint32_t k = words_divide(t, den, rest);
            if (words_zero(rest)) {
                q -= k;
                words_copy(t, rest);
            } else {
                q -= (int64_t)k + 1;
                words_sub(t, den, rest);
            }
        }
    }
    *quotient = q;
    words_copy(remainder, t);
    return true;
}

/* (qa den + ra) + (qb den + rb) as quotient (returned) and remainder, for remainders below
 * den; r may be ra or rb. As den < 2^88, a remainder's top word is 0 and a sum of two fits
 * three words: the addition and the comparison take three. */
static inline int64_t qr_add3(int64_t qa, const uint32_t *ra, int64_t qb, const uint32_t *rb,
                              const uint32_t *den, uint32_t *r) {
    uint32_t x0 = ra[0] + rb[0];
    uint32_t c0 = x0 < rb[0];
    uint32_t t1 = ra[1] + c0;
    uint32_t x1 = t1 + rb[1];
    uint32_t c1 = (t1 < c0) + (x1 < t1);
    uint32_t x2 = ra[2] + rb[2] + c1;
    int64_t q = qa + qb;
    /* x >= den ? */
    bool over = x2 != den[2] ? x2 > den[2] : x1 != den[1] ? x1 > den[1] : x0 >= den[0];
    if (over) {
        uint32_t w0 = x0 < den[0];
        uint32_t y1 = den[1] + w0;
        uint32_t w1 = (y1 < w0) | (x1 < y1);
        x2 = x2 - den[2] - w1;
        x1 = x1 - y1;
        x0 = x0 - den[0];
        q++;
    }
    r[0] = x0;
    r[1] = x1;
    r[2] = x2;
    r[3] = 0;
    return q;
}

static inline uint64_t words_u64(const uint32_t *a) {
    return ((uint64_t)a[1] << 32) | a[0];
}

/* qr_add3 for den < 2^64 (den = 1024 d^3 with d < 2^18: a segment of up to 262 ms): the
 * remainders' third words are 0, and a + b >= den exactly when a >= den - b (b < den: no
 * borrow), which needs no carry out of 64 bits. Their fourth words stay 0. */
static inline int64_t qr_add2(int64_t qa, const uint32_t *ra, int64_t qb, const uint32_t *rb,
                              const uint32_t *den, uint32_t *r) {
    uint64_t a = words_u64(ra);
    uint64_t b = words_u64(rb);
    uint64_t room = words_u64(den) - b;
    int64_t q = qa + qb;
    if (a >= room) {
        a -= room;
        q++;
    } else {
        a += b;
    }
    r[0] = (uint32_t)a;
    r[1] = (uint32_t)(a >> 32);
    r[2] = 0;
    return q;
}

/* qr_add3, in two words when den allows it. */
static inline int64_t qr_add(int64_t qa, const uint32_t *ra, int64_t qb, const uint32_t *rb,
                             const uint32_t *den, uint32_t *r) {
    if (den[2] == 0u) {
        return qr_add2(qa, ra, qb, rb, den, r);
    }
    return qr_add3(qa, ra, qb, rb, den, r);
}

/* floor and modulo of a signed int64 by a positive divisor */
static inline int64_t floor_divide64(int64_t x, int64_t divisor, int64_t *rest) {
    int64_t q = x / divisor;
    int64_t r = x - q * divisor;
    if (r < 0) {
        r += divisor;
        q--;
    }
    *rest = r;
    return q;
}

/* The exact preparation of the differences at e0 = 0 as quotients and remainders by den
 * (entries 1 to 3 of quotient and remainder), for h < 2^9 (the periods of 10 kHz to 2 kHz),
 * from a_k = c_k h^k without dividing 128-bit numbers:
 *   a1 / den = m0 h / 1024000 (as d = 1000 D), so a1 = q1 den + r1 D d^2;
 *   a2 / den = k2 h^2 / (1024 d^2), so a2 = q2 den + r2 d;
 *   a3 = c3 h^3 (below 2^71) divided by den;
 * then delta1 = a1 + a2 + a3, delta2 = 2 a2 + 6 a3, delta3 = 6 a3. In phases, each one
 * 128-bit addition or product or so, about 150 cycles: a segment started unprepared runs
 * them over its first ticks (curve_warm_step), so that no tick of it costs much more than
 * another. */

/* The arguments every phase takes: the coefficients (set by the first two phases), den
 * (set by the third), the slots, and a scratch slot. */
typedef struct {
    const segment_t *s;
    coefficients_t *c;
    uint32_t h;
    uint32_t *den;
    int64_t *quotient;
    uint32_t (*remainder)[WORDS];
    int64_t *scratch_quotient;
    uint32_t *scratch;
} phase_t;

/* A phase is inlined where it runs. */
#define PHASE static inline __attribute__((always_inline))

PHASE void phase_coefficients(const phase_t *p) {
    coefficients_k2(p->s, p->c);
}

PHASE void phase_c3(const phase_t *p) {
    coefficients_c3(p->s, p->c);
}

/* slot 1 = a1: the quotient, and the remainder's factor r1 D (in the scratch) */
PHASE void phase_a1(const phase_t *p) {
    const coefficients_t *c = p->c;
    if (c->m0 == 0) {   /* a curve's first segment */
        p->quotient[1] = 0;
        words_from_int64(p->remainder[1], 0);
        return;
    }
    int32_t x1 = c->m0 * (int32_t)p->h;   /* |m0 h| < 2^24 */
    int32_t q1 = x1 / 1024000;
    int32_t r1 = x1 - q1 * 1024000;
    if (r1 < 0) {
        r1 += 1024000;
        q1--;
    }
    p->quotient[1] = q1;
    uint32_t *factor = p->scratch;
    factor[0] = mul_32x32((uint32_t)r1, p->s->duration_ms, &factor[1]);   /* r1 D < 2^36 */
}

/* ... the remainder: the factor times the low word of d^2 */
PHASE void phase_a1_low(const phase_t *p) {
    if (p->c->m0 == 0) {
        return;
    }
    uint32_t low[WORDS + 1];
    words_mul(low, p->scratch, 2, p->c->d2[0]);
    low[3] = 0;
    words_copy(p->remainder[1], low);
}

/* ... plus the factor times the high word of d^2, a word up */
PHASE void phase_a1_high(const phase_t *p) {
    if (p->c->m0 == 0) {
        return;
    }
    uint32_t high[WORDS + 1];
    high[0] = 0;
    words_mul(&high[1], p->scratch, 2, p->c->d2[1]);
    words_add(p->remainder[1], p->remainder[1], high);
}

/* slot 2 = a2 */
PHASE void phase_a2(const phase_t *p) {
    const coefficients_t *c = p->c;
    int64_t k2 = c->k2_negative ? -(int64_t)c->k2_magnitude : (int64_t)c->k2_magnitude;
    uint64_t d2 = ((uint64_t)c->d2[1] << 32) | c->d2[0];
    /* |k2| < 2^45 and h^2 < 2^18; 1024 d^2 < 2^62 */
    int64_t x2 = (int64_t)((uint64_t)k2 * (p->h * p->h));
    int64_t divisor = (int64_t)(d2 << 10);
    int64_t rest;
    if (x2 >= 0 && x2 < divisor) {   /* the usual case: below one count a tick^2 */
        p->quotient[2] = 0;
        rest = x2;
    } else if (x2 < 0 && x2 >= -divisor) {
        p->quotient[2] = -1;
        rest = x2 + divisor;
    } else {
        p->quotient[2] = floor_divide64(x2, divisor, &rest);
    }
    uint32_t rest_words[2] = {(uint32_t)rest, (uint32_t)((uint64_t)rest >> 32)};
    uint32_t r2[WORDS + 1];
    words_mul(r2, rest_words, 2, c->d);
    r2[3] = 0;
    words_copy(p->remainder[2], r2);
}

/* slot 3 = a3 = c3 h^3 (below 2^71), not yet divided */
PHASE void phase_a3(const phase_t *p) {
    const coefficients_t *c = p->c;
    uint64_t c3_magnitude = (uint64_t)(c->c3 < 0 ? -c->c3 : c->c3);
    uint32_t c3_words[2] = {(uint32_t)c3_magnitude, (uint32_t)(c3_magnitude >> 32)};
    uint32_t a3[WORDS + 1];
    words_mul(a3, c3_words, 2, p->h * p->h * p->h);   /* h^3 < 2^27 */
    a3[3] = 0;
    if (c->c3 < 0) {
        words_negate(a3);
    }
    words_copy(p->remainder[3], a3);
}

/* slot 3 divided by den: a quotient below 2^31 */
PHASE void phase_a3_divide(const phase_t *p) {
    uint32_t a3[WORDS];
    words_copy(a3, p->remainder[3]);
    /* the usual cases: the cubic term is within one count a tick */
    if (!words_negative(a3)) {
        if (words_less(a3, p->den)) {
            p->quotient[3] = 0;
            return;
        }
    } else {
        uint32_t above[WORDS];
        words_add(above, a3, p->den);
        if (!words_negative(above)) {
            p->quotient[3] = -1;
            words_copy(p->remainder[3], above);
            return;
        }
    }
    (void)words_floor_divide(a3, p->den, &p->quotient[3], p->remainder[3]);
}

/* slot 1 = a1 + a2 */
PHASE void phase_a1_plus_a2(const phase_t *p) {
    p->quotient[1] = qr_add(p->quotient[1], p->remainder[1], p->quotient[2], p->remainder[2],
                            p->den, p->remainder[1]);
}

/* slot 1 = a1 + a2 + a3: delta1 */
PHASE void phase_delta1(const phase_t *p) {
    p->quotient[1] = qr_add(p->quotient[1], p->remainder[1], p->quotient[3], p->remainder[3],
                            p->den, p->remainder[1]);
}

/* scratch = 2 a3 */
PHASE void phase_two_a3(const phase_t *p) {
    *p->scratch_quotient = qr_add(p->quotient[3], p->remainder[3], p->quotient[3],
                                  p->remainder[3], p->den, p->scratch);
}

/* slot 3 = 4 a3 */
PHASE void phase_four_a3(const phase_t *p) {
    p->quotient[3] = qr_add(*p->scratch_quotient, p->scratch, *p->scratch_quotient, p->scratch,
                            p->den, p->remainder[3]);
}

/* slot 3 = 6 a3: delta3 */
PHASE void phase_delta3(const phase_t *p) {
    p->quotient[3] = qr_add(p->quotient[3], p->remainder[3], *p->scratch_quotient, p->scratch,
                            p->den, p->remainder[3]);
}

/* slot 2 = 2 a2 */
PHASE void phase_two_a2(const phase_t *p) {
    p->quotient[2] = qr_add(p->quotient[2], p->remainder[2], p->quotient[2], p->remainder[2],
                            p->den, p->remainder[2]);
}

/* slot 2 = 2 a2 + 6 a3: delta2 */
PHASE void phase_delta2(const phase_t *p) {
    p->quotient[2] = qr_add(p->quotient[2], p->remainder[2], p->quotient[3], p->remainder[3],
                            p->den, p->remainder[2]);
}

/* The phases after a1's up to delta1, and those after delta1 (a preparation on one tick
 * runs a1's and both; a warming segment one group a tick). */
PHASE void phases_to_delta1(const phase_t *p) {
    phase_a2(p);
    phase_a3(p);
    phase_a3_divide(p);
    phase_a1_plus_a2(p);
    phase_delta1(p);
}

PHASE void phases_after_delta1(const phase_t *p) {
    phase_two_a3(p);
    phase_four_a3(p);
    phase_delta3(p);
    phase_two_a2(p);
    phase_delta2(p);
}

/* Segments of more than WARM_TICKS ticks start warming (curve_prepare_start); those of
 * this many or fewer are prepared on their first. The ticks after the first that a warming
 * segment takes to stand where a stepping one would (curve_warm_step): WARM_STEPS, of
 * which the last may be past the segment's end (it is then never run). */
#define WARM_TICKS 4
#define WARM_STEPS 5

/* The phases' arguments for the head segment's own slots (its segment set by the caller). */
static inline phase_t curve_warm_phase(curve_player_t *curve) {
    phase_t p = {0, &curve->coefficients, (uint32_t)curve->step_us, curve->own.den,
                 curve->own.quotient, curve->own.remainder, &curve->warm_quotient,
                 curve->warm_remainder};
    return p;
}

/* --- the keyframe buffer and the player (curve.py CurvePlayer) ------------------------- */

/* A keyframe's duration in microseconds (below 2^26: a 32-bit product, where a 64-bit one
 * is a library call on the M0+). */
static inline uint32_t segment_us(const keyframe_t *keyframe) {
    return keyframe->duration_ms * 1000u;
}

static inline const keyframe_t *curve_first(const curve_player_t *curve) {
    return &curve->buffer[curve->head];
}

static inline void curve_pop(curve_player_t *curve) {
    curve->head = (uint8_t)((curve->head + 1u) % CURVE_BUFFER_CAPACITY);
    curve->count--;
    curve->stepping = false;
    curve->warming = 0;
}

static inline segment_t curve_segment(const curve_player_t *curve) {
    const keyframe_t *target = curve_first(curve);
    segment_t s = {curve->start_position, target->position_counts, curve->start_tangent,
                   target->tangent_in, target->duration_ms};
    return s;
}

static void curve_prepare_start(curve_player_t *curve, int64_t tick_us);
static bool curve_adopt_prepared(curve_player_t *curve, int64_t tick_us);

bool curve_append_prepared(curve_player_t *curve, keyframe_t keyframe,
                           const curve_prepared_t *prepared) {
    if (curve->count >= CURVE_BUFFER_CAPACITY) {
        return false;
    }
    unsigned slot = (curve->head + curve->count) % CURVE_BUFFER_CAPACITY;
    curve->buffer[slot] = keyframe;
    curve->prepared[slot] = *prepared;
    curve->last = keyframe;
    curve->has_last = true;
    curve->count++;
    if (curve->playing && curve->count == 1 && curve->elapsed_us == 0 && curve->step_us > 0 &&
        !curve_adopt_prepared(curve, curve->step_us)) {
        /* the curve reached its last keyframe exactly on the last tick and goes on with
         * this one on the next: start its segment here, as that tick would have */
        curve_prepare_start(curve, curve->step_us);
    }
    return true;
}

bool curve_append(curve_player_t *curve, keyframe_t keyframe) {
    curve_prepared_t prepared;
    curve_prepare_keyframe(curve, keyframe, curve->step_us, &prepared);
    return curve_append_prepared(curve, keyframe, &prepared);
}

void curve_clear(curve_player_t *curve) {
    curve->head = 0;
    curve->count = 0;
    curve->playing = false;
    curve->elapsed_us = 0;
    curve->stepping = false;
    curve->warming = 0;
    curve->active = 0;
    curve->has_last = false;
}

void curve_interrupt(curve_player_t *curve) {
    curve->playing = false;
    curve->elapsed_us = 0;
    curve->stepping = false;
    curve->warming = 0;
    curve->active = 0;
}

uint32_t curve_queued(const curve_player_t *curve) {
    return curve->count;
}

/* The differences of segment s at e0 for steps of h (0 < h, den set) as quotients and
 * remainders by den (entries 1 to 3); false when a quotient is 2^32 counts a tick or more
 * (the segment is then evaluated tick by tick). */
static bool differences_prepared(const segment_t *s, uint32_t e0, uint32_t h, uint32_t *den,
                                 int64_t *quotient, uint32_t (*remainder)[WORDS]) {
    coefficients_t c;
    segment_coefficients(s, &c);
    if (e0 == 0 && h < 512) {
        int64_t scratch_quotient;
        uint32_t scratch[WORDS];
        phase_t p = {s, &c, h, den, quotient, remainder, &scratch_quotient, scratch};
        phase_a1(&p);
        phase_a1_low(&p);
        phase_a1_high(&p);
        phases_to_delta1(&p);
        phases_after_delta1(&p);
        return true;
    }
    uint32_t delta[3][WORDS];
    if (e0 == 0 && h < 0x10000) {
        differences_at_start(&c, h, delta);
    } else {
        differences_at(&c, e0, h, delta);
    }
    for (unsigned k = 0; k < 3; k++) {
        if (!words_floor_divide(delta[k], den, &quotient[k + 1], remainder[k + 1])) {
            return false;
        }
    }
    return true;
}

/* Ready the differences of the head segment at elapsed e0 (the numerator's quotient and
 * remainder, and den, are set), when a later tick of the segment will use them. */
static void curve_prepare(curve_player_t *curve, uint32_t e0, int64_t tick_us) {
    curve->stepping = false;
    uint32_t d = curve_first(curve)->duration_ms * 1000u;
    if (tick_us <= 0 || (int64_t)e0 + tick_us >= (int64_t)d) {
        return;
    }
    segment_t s = curve_segment(curve);
    curve->stepping = differences_prepared(&s, e0, (uint32_t)tick_us, curve->own.den,
                                           curve->own.quotient, curve->own.remainder);
}

void curve_prepare_keyframe(const curve_player_t *curve, keyframe_t keyframe, int64_t tick_us,
                            curve_prepared_t *prepared) {
    prepared->ready = false;
    uint32_t d = segment_us(&keyframe);
    if (!curve->has_last || tick_us <= 0 || tick_us >= (int64_t)d) {
        return;   /* a curve's first segment, or one no tick steps in */
    }
    const keyframe_t *from = &curve->last;
    segment_t s = {from->position_counts, keyframe.position_counts, from->tangent_out,
                   keyframe.tangent_in, keyframe.duration_ms};
    curve_differences_t *differences = &prepared->differences;
    segment_den(d, differences->den);
    /* numerator + den/2 at the start: p0 den + den/2 */
    differences->quotient[0] = from->position_counts;
    words_half(differences->remainder[0], differences->den);
    if (differences_prepared(&s, 0, (uint32_t)tick_us, differences->den,
                             differences->quotient, differences->remainder)) {
        prepared->p0 = from->position_counts;
        prepared->m0 = from->tangent_out;
        prepared->step_us = (int32_t)tick_us;
        prepared->ready = true;
    }
}

/* The head segment starts (elapsed 0) from start_position with start_tangent: its
 * differences as core0 prepared them, when they were prepared for this start and period
 * (a segment is its keyframe's, start and period: the same numbers). */
static bool curve_adopt_prepared(curve_player_t *curve, int64_t tick_us) {
    const curve_prepared_t *next = &curve->prepared[curve->head];
    if (!next->ready || next->p0 != curve->start_position ||
        next->m0 != curve->start_tangent || next->step_us != tick_us) {
        return false;
    }
    curve->active = (uint8_t)(curve->head + 1u);
    curve->stepping = true;   /* ready: the segment is longer than a tick */
    return true;
}

/* A segment's first tick (elapsed 0): the value p0 exactly, numerator + den/2 =
 * p0 den + den/2. */
static void curve_prepare_start(curve_player_t *curve, int64_t tick_us) {
    uint32_t d = segment_us(curve_first(curve));
    curve->active = 0;
    segment_den(d, curve->own.den);
    curve->own.quotient[0] = curve->start_position;
    words_half(curve->own.remainder[0], curve->own.den);
    if (tick_us > 0 && tick_us < 512 && (int64_t)d > WARM_TICKS * tick_us) {
        curve->stepping = false;
        phase_t p = curve_warm_phase(curve);
        segment_t s = curve_segment(curve);
        p.s = &s;
        phase_coefficients(&p);
        phase_c3(&p);
        phase_a1(&p);
        phase_a1_low(&p);
        phase_a1_high(&p);
        curve->warming = WARM_STEPS;
        return;
    }
    curve_prepare(curve, 0, tick_us);
}

/* The value of the numerator as it stands: the quotient, less one for a tie or an exact
 * value below 0 (the rounding, curve.c's head). */
static inline int64_t numerator_value(const curve_differences_t *differences) {
    const uint32_t *r = differences->remainder[0];
    int64_t q = differences->quotient[0];
    return q - ((r[0] | r[1] | r[2]) == 0 && q <= 0);
}

/* The next tick of a stepping segment: each of the numerator and its first two
 * differences gains the next difference, exactly, remainder by remainder. Remainders are
 * below den < 2^88, so their sums fit 3 words. */
/* slot k += slot k + 1 for den < 2^64 (qr_add2). */
static inline void slot_step2(curve_differences_t *differences, unsigned k) {
    uint32_t *r = differences->remainder[k];
    uint64_t b = words_u64(differences->remainder[k + 1]);
    uint64_t room = words_u64(differences->den) - b;
    uint64_t a = words_u64(r);
    uint32_t carry = a >= room;
    a = carry ? a - room : a + b;
    r[0] = (uint32_t)a;
    r[1] = (uint32_t)(a >> 32);
    differences->quotient[k] += differences->quotient[k + 1] + carry;
}

static inline curve_differences_t *active_differences(curve_player_t *curve) {
    return curve->active == 0 ? &curve->own : &curve->prepared[curve->active - 1u].differences;
}

static int64_t curve_step(curve_player_t *curve) {
    curve_differences_t *d = active_differences(curve);
    if (d->den[2] == 0u) {
        /* two words: the third of every remainder stays 0 */
        slot_step2(d, 0);
        slot_step2(d, 1);
        slot_step2(d, 2);
    } else {
        for (unsigned k = 0; k < 3; k++) {
            d->quotient[k] = qr_add3(d->quotient[k], d->remainder[k], d->quotient[k + 1],
                                     d->remainder[k + 1], d->den, d->remainder[k]);
        }
    }
    return numerator_value(d);
}

/* slot k += slot j (curve_warm_step) */
static inline void slot_add(curve_player_t *curve, unsigned k, unsigned j) {
    curve_differences_t *d = &curve->own;   /* a warming segment's */
    d->quotient[k] = qr_add(d->quotient[k], d->remainder[k], d->quotient[j], d->remainder[j],
                            d->den, d->remainder[k]);
}

/* The ticks of a warming segment after its first, e = h to 5h (N the numerator, D1 to D3
 * its differences, _i at tick i): each finds the value with only what it needs prepared,
 * and the differences catch up with the step an addition a tick, so that no tick takes
 * more than about six additions' worth.
 * Tick 1: D1_0 = a1 + a2 + a3, N_1 = N_0 + D1_0. Tick 2: T = 3 a3 (the scratch),
 * D2_0 = 2 (a2 + T) = 2 a2 + 6 a3, D1_1 = D1_0 + D2_0, N_2 = N_1 + D1_1. Tick 3: D3 = 2 T,
 * D2_1 = D2_0 + D3, D1_2 = D1_1 + D2_1, N_3 = N_2 + D1_2, D2_2 = D2_1 + D3. Tick 4:
 * D1_3 = D1_2 + D2_2, N_4 = N_3 + D1_3, D2_3 = D2_2 + D3, D1_4 = D1_3 + D2_3. Tick 5:
 * D2_4 = D2_3 + D3 (where stepping stands after tick 4), then the step. */
static int64_t curve_warm_step(curve_player_t *curve) {
    int64_t *q = curve->own.quotient;
    uint32_t(*r)[WORDS] = curve->own.remainder;
    const uint32_t *den = curve->own.den;
    switch (curve->warming--) {
    case 5: {
        phase_t p = curve_warm_phase(curve);   /* the phases after a1's read no segment */
        phases_to_delta1(&p);
        slot_add(curve, 0, 1);
        break;
    }
    case 4:
        curve->warm_quotient = qr_add(q[3], r[3], q[3], r[3], den, curve->warm_remainder);
        curve->warm_quotient = qr_add(curve->warm_quotient, curve->warm_remainder, q[3], r[3],
                                      den, curve->warm_remainder);
        q[2] = qr_add(q[2], r[2], curve->warm_quotient, curve->warm_remainder, den, r[2]);
        slot_add(curve, 2, 2);
        slot_add(curve, 1, 2);
        slot_add(curve, 0, 1);
        break;
    case 3:
        q[3] = qr_add(curve->warm_quotient, curve->warm_remainder, curve->warm_quotient,
                      curve->warm_remainder, den, r[3]);
        slot_add(curve, 2, 3);
        slot_add(curve, 1, 2);
        slot_add(curve, 0, 1);
        slot_add(curve, 2, 3);
        break;
    case 2:
        slot_add(curve, 1, 2);
        slot_add(curve, 0, 1);
        slot_add(curve, 2, 3);
        slot_add(curve, 1, 2);
        break;
    default:
        slot_add(curve, 2, 3);
        curve->stepping = true;
        return curve_step(curve);
    }
    return numerator_value(&curve->own);
}

static int64_t __attribute__((noinline))
curve_next_position_general(curve_player_t *curve, int32_t current_desired, int64_t tick_us);

int64_t curve_next_position(curve_player_t *curve, int32_t current_desired, int64_t tick_us) {
    if (curve->stepping && curve->warming == 0 && curve->playing && curve->step_us == tick_us) {
        /* the usual tick: within the segment, which steps (what the general path comes
         * to: no keyframe passed or reached, elapsed neither 0 nor the end) */
        int64_t elapsed = curve->elapsed_us + tick_us;
        if (elapsed < (int64_t)segment_us(curve_first(curve))) {
            curve->elapsed_us = elapsed;
            return curve_step(curve);
        }
    }
    return curve_next_position_general(curve, current_desired, tick_us);
}

static int64_t curve_next_position_general(curve_player_t *curve, int32_t current_desired,
                                           int64_t tick_us) {
    if (curve->step_us != tick_us) {
        curve->stepping = false;   /* prepared for another period */
        curve->warming = 0;
        curve->step_us = (int32_t)tick_us;
    }
    if (curve->playing) {
        curve->elapsed_us += tick_us;
    } else if (curve->count != 0) {
        curve->playing = true;
        curve->elapsed_us = 0;
        curve->start_position = current_desired;
        curve->start_tangent = 0;
        curve->stepping = false;
    } else {
        return current_desired;
    }
    while (curve->count != 0 &&
           curve->elapsed_us > (int64_t)segment_us(curve_first(curve))) {
        const keyframe_t *done = curve_first(curve);
        curve->elapsed_us -= (int64_t)segment_us(done);
        curve->start_position = done->position_counts;
        curve->start_tangent = done->tangent_out;
        curve_pop(curve);
    }
    if (curve->count == 0) {
        curve->playing = false;
        curve->stepping = false;
        return curve->start_position;
    }
    const keyframe_t target = *curve_first(curve);
    int64_t d = (int64_t)segment_us(&target);
    uint32_t e = (uint32_t)curve->elapsed_us;
    int64_t position;
    if (e == 0) {
        position = curve->start_position;   /* hermite_position at 0 is p0 exactly */
        curve_prepare_start(curve, tick_us);   /* only a curve's first tick is at 0 */
    } else if (e == d) {
        position = target.position_counts;   /* and p1 at the end */
    } else if (curve->warming != 0) {
        position = curve_warm_step(curve);
    } else if (curve->stepping) {
        position = curve_step(curve);
    } else {
        segment_t s = curve_segment(curve);
        curve->active = 0;
        segment_den(target.duration_ms * 1000u, curve->own.den);
        position = segment_evaluate(&s, e, curve->own.den, &curve->own.quotient[0],
                                    curve->own.remainder[0]);
        curve_prepare(curve, e, tick_us);   /* the later ticks of this segment */
    }
    if (e == d) {
        curve_pop(curve);
        curve->elapsed_us = 0;
        curve->start_position = target.position_counts;
        curve->start_tangent = target.tangent_out;
        if (curve->count != 0 && !curve_adopt_prepared(curve, tick_us)) {
            curve_prepare_start(curve, tick_us);   /* a tick with nothing to evaluate */
        }
    }
    return position;
}
