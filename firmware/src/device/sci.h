/* Scientific-notation integers: the firmware's real-time arithmetic, bit-exact with the
 * functional core of src/usbmotion/scimath.py at 4 significant digits (the device's DIGITS).
 *
 * A number is c * 10^e, normalised: 1000 <= |c| <= 9999, or c == 0 with e == 0. Every
 * operation truncates toward zero, as scimath.py documents; a product of two coefficients
 * fits int32. Operands of mul, div, add, sub and compare are normalised 4-digit numbers
 * (|c| <= 9999 is what the code relies on) whose exponents, and the result's, stay within
 * +-2^29 (the device's stay within a few hundred).
 *
 * The operations the servo tick uses are inline definitions here (C11 inline; sci.c holds
 * the external definitions), so the tick runs them without calls. sci_to_double and
 * sci_from_double are core0's (soft floating point), never called on core1. */
#ifndef USBMOTION_SCI_H
#define USBMOTION_SCI_H

#include <stdbool.h>
#include <stdint.h>

#ifdef USBMOTION_SIO_DIVIDER
#include "hardware/structs/sio.h"
#endif

#define SCI_DIGITS 4
#define SCI_UPPER 10000   /* 10^SCI_DIGITS */

typedef struct {
    int32_t c;
    int32_t e;
} sci_t;

/* 10^0 .. 10^9 and 10^0 .. 10^19. */
extern const uint32_t sci_pow10_u32[10];
extern const uint64_t sci_pow10_u64[20];

/* n / d, truncated as C's. On the RP2040 (USBMOTION_SIO_DIVIDER) the core's hardware
 * divider, its registers written and read in place: about 15 cycles, against 35 through the SDK's
 * __aeabi_uidiv, which also saves the divider's state for whatever division it
 * interrupted. Doing without that is safe as long as no interrupt handler divides this
 * way: the servo tick (core1's alarm interrupt) interrupts only core1's idle loop, and
 * core0's code is interrupted only by the SDK's, whose divisions save and restore. */
inline uint32_t sci_udiv(uint32_t n, uint32_t d) {
#ifdef USBMOTION_SIO_DIVIDER
    sio_hw->div_udividend = n;
    sio_hw->div_udivisor = d;
    while ((sio_hw->div_csr & SIO_DIV_CSR_READY_BITS) == 0) {
    }
    return sio_hw->div_quotient;
#else
    return n / d;
#endif
}

inline int32_t sci_sdiv(int32_t n, int32_t d) {
#ifdef USBMOTION_SIO_DIVIDER
    sio_hw->div_sdividend = n;
    sio_hw->div_sdivisor = d;
    while ((sio_hw->div_csr & SIO_DIV_CSR_READY_BITS) == 0) {
    }
    return (int32_t)sio_hw->div_quotient;
#else
    return n / d;
#endif
}

/* (hi, lo) = a * b from four 16 x 16-bit products: the Cortex-M0+ multiplies 32 x 32 -> 32
 * bits only, and a 64-bit multiply is a library call there. */
inline uint32_t sci_mul_32x32(uint32_t a, uint32_t b, uint32_t *hi) {
    uint32_t a_lo = a & 0xffffu;
    uint32_t a_hi = a >> 16;
    uint32_t b_lo = b & 0xffffu;
    uint32_t b_hi = b >> 16;
    uint32_t cross1 = a_lo * b_hi;
    uint32_t cross2 = a_hi * b_lo;
    uint32_t middle = cross1 + cross2;
    uint32_t high = a_hi * b_hi + (middle >> 16) + (middle < cross1 ? 0x10000u : 0u);
    uint32_t low = a_lo * b_lo;
    uint32_t sum = low + (middle << 16);
    *hi = high + (sum < low);
    return sum;
}

/* a * b modulo 2^64, for a 32-bit a. */
inline uint64_t sci_mul_32x64(uint32_t a, uint64_t b) {
    uint32_t hi;
    uint32_t lo = sci_mul_32x32(a, (uint32_t)b, &hi);
    hi += a * (uint32_t)(b >> 32);
    return ((uint64_t)hi << 32) | lo;
}

/* floor(n / d) for 0 < d < 2^16: one 32-bit division when n < 2^32, two when n < 2^48 (the
 * RP2040's hardware divider; its 64-bit division takes three and more), else C's 64-bit
 * division. */
inline uint64_t sci_div_u64_small(uint64_t n, uint32_t d) {
    if ((n >> 32) == 0) {
        return sci_udiv((uint32_t)n, d);
    }
    if ((n >> 48) != 0) {
        return n / d;
    }
    uint32_t high = (uint32_t)(n >> 16);
    uint32_t q_high = sci_udiv(high, d);
    uint32_t rest = high - q_high * d;
    uint32_t q_low = sci_udiv((rest << 16) | (uint32_t)(n & 0xffffu), d);
    return ((uint64_t)q_high << 16) + q_low;
}

/* The magnitude of an int64, as uint64 (INT64_MIN included). */
inline uint64_t sci_magnitude64(int64_t value) {
    return value < 0 ? 0u - (uint64_t)value : (uint64_t)value;
}

/* The coefficient of magnitude m (< 2^31) with a sign. */
inline int32_t sci_signed(uint32_t m, bool negative) {
    return negative ? -(int32_t)m : (int32_t)m;
}

/* floor(m / 10^k) for m < 2^63 whose quotient is below 10^4 (6 <= k <= 15), without a
 * 64-bit division: a 32-bit quotient of the operands shifted so that the divisor keeps at
 * least 16 bits (an underestimate by at most 2), corrected exactly. */
uint32_t sci_div_pow10_u64(uint64_t m, unsigned k);

/* sci_normalize for a magnitude below 2^32 (the fast path of every operation). */
inline sci_t sci_normalize_u32(uint32_t m, int32_t e, bool negative) {
    sci_t r;
    if (m == 0) {
        r.c = 0;
        r.e = 0;
        return r;
    }
    if (m >= 10000u) {
        unsigned k;
        if (m < 100000u) {
            k = 1;
        } else if (m < 1000000u) {
            k = 2;
        } else if (m < 10000000u) {
            k = 3;
        } else if (m < 100000000u) {
            k = 4;
        } else if (m < 1000000000u) {
            k = 5;
        } else {
            k = 6;
        }
        m = sci_udiv(m, sci_pow10_u32[k]);
        e += (int32_t)k;
    } else if (m < 1000u) {
        unsigned k = m < 10u ? 3u : m < 100u ? 2u : 1u;
        m *= sci_pow10_u32[k];
        e -= (int32_t)k;
    }
    r.c = sci_signed(m, negative);
    r.e = e;
    return r;
}

/* scimath.sci_normalize(c, e, 4) for any int64 c. */
inline sci_t sci_normalize(int64_t c, int32_t e) {
    uint64_t m = sci_magnitude64(c);
    if (m <= UINT32_MAX) {
        return sci_normalize_u32((uint32_t)m, e, c < 0);
    }
    unsigned digits = 10;   /* m >= 2^32 > 10^9 */
    while (digits < 20 && m >= sci_pow10_u64[digits]) {
        digits++;
    }
    unsigned k = digits - SCI_DIGITS;
    sci_t r;
    r.c = sci_signed(sci_div_pow10_u64(m, k), c < 0);
    r.e = e + (int32_t)k;
    return r;
}

/* scimath.sci_from_int(value, 4). */
inline sci_t sci_from_int(int64_t value) {
    return sci_normalize(value, 0);
}

/* floor(m / 10^k) = (m * sci_recip_pow10[k]) >> sci_recip_shift[k] for m < 2^14 and k = 1..4
 * (each checked for every such m; the products stay below 2^32). */
extern const uint32_t sci_recip_pow10[5];
extern const uint8_t sci_recip_shift[5];
#define SCI_RECIP_LIMIT (1u << 14)

/* scimath.sci_to_int(c, e): c * 10^e truncated toward zero. The caller keeps the value
 * within int64 (|c| <= 9999 and e <= 14 always does; beyond int64 the result is not the
 * Python's); any int32 c with e < 0 is exact. A coefficient below 2^14 with -4 <= e <= 5,
 * the usual case, takes 32-bit operations: |c| 10^5 < 2^31, and a multiply and a shift in
 * place of a division (sci_recip_pow10). */
inline int64_t sci_to_int(sci_t x) {
    uint32_t m = x.c < 0 ? 0u - (uint32_t)x.c : (uint32_t)x.c;
    if (m < SCI_RECIP_LIMIT && x.e >= -4 && x.e <= 5) {
        uint32_t value = x.e >= 0 ? m * sci_pow10_u32[x.e]
                                  : (m * sci_recip_pow10[-x.e]) >> sci_recip_shift[-x.e];
        return x.c < 0 ? -(int64_t)value : (int64_t)value;
    }
    if (x.e >= 0) {
        uint64_t scale = sci_pow10_u64[x.e > 19 ? 19 : x.e];
        uint64_t product = sci_mul_32x64(m, scale);
        return x.c < 0 ? -(int64_t)product : (int64_t)product;
    }
    if (x.e <= -10) {
        return 0;   /* |c| < 2^31 < 10^10 */
    }
    m = sci_udiv(m, sci_pow10_u32[-x.e]);
    return x.c < 0 ? -(int64_t)m : (int64_t)m;
}

/* scimath.sci_mul: A = C1*C2; A / 10^4 (E + 4) when |A| >= 10^7, else A / 10^3 (E + 3). */
inline sci_t sci_mul(sci_t a, sci_t b) {
    int32_t product = a.c * b.c;
    sci_t r;
    if (product == 0) {
        r.c = 0;
        r.e = 0;
    } else if (product >= 10000000 || product <= -10000000) {
        r.c = sci_sdiv(product, 10000);
        r.e = a.e + b.e + SCI_DIGITS;
    } else {
        r.c = sci_sdiv(product, 1000);
        r.e = a.e + b.e + SCI_DIGITS - 1;
    }
    return r;
}

/* scimath.sci_add: a dropped operand when the exponents differ by 4 or more, else the sum
 * levelled to the smaller exponent and renormalised. */
inline sci_t sci_add(sci_t a, sci_t b) {
    if (a.c == 0) {
        return b;
    }
    if (b.c == 0) {
        return a;
    }
    int32_t shift = a.e - b.e;
    if (shift >= SCI_DIGITS) {
        return a;
    }
    if (shift <= -SCI_DIGITS) {
        return b;
    }
    int32_t sum;
    int32_t e;
    if (shift >= 0) {
        sum = a.c * (int32_t)sci_pow10_u32[shift] + b.c;
        e = b.e;
    } else {
        sum = a.c + b.c * (int32_t)sci_pow10_u32[-shift];
        e = a.e;
    }
    uint32_t m = sum < 0 ? 0u - (uint32_t)sum : (uint32_t)sum;
    return sci_normalize_u32(m, e, sum < 0);
}

/* scimath.sci_sub: a + (-b). */
inline sci_t sci_sub(sci_t a, sci_t b) {
    b.c = -b.c;
    return sci_add(a, b);
}

/* scimath.sci_compare: -1, 0 or 1 (exact). */
inline int sci_compare(sci_t a, sci_t b) {
    int sa = (a.c > 0) - (a.c < 0);
    int sb = (b.c > 0) - (b.c < 0);
    if (sa != sb) {
        return sa > sb ? 1 : -1;
    }
    if (sa == 0) {
        return 0;
    }
    if (a.e != b.e) {
        return a.e > b.e ? sa : -sa;
    }
    if (a.c == b.c) {
        return 0;
    }
    return a.c > b.c ? 1 : -1;
}

/* scimath.sci_div: D = C1*10^4 / C2; D / 10 (E1 - E2 - 3) when |D| >= 10^4, else D
 * (E1 - E2 - 4). Core0 only (derived constants). The device never divides by zero (the
 * Python raises ZeroDivisionError there); a zero divisor gives 0. */
sci_t sci_div(sci_t a, sci_t b);

/* float(SciNumber): the double nearest to c * 10^e (ties to even), exactly as Python's
 * int-to-float and int/int true division round. Exponents above 400 give +-infinity (the
 * Python raises OverflowError), below -400 a zero of c's sign, as the Python. Core0 only. */
double sci_to_double(sci_t x);

/* SciNumber.from_float(x, digits=4): repr(x) (the shortest decimal that reads back as x)
 * truncated toward zero to 4 significant digits, for every normal double (|x| >= 2^-1022;
 * the device converts numbers above 1e-112), and 0 for a zero. A subnormal's rounding
 * interval holds several 4-digit numbers, among which repr picks the shortest: not done
 * here (the result is then the largest 4-digit number that reads back as |x|). A NaN or an
 * infinity, which the Python refuses, gives 0. Core0 only. */
sci_t sci_from_double(double x);

#endif
