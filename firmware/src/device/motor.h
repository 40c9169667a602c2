/* The simulated servo motor (src/usbmotion/device/motor.py): a brushed DC gearmotor with an
 * incremental encoder, integrated exactly over each step in scientific-notation integers.
 * motor_step runs on core1; motor_derive_constants on core0 (soft floating point). */
#ifndef USBMOTION_MOTOR_H
#define USBMOTION_MOTOR_H

#include <stdint.h>

#include "sci.h"
#include "servo.h"

#define MOTOR_MICRO 1000000
#define MOTOR_OMEGA_MAX_C 1000   /* the speed bound 10^12 micro-counts/s: 1000e9 */
#define MOTOR_OMEGA_MAX_E 9

/* motor.MotorConstants: what core1 needs of the motor for one servo period. */
typedef struct {
    int32_t steps;            /* integration steps per servo tick */
    sci_t drive;              /* g_v: steady speed per volt, micro-counts/s per V */
    sci_t friction_speed;     /* w_f: speed the load torque takes off, micro-counts/s */
    sci_t decay;              /* F = 1 - exp(-h/tau) for one step */
    sci_t lag;                /* Q = h - tau * F for one step, s */
    int64_t tick_us;
    int64_t stop_low_micro;   /* hard stops, micro-counts */
    int64_t stop_high_micro;
} motor_constants_t;

#define MOTOR_SERIES_TERMS 24  /* motor.SERIES_TERMS */

/* motor.decay_and_lag: F = 1 - exp(-ratio) and Q = tau * (ratio - F), bit for bit. */
void motor_decay_and_lag(double ratio, double tau, double *decay, double *lag);

/* motor.derive_constants(motor, tick_us=tick_us) over the motor variables of `vars`
 * (calls 12, 14-17, 32-34 and the overtravel). tick_us > 0. */
void motor_derive_constants(const device_vars_t *vars, int64_t tick_us, motor_constants_t *out);

/* motor.motor_step: one integration step of the motor under the drive speed `drive`
 * (g_v * V, micro-counts/s), with the friction speed, decay, lag, step length
 * (tick_us / steps, as params->travel_num / params->travel_den) and hard stops of
 * `params`. Updates the shaft position (micro-counts) and speed (micro-counts/s). */
void motor_step(int64_t *theta_micro, int64_t *omega_micro, sci_t drive,
                const servo_params_t *params);

#endif
