/* core0's _copy_in (core0.py): the params core1 runs with, from the RAM variables. */
#include "motor.h"
#include "platform.h"
#include "servo.h"
#include "stepper.h"

#define INTEGRAL_CAP ((int64_t)1 << 62)

static sci_t sci_value(sci_t pair) {
    return sci_normalize(pair.c, pair.e);
}

/* max(1, min(2^62, int(x))) without overflow: int(x) truncates toward zero. */
static int64_t integral_limit_of(sci_t x) {
    if (x.c <= 0) {
        return 1;
    }
    if (x.e >= 16) {
        return INTEGRAL_CAP;   /* at least 1000 * 10^16 > 2^62 */
    }
    uint64_t value;
    if (x.e >= 0) {
        value = (uint64_t)x.c * sci_pow10_u64[x.e];   /* below 10^4 * 10^15 < 2^64 */
    } else {
        value = (uint64_t)sci_to_int(x);
    }
    if (value > (uint64_t)INTEGRAL_CAP) {
        return INTEGRAL_CAP;
    }
    return value < 1u ? 1 : (int64_t)value;
}

static int64_t gcd64(int64_t a, int64_t b) {
    while (b != 0) {
        int64_t t = a % b;
        a = b;
        b = t;
    }
    return a;
}

void servo_params_finish(servo_params_t *params) {
    int64_t step = params->tick_us;
    int64_t per_second = (int64_t)params->steps * MOTOR_MICRO;
    if (step > 0 && per_second > 0) {
        int64_t g = gcd64(step, per_second);
        params->travel_num = step / g;
        params->travel_den = per_second / g;
    } else {
        params->travel_num = 0;
        params->travel_den = 1;
    }
    int64_t span = (int64_t)params->window * params->tick_us;
    if (span > 0) {
        int64_t g = gcd64(MOTOR_MICRO, span);
        params->velocity_num = MOTOR_MICRO / g;
        params->velocity_den = span / g;
    } else {
        params->velocity_num = 0;
        params->velocity_den = 1;
    }
    if (params->tick_us > 0) {
        int64_t g = gcd64(params->tick_us, MOTOR_MICRO);
        params->tick_num = params->tick_us / g;
        params->tick_den = MOTOR_MICRO / g;
    } else {
        params->tick_num = 0;
        params->tick_den = 1;
    }
    params->reach = (int32_t)(params->full / STEPPER_MICRO);
    params->sine_k = (int32_t)(params->full / 64);
    uint32_t microsteps = (uint32_t)params->reach;
    bool power_of_two = microsteps != 0u && (microsteps & (microsteps - 1u)) == 0u;
    params->full_mask = power_of_two ? microsteps - 1u : 0u;
    params->cycle_mask = power_of_two ? 4u * microsteps - 1u : 0u;
    params->holding_corner = params->holding * params->corner;
    if (params->encoder_cpr > 0 && params->per_rev > 0) {
        stepper_encoder_ratio(params->encoder_cpr, params->per_rev, &params->encoder_ratio);
    } else {
        params->encoder_ratio = (stepper_encoder_ratio_t){0, 1, STEPPER_NO_SHIFT, 0};
    }
}

void servo_params_derive(const device_vars_t *vars, servo_params_t *params) {
    int64_t tick_us = (int64_t)vars->interval_dms * 100;
    sci_t micro = sci_normalize(1, -6);
    sci_t dt_s = sci_mul(sci_from_int(tick_us), micro);
    sci_t kp = sci_value(vars->kp);
    sci_t ki_dt = sci_mul(sci_value(vars->ki), dt_s);
    int64_t window = 1000 / tick_us;
    window = window < 1 ? 1 : window > SERVO_HISTORY_SLOTS ? SERVO_HISTORY_SLOTS : window;
    sci_t kd_dt = sci_div(sci_value(vars->kd), sci_mul(dt_s, sci_from_int(window)));
    sci_t vs = sci_value(vars->source_voltage_v);
    if (vars->drive == DRIVE_STEP_CLOSED) {
        vs = sci_from_int(vars->microsteps);   /* one full step */
    }
    int64_t integral_limit = ki_dt.c == 0 ? 0 : integral_limit_of(sci_div(vs, ki_dt));
    motor_constants_t constants;
    motor_derive_constants(vars, tick_us, &constants);
    stepper_constants_t steps;
    stepper_derive(vars, tick_us, constants.steps, &steps);
    params->tick_us = tick_us;
    params->scalar = vars->scalar;
    params->kp = kp;
    params->ki_dt = ki_dt;
    params->kd_dt = kd_dt;
    params->vs = vs;
    params->motor_pins = vars->motor_pins;
    params->pins_level_per_volt =
        vars->motor_pins ? sci_div(sci_from_int(platform_motor_pins_full()), vs) : sci_normalize(0, 0);
    params->integral_limit = integral_limit;
    params->watchdog_us = (int64_t)vars->watchdog_ms * 1000;
    params->fe_limit = vars->fe_limit;
    params->diag_n = vars->diag_n;
    params->steps = constants.steps;
    params->drive = constants.drive;
    params->friction = constants.friction_speed;
    params->decay = constants.decay;
    params->lag = constants.lag;
    params->lower = vars->travel_lower_counts;
    params->upper = vars->travel_upper_counts;
    params->stop_low = constants.stop_low_micro;
    params->stop_high = constants.stop_high_micro;
    params->window = (int32_t)window;
    params->probe_side = vars->probe_side;
    params->probe_position = vars->probe_position;
    params->drive_kind = vars->drive;
    params->max_steps = steps.max_steps;
    params->cycle = steps.cycle;
    params->full = steps.full;
    params->holding = steps.holding_unm;
    params->detent = steps.detent_unm;
    params->corner = steps.corner;
    params->load_unm = steps.load_unm;
    params->viscous = steps.viscous;
    params->accel = steps.accel;
    params->encoder_cpr = vars->counts_per_revolution;
    params->per_rev = vars->full_steps * vars->microsteps;
    params->encoder_kind = vars->encoder_kind;
    params->encoder_turn =
        vars->drive == DRIVE_STEP_CLOSED ? params->per_rev : vars->counts_per_revolution;
    servo_params_finish(params);
}
