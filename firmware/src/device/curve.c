/* Curve mode (curve.h): the keyframe buffer, the player, and the Hermite segment evaluated
 * exactly in 128-bit integers built from 32-bit multiplies (the Cortex-M0+ has no wider
 * multiply, and no 128-bit type). */
#include "curve.h"

#define TANGENT_ONE 1024

/* --- 128-bit integers: four 32-bit words, little-endian; two's complement when signed --- */

typedef struct {
    uint32_t w[4];
} u128_t;

/* a * b in 32-bit multiplies of 16-bit halves. */
static inline uint64_t mul_32x32(uint32_t a, uint32_t b) {
    uint32_t a_lo = a & 0xffffu;
    uint32_t a_hi = a >> 16;
    uint32_t b_lo = b & 0xffffu;
    uint32_t b_hi = b >> 16;
    uint64_t middle = (uint64_t)(a_lo * b_hi) + (a_hi * b_lo);
    return (uint64_t)(a_lo * b_lo) + (middle << 16) + ((uint64_t)(a_hi * b_hi) << 32);
}

/* a * b for b < 2^16. */
static inline uint64_t mul_32x16(uint32_t a, uint32_t b) {
    return (uint64_t)((a & 0xffffu) * b) + ((uint64_t)((a >> 16) * b) << 16);
}

static inline u128_t u128_from_u64(uint64_t value) {
    u128_t r = {{(uint32_t)value, (uint32_t)(value >> 32), 0, 0}};
    return r;
}

/* a * b modulo 2^128. */
static inline u128_t u128_mul_u32(u128_t a, uint32_t b) {
    u128_t r;
    uint64_t carry = 0;
    for (unsigned i = 0; i < 4; i++) {
        uint64_t t = mul_32x32(a.w[i], b) + carry;
        r.w[i] = (uint32_t)t;
        carry = t >> 32;
    }
    return r;
}

/* a * b, both below 2^64 (the product below 2^128). */
static inline u128_t u128_mul_u64(uint64_t a, uint64_t b) {
    uint32_t a0 = (uint32_t)a;
    uint32_t a1 = (uint32_t)(a >> 32);
    uint32_t b0 = (uint32_t)b;
    uint32_t b1 = (uint32_t)(b >> 32);
    uint64_t p00 = mul_32x32(a0, b0);
    uint64_t p01 = mul_32x32(a0, b1);
    uint64_t p10 = mul_32x32(a1, b0);
    uint64_t p11 = mul_32x32(a1, b1);
    u128_t r;
    r.w[0] = (uint32_t)p00;
    uint64_t t = (p00 >> 32) + (uint32_t)p01 + (uint32_t)p10;
    r.w[1] = (uint32_t)t;
    t = (t >> 32) + (p01 >> 32) + (p10 >> 32) + (uint32_t)p11;
    r.w[2] = (uint32_t)t;
    r.w[3] = (uint32_t)((t >> 32) + (p11 >> 32));
    return r;
}

static inline u128_t u128_add(u128_t a, u128_t b) {
    u128_t r;
    uint64_t carry = 0;
    for (unsigned i = 0; i < 4; i++) {
        uint64_t t = (uint64_t)a.w[i] + b.w[i] + carry;
        r.w[i] = (uint32_t)t;
        carry = t >> 32;
    }
    return r;
}

static inline u128_t u128_sub(u128_t a, u128_t b) {
    u128_t r;
    uint32_t borrow = 0;
    for (unsigned i = 0; i < 4; i++) {
        uint64_t t = (uint64_t)a.w[i] - b.w[i] - borrow;
        r.w[i] = (uint32_t)t;
        borrow = (uint32_t)(t >> 63);
    }
    return r;
}

static inline u128_t u128_negate(u128_t a) {
    u128_t zero = {{0, 0, 0, 0}};
    return u128_sub(zero, a);
}

/* The signed value: the magnitude with this sign (negative: two's complement). */
static inline u128_t u128_signed(u128_t magnitude, bool negative) {
    return negative ? u128_negate(magnitude) : magnitude;
}

static inline bool u128_is_negative(u128_t a) {
    return (a.w[3] >> 31) != 0;
}

static inline bool u128_less(u128_t a, u128_t b) {
    for (unsigned i = 4; i-- > 0;) {
        if (a.w[i] != b.w[i]) {
            return a.w[i] < b.w[i];
        }
    }
    return false;
}

/* a << bits for bits < 32. */
static inline u128_t u128_shift_left(u128_t a, unsigned bits) {
    u128_t r;
    r.w[0] = a.w[0] << bits;
    for (unsigned i = 1; i < 4; i++) {
        r.w[i] = (a.w[i] << bits) | (bits ? a.w[i - 1] >> (32u - bits) : 0u);
    }
    return r;
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

/* Bits [shift, shift + 64) of a, for 0 < shift < 64 + 32. */
static inline uint64_t u128_bits64(u128_t a, unsigned shift) {
    unsigned word = shift / 32u;
    unsigned bit = shift % 32u;
    uint32_t w0 = a.w[word];
    uint32_t w1 = word + 1 < 4 ? a.w[word + 1] : 0u;
    uint32_t w2 = word + 2 < 4 ? a.w[word + 2] : 0u;
    if (bit == 0) {
        return ((uint64_t)w1 << 32) | w0;
    }
    uint32_t lo = (w0 >> bit) | (w1 << (32u - bit));
    uint32_t hi = (w1 >> bit) | (w2 << (32u - bit));
    return ((uint64_t)hi << 32) | lo;
}

/* floor(n / d) for d >= 2^31 and n < 2^32 * d (the quotient fits 32 bits): one 64-by-32-bit
 * division of the operands shifted so that the divisor keeps 31 bits, then an exact
 * correction. With s the shift, D = d >> s in [2^30, 2^31) and N = n >> s < 2^63:
 * N / (D + 1) < n / d, and N / (D + 1) > (n - 2^s) / (d + 2^s) - 1 >= n / d - 6 (as
 * 2^s <= d * 2^-30 and n / d < 2^32), so at most 6 corrections. */
static uint32_t u128_divide(u128_t n, u128_t d) {
    unsigned top = 3;
    while (d.w[top] == 0) {
        top--;
    }
    unsigned length = top * 32u + bit_length_32(d.w[top]);
    unsigned shift = length - 31u;
    uint32_t d_high = (uint32_t)u128_bits64(d, shift);
    uint64_t n_high = u128_bits64(n, shift);
    uint32_t q = (uint32_t)(n_high / (d_high + 1u));
    u128_t rest = u128_sub(n, u128_mul_u32(d, q));
    while (!u128_less(rest, d)) {
        rest = u128_sub(rest, d);
        q++;
    }
    return q;
}

int64_t curve_hermite_position(int32_t p0, int32_t p1, int32_t m0, int32_t m1,
                               uint32_t duration_ms, uint32_t elapsed_us) {
    uint32_t d = duration_ms * 1000u;   /* < 2^26 */
    uint32_t e = elapsed_us;
    if (e == 0) {
        return p0;   /* the formula's exact value at the ends */
    }
    if (e == d) {
        return p1;
    }
    uint32_t rest = d - e;
    /* numerator = 1024 * (d^3 p0 + (p1 - p0) e^2 (3d - 2e))
     *             + duration * e * rest * (m0 * rest - m1 * e)
     * |d^3 p0| < 2^109, |(p1 - p0) e^2 (3d - 2e)| <= 2^32 d^3 < 2^110, the tangent term
     * < 2^16 * 2^50 * 2^41 = 2^107: |numerator| < 2^121. */
    u128_t d3 = u128_mul_u32(u128_from_u64(mul_32x32(d, d)), d);
    uint32_t p0_magnitude = p0 < 0 ? 0u - (uint32_t)p0 : (uint32_t)p0;
    u128_t start = u128_signed(u128_mul_u32(d3, p0_magnitude), p0 < 0);
    int64_t dp = (int64_t)p1 - p0;
    uint32_t dp_magnitude = (uint32_t)(dp < 0 ? -dp : dp);   /* < 2^32 */
    u128_t blend = u128_mul_u32(u128_mul_u32(u128_from_u64(mul_32x32(e, e)), 3u * d - 2u * e),
                                dp_magnitude);
    u128_t positions = u128_add(start, u128_signed(blend, dp < 0));
    /* m0 * rest - m1 * e: |m| <= 2^15, rest + e = d, so below 2^41 */
    uint32_t m0_magnitude = m0 < 0 ? 0u - (uint32_t)m0 : (uint32_t)m0;
    uint32_t m1_magnitude = m1 < 0 ? 0u - (uint32_t)m1 : (uint32_t)m1;
    int64_t slope0 = (int64_t)mul_32x16(rest, m0_magnitude);
    int64_t slope1 = (int64_t)mul_32x16(e, m1_magnitude);
    int64_t slopes = (m0 < 0 ? -slope0 : slope0) - (m1 < 0 ? -slope1 : slope1);
    uint64_t slopes_magnitude = (uint64_t)(slopes < 0 ? -slopes : slopes);
    /* duration * |slopes| < 2^16 * 2^42: 64 bits */
    uint64_t scaled = mul_32x16((uint32_t)slopes_magnitude, duration_ms) +
                      (mul_32x16((uint32_t)(slopes_magnitude >> 32), duration_ms) << 32);
    u128_t tangents = u128_signed(u128_mul_u64(mul_32x32(e, rest), scaled), slopes < 0);
    u128_t numerator = u128_add(u128_shift_left(positions, 10), tangents);
    /* _round_half_away: (2|n| + den) // (2 den), den = 1024 d^3, with the sign of n */
    bool negative = u128_is_negative(numerator);
    u128_t magnitude = negative ? u128_negate(numerator) : numerator;
    u128_t twice_den = u128_shift_left(d3, 11);
    u128_t rounded = u128_add(u128_shift_left(magnitude, 1), u128_shift_left(d3, 10));
    uint32_t q = u128_divide(rounded, twice_den);
    return negative ? -(int64_t)q : (int64_t)q;
}

/* --- the keyframe buffer and the player (curve.py CurvePlayer) ------------------------- */

static inline const keyframe_t *curve_first(const curve_player_t *curve) {
    return &curve->buffer[curve->head];
}

static inline void curve_pop(curve_player_t *curve) {
    curve->head = (uint8_t)((curve->head + 1u) % CURVE_BUFFER_CAPACITY);
    curve->count--;
}

bool curve_append(curve_player_t *curve, keyframe_t keyframe) {
    if (curve->count >= CURVE_BUFFER_CAPACITY) {
        return false;
    }
    curve->buffer[(curve->head + curve->count) % CURVE_BUFFER_CAPACITY] = keyframe;
    curve->count++;
    return true;
}

void curve_clear(curve_player_t *curve) {
    curve->head = 0;
    curve->count = 0;
    curve->playing = false;
    curve->elapsed_us = 0;
}

void curve_interrupt(curve_player_t *curve) {
    curve->playing = false;
    curve->elapsed_us = 0;
}

uint32_t curve_queued(const curve_player_t *curve) {
    return curve->count;
}

int64_t curve_next_position(curve_player_t *curve, int32_t current_desired, int64_t tick_us) {
    if (curve->playing) {
        curve->elapsed_us += tick_us;
    } else if (curve->count != 0) {
        curve->playing = true;
        curve->elapsed_us = 0;
        curve->start_position = current_desired;
        curve->start_tangent = 0;
    } else {
        return current_desired;
    }
    while (curve->count != 0 &&
           curve->elapsed_us > (int64_t)curve_first(curve)->duration_ms * 1000) {
        const keyframe_t *done = curve_first(curve);
        curve->elapsed_us -= (int64_t)done->duration_ms * 1000;
        curve->start_position = done->position_counts;
        curve->start_tangent = done->tangent_out;
        curve_pop(curve);
    }
    if (curve->count == 0) {
        curve->playing = false;
        return curve->start_position;
    }
    const keyframe_t target = *curve_first(curve);
    int64_t position = curve_hermite_position(curve->start_position, target.position_counts,
                                              curve->start_tangent, target.tangent_in,
                                              target.duration_ms, (uint32_t)curve->elapsed_us);
    if (curve->elapsed_us == (int64_t)target.duration_ms * 1000) {
        curve_pop(curve);
        curve->elapsed_us = 0;
        curve->start_position = target.position_counts;
        curve->start_tangent = target.tangent_out;
    }
    return position;
}
