/* The simulated motor (motor.h): motor.py's motor_step and derive_constants, the same
 * operations in the same order. */
#include "motor.h"


static sci_t sci_value(sci_t pair) {
    return sci_normalize(pair.c, pair.e);
}

static sci_t sci_make(int32_t c, int32_t e) {
    return sci_normalize(c, e);
}

/* motor.py's decay_and_lag: F = 1 - exp(-ratio) and Q = tau (ratio - F) by one fixed
 * sequence of binary64 operations (no library function: expm1 is not correctly rounded
 * everywhere, and Q cancels almost all of ratio for a slow motor). */
void motor_decay_and_lag(double ratio, double tau, double *decay, double *lag) {
    int halvings = 0;
    double x = ratio;
    while (x > 0.5) {
        x = x / 2.0;
        halvings++;
    }
    double terms[MOTOR_SERIES_TERMS];
    terms[0] = x * x / 2.0;
    for (int k = 3; k < MOTOR_SERIES_TERMS + 2; k++) {
        terms[k - 2] = terms[k - 3] * x / (double)k;
    }
    double g = terms[MOTOR_SERIES_TERMS - 1];
    for (int i = MOTOR_SERIES_TERMS - 2; i >= 0; i--) {
        g = terms[i] - g;
    }
    if (halvings == 0) {
        *decay = x - g;
        *lag = tau * g;
        return;
    }
    double survivor = 1.0 - (x - g);
    for (int i = 0; i < halvings; i++) {
        survivor = survivor * survivor;
    }
    *decay = 1.0 - survivor;
    *lag = tau * (ratio - *decay);
}

void motor_derive_constants(const device_vars_t *vars, int64_t tick_us, motor_constants_t *out) {
    int64_t sim_us = (int64_t)vars->sim_update_interval_dms * 100;
    int64_t steps = (tick_us + sim_us - 1) / sim_us;
    sci_t kt = sci_mul(sci_value(vars->torque_constant_mnm_per_a), sci_make(1, -3));
    sci_t resistance = sci_value(vars->winding_resistance_ohm);
    sci_t inertia = sci_value(vars->inertia_kg_m2);
    sci_t viscous = sci_mul(sci_value(vars->viscous_friction_unm_per_rad_s), sci_make(1, -6));
    sci_t load = sci_mul(sci_value(vars->load_torque_mnm), sci_make(1, -3));
    sci_t rad_per_count = sci_div(sci_make(6283, -3), sci_from_int(vars->counts_per_revolution));
    sci_t damping = sci_add(sci_div(sci_mul(kt, kt), resistance), viscous);
    sci_t tau_s = sci_div(inertia, damping);
    sci_t drive = sci_mul(sci_div(sci_div(sci_div(kt, resistance), damping), rad_per_count),
                          sci_make(1, 6));
    sci_t friction_speed = sci_mul(sci_div(sci_div(load, damping), rad_per_count),
                                   sci_make(1, 6));
    sci_t step_s = sci_div(sci_mul(sci_from_int(tick_us), sci_make(1, -6)), sci_from_int(steps));
    /* double arithmetic as the Python's floats: IEEE-754 binary64, round to nearest even */
    double tau = sci_to_double(tau_s);
    double decay = 0.0;
    double lag = 0.0;
    motor_decay_and_lag(sci_to_double(step_s) / tau, tau, &decay, &lag);
    out->steps = (int32_t)steps;
    out->drive = drive;
    out->friction_speed = friction_speed;
    out->decay = sci_from_double(decay);
    out->lag = sci_from_double(lag);
    out->tick_us = tick_us;
    out->stop_low_micro =
        ((int64_t)vars->travel_lower_counts - vars->overtravel_counts) * MOTOR_MICRO;
    out->stop_high_micro =
        ((int64_t)vars->travel_upper_counts + vars->overtravel_counts + 1) * MOTOR_MICRO - 1;
}

void motor_step(int64_t *theta_micro, int64_t *omega_micro, sci_t drive,
                const servo_params_t *params) {
    int64_t omega = *omega_micro;
    int direction;
    if (omega > 0) {
        direction = 1;
    } else if (omega < 0) {
        direction = -1;
    } else {
        sci_t magnitude = {drive.c >= 0 ? drive.c : -drive.c, drive.e};
        if (sci_compare(magnitude, params->friction) <= 0) {
            *omega_micro = 0;
            return;
        }
        direction = drive.c > 0 ? 1 : -1;
    }
    sci_t target = direction > 0 ? sci_sub(drive, params->friction)
                                 : sci_add(drive, params->friction);
    const sci_t omega_max = {MOTOR_OMEGA_MAX_C, MOTOR_OMEGA_MAX_E};
    const sci_t omega_min = {-MOTOR_OMEGA_MAX_C, MOTOR_OMEGA_MAX_E};
    if (sci_compare(target, omega_max) > 0) {
        target = omega_max;
    } else if (sci_compare(target, omega_min) < 0) {
        target = omega_min;
    }
    /* |omega| and |target| are at most 10^12, so the gap, the change and the lag travel
     * (the gap times a decay <= 1 or a lag <= 1 s) are within 2 * 10^12 */
    int64_t gap = omega - sci_to_int(target);
    sci_t gap_sci = sci_from_int(gap);
    int64_t new_omega = omega - sci_to_int(sci_mul(gap_sci, params->decay));
    /* omega * tick_us / (steps * 10^6) truncated toward zero (_trunc_div), as the reduced
     * fraction: |omega| * travel_num is at most 10^12 * 10^6, travel_num at most 10^6 */
    uint64_t base = sci_mul_32x64((uint32_t)params->travel_num, sci_magnitude64(omega));
    if (params->travel_den != 1) {
        base = params->travel_den < 0x10000 ? sci_div_u64_small(base, (uint32_t)params->travel_den)
                                             : base / (uint64_t)params->travel_den;
    }
    int64_t travel = omega < 0 ? -(int64_t)base : (int64_t)base;
    travel -= sci_to_int(sci_mul(gap_sci, params->lag));
    if (direction > 0) {
        new_omega = new_omega > 0 ? new_omega : 0;
        travel = travel > 0 ? travel : 0;
    } else {
        new_omega = new_omega < 0 ? new_omega : 0;
        travel = travel < 0 ? travel : 0;
    }
    int64_t theta = *theta_micro + travel;
    if (theta < params->stop_low) {
        *theta_micro = params->stop_low;
        *omega_micro = 0;
    } else if (theta > params->stop_high) {
        *theta_micro = params->stop_high;
        *omega_micro = 0;
    } else {
        *theta_micro = theta;
        *omega_micro = new_omega;
    }
}
