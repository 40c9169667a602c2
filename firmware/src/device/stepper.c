/* The simulated stepper (stepper.h): stepper.py's functions, the same operations in the same
 * order. Python's // and % floor where C's / and % truncate: every division of a value that
 * may be negative goes through floor_div or the sign-aware code below.
 *
 * Ranges (why 64 bits suffice where the Python's ints are unbounded): the shaft stays within
 * the hard stops, |theta| < (2^31 + 201) * 10^6 < 2^52; |omega| <= 10^13; the field is the
 * driver's step count in micro-microsteps (steps issued x 10^6); the torques are at most
 * 10^8 uNm (holding, detent) and 10^13 uNm (the load, call 33's 9999e6 mNm); the viscous
 * torque at most 10^13 x 6.3e4 (call 32's largest over one microstep a turn). */
#include "stepper.h"

static sci_t sci_value(sci_t pair) {
    return sci_normalize(pair.c, pair.e);
}

/* floor(n / d) of a magnitude: the hardware divider when n fits 32 bits. */
static inline uint64_t div_u64(uint64_t n, uint32_t d) {
    if ((n >> 32) == 0u) {
        return sci_udiv((uint32_t)n, d);
    }
    if (d < 0x10000u) {
        return sci_div_u64_small(n, d);
    }
    return n / d;
}

/* Python's n // d for d > 0. */
static inline int64_t floor_div(int64_t n, uint32_t d) {
    if (n >= 0) {
        return (int64_t)div_u64((uint64_t)n, d);
    }
    uint64_t magnitude = 0u - (uint64_t)n;
    return -(int64_t)div_u64(magnitude + d - 1u, d);
}

int64_t stepper_cycles(int64_t ns) {
    return (ns * (int64_t)STEPPER_CYCLES_PER_US + 999) / 1000;   /* ns >= 0 */
}

int32_t stepper_max_steps_per_tick(int64_t tick_us, int64_t pulse_ns, int64_t setup_ns) {
    int64_t room = tick_us * (int64_t)STEPPER_CYCLES_PER_US - stepper_cycles(setup_ns);
    if (room <= 0) {
        return 0;   /* max(0, room // ...): a negative room floors below 0 */
    }
    return (int32_t)(room / (2 * stepper_cycles(pulse_ns)));
}

void stepper_derive(const device_vars_t *vars, int64_t tick_us, int32_t substeps,
                    stepper_constants_t *out) {
    int64_t microsteps_per_revolution = (int64_t)vars->full_steps * vars->microsteps;
    const sci_t two_pi = sci_normalize(6283, -3);
    sci_t per_rev = sci_from_int(microsteps_per_revolution);
    sci_t micro = sci_normalize(1, 6);
    sci_t step_s = sci_div(sci_mul(sci_from_int(tick_us), sci_normalize(1, -6)),
                           sci_from_int(substeps));
    sci_t accel = sci_mul(sci_div(sci_mul(sci_div(sci_mul(per_rev, micro), two_pi),
                                          sci_normalize(1, -6)),
                                  sci_value(vars->inertia_kg_m2)),
                          step_s);
    sci_t viscous = sci_div(sci_div(sci_mul(sci_value(vars->viscous_friction_unm_per_rad_s),
                                            two_pi),
                                    per_rev),
                            micro);
    out->max_steps = stepper_max_steps_per_tick(tick_us, vars->pulse_ns, vars->setup_ns);
    out->cycle = 4 * (int64_t)vars->microsteps * STEPPER_MICRO;
    out->full = (int64_t)vars->microsteps * STEPPER_MICRO;
    out->holding_unm = (int64_t)vars->holding_mnm * 1000;
    out->detent_unm = (int64_t)vars->detent_mnm * 1000;
    out->corner = (int64_t)vars->corner_rpm * microsteps_per_revolution / 60;
    out->load_unm = sci_to_int(sci_mul(sci_value(vars->load_torque_mnm), sci_normalize(1, 3)));
    out->viscous = viscous;
    out->accel = accel;
}

static uint32_t gcd32(uint32_t a, uint32_t b) {
    while (b != 0u) {
        uint32_t t = a % b;
        a = b;
        b = t;
    }
    return a;
}

/* log2(n) for a power of two n, else STEPPER_NO_SHIFT. */
static uint32_t shift_of(uint32_t n) {
    if (n == 0u || (n & (n - 1u)) != 0u) {
        return STEPPER_NO_SHIFT;
    }
    uint32_t shift = 0;
    while ((n >> shift) != 1u) {
        shift++;
    }
    return shift;
}

void stepper_encoder_ratio(int32_t cpr, int32_t per_rev, stepper_encoder_ratio_t *out) {
    uint32_t g = gcd32((uint32_t)cpr, (uint32_t)per_rev);
    out->num = (uint32_t)cpr / g;
    out->den = (uint32_t)per_rev / g;
    out->num_shift = shift_of(out->num);
    out->den_shift = shift_of(out->den);
}

/* floor(n / d) of n < 2^32: a shift when d is a power of two (shift its log2). */
static inline uint32_t divide_u32(uint32_t n, uint32_t d, uint32_t shift) {
    return shift != STEPPER_NO_SHIFT ? n >> shift : sci_udiv(n, d);
}

int64_t stepper_encoder_ratio_microsteps(int64_t shaft, const stepper_encoder_ratio_t *ratio) {
    uint32_t num = ratio->num;
    uint32_t den = ratio->den;
    if (den <= num && ratio->den_shift != STEPPER_NO_SHIFT) {
        /* an encoder as fine as the microsteps or finer, den a power of two (4000 counts
         * over 3200 microsteps: 5 / 4): floor(shaft num / den) den = shaft num - t with
         * t = (shaft num) mod den < den <= num, so the microsteps are
         * floor((shaft num - t) / num) = shaft - ceil(t / num) = shaft - (t != 0); t is the
         * low bits of the product, which its wrapping modulo 2^32 leaves alone */
        uint32_t t = ((uint32_t)shaft * num) & (den - 1u);
        return shaft - (t != 0u);
    }
    /* the counts a turn over the microsteps a turn as the reduced num / den: the same
     * floors. |shaft| < 2^32 (within the hard stops), so |shaft| * num is one 32 x 32-bit
     * product (one 32-bit multiply when both are below 2^16), and |count| * den <=
     * |shaft| * num + den; below 2^31 both divide in 32 bits */
    uint32_t m = (uint32_t)sci_magnitude64(shaft);
    uint32_t high = 0;
    uint32_t low = (m | num) < 0x10000u ? m * num : sci_mul_32x32(m, num, &high);
    if (high == 0u && low < 0x80000000u) {
        uint32_t q = divide_u32(low, den, ratio->den_shift);
        if (shaft < 0 && q * den != low) {
            q += 1u;   /* the floor of a negative quotient */
        }
        uint32_t steps = q * den;   /* <= low + den < 2^32 */
        uint32_t r = divide_u32(steps, num, ratio->num_shift);
        if (shaft >= 0) {
            return r;
        }
        return -(int64_t)r - (r * num != steps);
    }
    int64_t counts = (int64_t)(((uint64_t)high << 32) | low);
    int64_t count = floor_div(shaft < 0 ? -counts : counts, den);
    int64_t steps = (int64_t)sci_mul_32x64(den, sci_magnitude64(count));
    return floor_div(count < 0 ? -steps : steps, num);
}

int64_t stepper_encoder_microsteps(int64_t shaft, int32_t cpr, int32_t per_rev) {
    stepper_encoder_ratio_t ratio;
    stepper_encoder_ratio(cpr, per_rev, &ratio);
    return stepper_encoder_ratio_microsteps(shaft, &ratio);
}

/* trunc_div(torque * sine, SINE_ONE) for 0 <= torque < 2^27 (10^8 uNm, call 47's largest)
 * and |sine| <= SINE_ONE = 2^14, in 32 bits: with torque = high 2^14 + low, the quotient of
 * the magnitude is high |sine| + (low |sine|) >> 14, each product below 2^28. */
static inline int32_t scaled_by_sine(int64_t torque, int32_t sine) {
    _Static_assert(TABLE_SINE_ONE == 1 << 14, "SINE_ONE is 2^14");
    uint32_t magnitude = sine < 0 ? 0u - (uint32_t)sine : (uint32_t)sine;
    uint32_t value = (uint32_t)torque;
    uint32_t scaled = (value >> 14) * magnitude + (((value & 0x3fffu) * magnitude) >> 14);
    return sine < 0 ? -(int32_t)scaled : (int32_t)scaled;
}

/* Python's x % d for 0 < d < 2^16; `mask` is d - 1 when d is a power of two (the low bits
 * of x in two's complement are its floor modulo then), else 0. */
static inline uint32_t floor_mod(int64_t x, uint32_t d, uint32_t mask) {
    if (mask != 0u || d == 1u) {
        return (uint32_t)x & mask;
    }
    uint64_t magnitude = sci_magnitude64(x);
    uint32_t rest;
    if ((magnitude >> 32) == 0u) {
        uint32_t low = (uint32_t)magnitude;
        rest = low - sci_udiv(low, d) * d;
    } else {
        rest = (uint32_t)(magnitude - sci_div_u64_small(magnitude, d) * d);
    }
    return x < 0 && rest != 0u ? d - rest : rest;
}

/* scimath.sci_from_int(omega, 4) for |omega| <= 10^13, given speed = |omega| // 10^6: at or
 * above 2^32 (10 digits or more) the 4 digits kept are those of the speed with the exponent
 * 6 more (a floor of a floor), which fits 32 bits: no 64-bit division. */
static inline sci_t speed_sci(int64_t omega, uint32_t speed) {
    uint64_t magnitude = sci_magnitude64(omega);
    if ((magnitude >> 32) == 0u) {
        return sci_normalize_u32((uint32_t)magnitude, 0, omega < 0);
    }
    return sci_normalize_u32(speed, 6, omega < 0);
}

/* stepper.speed_change: sci_to_int of a speed change, capped at 10^15 in magnitude (any
 * change beyond 2 x 10^13 takes the speed past its bound or through 0 alike). Up to 10^5
 * a 4-digit coefficient's product stays within 32 bits. */
static inline int64_t speed_change(sci_t change) {
    if (change.e > 11) {
        return change.c < 0 ? -1000000000000000LL : 1000000000000000LL;
    }
    if (change.e >= 6) {
        /* |c| 10^(e - 6) < 10^9, times 10^6 in one 32 x 32-bit product */
        uint32_t m = change.c < 0 ? 0u - (uint32_t)change.c : (uint32_t)change.c;
        uint32_t high;
        uint32_t low = sci_mul_32x32(m * sci_pow10_u32[change.e - 6], 1000000u, &high);
        uint64_t value = ((uint64_t)high << 32) | low;
        return change.c < 0 ? -(int64_t)value : (int64_t)value;
    }
    return sci_to_int(change);
}

/* holding * corner // speed for speed > corner >= 0 (a nonnegative product below 2^57);
 * speed <= 10^7 < 2^24 (|omega| <= STEPPER_OMEGA_MAX). A product below 2^40 (the power-up
 * stepper's is 2.4 x 10^10) divides in two 32-bit divisions, its top 32 bits and then the
 * remainder (below speed < 2^24) with its last 8. */
static inline int64_t torque_above_corner(const servo_params_t *p, uint32_t speed) {
    uint64_t product = (uint64_t)p->holding_corner;
    if (speed < 0x10000u) {
        return (int64_t)sci_div_u64_small(product, speed);
    }
    if ((product >> 40) == 0u) {
        uint32_t high = (uint32_t)(product >> 8);
        uint32_t q_high = sci_udiv(high, speed);
        uint32_t rest = high - q_high * speed;
        uint32_t q_low = sci_udiv((rest << 8) | ((uint32_t)product & 0xffu), speed);
        return ((int64_t)q_high << 8) + q_low;
    }
    return (int64_t)(product / speed);
}

void stepper_step(int64_t *theta_io, int64_t *omega_io, int64_t field, int32_t powered,
                  const servo_params_t *p) {
    int64_t theta = *theta_io;
    int64_t omega = *omega_io;
    /* the shaft at count + fraction / 10^6 microsteps, 0 <= fraction < 10^6; the sines'
     * angles taken modulo their periods (sine_at) through the whole microsteps, their table
     * index floor(rest * SINE_SIZE / period) with period = 4 u 10^6 (the cycle) or u 10^6
     * (a full step) as rest * 4 or rest * 16 over u * 15625 (sine_k): below 2^32 */
    _Static_assert(TABLE_SINE_SIZE == 1024u, "the index's scaling is for 1024 entries");
    int64_t count = floor_micro(theta);
    uint32_t fraction = (uint32_t)theta - (uint32_t)count * (uint32_t)STEPPER_MICRO;
    uint32_t microsteps = (uint32_t)p->reach;
    uint32_t sine_k = (uint32_t)p->sine_k;
    /* |omega| // 10^6 (microsteps/s, below 2^24) */
    uint32_t speed = (uint32_t)sci_div_u64_small(sci_magnitude64(omega) >> 6, 15625u);
    int32_t pull = 0;   /* |pull|, |torque| <= 2 x 10^8 */
    if (powered == 1) {
        int64_t available = speed <= p->corner ? p->holding : torque_above_corner(p, speed);
        /* field * 10^6 - theta = (field - count - 1) * 10^6 + (10^6 - fraction) */
        uint32_t rest = fraction != 0u
            ? floor_mod(field - count - 1, 4u * microsteps, p->cycle_mask) *
                      (uint32_t)STEPPER_MICRO + ((uint32_t)STEPPER_MICRO - fraction)
            : floor_mod(field - count, 4u * microsteps, p->cycle_mask) *
                      (uint32_t)STEPPER_MICRO;
        pull = scaled_by_sine(available, table_sine[sci_udiv(rest << 2, sine_k)]);
    }
    uint32_t detent_rest =
        floor_mod(count, microsteps, p->full_mask) * (uint32_t)STEPPER_MICRO + fraction;
    int32_t torque = pull - scaled_by_sine(p->detent,
                                           table_sine[sci_udiv(detent_rest << 4, sine_k)]);
    int64_t load = p->load_unm;
    int64_t net;
    if (omega == 0) {
        if (-load <= torque && torque <= load) {
            *omega_io = 0;
            return;
        }
        net = torque > 0 ? torque - load : torque + load;
    } else {
        int64_t viscous = sci_to_int(sci_mul(speed_sci(omega, speed), p->viscous));
        net = torque - viscous - (omega > 0 ? load : -load);
    }
    int64_t new_omega = omega + speed_change(sci_mul(sci_from_int(net), p->accel));
    if ((omega > 0 && new_omega < 0) || (omega < 0 && new_omega > 0)) {
        new_omega = 0;
    }
    if (new_omega > STEPPER_OMEGA_MAX) {
        new_omega = STEPPER_OMEGA_MAX;
    } else if (new_omega < -STEPPER_OMEGA_MAX) {
        new_omega = -STEPPER_OMEGA_MAX;
    }
    /* stepper.travel: new_omega * tick_us / (steps * 10^6) truncated toward zero, as the
     * reduced fraction: |new_omega| * travel_num <= 10^13 * 10^6 < 2^64 */
    uint64_t moved = sci_magnitude64(new_omega);
    if (p->travel_num != 1) {
        moved = sci_mul_32x64((uint32_t)p->travel_num, moved);
    }
    if (p->travel_den != 1) {
        moved = p->travel_den < 0x10000 ? sci_div_u64_small(moved, (uint32_t)p->travel_den)
                                        : moved / (uint64_t)p->travel_den;
    }
    theta += new_omega < 0 ? -(int64_t)moved : (int64_t)moved;
    if (theta < p->stop_low) {
        *theta_io = p->stop_low;
        *omega_io = 0;
    } else if (theta > p->stop_high) {
        *theta_io = p->stop_high;
        *omega_io = 0;
    } else {
        *theta_io = theta;
        *omega_io = new_omega;
    }
}
