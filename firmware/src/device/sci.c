/* Scientific-notation integers (sci.h): the external definitions of the inline operations,
 * the 64-bit truncation, division, and the exact conversions to and from double. */
#include "sci.h"

#include <string.h>

const uint32_t sci_pow10_u32[10] = {
    1u, 10u, 100u, 1000u, 10000u, 100000u, 1000000u, 10000000u, 100000000u, 1000000000u,
};

const uint64_t sci_pow10_u64[20] = {
    1u,
    10u,
    100u,
    1000u,
    10000u,
    100000u,
    1000000u,
    10000000u,
    100000000u,
    1000000000u,
    10000000000u,
    100000000000u,
    1000000000000u,
    10000000000000u,
    100000000000000u,
    1000000000000000u,
    10000000000000000u,
    100000000000000000u,
    1000000000000000000u,
    10000000000000000000u,
};

const uint32_t sci_recip_pow10[5] = {1u, 209716u, 167773u, 134218u, 214749u};
const uint8_t sci_recip_shift[5] = {0u, 21u, 24u, 27u, 31u};

extern inline uint32_t sci_udiv(uint32_t n, uint32_t d);
extern inline int32_t sci_sdiv(int32_t n, int32_t d);
extern inline uint32_t sci_mul_32x32(uint32_t a, uint32_t b, uint32_t *hi);
extern inline uint64_t sci_mul_32x64(uint32_t a, uint64_t b);
extern inline uint64_t sci_div_u64_small(uint64_t n, uint32_t d);
extern inline uint64_t sci_magnitude64(int64_t value);
extern inline int32_t sci_signed(uint32_t m, bool negative);
extern inline sci_t sci_normalize_u32(uint32_t m, int32_t e, bool negative);
extern inline sci_t sci_normalize(int64_t c, int32_t e);
extern inline sci_t sci_from_int(int64_t value);
extern inline int64_t sci_to_int(sci_t x);
extern inline sci_t sci_mul(sci_t a, sci_t b);
extern inline sci_t sci_add(sci_t a, sci_t b);
extern inline sci_t sci_sub(sci_t a, sci_t b);
extern inline int sci_compare(sci_t a, sci_t b);

/* For k = 6..15: bit length of 10^k minus 17, so that 10^k >> shift keeps 17 bits. */
static const uint8_t POW10_SHIFT[16] = {0, 0, 0, 0, 0, 0, 3, 7, 10, 13, 17, 20, 23, 27, 30, 33};

/* small * big for small < 2^14 and big < 2^50, in 32-bit multiplies. */
static inline uint64_t mul_small_u64(uint32_t small, uint64_t big) {
    uint32_t lo = (uint32_t)big;
    uint32_t hi = (uint32_t)(big >> 32);
    uint64_t low_half = small * (lo & 0xffffu);
    uint64_t high_half = (uint64_t)(small * (lo >> 16)) << 16;
    return low_half + high_half + ((uint64_t)(small * hi) << 32);
}

uint32_t sci_div_pow10_u64(uint64_t m, unsigned k) {
    /* Proof of the bound: with s = POW10_SHIFT[k], P = 10^k >= 2^(16+s) and q = m / P < 10^4,
     * (m >> s) / ((P >> s) + 1) >= (m - 2^s) / (P + 2^s) - 1 >= q - q*2^-16 - 2^-16 - 1, so
     * it is at most 2 below floor(q), never above; m >> s < 10^4 * 2^17 fits 32 bits. */
    uint64_t divisor = sci_pow10_u64[k];
    unsigned s = POW10_SHIFT[k];
    uint32_t q = sci_udiv((uint32_t)(m >> s), (uint32_t)(divisor >> s) + 1u);
    uint64_t rest = m - mul_small_u64(q, divisor);
    while (rest >= divisor) {
        rest -= divisor;
        q++;
    }
    return q;
}

sci_t sci_div(sci_t a, sci_t b) {
    sci_t r = {0, 0};
    if (b.c == 0 || a.c == 0) {
        return r;
    }
    int32_t d = sci_sdiv(a.c * SCI_UPPER, b.c);
    if (d >= SCI_UPPER || d <= -SCI_UPPER) {
        r.c = sci_sdiv(d, 10);
        r.e = a.e - b.e - SCI_DIGITS + 1;
    } else {
        r.c = d;
        r.e = a.e - b.e - SCI_DIGITS;
    }
    return r;
}

/* --- exact conversions (core0) ---------------------------------------------------------- */

/* A natural number in 16-bit limbs (little-endian), so that every step of a multiplication
 * or a division by a number up to 10^4 fits 32 bits. 96 limbs hold 1536 bits: 9999 * 10^400
 * needs 1343, and 9999 << (64 + 1334) needs 1412. */
#define BIG_LIMBS 96u
typedef struct {
    uint32_t limb[BIG_LIMBS];
    unsigned used;
} big_t;

static void big_set(big_t *b, uint32_t value) {
    b->limb[0] = value & 0xffffu;
    b->limb[1] = value >> 16;
    b->used = b->limb[1] ? 2u : 1u;
}

static void big_mul_small(big_t *b, uint32_t factor) {
    uint32_t carry = 0;
    for (unsigned i = 0; i < b->used; i++) {
        uint32_t t = b->limb[i] * factor + carry;
        b->limb[i] = t & 0xffffu;
        carry = t >> 16;
    }
    while (carry != 0 && b->used < BIG_LIMBS) {
        b->limb[b->used++] = carry & 0xffffu;
        carry >>= 16;
    }
}

static void big_shift_left(big_t *b, unsigned bits) {
    unsigned limbs = bits / 16u;
    unsigned rest = bits % 16u;
    b->limb[b->used + limbs] = 0;   /* within BIG_LIMBS for every shift sci_to_double makes */
    for (unsigned i = b->used; i-- > 0;) {
        uint32_t t = b->limb[i] << rest;
        b->limb[i + limbs + 1] |= t >> 16;
        b->limb[i + limbs] = t & 0xffffu;
    }
    for (unsigned i = 0; i < limbs; i++) {
        b->limb[i] = 0;
    }
    b->used += limbs + 1;
    while (b->used > 1 && b->limb[b->used - 1] == 0) {
        b->used--;
    }
}

/* Divides in place; returns the remainder. */
static uint32_t big_div_small(big_t *b, uint32_t divisor) {
    uint32_t rest = 0;
    for (unsigned i = b->used; i-- > 0;) {
        uint32_t t = (rest << 16) | b->limb[i];
        b->limb[i] = t / divisor;
        rest = t % divisor;
    }
    while (b->used > 1 && b->limb[b->used - 1] == 0) {
        b->used--;
    }
    return rest;
}

static unsigned big_bit_length(const big_t *b) {
    uint32_t top = b->limb[b->used - 1];
    unsigned bits = 0;
    while (top != 0) {
        bits++;
        top >>= 1;
    }
    return (b->used - 1) * 16u + bits;
}

static unsigned big_bit(const big_t *b, unsigned index) {
    unsigned limb = index / 16u;
    return limb < b->used ? (b->limb[limb] >> (index % 16u)) & 1u : 0u;
}

static bool big_any_below(const big_t *b, unsigned index) {
    unsigned whole = index / 16u;
    for (unsigned i = 0; i < whole && i < b->used; i++) {
        if (b->limb[i] != 0) {
            return true;
        }
    }
    return whole < b->used && (b->limb[whole] & ((1u << (index % 16u)) - 1u)) != 0;
}

/* Bits [from, from + count) as an integer (count <= 64). */
static uint64_t big_bits(const big_t *b, unsigned from, unsigned count) {
    uint64_t value = 0;
    for (unsigned i = count; i-- > 0;) {
        value = (value << 1) | big_bit(b, from + i);
    }
    return value;
}

static double bits_to_double(uint64_t bits) {
    double value;
    memcpy(&value, &bits, sizeof value);
    return value;
}

/* q * 2^scale (q != 0), plus a nonzero fraction below q's last bit when `sticky`, rounded
 * to the nearest double (ties to even), with subnormals. */
static double big_to_double(const big_t *q, int32_t scale, bool sticky, bool negative) {
    const uint64_t sign = negative ? (uint64_t)1 << 63 : 0u;
    int32_t length = (int32_t)big_bit_length(q);
    int32_t exponent = length - 1 + scale;   /* of the leading bit */
    if (exponent > 1023) {
        return bits_to_double(sign | 0x7ff0000000000000u);
    }
    int32_t precision = exponent >= -1022 ? 53 : exponent + 1075;
    if (precision < 0) {
        return bits_to_double(sign);   /* below half the least subnormal */
    }
    uint64_t mantissa;
    int32_t shift = length - precision;
    if (shift <= 0) {
        mantissa = big_bits(q, 0, (unsigned)length) << (unsigned)(-shift);
    } else {
        mantissa = big_bits(q, (unsigned)shift, (unsigned)precision);
        bool half = big_bit(q, (unsigned)shift - 1u) != 0;
        bool below = sticky || big_any_below(q, (unsigned)shift - 1u);
        if (half && (below || (mantissa & 1u))) {
            mantissa++;
        }
    }
    if (precision < 53) {
        return bits_to_double(sign | mantissa);   /* 2^52 here is the least normal */
    }
    if (mantissa == (uint64_t)1 << 53) {
        mantissa >>= 1;
        exponent++;
        if (exponent > 1023) {
            return bits_to_double(sign | 0x7ff0000000000000u);
        }
    }
    return bits_to_double(sign | ((uint64_t)(exponent + 1023) << 52) |
                          (mantissa & (((uint64_t)1 << 52) - 1u)));
}

double sci_to_double(sci_t x) {
    if (x.c == 0) {
        return 0.0;
    }
    bool negative = x.c < 0;
    if (x.e > 400) {
        return bits_to_double((negative ? (uint64_t)1 << 63 : 0u) | 0x7ff0000000000000u);
    }
    if (x.e < -400) {
        return bits_to_double(negative ? (uint64_t)1 << 63 : 0u);
    }
    big_t n;
    big_set(&n, negative ? 0u - (uint32_t)x.c : (uint32_t)x.c);
    if (x.e >= 0) {
        /* float(c * 10**e): the integer, correctly rounded */
        int32_t left = x.e;
        for (; left >= 4; left -= 4) {
            big_mul_small(&n, 10000u);
        }
        big_mul_small(&n, sci_pow10_u32[left]);
        return big_to_double(&n, 0, false, negative);
    }
    /* c / 10**k: floor(c * 2^s / 10^k) has 64 bits at least (s >= 64 + k log2 10), and a
     * nonzero remainder of any of the divisions is the fraction below its last bit */
    int32_t k = -x.e;
    int32_t s = 64 + (10 * k + 2) / 3;
    big_shift_left(&n, (unsigned)s);
    bool sticky = false;
    for (; k >= 4; k -= 4) {
        sticky |= big_div_small(&n, 10000u) != 0;
    }
    sticky |= big_div_small(&n, sci_pow10_u32[k]) != 0;
    return big_to_double(&n, -s, sticky, negative);
}

/* The 4-digit number c * 10^e as a double (c in 1000..9999). */
static double grid_value(int32_t c, int32_t e) {
    sci_t x = {c, e};
    return sci_to_double(x);
}

sci_t sci_from_double(double x) {
    /* repr(x) is the shortest decimal that reads back as x. Among the 4-digit numbers
     * (g = c * 10^e, 1000 <= c <= 9999) at most one reads back as x, as their spacing is
     * above 10^-4 relative and a double's rounding interval below 2^-52. If one does, repr
     * is it (with its trailing zeros stripped): the 4-digit truncation is g. If none does,
     * no 4-digit boundary lies between x and repr(x) (it would be a shorter decimal that
     * reads back as x), so the truncation of repr(x) is that of x itself. Both cases give
     * the largest g whose double is at most |x|, which sci_to_double decides exactly. */
    sci_t r = {0, 0};
    if (!(x == x) || x == 0.0 || x - x != 0.0) {
        return r;   /* zero, NaN, infinity */
    }
    bool negative = x < 0.0;
    double magnitude = negative ? -x : x;
    uint64_t bits;
    memcpy(&bits, &magnitude, sizeof bits);
    int32_t binary = (int32_t)(bits >> 52) - 1023;
    if (binary == -1023) {
        binary = -1075;   /* subnormal: the leading bit of the mantissa */
        for (uint64_t m = bits; m != 0; m >>= 1) {
            binary++;
        }
    }
    int32_t e = binary * 30103 / 100000 - 3;   /* within one of floor(log10 |x|) - 3 */
    while (grid_value(1000, e) > magnitude) {
        e--;
    }
    while (grid_value(1000, e + 1) <= magnitude) {
        e++;
    }
    int32_t low = 1000;
    int32_t high = 9999;
    while (low < high) {
        int32_t middle = (low + high + 1) / 2;
        if (grid_value(middle, e) <= magnitude) {
            low = middle;
        } else {
            high = middle - 1;
        }
    }
    r.c = negative ? -low : low;
    r.e = e;
    return r;
}
