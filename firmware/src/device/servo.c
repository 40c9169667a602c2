/* core1's servo tick (servo.h): core1.servo_block for one tick, the same operations in the
 * same order, over servo_state_t and servo_params_t; and the state changes core0 makes on
 * core1's state (power-up, switches, the probe, coordinate shift).
 *
 * Ranges (why int64 suffices where the Python's ints are unbounded): the shaft stays within
 * the hard stops, |theta| < (2^31 + 201) * 10^6 < 2^52; |omega| <= 10^12 (motor_step moves it
 * toward a target clamped to 10^12, by a decay of at most 1); the velocity is at most
 * 2^31 * 10^6 / 600 in magnitude (window * tick_us >= 600), so errors and their changes are
 * below 2^43; the integral sum is clamped to the integral limit <= 2^62 and one error more
 * stays below 2^63; a square of a following error is at most 2^62; the timer stops at 2^62. */
#include <stdatomic.h>

#include "curve.h"
#include "motor.h"
#include "platform.h"
#include "servo.h"
#include "stepper.h"

#define EDGE_TICK_NONE 0

static inline void shift_edge(switch_edge_t *edge, int64_t shift) {
    if (edge->tick != EDGE_TICK_NONE) {
        edge->position = wrap_int32((int64_t)edge->position + shift);
    }
}

/* core1.shift_edges: the switches' and the probe's latched positions */
static void shift_edges(servo_state_t *state, int64_t shift) {
    shift_edge(&state->edges[0], shift);
    shift_edge(&state->edges[1], shift);
    shift_edge(&state->probe_edge, shift);
}

/* core1.probe_closed: the simulated probe input at this shaft count. */
static inline int32_t probe_closed(int64_t count, const servo_params_t *p) {
    if (p->probe_side == PROBE_SIDE_BELOW) {
        return count <= p->probe_position;
    }
    if (p->probe_side == PROBE_SIDE_ABOVE) {
        return count >= p->probe_position;
    }
    return 0;
}

/* The slot the next record goes to, or NULL (counted as dropped) when the ring is full;
 * ring_commit publishes it. The record is written in place: no copy. */
static record_t *ring_slot(record_ring_t *ring) {
    uint32_t head = ring->head;
    if (head - ring->tail >= RECORD_RING_SLOTS) {
        ring->dropped = ring->dropped + 1u;
        return 0;
    }
    return &ring->slots[head % RECORD_RING_SLOTS];
}

static void ring_commit(record_ring_t *ring) {
    atomic_thread_fence(memory_order_release);   /* the record before the head */
    ring->head = ring->head + 1u;
}

void servo_state_init(servo_state_t *state, int32_t mode) {
    *state = (servo_state_t){0};
    state->mode = mode;
    state->start = -1;
    state->last_take = -1;
    state->outputs.next = OUTPUT_NONE_PENDING;
    state->outputs.last = -1;
}

void servo_drop_pending_outputs(servo_state_t *state) {
    state->outputs.records = 0;
    state->outputs.head = 0;
    state->outputs.next = OUTPUT_NONE_PENDING;
}

uint32_t servo_pending_outputs(const servo_state_t *state) {
    const output_queue_t *q = &state->outputs;
    uint32_t changes = 0;
    for (uint32_t k = 0; k < q->records; k++) {
        changes += q->queue[(q->head + k) % OUTPUT_QUEUE_CAPACITY].changes;
    }
    return changes;
}

/* The oldest pending record, taken off the queue; `next` the tick of the one after it. */
static inline const output_record_t *output_pop(output_queue_t *q) {
    uint32_t head = q->head;
    const output_record_t *record = &q->queue[head];
    head = (head + 1u) % OUTPUT_QUEUE_CAPACITY;
    q->head = head;
    uint32_t records = q->records - 1u;
    q->records = records;
    q->next = records != 0 ? q->queue[head].tick : OUTPUT_NONE_PENDING;
    return record;
}

/* The records after the first that are due on the same tick (queued late); the last. */
static const output_record_t *__attribute__((noinline)) output_pop_late(output_queue_t *q) {
    const output_record_t *record;
    do {
        record = output_pop(q);
    } while (q->last >= q->next);
    return record;
}

/* core1.apply_outputs: every pending record due at this tick's clock; the outputs as the
 * last of them leaves them, written at once. Called when the clock reached `next`, the
 * oldest pending record's tick. Out of line: the tick that calls it pays for it, no other
 * does. */
static void __attribute__((noinline)) apply_outputs(output_queue_t *q, int64_t clock) {
    q->last = clock;
    const output_record_t *due = output_pop(q);
    if (clock >= q->next) {
        due = output_pop_late(q);
    }
    q->values.words[0] = due->values.words[0];   /* two moves, not a call of memcpy */
    q->values.words[1] = due->values.words[1];
    platform_outputs_write(&due->pins);
}

/* core1.outputs_off: a fault latched. */
static void outputs_off(servo_state_t *s) {
    static const output_pins_t off = {{0, 0}};
    s->outputs.values = (output_values_t){{0}};
    platform_outputs_write(&off);
    servo_drop_pending_outputs(s);
}

int32_t servo_switches(const servo_state_t *state, const servo_params_t *params) {
    int64_t count = floor_micro(state->theta);
    int32_t bits = 0;
    if (count <= params->lower) {
        bits |= 1;
    }
    if (count >= params->upper) {
        bits |= 2;
    }
    return bits;
}

int32_t servo_probe(const servo_state_t *state, const servo_params_t *params) {
    return probe_closed(floor_micro(state->theta), params);
}

void servo_shift_position(servo_state_t *state, int64_t shift) {
    state->offset = wrap_int32((int64_t)state->offset + shift);
    state->actual = wrap_int32((int64_t)state->actual + shift);
    state->desired = wrap_int32((int64_t)state->desired + shift);
    state->desired_prev = wrap_int32((int64_t)state->desired_prev + shift);
    for (unsigned slot = 0; slot < SERVO_HISTORY_SLOTS; slot++) {
        state->counts[slot] = wrap_int32((int64_t)state->counts[slot] + shift);
    }
    shift_edges(state, shift);
}

/* 1. motion update (servo enabled) */
static void motion_update(servo_state_t *s, const servo_params_t *p) {
    if (s->start >= 0 && s->clock >= s->start) {
        s->start = -1;
        s->motion_left = 0;
    }
    if (s->start >= 0) {
        return;
    }
    if (s->mode == MODE_CURVE) {
        s->desired = wrap_int32(curve_next_position(&s->curve, s->desired, p->tick_us));
        return;
    }
    if (s->motion_left <= 0) {
        int32_t value;
        if (mq_try_remove(&value)) {
            s->last_take = s->clock;
            if (s->mode == MODE_VELOCITY) {
                s->desired_vel = value;
            } else {
                s->desired = value;
            }
        } else if (s->mode == MODE_VELOCITY) {
            s->desired_vel = 0;
        }
        s->motion_left = p->scalar;
    }
    s->motion_left -= 1;
    if (p->drive_kind != DRIVE_DC && s->mode == MODE_VELOCITY) {
        /* a stepper follows the desired velocity's position: |vel_acc| < 10^6 + 2^31 * 10^6 */
        s->vel_acc += (int64_t)s->desired_vel * p->tick_us;
        int64_t move = trunc_micro(s->vel_acc);
        s->vel_acc -= move * STEPPER_MICRO;
        s->desired = wrap_int32((int64_t)s->desired + move);
    }
}

/* 2. PID (servo enabled): the output in volts, saturated, with conditional integration */
static void pid(servo_state_t *s, const servo_params_t *p) {
    int64_t error;
    if (s->mode == MODE_VELOCITY && p->drive_kind == DRIVE_DC) {
        error = (int64_t)s->desired_vel - s->velocity;
    } else {
        error = wrap_int32((int64_t)s->desired - s->actual);
    }
    int32_t window = p->window;
    if (s->fresh == 1) {
        for (int32_t slot = 0; slot < window; slot++) {
            s->history[slot] = error;
        }
        s->history_pos = 0;
        s->fresh = 0;
    }
    int64_t change = error - s->history[s->history_pos];
    s->history[s->history_pos] = error;
    s->history_pos += 1;
    if (s->history_pos >= (uint32_t)window) {
        s->history_pos = 0;
    }
    sci_t proportional = sci_mul(p->kp, sci_from_int(error));
    sci_t derivative = sci_mul(p->kd_dt, sci_from_int(change));
    int64_t candidate = 0;
    if (p->integral_limit > 0) {
        candidate = s->integral + error;
        if (candidate > p->integral_limit) {
            candidate = p->integral_limit;
        } else if (candidate < -p->integral_limit) {
            candidate = -p->integral_limit;
        }
    }
    sci_t integral = sci_mul(p->ki_dt, sci_from_int(candidate));
    sci_t u = sci_add(sci_add(proportional, integral), derivative);
    sci_t negative_vs = {-p->vs.c, p->vs.e};
    if (sci_compare(u, p->vs) > 0) {
        u = p->vs;
        if (error <= 0) {
            s->integral = candidate;
        }
    } else if (sci_compare(u, negative_vs) < 0) {
        u = negative_vs;
        if (error >= 0) {
            s->integral = candidate;
        }
    } else {
        s->integral = candidate;
    }
    s->out = u;
}

/* 4. encoder, switches, the edge latch, the probe and its edge latch, and the velocity-mode
 * counter reset; returns the switches that closed on this tick. `source` is what the counter
 * counts (core1.py's: the shaft's count, a stepper's steps issued or its encoder in
 * microsteps), `limits` the switches, `probe` the probe input; `pins` the edges the
 * switches' pins latched (NULL: the simulated travel's, latched here). */
static inline int32_t encoder(servo_state_t *s, const servo_params_t *p, int64_t source,
                              int32_t limits, int32_t probe, const motor_pins_sample_t *pins) {
    s->actual = wrap_int32(source + s->offset);
    int32_t then = s->counts[s->counts_pos];
    /* wrap32(actual - then) * 10^6 / (window * tick_us) truncated toward zero (trunc_div),
     * as the reduced fraction: velocity_num <= 10^6, velocity_den <= 10^4 */
    int32_t moved = wrap_int32((int64_t)s->actual - then);
    uint32_t moved_magnitude = moved < 0 ? 0u - (uint32_t)moved : (uint32_t)moved;
    uint32_t num = (uint32_t)p->velocity_num;
    uint32_t high = 0;   /* one 32-bit multiply when both are below 2^16 */
    uint32_t low = (moved_magnitude | num) < 0x10000u ? moved_magnitude * num
                                                      : sci_mul_32x32(moved_magnitude, num, &high);
    uint64_t speed = ((uint64_t)high << 32) | low;
    if (p->velocity_den != 1) {
        speed = p->velocity_den < 0x10000 ? sci_div_u64_small(speed, (uint32_t)p->velocity_den)
                                          : speed / (uint64_t)p->velocity_den;
    }
    s->velocity = moved < 0 ? -(int64_t)speed : (int64_t)speed;
    s->counts[s->counts_pos] = s->actual;
    s->counts_pos += 1;
    if (s->counts_pos >= (uint32_t)p->window) {
        s->counts_pos = 0;
    }
    int32_t closing = limits & ~s->limits;
    int32_t changed = limits ^ s->limits;
    s->limits = limits;
    if (pins) {
        int64_t tick_after = s->clock + 1;
        for (unsigned i = 0; i < 2; i++) {
            uint32_t new_edges = pins->edges[i] - s->pins_edges[i];
            if (new_edges != 0u) {
                switch_edge_t *edge = &s->edges[i];
                edge->edges += new_edges;   /* modulo 2^32 */
                edge->closed = (limits >> i) & 1;
                edge->position = wrap_int32((int64_t)pins->edge_count[i] + s->offset);
                edge->tick = tick_after;
                s->pins_edges[i] = pins->edges[i];
            }
        }
    } else if (changed != 0) {
        for (unsigned i = 0; i < 2; i++) {
            if (changed & (1 << i)) {
                switch_edge_t *edge = &s->edges[i];
                edge->edges += 1u;   /* modulo 2^32 */
                edge->closed = (limits >> i) & 1;
                edge->position = s->actual;
                edge->tick = s->clock + 1;
            }
        }
    }
    if (probe != s->probe) {
        s->probe = probe;
        s->probe_edge.edges += 1u;   /* modulo 2^32 */
        s->probe_edge.closed = probe;
        s->probe_edge.position = s->actual;
        s->probe_edge.tick = s->clock + 1;
    }
    if (s->mode == MODE_VELOCITY) {
        s->velocity_mode_us += p->tick_us;
        if (s->velocity_mode_us >= VELOCITY_RESET_US) {
            s->velocity_mode_us -= VELOCITY_RESET_US;
            s->offset = wrap_int32(-source);
            for (int32_t slot = 0; slot < p->window; slot++) {
                s->counts[slot] = wrap_int32((int64_t)s->counts[slot] - s->actual);
            }
            shift_edges(s, -(int64_t)s->actual);
            if (p->drive_kind != DRIVE_DC) {
                s->desired = wrap_int32((int64_t)s->desired - s->actual);
                s->desired_prev = wrap_int32((int64_t)s->desired_prev - s->actual);
            }
            s->actual = 0;
        }
    }
    return closing;
}

/* The switch bits the simulated travel gives at this shaft count. */
static inline int32_t travel_switches(int64_t count, const servo_params_t *p) {
    int32_t limits = 0;
    if (count <= p->lower) {
        limits = 1;
    }
    if (count >= p->upper) {
        limits |= 2;
    }
    return limits;
}

/* 0-2: the outputs due, the motion update and the PID (0 V while disabled); returns whether
 * it ran enabled */
static inline bool tick_start(servo_state_t *s, const servo_params_t *p) {
    if (s->clock >= s->outputs.next) {
        apply_outputs(&s->outputs, s->clock);
    }
    bool enabled = s->enable == 1;
    if (enabled) {
        motion_update(s, p);
        if (p->drive_kind != DRIVE_STEP_OPEN) {
            pid(s, p);
        } else {
            s->out.c = 0;
            s->out.e = 0;
        }
    } else {
        s->out.c = 0;
        s->out.e = 0;
    }
    return enabled;
}

/* 5-6: faults, clock, statistics (and the diagnostics line's peak), fault latch,
 * diagnostics, after the encoder step */
static inline void tick_finish(servo_state_t *s, const servo_params_t *p, record_ring_t *ring,
                               bool enabled, int32_t closing) {
    /* 5. faults */
    s->since_command_us += p->tick_us;
    if (s->since_command_us > TIMER_CAP_US) {
        s->since_command_us = TIMER_CAP_US;
    }
    int32_t new_fault = FAULT_NONE;
    int64_t following = 0;
    if (enabled) {
        if (s->mode != MODE_VELOCITY) {
            following = wrap_int32((int64_t)s->desired - s->actual);
            if (closing != 0) {
                new_fault = FAULT_LIMIT_SWITCH;
            } else if (p->fe_limit > 0 && (following > p->fe_limit || -following > p->fe_limit)) {
                new_fault = FAULT_FOLLOWING_ERROR;
            }
        }
        if (new_fault == FAULT_NONE && p->watchdog_us > 0 &&
            s->since_command_us >= p->watchdog_us) {
            new_fault = FAULT_WATCHDOG;
        }
        if (s->encoder_lost) {   /* first: the other faults read a count that stands still */
            new_fault = FAULT_ENCODER_LOST;
        }
    }

    /* 6. clock, statistics, fault latch, diagnostics */
    s->clock += 1;
    if (enabled && s->mode != MODE_VELOCITY && s->start < 0) {
        s->stats_ticks += 1;
        int64_t size = following >= 0 ? following : -following;   /* <= 2^31 */
        if (size > s->stats_max) {
            s->stats_max = size;
            s->stats_max_tick = s->clock;
        }
        int32_t peak = s->diag_peak;
        uint32_t peak_size = peak < 0 ? 0u - (uint32_t)peak : (uint32_t)peak;
        if ((uint32_t)size > peak_size) {   /* the earlier tick wins a tie */
            s->diag_peak = (int32_t)following;
        }
        uint32_t square_high = 0;   /* one 32-bit multiply below 2^16 */
        uint32_t square_low = size < 0x10000 ? (uint32_t)size * (uint32_t)size
                                             : sci_mul_32x32((uint32_t)size, (uint32_t)size,
                                                             &square_high);
        int64_t square = (int64_t)(((uint64_t)square_high << 32) | square_low);   /* <= 2^62 */
        if (square > STATS_SUM_CAP - s->stats_sum_sq) {
            s->stats_sum_sq = STATS_SUM_CAP;
        } else {
            s->stats_sum_sq += square;
        }
    }
    if (new_fault != FAULT_NONE) {
        s->fault = new_fault;
        s->fault_tick = s->clock;
        s->enable = 0;
        s->out.c = 0;
        s->out.e = 0;
        outputs_off(s);
    }
    if (p->diag_n > 0) {
        s->diag_left -= 1;
        if (s->diag_left <= 0) {
            s->diag_left = p->diag_n;
            record_t *record = ring_slot(ring);
            if (record) {
                record->kind = RECORD_DIAGNOSTICS;
                record->clock = s->clock;
                record->desired = s->mode == MODE_VELOCITY ? s->desired_vel : s->desired;
                record->actual = s->actual;
                record->velocity = s->velocity;
                record->out.c = s->out.c;
                record->out.e = s->out.e;
                record->queued =
                    (int32_t)(s->mode == MODE_CURVE ? curve_queued(&s->curve) : mq_level());
                record->peak = s->diag_peak;
                record->fault = FAULT_NONE;
                ring_commit(ring);
            }
            s->diag_peak = 0;
        }
    }
    if (new_fault != FAULT_NONE) {
        record_t *alarm = ring_slot(ring);
        if (alarm) {
            alarm->kind = RECORD_ALARM;
            alarm->clock = s->fault_tick;
            alarm->desired = 0;
            alarm->actual = 0;
            alarm->velocity = 0;
            alarm->out.c = 0;
            alarm->out.e = 0;
            alarm->queued = 0;
            alarm->peak = 0;
            alarm->fault = s->fault;
            ring_commit(ring);
        }
    }
}

/* 2-3 of a step drive: the steps this tick issues (the open loop's to the desired position,
 * the closed loop's to where the rotor is going plus the PID's output, its field's lead),
 * handed to the platform's step generator, and the simulated stepper over the tick with the
 * steps reaching its field spread evenly over the sub-steps. Returns what the counter
 * counts: the steps issued (open loop) or the encoder in microsteps (closed loop); *count
 * is the shaft's whole microsteps after the tick. */
/* Inlined into both ticks (the simulated one's and the pins'): a call here costs the
 * simulated closed loop's costliest tick about 80 cycles. */
static inline __attribute__((always_inline)) int64_t step_drive(servo_state_t *s,
                                                                const servo_params_t *p,
                                                                int64_t *count) {
    int32_t issue = 0;
    if (s->enable == 1) {
        if (p->drive_kind == DRIVE_STEP_OPEN) {
            issue = wrap_int32((int64_t)s->desired - s->actual);
        } else {
            /* trunc_div(velocity * tick_us, 10^6) as velocity * tick_num / tick_den (the
             * same fraction reduced): one 32-bit division for a whole number of ticks a
             * second and a velocity below 2^32; |velocity| * tick_us <= 2^31 * 10^6 */
            uint64_t velocity = sci_magnitude64(s->velocity);
            uint64_t magnitude;
            if (p->tick_num == 1 && (velocity >> 32) == 0u) {
                magnitude = sci_udiv((uint32_t)velocity, (uint32_t)p->tick_den);
            } else {
                magnitude = sci_div_u64_small(
                    sci_mul_32x64((uint32_t)p->tick_us, velocity) >> 6, 15625u);
            }
            int64_t moved = s->velocity < 0 ? -(int64_t)magnitude : (int64_t)magnitude;
            /* where the rotor goes this tick: as measured, never beyond the command's move */
            int64_t wanted = wrap_int32((int64_t)s->desired - s->desired_prev);
            int64_t ahead;
            if (wanted >= 0) {
                ahead = moved < 0 ? 0 : (moved > wanted ? wanted : moved);
            } else {
                ahead = moved > 0 ? 0 : (moved < wanted ? wanted : moved);
            }
            /* the PID's output (saturated at a full step) is the field's lead over the rotor */
            int32_t target = wrap_int32((int64_t)s->actual + ahead + sci_to_int(s->out));
            issue = wrap_int32((int64_t)target - wrap_int32(s->phase + s->offset));
        }
        if (issue > p->max_steps) {
            issue = p->max_steps;
        } else if (issue < -p->max_steps) {
            issue = -p->max_steps;
        }
    }
    /* sci_from_int(issue) on its 32-bit magnitude (|issue| <= max_steps) */
    s->out = sci_normalize_u32(issue < 0 ? 0u - (uint32_t)issue : (uint32_t)issue, 0, issue < 0);
    /* the driver holds its field while the servo runs and after a fault, until it is
     * cleared (a fault stops the steps; it does not drop a vertical axis) */
    int32_t powered = (s->enable == 1 || s->fault != FAULT_NONE) ? 1 : 0;
    platform_steps_issue(issue, powered == 1);
    if (p->motor_pins) {
        /* the stepper is outside the chip: the next tick reads its encoder as it starts */
        s->phase += issue;
        s->last_steps = issue;
        *count = 0;
        return s->phase;
    }

    /* the field after sub-step k is phase + trunc_div(issue * k, steps) microsteps: the
     * quotient and remainder of |issue| / steps added up, a carry when the remainder reaches
     * steps */
    uint32_t steps = (uint32_t)p->steps;
    if (steps == 1u) {   /* the field after the one sub-step: phase + issue */
        stepper_step(&s->theta, &s->omega, s->phase + issue, powered, p);
        steps = 0;
    }
    uint32_t magnitude = issue < 0 ? 0u - (uint32_t)issue : (uint32_t)issue;
    uint32_t whole = steps <= 1u ? magnitude : sci_udiv(magnitude, steps);
    uint32_t rest = magnitude - whole * steps;
    uint32_t moved = 0;
    uint32_t remainder = 0;
    for (uint32_t step = 0; step < steps; step++) {
        moved += whole;
        remainder += rest;
        if (remainder >= steps) {
            remainder -= steps;
            moved += 1u;
        }
        int64_t field = issue < 0 ? s->phase - moved : s->phase + moved;
        stepper_step(&s->theta, &s->omega, field, powered, p);
    }
    s->phase += issue;
    s->last_steps = issue;
    *count = floor_micro(s->theta);
    if (p->drive_kind == DRIVE_STEP_OPEN) {
        return s->phase;
    }
    return stepper_encoder_ratio_microsteps(*count, &p->encoder_ratio);
}

void servo_tick(servo_state_t *s, const servo_params_t *p, record_ring_t *ring) {
    bool enabled = tick_start(s, p);

    /* 3. motor */
    int64_t count;
    int64_t source;
    if (p->drive_kind == DRIVE_DC) {
        sci_t drive = sci_mul(s->out, p->drive);
        for (int32_t step = 0; step < p->steps; step++) {
            motor_step(&s->theta, &s->omega, drive, p);
        }
        count = floor_micro(s->theta);
        source = count;
    } else {
        source = step_drive(s, p, &count);
    }
    s->desired_prev = s->desired;

    int32_t closing =
        encoder(s, p, source, travel_switches(count, p), probe_closed(count, p), NULL);
    tick_finish(s, p, ring, enabled, closing);
}

/* The bridge's level for the output voltage: out * full / supply, truncated toward zero. */
static inline int32_t pins_level(sci_t out, const servo_params_t *p) {
    return (int32_t)sci_to_int(sci_mul(out, p->pins_level_per_volt));
}

/* The absolute encoder's source from the tick's sample: a new frame's angle counted on
 * across turns (the first one's taken as the counter at once); with no new frame (or one no
 * sensor sends) the count stands, and after ABSENC_TIMEOUT_US the encoder is lost. */
static int64_t absenc_source(servo_state_t *s, const servo_params_t *p,
                             const motor_pins_sample_t *pins) {
    absenc_t *a = &s->absenc;
    int32_t code = -1;
    if (pins->pwm_frames != a->frames) {
        a->frames = pins->pwm_frames;
        code = absenc_code(pins->pwm_high, pins->pwm_period);
    }
    if (code < 0) {
        if (s->absenc_quiet_us < ABSENC_TIMEOUT_US) {
            s->absenc_quiet_us += p->tick_us;
        }
        s->encoder_lost = s->absenc_quiet_us >= ABSENC_TIMEOUT_US;
        return a->have ? a->source : wrap_int32((int64_t)s->actual - s->offset);
    }
    s->absenc_quiet_us = 0;
    s->encoder_lost = false;
    int32_t angle = absenc_angle(code, p->encoder_turn);
    if (!a->have) {
        a->have = true;
        a->source = wrap_int32((int64_t)s->actual - s->offset);
        a->base = a->source - angle;
        servo_shift_position(s, (int64_t)angle - s->actual);   /* the counter is the angle */
    } else {
        a->source += absenc_move(a->angle, angle, p->encoder_turn);
    }
    a->angle = angle;
    return a->source;
}

/* A closed-loop stepper's encoder count in microsteps: floor(count x per_rev / cpr). */
static inline int64_t count_microsteps(int32_t count, const servo_params_t *p) {
    int64_t product = (int64_t)count * p->per_rev;
    int64_t quotient = product / p->encoder_cpr;
    return quotient * p->encoder_cpr > product ? quotient - 1 : quotient;
}

/* What the counter counts with the motor on the pins, from the tick's sample: the decoder's
 * count (a closed-loop stepper's in microsteps), the absolute encoder's angle counted on
 * across turns, or an open-loop stepper's steps issued; the switches' latched counts made
 * the same (the absolute encoder's and the steps': the tick's own). */
static int64_t pins_source(servo_state_t *s, const servo_params_t *p,
                           motor_pins_sample_t *pins) {
    int64_t source;
    if (p->drive_kind == DRIVE_STEP_OPEN) {
        source = s->phase;
    } else if (p->encoder_kind == 1) {
        source = absenc_source(s, p, pins);
    } else if (p->drive_kind == DRIVE_STEP_CLOSED) {
        pins->edge_count[0] = wrap_int32(count_microsteps(pins->edge_count[0], p));
        pins->edge_count[1] = wrap_int32(count_microsteps(pins->edge_count[1], p));
        return count_microsteps(pins->count, p);
    } else {
        return pins->count;
    }
    pins->edge_count[0] = wrap_int32(source);
    pins->edge_count[1] = pins->edge_count[0];
    return source;
}

void servo_tick_pins(servo_state_t *s, const servo_params_t *p, record_ring_t *ring) {
    motor_pins_sample_t pins;
    platform_motor_pins_sample(&pins);
    if (s->pins_started) {
        int64_t source = pins_source(s, p, &pins);
        int32_t closing = encoder(s, p, source, pins.switches, pins.probe, &pins);
        tick_finish(s, p, ring, s->pins_enabled, closing);
    }
    s->pins_started = true;
    s->pins_enabled = tick_start(s, p);
    if (p->drive_kind == DRIVE_DC) {
        platform_motor_pins_drive(pins_level(s->out, p), s->enable == 1);
    } else {
        int64_t count;
        (void)step_drive(s, p, &count);   /* the steps on STEP/DIR/EN */
    }
    s->desired_prev = s->desired;
}

void servo_pins_power_up(servo_state_t *s, const servo_params_t *p,
                         motor_pins_sample_t *sample) {
    s->limits = sample->switches;
    s->probe = sample->probe;
    s->pins_edges[0] = sample->edges[0];
    s->pins_edges[1] = sample->edges[1];
    s->actual = 0;
    s->offset = 0;
    servo_pins_encoder_changed(s, p, sample);
    s->pins_started = false;
}

void servo_pins_encoder_changed(servo_state_t *s, const servo_params_t *p,
                                motor_pins_sample_t *sample) {
    s->absenc = (absenc_t){.have = false, .frames = sample->pwm_frames};
    s->absenc_quiet_us = 0;
    s->encoder_lost = false;
    if (p->encoder_kind != 1 || p->drive_kind == DRIVE_STEP_OPEN) {
        s->offset = wrap_int32((int64_t)s->actual - pins_source(s, p, sample));
    }
}
