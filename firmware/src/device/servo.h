/* core1: the servo loop over flat state, mirroring src/usbmotion/device/core1.py field for
 * field (the S_* entries are servo_state_t, the P_* entries servo_params_t). Every value is
 * the integer the Python device holds; the widths below hold every value it can reach. */
#ifndef USBMOTION_SERVO_H
#define USBMOTION_SERVO_H

#include <stdbool.h>
#include <stdint.h>

#include "absenc.h"
#include "platform.h"
#include "sci.h"

#define MODE_POSITION 1
#define MODE_VELOCITY 2
#define MODE_CURVE 3

#define DRIVE_DC 0            /* call 44: a DC motor */
#define DRIVE_STEP_OPEN 1     /* step/direction, open loop */
#define DRIVE_STEP_CLOSED 2   /* step/direction, closed loop */

#define FAULT_NONE 0
#define FAULT_WATCHDOG 1
#define FAULT_FOLLOWING_ERROR 2
#define FAULT_LIMIT_SWITCH 3
#define FAULT_INTERNAL 4
#define FAULT_ENCODER_LOST 5   /* not in core1.py: the absolute encoder on the pins is silent */

#define PROBE_SIDE_NONE 0
#define PROBE_SIDE_BELOW 1   /* the probe closes at or below the surface */
#define PROBE_SIDE_ABOVE 2   /* ... at or above it */

#define SERVO_HISTORY_SLOTS 10
#define CURVE_BUFFER_CAPACITY 8
#define VELOCITY_RESET_US 60000000LL
#define TIMER_CAP_US (1LL << 62)
#define STATS_SUM_CAP (1LL << 62)
#define MICRO 1000000LL
#define OUTPUT_COUNT 4
_Static_assert(OUTPUT_COUNT == PLATFORM_OUTPUT_COUNT, "the platform's outputs are call 42's");
#define OUTPUT_QUEUE_CAPACITY 16u
#define OUTPUT_NONE_PENDING (1LL << 62)   /* `next` with no change pending: beyond every clock */

/* One Hermite keyframe as call 25 carries it (hermite.Keyframe). */
typedef struct {
    uint16_t duration_ms;
    int32_t position_counts;
    int16_t tangent_in;
    int16_t tangent_out;
} keyframe_t;

/* A segment's numerator as a polynomial in the elapsed e (curve.c): c1 = D m0 d^2 and
 * c2 = d (3072 dp - D (2m0 + m1)) as their magnitudes' factors, c3 = D (m0 + m1) - 2048 dp,
 * for d = 1000 D and dp = p1 - p0. */
typedef struct {
    uint32_t d;
    uint32_t d2[2];          /* d^2 */
    int32_t m0;
    uint32_t dm0;            /* D |m0| < 2^31 */
    bool m0_negative;
    uint64_t k2_magnitude;   /* |3072 dp - D (2m0 + m1)| < 2^45 */
    bool k2_negative;
    int64_t c3;
} curve_coefficients_t;

/* A segment's exact numerator (plus den / 2) and its three forward differences, each as
 * quotient * den + remainder (0 <= remainder < den, little-endian 32-bit words), so that a
 * tick within a segment costs additions (curve.c). */
typedef struct {
    int64_t quotient[4];
    uint32_t remainder[4][4];
    uint32_t den[4];           /* 1024 * (duration_ms * 1000)^3 */
} curve_differences_t;

/* A keyframe's segment prepared by core0 when it was appended (curve.c
 * curve_prepare_keyframe): its numerator and differences at its start for ticks of
 * step_us, valid for a segment that starts at p0 with the out-tangent m0 (the keyframe
 * appended before it), so that the tick that starts it only switches to them. */
typedef struct {
    bool ready;
    int32_t p0;
    int32_t m0;
    int32_t step_us;
    curve_differences_t differences;
} curve_prepared_t;

/* The keyframe buffer and the player of curve mode (device/curve.py CurvePlayer). What a
 * stepping tick reads comes first: the M0+ reaches a field at a small offset (bytes below
 * 32, words below 128) from the pointer in one instruction. */
typedef struct {
    bool playing;
    bool stepping;
    uint8_t head;
    uint8_t count;
    uint8_t warming;
    /* Not in curve.py: the playing segment's differences, valid while `stepping`, for ticks
     * of step_us (a cache the curve_* functions keep): `own` (active 0) or those core0
     * prepared for the head keyframe (active: its slot + 1). */
    uint8_t active;
    int32_t step_us;
    int64_t elapsed_us;
    curve_differences_t own;
    keyframe_t buffer[CURVE_BUFFER_CAPACITY];
    int32_t start_position;
    int32_t start_tangent;
    /* Each buffered keyframe's segment as core0 prepared it (the slot of buffer[]), and the
     * keyframe core0 appended last (since the buffer was cleared: has_last), which the next
     * one's segment starts from (core1 never writes them). core0 writes a slot only when it
     * appends into it, a slot no keyframe holds; core1 steps the head's differences in place
     * once its segment started from them (`active`), and is done with them when it pops it. */
    curve_prepared_t prepared[CURVE_BUFFER_CAPACITY];
    keyframe_t last;
    bool has_last;
    /* A segment started without its differences prepared (a curve's first, or one started
     * again after the curve was interrupted) prepares them over its first ticks instead
     * of on one (`warming` counts the ticks of that left: curve.c curve_warm_step), with the
     * segment's coefficients and a scratch slot meanwhile. */
    curve_coefficients_t coefficients;
    int64_t warm_quotient;
    uint32_t warm_remainder[4];
} curve_player_t;

/* The latch of one limit switch (call 36) or of the probe input (call 41). */
typedef struct {
    uint32_t edges;    /* edges since power-up, modulo 2^32 */
    int32_t closed;    /* 1: the last edge closed the switch */
    int32_t position;  /* the counter on that tick, in the counter's current coordinates */
    int64_t tick;      /* the clock after that tick; 0: no edge yet */
} switch_edge_t;

/* The outputs' values, per mille (0..1000, call 43's); `words` copies them in two moves. */
typedef union {
    int16_t per_mille[OUTPUT_COUNT];
    uint32_t words[OUTPUT_COUNT / 2];
} output_values_t;

/* The pending changes of call 42 for one tick, as the outputs stand once they applied
 * (core1.py OUT_RECORD): core0 queues a change into the last record when it is for that
 * record's tick, else into a new one. */
typedef struct {
    int64_t tick;                   /* the clock at the start of the tick they apply on */
    output_values_t values;         /* every output once they applied */
    output_pins_t pins;             /* Not in core1.py: the values in the platform's form */
    uint32_t changes;               /* the changes it holds, 1..OUTPUT_QUEUE_CAPACITY */
} output_record_t;

/* The outputs and the changes pending for them (core1.py S_OUT*), together so that the tick
 * that applies a change reaches them from one pointer. */
typedef struct {
    int64_t next;              /* the oldest pending record's tick, or OUTPUT_NONE_PENDING:
                                * what a tick compares its clock with */
    int64_t last;              /* the clock at the start of the tick that applied the last
                                * change; -1: none yet */
    uint32_t records;          /* records pending (one per tick with changes) */
    uint32_t head;             /* the oldest one's slot in queue */
    output_values_t values;    /* the outputs now (call 43) */
    output_record_t queue[OUTPUT_QUEUE_CAPACITY];
} output_queue_t;

/* What core1 changes (core1.py S_*). */
typedef struct {
    int64_t clock;
    int32_t enable;
    int32_t mode;
    int32_t fault;
    int64_t fault_tick;
    int64_t theta;             /* shaft, micro-counts from power-up (not wrapped) */
    int64_t omega;             /* shaft speed, micro-counts/s */
    int32_t offset;            /* counter minus shaft count */
    int32_t actual;            /* the encoder counter (int32, wraps) */
    uint32_t counts_pos;
    int64_t velocity;          /* counts/s over the derivative window */
    int32_t desired;
    int32_t desired_vel;
    int64_t integral;
    uint32_t history_pos;
    int32_t fresh;
    sci_t out;                 /* PID output, V */
    int64_t motion_left;
    int64_t start;             /* armed start tick, or -1 */
    int64_t since_command_us;
    int64_t velocity_mode_us;
    int64_t diag_left;
    int32_t limits;            /* bit 0 lower, bit 1 upper */
    int64_t history[SERVO_HISTORY_SLOTS];       /* errors of the last window ticks */
    int32_t counts[SERVO_HISTORY_SLOTS];        /* counters of the last window ticks */
    int64_t stats_ticks;
    int64_t stats_max;
    int64_t stats_max_tick;
    int64_t stats_sum_sq;
    int64_t last_take;
    int32_t diag_peak;         /* the next diagnostics line's peak: the counted following
                                * error of the largest magnitude since the last line, signed */
    switch_edge_t edges[2];    /* lower, upper */
    switch_edge_t probe_edge;  /* the probe input's last edge (call 41) */
    int32_t probe;             /* the probe input now: 1 closed (touching) */
    int64_t phase;             /* step drives: the driver's step counter, the steps issued
                                * since the drive was set (signed, not wrapped) */
    int32_t last_steps;        /* step drives: the steps the last tick issued */
    int64_t vel_acc;           /* step drives in velocity mode: the desired velocity's travel
                                * not yet a whole microstep, microsteps x 10^6 */
    int32_t desired_prev;      /* the desired position of the tick before */
    output_queue_t outputs;    /* call 42's changes and the outputs they set */
    curve_player_t curve;
    /* Not in core1.py: the motor on the pins (servo_tick_pins). A tick there reads the
     * encoder and the switches as it starts, which completes the tick before it (its
     * encoder step, faults, clock, statistics and records, with `pins_enabled` as it ran),
     * then runs its own motion update, PID and output. */
    bool pins_started;         /* a tick has started and waits for the next to complete it */
    bool pins_enabled;         /* ... and it ran enabled */
    uint32_t pins_edges[2];    /* the switches' edges taken into edges[] so far */
    absenc_t absenc;           /* the absolute encoder on the pins (call 49 kind 1) */
    int64_t absenc_quiet_us;   /* ... the time since its last frame, capped */
    bool encoder_lost;         /* ... no frame for ABSENC_TIMEOUT_US: fault 5 while enabled */
} servo_state_t;

/* A ratio num / den in lowest terms and the shift that divides by each, its log2 when it is a
 * power of two, else STEPPER_NO_SHIFT (stepper.c). */
#define STEPPER_NO_SHIFT 32u
typedef struct {
    uint32_t num;
    uint32_t den;
    uint32_t num_shift;
    uint32_t den_shift;
} stepper_encoder_ratio_t;

/* What core0 copies in when a variable changes (core1.py P_*). */
typedef struct {
    int64_t tick_us;
    int64_t scalar;
    sci_t kp;
    sci_t ki_dt;               /* Ki times the period, V per error-tick */
    sci_t kd_dt;               /* Kd over the window, V per error change */
    sci_t vs;                  /* source voltage, the output ceiling */
    int64_t integral_limit;    /* 0: integrator off */
    int64_t watchdog_us;
    int64_t fe_limit;
    int64_t diag_n;
    int32_t steps;             /* motor integration steps per tick */
    sci_t drive;
    sci_t friction;
    sci_t decay;
    sci_t lag;
    int32_t lower;             /* switch positions, counts from power-up */
    int32_t upper;
    int64_t stop_low;          /* hard stops, micro-counts */
    int64_t stop_high;
    int32_t window;            /* derivative window, ticks (1..SERVO_HISTORY_SLOTS) */
    int32_t probe_side;        /* the simulated probe surface (call 40): PROBE_SIDE_* */
    int32_t probe_position;    /* ... counts from power-up */
    int32_t drive_kind;        /* call 44 (core1.py P_DRIVE): DRIVE_* */
    int32_t max_steps;         /* step drives: the most steps one tick issues */
    int64_t cycle;             /* the simulated stepper's electrical cycle, micro-microsteps */
    int64_t full;              /* a full step, micro-microsteps (the detent's period) */
    int64_t holding;           /* holding torque, uNm */
    int64_t detent;            /* detent torque, uNm */
    int64_t corner;            /* corner speed, microsteps/s */
    int64_t load_unm;          /* call 33's load torque, uNm (the stepper's) */
    sci_t viscous;             /* uNm per micro-microstep/s (the stepper's) */
    sci_t accel;               /* micro-microsteps/s per uNm over one sub-step */
    int32_t encoder_cpr;       /* call 16: the closed loop's encoder counts per revolution */
    int32_t per_rev;           /* call 45: microsteps per revolution */
    /* Not in core1.py: the motor on the pins (call 39, at power-up) and the bridge's level
     * per volt of output (platform_motor_pins_full over the supply voltage). */
    int32_t motor_pins;
    sci_t pins_level_per_volt;
    /* Not in core1.py: the tick's two divisions as reduced fractions, set by
     * servo_params_finish from tick_us, steps and window (servo_params_derive calls it), so
     * that the usual periods divide by a small number or not at all. */
    int64_t travel_num;        /* tick_us / (steps * 10^6) = travel_num / travel_den */
    int64_t travel_den;
    int64_t velocity_num;      /* 10^6 / (window * tick_us) = velocity_num / velocity_den */
    int64_t velocity_den;
    /* Not in core1.py: from full, holding and corner (servo_params_finish). */
    int32_t reach;             /* full / 10^6: a full step, microsteps (the closed loop's lead) */
    int32_t sine_k;            /* full / 64: the sines' table index divides by it (stepper.c) */
    uint32_t full_mask;        /* microsteps - 1 when a power of two, else 0 (stepper.c) */
    uint32_t cycle_mask;       /* 4 microsteps - 1 likewise */
    int64_t holding_corner;    /* holding * corner, the torque above the corner times the speed */
    /* Not in core1.py: encoder_cpr / per_rev reduced (stepper_encoder_ratio). */
    stepper_encoder_ratio_t encoder_ratio;
    /* Not in core1.py: tick_us / 10^6 reduced (servo_params_finish): the closed loop's
     * rotor moves velocity * tick_num / tick_den microsteps a tick. */
    int64_t tick_num;
    int64_t tick_den;
    /* Not in core1.py: call 49's kind, and the counts of a turn its angle is in (call 16's
     * counts per revolution, a closed-loop stepper's microsteps per revolution); last, out
     * of the way of the simulated motor's hot fields. */
    int32_t encoder_kind;
    int32_t encoder_turn;
} servo_params_t;

/* The RAM variables core0 owns and the calls set (core0.py Device fields). Gains and the
 * scientific-notation motor parameters are (coefficient, exponent) as the calls carry them. */
typedef struct {
    int32_t interval_dms;               /* call 5 */
    int32_t scalar;                     /* call 6 */
    sci_t kp, ki, kd;                   /* calls 9-11 */
    int32_t sim_update_interval_dms;    /* call 12 */
    sci_t source_voltage_v;             /* call 13 */
    sci_t torque_constant_mnm_per_a;    /* call 14 */
    sci_t winding_resistance_ohm;       /* call 15 */
    int32_t counts_per_revolution;      /* call 16 */
    sci_t inertia_kg_m2;                /* call 17 */
    sci_t viscous_friction_unm_per_rad_s; /* call 32 */
    sci_t load_torque_mnm;              /* call 33 */
    int32_t travel_lower_counts;        /* call 34 */
    int32_t travel_upper_counts;
    int32_t overtravel_counts;          /* 200, fixed */
    int32_t diag_n;                     /* call 21 */
    int32_t watchdog_ms;                /* call 28 */
    int32_t fe_limit;                   /* call 29 */
    int32_t motor_pins;                 /* call 39 as the flash held it at power-up */
    int32_t probe_side;                 /* call 40 */
    int32_t probe_position;
    int32_t drive;                      /* call 44 */
    int32_t full_steps;                 /* call 45 */
    int32_t microsteps;
    int32_t pulse_ns;                   /* call 46 */
    int32_t setup_ns;
    int32_t holding_mnm;                /* call 47 */
    int32_t detent_mnm;
    int32_t corner_rpm;
    int32_t encoder_kind;               /* call 49 */
    int32_t encoder_angle;
} device_vars_t;

/* The records core1 writes for core0 to print, in order: a diagnostics line (call 21) or an
 * alarm (a fault latched). A single-producer (core1), single-consumer (core0) ring. */
#define RECORD_DIAGNOSTICS 1
#define RECORD_ALARM 2
typedef struct {
    uint8_t kind;
    int64_t clock;             /* diagnostics: the clock; alarm: the fault tick */
    int64_t desired;           /* the desired velocity in mode 2 */
    int64_t actual;
    int64_t velocity;
    sci_t out;
    int32_t queued;            /* keyframes in mode 3, queue values otherwise */
    int32_t peak;              /* the peak following error since the line before */
    int32_t fault;             /* alarm: the fault code */
} record_t;
#define RECORD_RING_SLOTS 512u
typedef struct {
    record_t slots[RECORD_RING_SLOTS];
    volatile uint32_t head;    /* written by core1 */
    volatile uint32_t tail;    /* written by core0 */
    volatile uint32_t dropped; /* records core1 could not write (ring full) */
} record_ring_t;

/* core1.wrap_int32: the int32 the hardware counter holds (two's complement wrap). */
static inline int32_t wrap_int32(int64_t value) {
    uint32_t bits = (uint32_t)value;
    return bits < 0x80000000u ? (int32_t)bits : -(int32_t)(~bits) - 1;
}

/* theta // 10^6 (floor), as floor(floor(|theta| / 2^6) / 15625) on the magnitude (below
 * 2^52): a 14-bit divisor, two 32-bit divisions. */
static inline int64_t floor_micro(int64_t theta) {
    if (theta >= 0) {
        return (int64_t)sci_div_u64_small((uint64_t)theta >> 6, 15625u);
    }
    uint64_t magnitude = 0u - (uint64_t)theta;
    return -(int64_t)sci_div_u64_small((magnitude + (MICRO - 1)) >> 6, 15625u);
}

/* trunc_div(value, 10^6) for |value| < 2^54, as floor_micro on the magnitude. */
static inline int64_t trunc_micro(int64_t value) {
    uint64_t magnitude = sci_div_u64_small(sci_magnitude64(value) >> 6, 15625u);
    return value < 0 ? -(int64_t)magnitude : (int64_t)magnitude;
}

/* Power-up state (core1.new_state): zeroes, start -1, mode from flash, last_take -1. */
void servo_state_init(servo_state_t *state, int32_t mode);

/* core0's _copy_in: the params core1 runs with, from the RAM variables. Soft floating point
 * (the motor's exponential), never called on core1. */
void servo_params_derive(const device_vars_t *vars, servo_params_t *params);

/* The fields of servo_params_t that are not core1.py's (travel_*, velocity_*, reach,
 * holding_corner, encoder_ratio), from tick_us, steps, window, full, holding, corner,
 * encoder_cpr and per_rev: whoever fills the others without servo_params_derive calls
 * this. */
void servo_params_finish(servo_params_t *params);

/* One servo tick (core1.servo_block for one tick, with curve mode's player run by core1 on
 * each running tick, as core0.py's _run_curve feeds it). The caller holds the servo lock.
 * Takes motion values with mq_try_remove (platform.h) and reads mq_level for the records.
 * Writes to `ring`, in this order, a diagnostics record when one is due and an alarm record
 * when a fault latched on this tick; a full ring counts the record in `dropped` instead. */
void servo_tick(servo_state_t *state, const servo_params_t *params, record_ring_t *ring);

/* One servo tick with the motor on the pins (params->motor_pins): the tick before this one
 * completed on the encoder count and the switches read now, then this one's motion update,
 * PID and bridge output. The caller holds the servo lock. */
void servo_tick_pins(servo_state_t *state, const servo_params_t *params, record_ring_t *ring);

/* Power-up with the motor on the pins (or a change of drive): the switches and the probe as
 * they read, no edge yet, the counter at 0 (an absolute encoder's: its angle, from the first
 * frame). `params` already the drive's. The caller holds the servo lock. */
void servo_pins_power_up(servo_state_t *state, const servo_params_t *params,
                         motor_pins_sample_t *sample);

/* The encoder input on the pins changed (call 49, platform_motor_pins_encoder; `params`
 * already the new kind's), `sample` read after it: the incremental counter counts on from
 * where it stood; an absolute one takes its angle from the first frame. The caller holds the
 * servo lock. */
void servo_pins_encoder_changed(servo_state_t *state, const servo_params_t *params,
                                motor_pins_sample_t *sample);

/* The switch bits the shaft position gives (core0._switches). */
int32_t servo_switches(const servo_state_t *state, const servo_params_t *params);

/* The simulated probe input the shaft position gives (core0._probe). */
int32_t servo_probe(const servo_state_t *state, const servo_params_t *params);

/* Calls 22 and 43: forget the pending output changes; the outputs stay as they are. */
void servo_drop_pending_outputs(servo_state_t *state);

/* Calls 42 and 43: the output changes pending (the records' changes). */
uint32_t servo_pending_outputs(const servo_state_t *state);

/* Calls 23 and 37: move the counter's coordinates by `shift` (core0._shift_position, without
 * the queue and curve clearing, which the caller does). */
void servo_shift_position(servo_state_t *state, int64_t shift);

/* Curve mode's buffer (core0 calls these with the servo lock held, but
 * curve_prepare_keyframe). curve_prepare_keyframe derives the segment that ends at
 * `keyframe` (from the keyframe appended before it) for ticks of tick_us: core0's work,
 * outside the lock (it reads only what core0 writes); curve_append_prepared appends the
 * keyframe with it. A keyframe that continues a curve which reached its last keyframe
 * exactly on the last tick starts its segment there, from what was prepared (or, not
 * prepared, over the next ticks). curve_append is both in one, for the period the player
 * last ran at. */
void curve_prepare_keyframe(const curve_player_t *curve, keyframe_t keyframe, int64_t tick_us,
                            curve_prepared_t *prepared);
bool curve_append_prepared(curve_player_t *curve, keyframe_t keyframe,
                           const curve_prepared_t *prepared);   /* false: full */
bool curve_append(curve_player_t *curve, keyframe_t keyframe);  /* false: full */
void curve_clear(curve_player_t *curve);
void curve_interrupt(curve_player_t *curve);
uint32_t curve_queued(const curve_player_t *curve);

#endif
