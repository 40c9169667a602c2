"""core1: the servo loop, as plain functions over flat integer state.

Everything core1 knows lives in two ``numpy.int64`` arrays indexed by the ``S_*`` and
``P_*`` constants below: ``state`` (what the loop changes) and ``params`` (what core0 copies
in when a variable changes). The motion queue is a ring buffer array owned by core0 whose
head and length live in ``state``. :func:`servo_block` runs servo ticks over them using only
ints, tuples, arrays, ``if``/``while`` and the ``usbmotion.scimath`` core, so the same
source compiles unchanged with ``numba.njit`` and stays bit-for-bit equal to this
reference: every value stays within int64 and the encoder counter wraps as an int32
explicitly.

One servo tick, in order:

0. outputs (call 42): on the tick that begins with the clock at or past the next pending
   record's tick, every pending record due applies: the outputs become those the last of
   them holds (each record holds the outputs as its changes, in the order given, leave
   them); with none pending this is one comparison.
1. motion update (servo enabled only): an armed start tick holds everything until the clock
   reaches it; then every ``scalar`` ticks, starting with the first, the next queue value
   becomes the desired position (mode 1) or velocity (mode 2). An empty queue holds the
   desired position, and sets the desired velocity to 0 (the loop brakes to a stop). In
   curve mode (3) core0 supplies the desired position of each running tick.
2. PID (servo enabled) on the error of the active mode, in volts, saturated to the source
   voltage, with conditional integration and a clamped integrator; the derivative is the
   error change over the last millisecond (``window`` ticks); 0 V when disabled.
3. the motor over the tick, in ``steps`` equal integration steps.
4. encoder: counter, velocity over the window (counts/s), limit switches, and for each switch
   that changed, the edge latch (call 36: the counter and the clock of the tick it changed
   on); the probe input (call 40's surface) and its edge latch the same way (call 41); in
   velocity mode the counter is reset to 0 after every 60 s of device time spent in that
   mode (latched edge positions move with it).
5. faults (servo enabled): limit switch closing in mode 1 or 3, following error in mode 1
   or 3, then watchdog; a fault disables the servo and cuts its output to 0 V (as call
   ``3 0`` does), so no line reports a drive the servo no longer applies; it also sets
   every output (call 43) to 0 and drops the pending changes.
6. clock + 1; the motion statistics (call 35) count the tick, and so does the peak of the
   next diagnostics line; diagnostics countdown: a diagnostics tick writes a record of the
   line into ``state`` for core0 to print (the block goes on until core0's room for records
   is used up) and restarts the peak.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from usbmotion.device.motor import DIGITS, MICRO, motor_step
from usbmotion.device.stepper import encoder_microsteps, stepper_step
from usbmotion.protocol.names import ControlMode, Drive, FaultCode
from usbmotion.protocol.table import OUTPUT_COUNT, OUTPUT_QUEUE_CAPACITY, QUEUE_CAPACITY
from usbmotion.scimath import sci_add, sci_compare, sci_from_int, sci_mul, sci_to_int

IntArray = npt.NDArray[np.int64]

# The kernel reads these as plain integer globals.
MODE_POSITION = int(ControlMode.POSITION)
MODE_VELOCITY = int(ControlMode.VELOCITY)
MODE_CURVE = int(ControlMode.CURVE)

FAULT_NONE = int(FaultCode.NONE)
FAULT_WATCHDOG = int(FaultCode.WATCHDOG)
FAULT_FOLLOWING_ERROR = int(FaultCode.FOLLOWING_ERROR)
FAULT_LIMIT_SWITCH = int(FaultCode.LIMIT_SWITCH)

VELOCITY_RESET_US = 60_000_000
"""Velocity mode resets the encoder counter after this much device time in the mode."""
TIMER_CAP_US = 1 << 62
"""The time-since-last-command timer stops here instead of overflowing."""

EVENT_DIAGNOSTICS = 1
"""``state[S_EVENTS]`` bit: the diagnostics records are full (core0 prints them)."""
EVENT_FAULT = 2
"""``state[S_EVENTS]`` bit: a fault latched during the block."""

# --- state: what core1 changes ---------------------------------------------------------
S_CLOCK = 0
S_ENABLE = 1
S_MODE = 2
S_FAULT = 3
S_FAULT_TICK = 4
S_THETA = 5
"""Motor shaft position, micro-counts from power-up (not wrapped)."""
S_OMEGA = 6
"""Motor shaft speed, micro-counts/s."""
S_OFFSET = 7
"""Encoder counter minus shaft count (call 23 and the velocity-mode reset change it)."""
S_ACTUAL = 8
S_COUNTS_POS = 9
"""Slot of the counter history holding the counter of ``window`` ticks ago."""
S_VELOCITY = 10
"""Encoder counts over the derivative window (the last millisecond), as counts/s."""
S_DESIRED = 11
S_DESIRED_VEL = 12
S_INTEGRAL = 13
"""Sum of the error over the ticks it was integrated (error units x ticks)."""
S_HISTORY_POS = 14
"""Slot of the error history holding the error of ``window`` ticks ago."""
S_FRESH = 15
"""1 until the first controlled tick after enabling (the history starts full of the first
error: no derivative kick from stale data)."""
S_OUT_C = 16
S_OUT_E = 17
S_QUEUE_HEAD = 18
S_QUEUE_COUNT = 19
S_MOTION_LEFT = 20
"""Ticks until the next motion update (0: the next running tick pops)."""
S_START = 21
"""Armed start tick, or -1."""
S_SINCE_COMMAND_US = 22
S_VELOCITY_MODE_US = 23
S_DIAG_LEFT = 24
S_LIMITS = 25
S_EVENTS = 26
HISTORY_SLOTS = 10
S_HISTORY = 27
"""First of ``HISTORY_SLOTS`` entries: the errors of the last ``window`` ticks (a ring)."""
S_COUNTS = S_HISTORY + HISTORY_SLOTS
"""First of ``HISTORY_SLOTS`` entries: the counters of the last ``window`` ticks (a ring)."""
S_STATS_TICKS = S_COUNTS + HISTORY_SLOTS
"""Motion statistics (call 35): servo ticks counted (enabled in mode 1 or 3, any armed start
reached) since a reset."""
S_STATS_MAX = S_STATS_TICKS + 1
"""Largest absolute following error counted, counts."""
S_STATS_MAX_TICK = S_STATS_TICKS + 2
"""Clock (after the tick) of the first tick with that largest error."""
S_STATS_SUM_SQ = S_STATS_TICKS + 3
"""Sum of the squared following errors counted, saturating at :data:`STATS_SUM_CAP`."""
S_LAST_TAKE = S_STATS_TICKS + 4
"""Clock of the tick that last took a value from the motion queue (-1: none yet)."""
S_DIAG_COUNT = S_STATS_TICKS + 5
"""Diagnostics records written since core0 last printed them."""
S_DIAG_PEAK = S_DIAG_COUNT + 1
"""The next diagnostics line's ``peak``: of the following errors (``wrap_int32(desired -
actual)``) of the ticks the statistics counted since the last line, the one of the largest
magnitude, signed (the earlier on a tie); 0 while none was counted. A line, call 21 setting
the interval and call 35's reset restart it."""
S_EDGES = S_DIAG_PEAK + 1
"""The switch-edge latch (call 36): for each switch (lower, then upper) ``EDGE_FIELDS``
entries: edges counted since power-up (modulo 2**32), whether the last one closed the switch
(1) or opened it (0), the encoder counter at the tick of that edge (kept in the counter's
current coordinates: call 23, call 37 and the velocity-mode reset shift it with the counter)
and the clock after that tick."""
EDGE_FIELDS = 4
EDGE_COUNT = 0
EDGE_CLOSED = 1
EDGE_POSITION = 2
EDGE_TICK = 3
EDGE_COUNT_MODULUS = 1 << 32
S_PROBE_EDGE = S_EDGES + 2 * EDGE_FIELDS
"""The probe input's edge latch (call 41): ``EDGE_FIELDS`` entries as a switch's."""
S_PROBE = S_PROBE_EDGE + EDGE_FIELDS
"""The probe input now: 1 closed (touching), 0 open."""
S_OUTPUTS = S_PROBE + 1
"""The outputs' values now (call 43): ``OUTPUT_COUNT`` entries, 0 .. ``OUTPUT_FULL``."""
S_OUT_RECORDS = S_OUTPUTS + OUTPUT_COUNT
"""Pending records of output changes (call 42), one per tick they apply on, at most
``OUTPUT_QUEUE_CAPACITY``."""
S_OUT_HEAD = S_OUT_RECORDS + 1
"""Slot of the oldest pending record in the ring at :data:`S_OUT_QUEUE`."""
S_OUT_NEXT = S_OUT_HEAD + 1
"""The oldest pending record's tick, or :data:`OUTPUT_NONE_PENDING`: the one number a tick
compares the clock with."""
S_OUT_LAST = S_OUT_NEXT + 1
"""The clock at the start of the tick that applied the last change (-1: none yet)."""
S_OUT_QUEUE = S_OUT_LAST + 1
"""The pending records: a ring of ``OUTPUT_QUEUE_CAPACITY`` records of ``OUT_RECORD``
entries, in tick order. A record holds the changes call 42 queued for one tick (in the
order given) as the outputs stand once they applied: core0 queues a change into the last
record when it is for that record's tick, else into a new record holding the outputs as
the last record (or, with none pending, the outputs now) leaves them, with the change."""
OUT_TICK = 0
"""A record's entry: the clock at the start of the tick its changes apply on."""
OUT_CHANGES = 1
"""A record's entry: the changes of call 42 it holds (1 .. ``OUTPUT_QUEUE_CAPACITY``)."""
OUT_VALUES = 2
"""A record's first of ``OUTPUT_COUNT`` entries: every output once its changes applied."""
OUT_RECORD = OUT_VALUES + OUTPUT_COUNT
OUTPUT_NONE_PENDING = 1 << 62
"""``S_OUT_NEXT`` with no change pending: beyond every clock."""
DIAG_SLOTS = 64
"""Diagnostics records ``state`` holds."""
DIAG_RECORD = 8
"""Entries of one record: clock, desired (velocity in mode 2), actual, velocity, output
(coefficient, exponent), queued values, peak following error."""
S_DIAG = S_OUT_QUEUE + OUTPUT_QUEUE_CAPACITY * OUT_RECORD
"""First entry of the ``DIAG_SLOTS`` records."""
S_PHASE = S_DIAG + DIAG_SLOTS * DIAG_RECORD
"""Step drives: the driver's step counter, the steps issued since the drive was set
(signed, not wrapped)."""
S_LAST_STEPS = S_PHASE + 1
"""Step drives: the steps the last tick issued (signed)."""
S_VEL_ACC = S_LAST_STEPS + 1
"""Step drives in velocity mode: the desired velocity's travel not yet a whole microstep,
microsteps x 10**6."""
S_DESIRED_PREV = S_VEL_ACC + 1
"""The desired position of the tick before (the closed-loop stepper's command moved by the
difference)."""
STATE_SIZE = S_DESIRED_PREV + 1
STATS_SUM_CAP = 1 << 62
"""The sum of squared following errors stops here instead of overflowing."""

# --- params: what core0 copies in -------------------------------------------------------
P_TICK_US = 0
P_SCALAR = 1
P_KP_C = 2
P_KP_E = 3
P_KI_C = 4
"""Integral gain times the servo period, V per error-tick."""
P_KI_E = 5
P_KD_C = 6
"""Derivative gain over the derivative window, V per error change across the window."""
P_KD_E = 7
P_VS_C = 8
P_VS_E = 9
P_INTEGRAL_LIMIT = 10
"""Largest integral sum (0: the integrator is off)."""
P_WATCHDOG_US = 11
P_FE_LIMIT = 12
P_DIAG_N = 13
P_STEPS = 14
P_DRIVE_C = 15
P_DRIVE_E = 16
P_FRICTION_C = 17
P_FRICTION_E = 18
P_DECAY_C = 19
P_DECAY_E = 20
P_LAG_C = 21
P_LAG_E = 22
P_LOWER = 23
P_UPPER = 24
P_STOP_LOW = 25
P_STOP_HIGH = 26
P_WINDOW = 27
"""Derivative window, ticks: the error change is taken over the last millisecond (at least
one tick, at most ``HISTORY_SLOTS``), so encoder quantisation does not grow with the rate."""
P_DIAG_ROOM = 28
"""Diagnostics records core0 takes per block: the block ends when this many are written
(1 to ``DIAG_SLOTS``; 1 prints every line at its own tick)."""
P_PROBE_SIDE = 29
"""The simulated probe surface's side (call 40): 0 none, 1 the probe closes at or below
:data:`P_PROBE_POSITION`, 2 at or above it."""
P_PROBE_POSITION = 30
"""The simulated probe surface, motor counts from power-up."""
P_DRIVE = 31
"""Call 44: 0 DC motor, 1 stepper open loop, 2 stepper closed loop."""
P_MAX_STEPS = 32
"""Step drives: the most steps one tick issues."""
P_CYCLE = 33
"""The simulated stepper's electrical cycle (4 full steps), micro-microsteps."""
P_FULL = 34
"""A full step, micro-microsteps (the detent's period)."""
P_HOLDING = 35
"""The simulated stepper's holding torque, uNm."""
P_DETENT = 36
"""Its detent torque, uNm."""
P_CORNER = 37
"""Its corner speed, microsteps/s."""
P_LOAD_UNM = 38
"""Call 33's load torque, uNm (the stepper's)."""
P_VISCOUS_C = 39
P_VISCOUS_E = 40
"""Viscous torque per speed, uNm per micro-microstep/s (the stepper's)."""
P_ACCEL_C = 41
P_ACCEL_E = 42
"""Speed change per uNm over one integration step, micro-microsteps/s (the stepper's)."""
P_ENCODER_CPR = 43
"""Call 16: the closed loop's encoder counts per revolution."""
P_PER_REV = 44
"""Call 45: microsteps per revolution."""
PARAMS_SIZE = 45

DRIVE_DC = int(Drive.DC)
DRIVE_STEP_OPEN = int(Drive.STEP_OPEN)
DRIVE_STEP_CLOSED = int(Drive.STEP_CLOSED)

_DYNAMIC = (
    S_ENABLE,
    S_MODE,
    S_FAULT,
    S_THETA,
    S_OMEGA,
    S_OFFSET,
    S_ACTUAL,
    S_VELOCITY,
    S_DESIRED,
    S_DESIRED_VEL,
    S_INTEGRAL,
    S_FRESH,
    S_OUT_C,
    S_OUT_E,
    S_QUEUE_HEAD,
    S_QUEUE_COUNT,
    S_START,
    S_LIMITS,
    S_PROBE,
    S_PHASE,
    S_LAST_STEPS,
    S_VEL_ACC,
    S_DESIRED_PREV,
    *range(S_HISTORY, S_HISTORY + 2 * HISTORY_SLOTS),
)
DYNAMIC_FIELDS: tuple[int, ...] = _DYNAMIC
"""State entries that a tick may change other than the clocks and countdowns: when one
tick leaves all of them as they were (and nothing is queued), every following tick does
too until an event, which lets :func:`idle_advance` skip ticks."""


def new_state() -> IntArray:
    """A zeroed state array."""
    state = np.zeros(STATE_SIZE, dtype=np.int64)
    state[S_START] = -1
    state[S_MODE] = MODE_POSITION
    state[S_LAST_TAKE] = -1
    state[S_OUT_NEXT] = OUTPUT_NONE_PENDING
    state[S_OUT_LAST] = -1
    return state


def new_params() -> IntArray:
    """A zeroed params array."""
    return np.zeros(PARAMS_SIZE, dtype=np.int64)


def wrap_int32(value: int) -> int:
    """``value`` as the int32 the hardware counter holds (two's complement wrap)."""
    return ((value + 2147483648) & 0xFFFFFFFF) - 2147483648


def probe_closed(count: int, side: int, position: int) -> int:
    """The simulated probe input at motor count ``count``: 1 touching the surface (call 40's
    ``side`` and ``position``), else 0."""
    if side == 1 and count <= position:
        return 1
    if side == 2 and count >= position:
        return 1
    return 0


def shift_edges(state: IntArray, shift: int) -> None:
    """Move the latched edge positions (the switches' and the probe's) with the encoder
    counter (``shift`` counts, wrapping as the counter does); an input with no edge yet (its
    tick is 0: an edge's tick is at least 1) keeps position 0."""
    for base in (S_EDGES, S_EDGES + EDGE_FIELDS, S_PROBE_EDGE):
        if state[base + EDGE_TICK] != 0:
            state[base + EDGE_POSITION] = wrap_int32(int(state[base + EDGE_POSITION]) + shift)


def apply_outputs(state: IntArray, clock: int) -> int:
    """Apply every pending output record whose tick is at or before ``clock`` (the clock at
    the start of this tick): the outputs as the last of them leaves them; returns the next
    pending record's tick, or :data:`OUTPUT_NONE_PENDING`."""
    records = int(state[S_OUT_RECORDS])
    head = int(state[S_OUT_HEAD])
    due = -1
    while records > 0:
        base = S_OUT_QUEUE + head * OUT_RECORD
        if int(state[base + OUT_TICK]) > clock:
            break
        due = base
        head += 1
        if head == OUTPUT_QUEUE_CAPACITY:
            head = 0
        records -= 1
    if due >= 0:
        for output in range(OUTPUT_COUNT):
            state[S_OUTPUTS + output] = state[due + OUT_VALUES + output]
        state[S_OUT_LAST] = clock
    state[S_OUT_RECORDS] = records
    state[S_OUT_HEAD] = head
    following = OUTPUT_NONE_PENDING
    if records > 0:
        following = int(state[S_OUT_QUEUE + head * OUT_RECORD + OUT_TICK])
    state[S_OUT_NEXT] = following
    return following


def pending_outputs(state: IntArray) -> int:
    """The output changes pending (call 43): the changes the pending records hold."""
    changes = 0
    head = int(state[S_OUT_HEAD])
    for k in range(int(state[S_OUT_RECORDS])):
        slot = (head + k) % OUTPUT_QUEUE_CAPACITY
        changes += int(state[S_OUT_QUEUE + slot * OUT_RECORD + OUT_CHANGES])
    return changes


def drop_pending_outputs(state: IntArray) -> None:
    """Forget every pending output change (call 43's clear, call 22); the outputs stay."""
    state[S_OUT_RECORDS] = 0
    state[S_OUT_HEAD] = 0
    state[S_OUT_NEXT] = OUTPUT_NONE_PENDING


def outputs_off(state: IntArray) -> None:
    """A fault latched: every output to 0 and the pending changes dropped."""
    for output in range(OUTPUT_COUNT):
        state[S_OUTPUTS + output] = 0
    drop_pending_outputs(state)


def trunc_div(numerator: int, denominator: int) -> int:
    """``numerator / denominator`` truncated toward zero (C semantics; ``denominator > 0``)."""
    if numerator >= 0:
        return numerator // denominator
    return -((-numerator) // denominator)


def servo_block(
    state: IntArray,
    params: IntArray,
    queue: IntArray,
    curve: IntArray,
    n_ticks: int,
) -> int:
    """Run up to ``n_ticks`` servo ticks; stop early after a tick that raised an event.

    Parameters:
        state: the ``S_*`` array, updated in place (``S_EVENTS`` says why it stopped).
        params: the ``P_*`` array.
        queue: the motion queue ring buffer (capacity ``QUEUE_CAPACITY``); head and
            length are ``state[S_QUEUE_HEAD]`` and ``state[S_QUEUE_COUNT]``.
        curve: in curve mode, the desired position of each running tick of this block
            (entry ``i`` for the ``i``-th tick); ticks beyond its end hold the desired
            position. Ignored in the other modes.
        n_ticks: ticks to run.

    Returns the number of ticks run (``n_ticks`` unless an event stopped the block).
    The caller empties the diagnostics records (``state[S_DIAG_COUNT] = 0``) after each
    block; records beyond ``DIAG_SLOTS`` are not written.
    """
    tick_us = int(params[P_TICK_US])
    scalar = int(params[P_SCALAR])
    kp_c = int(params[P_KP_C])
    kp_e = int(params[P_KP_E])
    ki_c = int(params[P_KI_C])
    ki_e = int(params[P_KI_E])
    kd_c = int(params[P_KD_C])
    kd_e = int(params[P_KD_E])
    vs_c = int(params[P_VS_C])
    vs_e = int(params[P_VS_E])
    integral_limit = int(params[P_INTEGRAL_LIMIT])
    watchdog_us = int(params[P_WATCHDOG_US])
    fe_limit = int(params[P_FE_LIMIT])
    diag_n = int(params[P_DIAG_N])
    steps = int(params[P_STEPS])
    drive_gain_c = int(params[P_DRIVE_C])
    drive_gain_e = int(params[P_DRIVE_E])
    friction_c = int(params[P_FRICTION_C])
    friction_e = int(params[P_FRICTION_E])
    decay_c = int(params[P_DECAY_C])
    decay_e = int(params[P_DECAY_E])
    lag_c = int(params[P_LAG_C])
    lag_e = int(params[P_LAG_E])
    lower = int(params[P_LOWER])
    upper = int(params[P_UPPER])
    stop_low = int(params[P_STOP_LOW])
    stop_high = int(params[P_STOP_HIGH])
    window = int(params[P_WINDOW])
    diag_room = min(max(1, int(params[P_DIAG_ROOM])), DIAG_SLOTS)
    probe_side = int(params[P_PROBE_SIDE])
    probe_position = int(params[P_PROBE_POSITION])
    drive = int(params[P_DRIVE])
    max_steps = int(params[P_MAX_STEPS])
    cycle = int(params[P_CYCLE])
    full = int(params[P_FULL])
    holding = int(params[P_HOLDING])
    detent = int(params[P_DETENT])
    corner = int(params[P_CORNER])
    load_unm = int(params[P_LOAD_UNM])
    viscous_c = int(params[P_VISCOUS_C])
    viscous_e = int(params[P_VISCOUS_E])
    accel_c = int(params[P_ACCEL_C])
    accel_e = int(params[P_ACCEL_E])
    encoder_cpr = int(params[P_ENCODER_CPR])
    per_rev = int(params[P_PER_REV])

    clock = int(state[S_CLOCK])
    enable = int(state[S_ENABLE])
    mode = int(state[S_MODE])
    fault = int(state[S_FAULT])
    fault_tick = int(state[S_FAULT_TICK])
    theta = int(state[S_THETA])
    omega = int(state[S_OMEGA])
    offset = int(state[S_OFFSET])
    actual = int(state[S_ACTUAL])
    counts_pos = int(state[S_COUNTS_POS])
    velocity = int(state[S_VELOCITY])
    desired = int(state[S_DESIRED])
    desired_vel = int(state[S_DESIRED_VEL])
    integral = int(state[S_INTEGRAL])
    history_pos = int(state[S_HISTORY_POS])
    fresh = int(state[S_FRESH])
    out_c = int(state[S_OUT_C])
    out_e = int(state[S_OUT_E])
    queue_head = int(state[S_QUEUE_HEAD])
    queue_count = int(state[S_QUEUE_COUNT])
    motion_left = int(state[S_MOTION_LEFT])
    start = int(state[S_START])
    since_command = int(state[S_SINCE_COMMAND_US])
    velocity_mode_us = int(state[S_VELOCITY_MODE_US])
    diag_left = int(state[S_DIAG_LEFT])
    limits = int(state[S_LIMITS])
    probe = int(state[S_PROBE])
    stats_ticks = int(state[S_STATS_TICKS])
    stats_max = int(state[S_STATS_MAX])
    stats_max_tick = int(state[S_STATS_MAX_TICK])
    stats_sum_sq = int(state[S_STATS_SUM_SQ])
    last_take = int(state[S_LAST_TAKE])
    diag_count = int(state[S_DIAG_COUNT])
    diag_peak = int(state[S_DIAG_PEAK])
    out_next = int(state[S_OUT_NEXT])
    phase = int(state[S_PHASE])
    last_steps = int(state[S_LAST_STEPS])
    vel_acc = int(state[S_VEL_ACC])
    desired_prev = int(state[S_DESIRED_PREV])

    curve_len = len(curve)
    events = 0
    executed = 0
    while executed < n_ticks:
        # 0. outputs
        if clock >= out_next:
            out_next = apply_outputs(state, clock)

        # 1. motion update
        if enable == 1:
            if start >= 0 and clock >= start:
                start = -1
                motion_left = 0
            if start < 0:
                if mode == MODE_CURVE:
                    if executed < curve_len:
                        desired = wrap_int32(int(curve[executed]))
                else:
                    if motion_left <= 0:
                        if queue_count > 0:
                            value = int(queue[queue_head])
                            queue_head += 1
                            if queue_head == QUEUE_CAPACITY:
                                queue_head = 0
                            queue_count -= 1
                            last_take = clock
                            if mode == MODE_VELOCITY:
                                desired_vel = value
                            else:
                                desired = value
                        elif mode == MODE_VELOCITY:
                            desired_vel = 0
                        motion_left = scalar
                    motion_left -= 1
                if drive != DRIVE_DC and mode == MODE_VELOCITY:
                    vel_acc += desired_vel * tick_us
                    move = trunc_div(vel_acc, MICRO)
                    vel_acc -= move * MICRO
                    desired = wrap_int32(desired + move)

        # 2. PID (the DC motor's and the closed-loop stepper's) and the steps to issue
        if enable == 1 and drive != DRIVE_STEP_OPEN:
            if mode == MODE_VELOCITY and drive == DRIVE_DC:
                error = desired_vel - velocity
            else:
                error = wrap_int32(desired - actual)
            if fresh == 1:
                for slot in range(window):
                    state[S_HISTORY + slot] = error
                history_pos = 0
                fresh = 0
            change = error - int(state[S_HISTORY + history_pos])
            state[S_HISTORY + history_pos] = error
            history_pos += 1
            if history_pos >= window:
                history_pos = 0
            e_c, e_e = sci_from_int(error, DIGITS)
            p_c, p_e = sci_mul(kp_c, kp_e, e_c, e_e, DIGITS)
            c_c, c_e = sci_from_int(change, DIGITS)
            d_c, d_e = sci_mul(kd_c, kd_e, c_c, c_e, DIGITS)
            candidate = 0
            if integral_limit > 0:
                candidate = integral + error
                if candidate > integral_limit:
                    candidate = integral_limit
                elif candidate < -integral_limit:
                    candidate = -integral_limit
            s_c, s_e = sci_from_int(candidate, DIGITS)
            i_c, i_e = sci_mul(ki_c, ki_e, s_c, s_e, DIGITS)
            u_c, u_e = sci_add(p_c, p_e, i_c, i_e, DIGITS)
            u_c, u_e = sci_add(u_c, u_e, d_c, d_e, DIGITS)
            if sci_compare(u_c, u_e, vs_c, vs_e) > 0:
                u_c = vs_c
                u_e = vs_e
                if error <= 0:
                    integral = candidate
            elif sci_compare(u_c, u_e, -vs_c, vs_e) < 0:
                u_c = -vs_c
                u_e = vs_e
                if error >= 0:
                    integral = candidate
            else:
                integral = candidate
            out_c = u_c
            out_e = u_e
        else:
            out_c = 0
            out_e = 0
        issue = 0
        if drive != DRIVE_DC:
            if enable == 1:
                if drive == DRIVE_STEP_OPEN:
                    issue = wrap_int32(desired - actual)
                else:
                    # where the rotor goes this tick: as measured, but never beyond the
                    # command's own move (a stalled rotor is not extrapolated, and one that
                    # ran ahead does not run on by its own measurement)
                    moved = trunc_div(velocity * tick_us, MICRO)
                    wanted = wrap_int32(desired - desired_prev)
                    if wanted >= 0:
                        ahead = min(max(moved, 0), wanted)
                    else:
                        ahead = max(min(moved, 0), wanted)
                    target = wrap_int32(actual + ahead + sci_to_int(out_c, out_e))
                    issue = wrap_int32(target - wrap_int32(phase + offset))
                if issue > max_steps:
                    issue = max_steps
                elif issue < -max_steps:
                    issue = -max_steps
            out_c, out_e = sci_from_int(issue, DIGITS)
        desired_prev = desired

        # 3. motor
        if drive == DRIVE_DC:
            drive_c, drive_e = sci_mul(out_c, out_e, drive_gain_c, drive_gain_e, DIGITS)
            for _ in range(steps):
                theta, omega = motor_step(
                    theta,
                    omega,
                    drive_c,
                    drive_e,
                    friction_c,
                    friction_e,
                    decay_c,
                    decay_e,
                    lag_c,
                    lag_e,
                    tick_us,
                    steps,
                    stop_low,
                    stop_high,
                )
        else:
            # The driver holds its field while the servo runs, and after a fault (a fault
            # stops the steps; it does not drop a vertical axis): only call 3 0 releases it.
            powered = 1 if enable == 1 or fault != FAULT_NONE else 0
            for step in range(steps):
                field = (phase + trunc_div(issue * (step + 1), steps)) * MICRO
                theta, omega = stepper_step(
                    theta,
                    omega,
                    field,
                    powered,
                    cycle,
                    full,
                    holding,
                    detent,
                    corner,
                    load_unm,
                    viscous_c,
                    viscous_e,
                    accel_c,
                    accel_e,
                    tick_us,
                    steps,
                    stop_low,
                    stop_high,
                )
            phase += issue
            last_steps = issue

        # 4. encoder and switches
        count = theta // MICRO
        if drive == DRIVE_DC:
            source = count
        elif drive == DRIVE_STEP_OPEN:
            source = phase
        else:
            source = encoder_microsteps(count, encoder_cpr, per_rev)
        actual = wrap_int32(source + offset)
        then = int(state[S_COUNTS + counts_pos])
        velocity = trunc_div(wrap_int32(actual - then) * MICRO, window * tick_us)
        state[S_COUNTS + counts_pos] = actual
        counts_pos += 1
        if counts_pos >= window:
            counts_pos = 0
        new_limits = 0
        if count <= lower:
            new_limits = 1
        if count >= upper:
            new_limits |= 2
        closing = new_limits & ~limits
        changed = new_limits ^ limits
        limits = new_limits
        if changed != 0:
            for switch in range(2):
                if changed & (1 << switch):
                    base = S_EDGES + switch * EDGE_FIELDS
                    state[base + EDGE_COUNT] = (int(state[base + EDGE_COUNT]) + 1) % (
                        EDGE_COUNT_MODULUS
                    )
                    state[base + EDGE_CLOSED] = (new_limits >> switch) & 1
                    state[base + EDGE_POSITION] = actual
                    state[base + EDGE_TICK] = clock + 1
        touching = probe_closed(count, probe_side, probe_position)
        if touching != probe:
            probe = touching
            state[S_PROBE_EDGE + EDGE_COUNT] = (int(state[S_PROBE_EDGE + EDGE_COUNT]) + 1) % (
                EDGE_COUNT_MODULUS
            )
            state[S_PROBE_EDGE + EDGE_CLOSED] = probe
            state[S_PROBE_EDGE + EDGE_POSITION] = actual
            state[S_PROBE_EDGE + EDGE_TICK] = clock + 1
        if mode == MODE_VELOCITY:
            velocity_mode_us += tick_us
            if velocity_mode_us >= VELOCITY_RESET_US:
                velocity_mode_us -= VELOCITY_RESET_US
                offset = wrap_int32(-source)
                for slot in range(window):
                    state[S_COUNTS + slot] = wrap_int32(int(state[S_COUNTS + slot]) - actual)
                shift_edges(state, -actual)
                if drive != DRIVE_DC:
                    desired = wrap_int32(desired - actual)
                    desired_prev = wrap_int32(desired_prev - actual)
                actual = 0

        # 5. faults
        since_command += tick_us
        since_command = min(since_command, TIMER_CAP_US)
        new_fault = FAULT_NONE
        following = 0
        if enable == 1:
            if mode != MODE_VELOCITY:
                following = wrap_int32(desired - actual)
                if closing != 0:
                    new_fault = FAULT_LIMIT_SWITCH
                elif fe_limit > 0 and (following > fe_limit or -following > fe_limit):
                    new_fault = FAULT_FOLLOWING_ERROR
            if new_fault == FAULT_NONE and watchdog_us > 0 and since_command >= watchdog_us:
                new_fault = FAULT_WATCHDOG

        # 6. clock, statistics and diagnostics
        clock += 1
        executed += 1
        if enable == 1 and mode != MODE_VELOCITY and start < 0:
            stats_ticks += 1
            size = following if following >= 0 else -following
            if size > stats_max:
                stats_max = size
                stats_max_tick = clock
            if size > abs(diag_peak):
                diag_peak = following
            square = size * size
            if square > STATS_SUM_CAP - stats_sum_sq:
                stats_sum_sq = STATS_SUM_CAP
            else:
                stats_sum_sq += square
        if new_fault != FAULT_NONE:
            fault = new_fault
            fault_tick = clock
            enable = 0
            out_c = 0
            out_e = 0
            outputs_off(state)
            out_next = OUTPUT_NONE_PENDING
            events |= EVENT_FAULT
        if diag_n > 0:
            diag_left -= 1
            if diag_left <= 0:
                diag_left = diag_n
                if diag_count < DIAG_SLOTS:
                    base = S_DIAG + diag_count * DIAG_RECORD
                    state[base] = clock
                    state[base + 1] = desired_vel if mode == MODE_VELOCITY else desired
                    state[base + 2] = actual
                    state[base + 3] = velocity
                    state[base + 4] = out_c
                    state[base + 5] = out_e
                    state[base + 6] = queue_count
                    state[base + 7] = diag_peak
                    diag_count += 1
                diag_peak = 0
                if diag_count >= diag_room:
                    events |= EVENT_DIAGNOSTICS
        if events != 0:
            break

    state[S_CLOCK] = clock
    state[S_ENABLE] = enable
    state[S_MODE] = mode
    state[S_FAULT] = fault
    state[S_FAULT_TICK] = fault_tick
    state[S_THETA] = theta
    state[S_OMEGA] = omega
    state[S_OFFSET] = offset
    state[S_ACTUAL] = actual
    state[S_COUNTS_POS] = counts_pos
    state[S_VELOCITY] = velocity
    state[S_DESIRED] = desired
    state[S_DESIRED_VEL] = desired_vel
    state[S_INTEGRAL] = integral
    state[S_HISTORY_POS] = history_pos
    state[S_FRESH] = fresh
    state[S_OUT_C] = out_c
    state[S_OUT_E] = out_e
    state[S_QUEUE_HEAD] = queue_head
    state[S_QUEUE_COUNT] = queue_count
    state[S_MOTION_LEFT] = motion_left
    state[S_START] = start
    state[S_SINCE_COMMAND_US] = since_command
    state[S_VELOCITY_MODE_US] = velocity_mode_us
    state[S_DIAG_LEFT] = diag_left
    state[S_LIMITS] = limits
    state[S_PROBE] = probe
    state[S_EVENTS] = events
    state[S_STATS_TICKS] = stats_ticks
    state[S_STATS_MAX] = stats_max
    state[S_STATS_MAX_TICK] = stats_max_tick
    state[S_STATS_SUM_SQ] = stats_sum_sq
    state[S_LAST_TAKE] = last_take
    state[S_DIAG_COUNT] = diag_count
    state[S_DIAG_PEAK] = diag_peak
    state[S_OUT_NEXT] = out_next
    state[S_PHASE] = phase
    state[S_LAST_STEPS] = last_steps
    state[S_VEL_ACC] = vel_acc
    state[S_DESIRED_PREV] = desired_prev
    return executed


def running(state: IntArray) -> bool:
    """True when the next tick consumes motion (enabled, and any armed start reached)."""
    if state[S_ENABLE] != 1:
        return False
    start = int(state[S_START])
    return start < 0 or int(state[S_CLOCK]) >= start


def ticks_to_scheduled_event(
    state: IntArray, params: IntArray, *, diagnostics: bool = True
) -> int | None:
    """Ticks until the next event of the clocks and countdowns alone, 1-based, or None.

    Counts a diagnostics line (unless ``diagnostics`` is False: a block records those
    lines and runs on), a pending output change coming due, the watchdog expiring, an
    armed start being reached, the
    queue running dry (its last value taken, or a velocity-mode motion update that finds
    it empty while a non-zero velocity is desired) and the velocity-mode counter reset.
    Faults that the motion itself causes (following error, limit switch) are not
    scheduled: they happen when the physics says.
    """
    head = state[:S_HISTORY].tolist()
    tick_us = int(params[P_TICK_US])
    candidates: list[int] = []
    if diagnostics and params[P_DIAG_N] > 0:
        candidates.append(max(1, head[S_DIAG_LEFT]))
    enabled = head[S_ENABLE] == 1
    watchdog_us = int(params[P_WATCHDOG_US])
    if enabled and watchdog_us > 0:
        left_us = watchdog_us - head[S_SINCE_COMMAND_US]
        candidates.append(max(1, -(-left_us // tick_us)))
    start = head[S_START]
    clock = head[S_CLOCK]
    if enabled and start >= 0 and clock < start:
        candidates.append(start - clock + 1)
    mode = head[S_MODE]
    if enabled and (start < 0 or clock >= start) and mode != MODE_CURVE:
        first = head[S_MOTION_LEFT] + 1
        count = head[S_QUEUE_COUNT]
        if count > 0:
            candidates.append(first + (count - 1) * int(params[P_SCALAR]))
        elif mode == MODE_VELOCITY and head[S_DESIRED_VEL] != 0:
            candidates.append(first)
    if mode == MODE_VELOCITY:
        left_us = VELOCITY_RESET_US - head[S_VELOCITY_MODE_US]
        candidates.append(max(1, -(-left_us // tick_us)))
    out_next = int(state[S_OUT_NEXT])
    if out_next != OUTPUT_NONE_PENDING:
        candidates.append(max(1, out_next - clock + 1))
    return min(candidates) if candidates else None


def ticks_to_full_records(state: IntArray, params: IntArray) -> int | None:
    """Ticks until the diagnostics record of the last free slot is written, or None.

    With diagnostics off, None; with every slot taken, 0.
    """
    diag_n = int(params[P_DIAG_N])
    if diag_n <= 0:
        return None
    room = DIAG_SLOTS - int(state[S_DIAG_COUNT])
    if room <= 0:
        return 0
    return max(1, int(state[S_DIAG_LEFT])) + (room - 1) * diag_n


def idle_advance(state: IntArray, params: IntArray, n_ticks: int) -> None:
    """Advance the clocks and countdowns by ``n_ticks`` ticks of a state at rest.

    Valid when one servo tick leaves every :data:`DYNAMIC_FIELDS` entry unchanged, no
    queue value or curve position is due, and ``n_ticks`` is below
    :func:`ticks_to_scheduled_event` (with ``diagnostics=False``) and
    :func:`ticks_to_full_records`: then each of these ticks changes only the clocks and
    countdowns, and writes the diagnostics records a tick would, and this gives the same
    state as running them. Every one of these ticks has the same following error, so the
    peak of each line after the first is that error.
    """
    tick_us = int(params[P_TICK_US])
    consuming = running(state) and state[S_MODE] != MODE_CURVE
    counted = running(state) and state[S_MODE] != MODE_VELOCITY
    following = wrap_int32(int(state[S_DESIRED]) - int(state[S_ACTUAL])) if counted else 0
    peak = int(state[S_DIAG_PEAK])
    if n_ticks > 0 and abs(following) > abs(peak):
        peak = following
    if counted:
        size = abs(following)
        if size > state[S_STATS_MAX]:
            state[S_STATS_MAX] = size
            state[S_STATS_MAX_TICK] = state[S_CLOCK] + 1
        state[S_STATS_TICKS] += n_ticks
        room = STATS_SUM_CAP - int(state[S_STATS_SUM_SQ])
        state[S_STATS_SUM_SQ] += min(room, n_ticks * size * size)
    state[S_CLOCK] += n_ticks
    state[S_SINCE_COMMAND_US] = min(
        TIMER_CAP_US, int(state[S_SINCE_COMMAND_US]) + n_ticks * tick_us
    )
    if state[S_MODE] == MODE_VELOCITY:
        state[S_VELOCITY_MODE_US] += n_ticks * tick_us
    diag_n = int(params[P_DIAG_N])
    if diag_n > 0:
        clock = int(state[S_CLOCK]) - n_ticks
        due = max(1, int(state[S_DIAG_LEFT]))
        record = (
            int(state[S_DESIRED_VEL] if state[S_MODE] == MODE_VELOCITY else state[S_DESIRED]),
            int(state[S_ACTUAL]),
            int(state[S_VELOCITY]),
            int(state[S_OUT_C]),
            int(state[S_OUT_E]),
            int(state[S_QUEUE_COUNT]),
        )
        count = int(state[S_DIAG_COUNT])
        while due <= n_ticks:
            if count < DIAG_SLOTS:
                base = S_DIAG + count * DIAG_RECORD
                state[base] = clock + due
                state[base + 1 : base + DIAG_RECORD - 1] = record
                state[base + DIAG_RECORD - 1] = peak
                count += 1
            peak = following if due < n_ticks else 0
            due += diag_n
        state[S_DIAG_COUNT] = count
        state[S_DIAG_LEFT] = due - n_ticks
    state[S_DIAG_PEAK] = peak
    window = int(params[P_WINDOW])
    state[S_COUNTS_POS] = (int(state[S_COUNTS_POS]) + n_ticks) % window
    if state[S_ENABLE] == 1:
        state[S_HISTORY_POS] = (int(state[S_HISTORY_POS]) + n_ticks) % window
    if consuming:
        scalar = int(params[P_SCALAR])
        state[S_MOTION_LEFT] = (int(state[S_MOTION_LEFT]) - n_ticks) % scalar
