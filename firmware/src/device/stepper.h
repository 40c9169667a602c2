/* The simulated stepper and the step/direction drive's arithmetic (calls 44-48), as
 * src/usbmotion/device/stepper.py: a two-phase hybrid stepper on a microstepping driver,
 * its field pulling the rotor toward the driver's step count through the generated sine
 * table (table.h, from stepper.SINE), a detent torque, a torque that falls as 1/speed above
 * the corner speed, friction and a load, integrated in 4-digit scientific notation.
 * stepper_step runs on core1; stepper_derive on core0. Positions are micro-microsteps
 * (microsteps x 10^6), speeds micro-microsteps/s. */
#ifndef USBMOTION_STEPPER_H
#define USBMOTION_STEPPER_H

#include <stdint.h>

#include "sci.h"
#include "servo.h"
#include "table.h"

#define STEPPER_MICRO 1000000
#define STEPPER_OMEGA_MAX 10000000000000LL   /* stepper.STEPPER_OMEGA_MAX: 10^7 microsteps/s */
#define STEPPER_CYCLES_PER_US (TABLE_STEP_CLOCK_HZ / 1000000u)

/* stepper.StepperConstants: what core1 needs of the stepper for one servo period. */
typedef struct {
    int32_t max_steps;     /* steps one tick can issue (call 48's max_per_tick) */
    int64_t cycle;         /* an electrical cycle (4 full steps), micro-microsteps */
    int64_t full;          /* a full step, micro-microsteps */
    int64_t holding_unm;
    int64_t detent_unm;
    int64_t corner;        /* the corner speed, microsteps/s */
    int64_t load_unm;
    sci_t viscous;         /* uNm per micro-microstep/s */
    sci_t accel;           /* micro-microsteps/s per uNm over one sub-step */
} stepper_constants_t;

/* stepper.cycles: ns in whole periods of the step clock, rounded up. */
int64_t stepper_cycles(int64_t ns);

/* stepper.max_steps_per_tick: the steps a tick of tick_us can issue after the set-up, a
 * pulse high and as long low each (0: not even one fits). */
int32_t stepper_max_steps_per_tick(int64_t tick_us, int64_t pulse_ns, int64_t setup_ns);

/* stepper.derive_stepper over the stepper and motor variables of `vars` (calls 16, 17, 32,
 * 33 and 45-47) for a servo period of tick_us in `substeps` sub-steps: the same
 * scientific-notation operations in the same order. Core0 only. */
void stepper_derive(const device_vars_t *vars, int64_t tick_us, int32_t substeps,
                    stepper_constants_t *out);

/* stepper.encoder_microsteps: an encoder of cpr counts a turn on a shaft at `shaft` whole
 * microsteps (of per_rev a turn): its count floored, in microsteps floored. */
int64_t stepper_encoder_microsteps(int64_t shaft, int32_t cpr, int32_t per_rev);

/* cpr / per_rev reduced (servo_params_finish keeps it in the params: the tick's encoder
 * divides by small numbers, by shifts when they are powers of two). */
void stepper_encoder_ratio(int32_t cpr, int32_t per_rev, stepper_encoder_ratio_t *out);

/* stepper_encoder_microsteps through the reduced ratio: the same result. */
int64_t stepper_encoder_ratio_microsteps(int64_t shaft, const stepper_encoder_ratio_t *ratio);

/* stepper.stepper_step: one integration sub-step of the shaft (theta, omega) under the
 * driver's step count `field`, the field pulling while `powered`, with the constants, the
 * sub-step's length (params->travel_num / travel_den) and the hard stops of `params`
 * (servo_params_finish run on them). The field is in whole microsteps here (the tick's
 * field always is: the steps issued): the Python's field is field * 10^6. */
void stepper_step(int64_t *theta, int64_t *omega, int64_t field, int32_t powered,
                  const servo_params_t *params);

#endif
