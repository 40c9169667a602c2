"""The firmware's core1 code in C (``firmware/src/device``), built for this machine, gives the
Python device's integers, value for value.

Compared, on random and extreme operands: every scientific-notation operation of the
functional core of ``usbmotion.scimath`` (and ``float(SciNumber)``, ``SciNumber.from_float``),
the motor step and the derived motor constants of ``usbmotion.device.motor``, core0's copy of
the RAM variables into core1's params (``Device._copy_in``), the exact Hermite position of
``usbmotion.hermite`` and the curve player of ``usbmotion.device.curve``, and the servo tick
against ``core1.servo_block`` one tick at a time, every field of the state and every record
after every tick, in every mode. The tests of the tests show that the comparisons see a
one-count change of any state field and that source mutants of one digit or one count fail.

``USBMOTION_FUZZ_EXAMPLES`` (``tests/fuzz/budget.py``) scales the random cases. The derived
constants call no library function: ``decay_and_lag`` is one fixed sequence of binary64
operations on both sides, compared bit for bit here.
"""

from __future__ import annotations

import ctypes
import math
import random
import struct
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fuzz.budget import examples, fuzz_settings
from usbmotion import scimath
from usbmotion.device import Device, core1
from usbmotion.device.core0 import Gains
from usbmotion.device.curve import CurvePlayer
from usbmotion.device.motor import MotorParams, derive_constants, motor_step
from usbmotion.device.stepper import (
    SINE_SIZE,
    StepperParams,
    derive_stepper,
    encoder_microsteps,
    max_steps_per_tick,
    stepper_step,
)
from usbmotion.hermite import Keyframe, hermite_position
from usbmotion.protocol import QUEUE_CAPACITY

from .native import CACHE, DEVICE_SOURCES, load

SOURCES = ("sci.c", "motor.c", "stepper.c", "curve.c", "params.c", "servo.c", "absenc.c",
           "table_gen.c")
INT32_MIN = -(2**31)
INT32_MAX = 2**31 - 1
INT64_MIN = -(2**63)
INT64_MAX = 2**63 - 1

# --- the C types (servo.h, sci.h, motor.h), checked against the compiler's layout -------

c_i8, c_u8, c_u16, c_i16 = ctypes.c_int8, ctypes.c_uint8, ctypes.c_uint16, ctypes.c_int16
c_i32, c_u32, c_i64, c_u64 = ctypes.c_int32, ctypes.c_uint32, ctypes.c_int64, ctypes.c_uint64


class Sci(ctypes.Structure):
    _fields_ = [("c", c_i32), ("e", c_i32)]


class KeyframeC(ctypes.Structure):
    _fields_ = [
        ("duration_ms", c_u16), ("position_counts", c_i32),
        ("tangent_in", c_i16), ("tangent_out", c_i16),
    ]


class CoefficientsC(ctypes.Structure):
    _fields_ = [
        ("d", c_u32), ("d2", c_u32 * 2), ("m0", c_i32), ("dm0", c_u32),
        ("m0_negative", ctypes.c_bool), ("k2_magnitude", c_u64), ("k2_negative", ctypes.c_bool),
        ("c3", c_i64),
    ]


class CurveDifferencesC(ctypes.Structure):
    _fields_ = [("quotient", c_i64 * 4), ("remainder", (c_u32 * 4) * 4), ("den", c_u32 * 4)]


class CurvePreparedC(ctypes.Structure):
    _fields_ = [
        ("ready", ctypes.c_bool), ("p0", c_i32), ("m0", c_i32), ("step_us", c_i32),
        ("differences", CurveDifferencesC),
    ]


class CurvePlayerC(ctypes.Structure):
    _fields_ = [
        ("playing", ctypes.c_bool), ("stepping", ctypes.c_bool), ("head", c_u8), ("count", c_u8),
        ("warming", c_u8), ("active", c_u8), ("step_us", c_i32), ("elapsed_us", c_i64),
        ("own", CurveDifferencesC), ("buffer", KeyframeC * 8),
        ("start_position", c_i32), ("start_tangent", c_i32),
        ("prepared", CurvePreparedC * 8), ("last", KeyframeC), ("has_last", ctypes.c_bool),
        ("coefficients", CoefficientsC), ("warm_quotient", c_i64),
        ("warm_remainder", c_u32 * 4),
    ]


class SwitchEdgeC(ctypes.Structure):
    _fields_ = [
        ("edges", c_u32), ("closed", c_i32), ("position", c_i32), ("tick", c_i64),
    ]


class OutputValuesC(ctypes.Union):
    _fields_ = [("per_mille", c_i16 * 4), ("words", c_u32 * 2)]


class OutputPinsC(ctypes.Structure):
    _fields_ = [("words", c_u32 * 2)]


class OutputRecordC(ctypes.Structure):
    _fields_ = [
        ("tick", c_i64), ("values", OutputValuesC), ("pins", OutputPinsC), ("changes", c_u32),
    ]


class OutputQueueC(ctypes.Structure):
    _fields_ = [
        ("next", c_i64), ("last", c_i64), ("records", c_u32), ("head", c_u32),
        ("values", OutputValuesC), ("queue", OutputRecordC * 16),
    ]


class AbsencC(ctypes.Structure):
    _fields_ = [("have", ctypes.c_bool), ("frames", c_u32), ("angle", c_i32),
                ("source", c_i64), ("base", c_i64)]


class ServoState(ctypes.Structure):
    _fields_ = [
        ("clock", c_i64), ("enable", c_i32), ("mode", c_i32), ("fault", c_i32),
        ("fault_tick", c_i64), ("theta", c_i64), ("omega", c_i64), ("offset", c_i32),
        ("actual", c_i32), ("counts_pos", c_u32), ("velocity", c_i64), ("desired", c_i32),
        ("desired_vel", c_i32), ("integral", c_i64), ("history_pos", c_u32), ("fresh", c_i32),
        ("out", Sci), ("motion_left", c_i64), ("start", c_i64), ("since_command_us", c_i64),
        ("velocity_mode_us", c_i64), ("diag_left", c_i64), ("limits", c_i32),
        ("history", c_i64 * 10), ("counts", c_i32 * 10), ("stats_ticks", c_i64),
        ("stats_max", c_i64), ("stats_max_tick", c_i64), ("stats_sum_sq", c_i64),
        ("last_take", c_i64), ("diag_peak", c_i32), ("edges", SwitchEdgeC * 2),
        ("probe_edge", SwitchEdgeC), ("probe", c_i32), ("phase", c_i64),
        ("last_steps", c_i32), ("vel_acc", c_i64), ("desired_prev", c_i32),
        ("outputs", OutputQueueC),
        ("curve", CurvePlayerC),
        ("pins_started", ctypes.c_bool), ("pins_enabled", ctypes.c_bool),
        ("pins_edges", c_u32 * 2),
        ("absenc", AbsencC), ("absenc_quiet_us", c_i64), ("encoder_lost", ctypes.c_bool),
    ]


class EncoderRatioC(ctypes.Structure):
    _fields_ = [("num", c_u32), ("den", c_u32), ("num_shift", c_u32), ("den_shift", c_u32)]


class ServoParams(ctypes.Structure):
    _fields_ = [
        ("tick_us", c_i64), ("scalar", c_i64), ("kp", Sci), ("ki_dt", Sci), ("kd_dt", Sci),
        ("vs", Sci), ("integral_limit", c_i64), ("watchdog_us", c_i64), ("fe_limit", c_i64),
        ("diag_n", c_i64), ("steps", c_i32), ("drive", Sci), ("friction", Sci), ("decay", Sci),
        ("lag", Sci), ("lower", c_i32), ("upper", c_i32), ("stop_low", c_i64),
        ("stop_high", c_i64), ("window", c_i32), ("probe_side", c_i32),
        ("probe_position", c_i32), ("drive_kind", c_i32), ("max_steps", c_i32),
        ("cycle", c_i64), ("full", c_i64), ("holding", c_i64), ("detent", c_i64),
        ("corner", c_i64), ("load_unm", c_i64), ("viscous", Sci), ("accel", Sci),
        ("encoder_cpr", c_i32), ("per_rev", c_i32), ("motor_pins", c_i32),
        ("pins_level_per_volt", Sci),
        ("travel_num", c_i64), ("travel_den", c_i64),
        ("velocity_num", c_i64), ("velocity_den", c_i64), ("reach", c_i32),
        ("sine_k", c_i32), ("full_mask", c_u32), ("cycle_mask", c_u32),
        ("holding_corner", c_i64), ("encoder_ratio", EncoderRatioC), ("tick_num", c_i64),
        ("tick_den", c_i64), ("encoder_kind", c_i32), ("encoder_turn", c_i32),
    ]


class DeviceVars(ctypes.Structure):
    _fields_ = [
        ("interval_dms", c_i32), ("scalar", c_i32), ("kp", Sci), ("ki", Sci), ("kd", Sci),
        ("sim_update_interval_dms", c_i32), ("source_voltage_v", Sci),
        ("torque_constant_mnm_per_a", Sci), ("winding_resistance_ohm", Sci),
        ("counts_per_revolution", c_i32), ("inertia_kg_m2", Sci),
        ("viscous_friction_unm_per_rad_s", Sci), ("load_torque_mnm", Sci),
        ("travel_lower_counts", c_i32), ("travel_upper_counts", c_i32),
        ("overtravel_counts", c_i32), ("diag_n", c_i32), ("watchdog_ms", c_i32),
        ("fe_limit", c_i32), ("motor_pins", c_i32), ("probe_side", c_i32),
        ("probe_position", c_i32), ("drive", c_i32), ("full_steps", c_i32),
        ("microsteps", c_i32), ("pulse_ns", c_i32), ("setup_ns", c_i32),
        ("holding_mnm", c_i32), ("detent_mnm", c_i32), ("corner_rpm", c_i32),
        ("encoder_kind", c_i32), ("encoder_angle", c_i32),
    ]


class RecordC(ctypes.Structure):
    _fields_ = [
        ("kind", c_u8), ("clock", c_i64), ("desired", c_i64), ("actual", c_i64),
        ("velocity", c_i64), ("out", Sci), ("queued", c_i32), ("peak", c_i32),
        ("fault", c_i32),
    ]


RING_SLOTS = 512


class RecordRing(ctypes.Structure):
    _fields_ = [
        ("slots", RecordC * RING_SLOTS), ("head", c_u32), ("tail", c_u32), ("dropped", c_u32),
    ]


class MotorConstantsC(ctypes.Structure):
    _fields_ = [
        ("steps", c_i32), ("drive", Sci), ("friction_speed", Sci), ("decay", Sci), ("lag", Sci),
        ("tick_us", c_i64), ("stop_low_micro", c_i64), ("stop_high_micro", c_i64),
    ]


STRUCTS: dict[str, type[ctypes.Structure]] = {
    "sci_t": Sci, "keyframe_t": KeyframeC, "curve_coefficients_t": CoefficientsC,
    "curve_differences_t": CurveDifferencesC, "curve_prepared_t": CurvePreparedC,
    "curve_player_t": CurvePlayerC,
    "switch_edge_t": SwitchEdgeC, "output_values_t": OutputValuesC,
    "output_pins_t": OutputPinsC, "output_record_t": OutputRecordC,
    "output_queue_t": OutputQueueC,
    "stepper_encoder_ratio_t": EncoderRatioC,
    "servo_state_t": ServoState, "servo_params_t": ServoParams,
    "device_vars_t": DeviceVars, "record_t": RecordC, "record_ring_t": RecordRing,
    "motor_constants_t": MotorConstantsC,
}


def _python_layout() -> list[int]:
    layout = []
    for struct_type in STRUCTS.values():
        layout.append(ctypes.sizeof(struct_type))
        for name, *_ in struct_type._fields_:
            field = getattr(struct_type, name)
            layout += [field.offset, field.size]
    return layout


def _shim_source() -> str:
    """The test's platform (the motion queue as a plain ring) and the compiler's layout."""
    layout = []
    for c_name, struct_type in STRUCTS.items():
        layout.append(f"sizeof({c_name})")
        for name, *_ in struct_type._fields_:
            layout += [f"offsetof({c_name}, {name})", f"sizeof((({c_name} *)0)->{name})"]
    return "\n".join([
        "/* generated by tests/firmware/test_native_servo.py */",
        "#include <stddef.h>",
        '#include "curve.h"',
        '#include "motor.h"',
        '#include "platform.h"',
        '#include "servo.h"',
        "static int32_t queue[MOTION_QUEUE_CAPACITY];",
        "static uint32_t queue_head, queue_count;",
        "bool mq_try_add(int32_t value) {",
        "    if (queue_count >= MOTION_QUEUE_CAPACITY) return false;",
        "    queue[(queue_head + queue_count++) % MOTION_QUEUE_CAPACITY] = value;",
        "    return true;",
        "}",
        "bool mq_try_remove(int32_t *value) {",
        "    if (queue_count == 0) return false;",
        "    *value = queue[queue_head];",
        "    queue_head = (queue_head + 1) % MOTION_QUEUE_CAPACITY;",
        "    queue_count--;",
        "    return true;",
        "}",
        "uint32_t mq_level(void) { return queue_count; }",
        "void mq_clear(void) { queue_head = queue_count = 0; }",
        "int32_t mq_peek(uint32_t index) {",
        "    return queue[(queue_head + index) % MOTION_QUEUE_CAPACITY];",
        "}",
        "/* the motor on the pins: a bare board */",
        "void platform_motor_pins_start(void) {}",
        "void platform_motor_pins_encoder(int32_t kind) { (void)kind; }",
        "void platform_motor_pins_sample(motor_pins_sample_t *s) {",
        "    *s = (motor_pins_sample_t){0};",
        "}",
        "void platform_motor_pins_drive(int32_t level, bool enable) {",
        "    (void)level;",
        "    (void)enable;",
        "}",
        "int32_t platform_motor_pins_full(void) { return 6250; }",
        "/* the outputs: core1's state holds them */",
        "void platform_outputs_start(void) {}",
        "void platform_outputs_form(const int16_t values[PLATFORM_OUTPUT_COUNT],",
        "                           output_pins_t *pins) {",
        "    (void)values;",
        "    *pins = (output_pins_t){{0, 0}};",
        "}",
        "void platform_outputs_write(const output_pins_t *pins) {",
        "    (void)pins;",
        "}",
        "/* the step outputs: the test keeps the steps of the last tick */",
        "int32_t test_steps_issued;",
        "bool test_steps_enabled;",
        "void platform_steps_start(void) {}",
        "void platform_steps_timing(uint32_t pulse, uint32_t setup, uint32_t tick) {",
        "    (void)pulse;",
        "    (void)setup;",
        "    (void)tick;",
        "}",
        "void platform_steps_issue(int32_t steps, bool enable) {",
        "    test_steps_issued = steps;",
        "    test_steps_enabled = enable;",
        "}",
        f"const size_t test_layout[] = {{{', '.join(layout)}}};",
        "const size_t test_layout_count = sizeof test_layout / sizeof test_layout[0];",
        "",
    ])


def _declare(lib: ctypes.CDLL) -> ctypes.CDLL:
    sig: dict[str, tuple[object, list[object]]] = {
        "sci_normalize": (Sci, [c_i64, c_i32]),
        "sci_from_int": (Sci, [c_i64]),
        "sci_to_int": (c_i64, [Sci]),
        "sci_mul": (Sci, [Sci, Sci]),
        "sci_div": (Sci, [Sci, Sci]),
        "sci_add": (Sci, [Sci, Sci]),
        "sci_sub": (Sci, [Sci, Sci]),
        "sci_compare": (ctypes.c_int, [Sci, Sci]),
        "sci_to_double": (ctypes.c_double, [Sci]),
        "sci_from_double": (Sci, [ctypes.c_double]),
        "sci_div_pow10_u64": (c_u32, [c_u64, ctypes.c_uint]),
        "motor_decay_and_lag": (None, [ctypes.c_double, ctypes.c_double,
                                       ctypes.POINTER(ctypes.c_double),
                                       ctypes.POINTER(ctypes.c_double)]),
        "motor_derive_constants": (None, [ctypes.POINTER(DeviceVars), c_i64,
                                          ctypes.POINTER(MotorConstantsC)]),
        "motor_step": (None, [ctypes.POINTER(c_i64), ctypes.POINTER(c_i64), Sci,
                              ctypes.POINTER(ServoParams)]),
        "stepper_cycles": (c_i64, [c_i64]),
        "stepper_max_steps_per_tick": (c_i32, [c_i64, c_i64, c_i64]),
        "stepper_encoder_microsteps": (c_i64, [c_i64, c_i32, c_i32]),
        "stepper_step": (None, [ctypes.POINTER(c_i64), ctypes.POINTER(c_i64), c_i64, c_i32,
                                ctypes.POINTER(ServoParams)]),
        "curve_hermite_position": (c_i64, [c_i32, c_i32, c_i32, c_i32, c_u32, c_u32]),
        "curve_next_position": (c_i64, [ctypes.POINTER(CurvePlayerC), c_i32, c_i64]),
        "curve_append": (ctypes.c_bool, [ctypes.POINTER(CurvePlayerC), KeyframeC]),
        "curve_clear": (None, [ctypes.POINTER(CurvePlayerC)]),
        "curve_interrupt": (None, [ctypes.POINTER(CurvePlayerC)]),
        "curve_queued": (c_u32, [ctypes.POINTER(CurvePlayerC)]),
        "servo_state_init": (None, [ctypes.POINTER(ServoState), c_i32]),
        "servo_params_derive": (None, [ctypes.POINTER(DeviceVars), ctypes.POINTER(ServoParams)]),
        "servo_params_finish": (None, [ctypes.POINTER(ServoParams)]),
        "servo_tick": (None, [ctypes.POINTER(ServoState), ctypes.POINTER(ServoParams),
                              ctypes.POINTER(RecordRing)]),
        "servo_switches": (c_i32, [ctypes.POINTER(ServoState), ctypes.POINTER(ServoParams)]),
        "servo_shift_position": (None, [ctypes.POINTER(ServoState), c_i64]),
        "mq_try_add": (ctypes.c_bool, [c_i32]),
        "mq_try_remove": (ctypes.c_bool, [ctypes.POINTER(c_i32)]),
        "mq_level": (c_u32, []),
        "mq_clear": (None, []),
        "mq_peek": (c_i32, [c_u32]),
    }
    for name, (restype, argtypes) in sig.items():
        function = getattr(lib, name)
        function.restype = restype
        function.argtypes = argtypes
    return lib


def _build(name: str, directory: Path) -> ctypes.CDLL:
    shim = CACHE / "servo-shim" / "test_platform.c"
    shim.parent.mkdir(parents=True, exist_ok=True)
    text = _shim_source()
    if not shim.exists() or shim.read_text() != text:
        shim.write_text(text)
    return _declare(load(name, [*(directory / s for s in SOURCES), shim]))


@pytest.fixture(scope="module")
def lib() -> ctypes.CDLL:
    """The portable core1 sources with the test's platform, as a shared library."""
    return _build("servo", DEVICE_SOURCES)


def test_struct_layout_matches_the_compiler(lib: ctypes.CDLL) -> None:
    count = ctypes.c_size_t.in_dll(lib, "test_layout_count").value
    compiled = list((ctypes.c_size_t * count).in_dll(lib, "test_layout"))
    assert compiled == _python_layout()


def sci(pair: tuple[int, int]) -> Sci:
    return Sci(pair[0], pair[1])


def pair(value: Sci) -> tuple[int, int]:
    return value.c, value.e


# --- operands -----------------------------------------------------------------------------


def random_coefficient(rnd: random.Random) -> int:
    roll = rnd.random()
    if roll < 0.05:
        return 0
    if roll < 0.15:
        return rnd.choice([1000, 9999, -1000, -9999, 1001, -1001, 9998, -9998])
    if roll < 0.2:
        return rnd.randint(-9999, 9999)   # not normalised: the formulas still apply
    return rnd.choice([-1, 1]) * rnd.randint(1000, 9999)


def random_exponent(rnd: random.Random) -> int:
    roll = rnd.random()
    if roll < 0.6:
        return rnd.randint(-12, 12)
    if roll < 0.9:
        return rnd.randint(-400, 400)
    return rnd.choice([-1, 1]) * rnd.randint(0, 2**29)


def random_sci(rnd: random.Random) -> tuple[int, int]:
    c = random_coefficient(rnd)
    return (c, random_exponent(rnd)) if c else (0, 0)


def random_int64(rnd: random.Random) -> int:
    roll = rnd.random()
    if roll < 0.3:
        return rnd.randint(-10**rnd.randint(0, 6), 10**rnd.randint(0, 6))
    if roll < 0.5:
        power = 10 ** rnd.randint(1, 18)
        return rnd.choice([-1, 1]) * (power + rnd.randint(-3, 3))
    if roll < 0.6:
        return rnd.choice([INT64_MIN, INT64_MAX, INT64_MIN + 1, 2**32, 2**32 - 1, -(2**32),
                           2**31, -(2**31), 2**62, -(2**62), 0])
    return rnd.randint(INT64_MIN, INT64_MAX)


def cases(factor: int) -> int:
    """Random cases of a cheap comparison: ``factor`` times the fuzz budget."""
    return factor * examples()


# Products, sums and quotients that sit exactly on the thresholds of the algorithms.
THRESHOLD_PAIRS = [
    ((2000, 0), (5000, 0)), ((-2000, 0), (5000, 0)), ((2500, 3), (4000, -3)),
    ((3125, 0), (3200, 0)), ((1000, 0), (1000, 0)), ((9999, 0), (9999, 0)),
    ((-9999, 0), (9999, 0)), ((1000, 0), (9999, 0)), ((3163, 0), (3162, 0)),
    ((9999, 0), (1, 3)), ((1, 0), (9999, 0)), ((5000, 0), (-5000, 0)), ((9999, 4), (1, 0)),
    ((9999, 3), (1, 0)), ((1000, 0), (-1000, -3)), ((1000, 0), (-1, 0)),
    ((9999, 0), (9999, -4)), ((9999, 0), (9999, -3)), ((-9999, 0), (-9999, 0)),
    ((5000, 0), (5000, 0)), ((1000, 0), (9999, 1)), ((1234, 5), (-1234, 5)),
]


def sci_mismatches(lib: ctypes.CDLL, operands: Sequence[tuple[tuple[int, int], tuple[int, int]]]
                   ) -> list[str]:
    """Every operation of the functional core on each operand pair, C against Python."""
    digits = 4
    found = []
    for a, b in operands:
        ca, cb = sci(a), sci(b)
        checks = [
            ("mul", pair(lib.sci_mul(ca, cb)), scimath.sci_mul(*a, *b, digits)),
            ("add", pair(lib.sci_add(ca, cb)), scimath.sci_add(*a, *b, digits)),
            ("sub", pair(lib.sci_sub(ca, cb)), scimath.sci_sub(*a, *b, digits)),
            ("compare", lib.sci_compare(ca, cb), scimath.sci_compare(*a, *b)),
        ]
        if b[0] != 0:
            checks.append(("div", pair(lib.sci_div(ca, cb)), scimath.sci_div(*a, *b, digits)))
        found += [f"{name}{a}{b}: C {got} Python {want}" for name, got, want in checks
                  if got != want]
    return found


def test_sci_operations_on_thresholds(lib: ctypes.CDLL) -> None:
    operands = [(a, b) for x, y in THRESHOLD_PAIRS
                for a, b in ((x, y), (y, x))]
    normalised = [((scimath.sci_normalize(a[0], a[1], 4)), scimath.sci_normalize(b[0], b[1], 4))
                  for a, b in operands]
    assert sci_mismatches(lib, operands + normalised) == []


def test_sci_operations_random(lib: ctypes.CDLL) -> None:
    rnd = random.Random(13)
    operands = [(random_sci(rnd), random_sci(rnd)) for _ in range(cases(40))]
    near = []
    for _ in range(cases(20)):   # exponents within a few of each other: levelled sums
        a = random_sci(rnd)
        c = random_coefficient(rnd)
        near.append((a, (c, a[1] + rnd.randint(-5, 5)) if c else (0, 0)))
    assert sci_mismatches(lib, operands + near) == []


@given(st.tuples(st.integers(-9999, 9999), st.integers(-2**29, 2**29)),
       st.tuples(st.integers(-9999, 9999), st.integers(-2**29, 2**29)))
@fuzz_settings()
def test_sci_operations_hypothesis(lib: ctypes.CDLL, a: tuple[int, int],
                                   b: tuple[int, int]) -> None:
    a = a if a[0] else (0, 0)
    b = b if b[0] else (0, 0)
    assert sci_mismatches(lib, [(a, b), (b, a)]) == []


def test_sci_from_int_and_normalize(lib: ctypes.CDLL) -> None:
    rnd = random.Random(17)
    values = [random_int64(rnd) for _ in range(cases(60))]
    for k in range(19):
        for delta in (-2, -1, 0, 1, 2):
            values += [10**k + delta, -(10**k) - delta]
    for k in range(64):
        values += [2**k - 1, 2**k, -(2**k), -(2**k) + 1]
    values += list(range(-20000, 20001, 7))
    values = [v for v in values if INT64_MIN <= v <= INT64_MAX]
    bad = [v for v in values
           if pair(lib.sci_from_int(v)) != scimath.sci_from_int(v, 4)]
    assert bad == []
    shifted = [(v, rnd.randint(-1000, 1000)) for v in values[: cases(10)]]
    bad_normal = [(v, e) for v, e in shifted
                  if pair(lib.sci_normalize(v, e)) != scimath.sci_normalize(v, e, 4)]
    assert bad_normal == []


def test_sci_div_pow10_is_floor_division(lib: ctypes.CDLL) -> None:
    rnd = random.Random(19)
    bad = []
    for _ in range(cases(30)):
        k = rnd.randint(6, 15)
        q = rnd.choice([1000, 9999, rnd.randint(1000, 9999)])
        m = q * 10**k + rnd.choice([0, 10**k - 1, rnd.randint(0, 10**k - 1)])
        if lib.sci_div_pow10_u64(m, k) != m // 10**k:
            bad.append((m, k))
    assert bad == []


def test_sci_to_int(lib: ctypes.CDLL) -> None:
    rnd = random.Random(23)
    pairs = [(random_coefficient(rnd), rnd.randint(-30, 14)) for _ in range(cases(30))]
    pairs += [(rnd.randint(INT32_MIN + 1, INT32_MAX), rnd.randint(-12, -1))
              for _ in range(cases(10))]
    pairs += [(c, e) for c in (9999, -9999, 1, -1, INT32_MAX, INT32_MIN + 1)
              for e in range(-12, 0)]
    bad = [(c, e) for c, e in pairs if lib.sci_to_int(Sci(c, e)) != scimath.sci_to_int(c, e)]
    assert bad == []


def test_sci_to_int_32_bit_path_every_coefficient(lib: ctypes.CDLL) -> None:
    """Every coefficient below 2^14 in magnitude, at every exponent of the 32-bit path (a
    multiply and a shift for -4..-1) and one beyond each end, and the first beyond 2^14."""
    bad = [(c, e) for e in range(-5, 7) for c in range(-(2**14), 2**14 + 1)
           if lib.sci_to_int(Sci(c, e)) != scimath.sci_to_int(c, e)]
    assert bad == []


def python_float(c: int, e: int) -> float:
    """float(SciNumber), with the C's answer where the Python raises OverflowError."""
    try:
        return float(scimath.SciNumber(c, e)) if c else 0.0
    except OverflowError:
        return math.copysign(math.inf, c)


def same_float(a: float, b: float) -> bool:
    return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)


def test_sci_to_double_is_pythons_float(lib: ctypes.CDLL) -> None:
    rnd = random.Random(29)
    pairs = []
    for _ in range(cases(15)):
        c = rnd.choice([-1, 1]) * rnd.randint(1000, 9999)
        pairs.append((c, rnd.choice([rnd.randint(-420, 420), rnd.randint(-30, 30),
                                     rnd.randint(-330, -300), rnd.randint(300, 310)])))
    pairs += [(c, e) for c in (1000, 9999, -1000, 1797, 1798, 4940, 4941, 2225, 2470)
              for e in (-401, -400, -327, -326, -325, -324, -311, -310, -309, -308, 305, 306,
                        401)]
    bad = [(c, e) for c, e in pairs
           if not same_float(lib.sci_to_double(Sci(c, e)), python_float(c, e))]
    assert bad == []


def double_of_bits(bits: int) -> float:
    return float(struct.unpack("<d", struct.pack("<Q", bits))[0])


def from_double_mismatches(lib: ctypes.CDLL, values: Sequence[float]) -> list[str]:
    found = []
    for x in values:
        want = scimath.SciNumber.from_float(x, digits=4)
        got = pair(lib.sci_from_double(x))
        if got != (want.coefficient, want.exponent):
            found.append(f"{x!r}: C {got} Python {want!r}")
    return found


def boundary_doubles(rnd: random.Random, count: int, exponents: tuple[int, int]
                     ) -> list[float]:
    """Doubles at and next to the doubles of 4-digit numbers, where repr's rounding and the
    truncation to 4 digits meet."""
    values = []
    for _ in range(count):
        c = rnd.randint(1000, 9999)
        x = float(scimath.SciNumber(c, rnd.randint(*exponents)))
        values.append(x)
        for direction in (0.0, math.inf):
            y = x
            for _ in range(rnd.randint(1, 3)):
                y = math.nextafter(y, direction)
            values.append(y)
    return values


NORMAL_MIN = 2.0**-1022
"""sci_from_double is exact for normal doubles (sci.h; the device's are above 1e-112)."""


def test_sci_from_double_is_from_float(lib: ctypes.CDLL) -> None:
    rnd = random.Random(31)
    values = boundary_doubles(rnd, cases(3), (-60, 10))
    values += boundary_doubles(rnd, cases(1) // 3, (-327, 304))
    for _ in range(cases(1)):
        x = double_of_bits(rnd.getrandbits(64))
        if math.isfinite(x) and abs(x) >= NORMAL_MIN:
            values.append(x)
    values += [rnd.random() * 10.0 ** rnd.randint(-70, 2) for _ in range(cases(3))]
    values += [0.3, 0.1, 1.0, 1e-5, NORMAL_MIN, 2.2250738585072014e-308, 1.7976931348623157e308,
               -0.0, 0.0, math.nextafter(NORMAL_MIN, 1.0), 2.0**1023, 0.047, 1e22, 1e23,
               9.999e-5, -1e-300, 12345.0, 0.5, 0.00010000000000000002, 2.225e-308]
    powers = [2.0**k for k in range(-1022, 1024, 3)]
    values += powers + [math.nextafter(p, 0.0) for p in powers]
    values = [x for x in values if x == 0.0 or abs(x) >= NORMAL_MIN]
    assert len(values) > cases(8)
    assert from_double_mismatches(lib, values) == []


# --- the motor: derived constants and the step -------------------------------------------


def _sci_param(rnd: random.Random, low: int = 1) -> tuple[int, int]:
    roll = rnd.random()
    exponent = rnd.randint(-12, 6) if roll < 0.5 else rnd.randint(-5, 1)
    coefficient = rnd.randint(low, 9999) if rnd.random() < 0.8 else rnd.choice([low, 9999])
    return coefficient, exponent


def random_motor(rnd: random.Random) -> MotorParams:
    """A motor within the calls' ranges: mostly near the default, sometimes anywhere."""
    default = MotorParams()
    if rnd.random() < 0.3:
        motor = default
    elif rnd.random() < 0.5:
        motor = MotorParams(
            source_voltage_v=_sci_param(rnd), torque_constant_mnm_per_a=_sci_param(rnd),
            winding_resistance_ohm=_sci_param(rnd),
            counts_per_revolution=rnd.choice([1, 1920, 1_000_000, rnd.randint(1, 1_000_000)]),
            inertia_kg_m2=_sci_param(rnd), viscous_friction_unm_per_rad_s=_sci_param(rnd, 0),
            load_torque_mnm=_sci_param(rnd, 0),
            sim_update_interval_dms=rnd.choice([1, 10, 10000, rnd.randint(1, 10000)]),
        )
    else:
        def near(value: tuple[int, int]) -> tuple[int, int]:
            return value[0], value[1] + rnd.randint(-1, 1)
        motor = replace(
            default,
            torque_constant_mnm_per_a=near(default.torque_constant_mnm_per_a),
            inertia_kg_m2=near(default.inertia_kg_m2),
            load_torque_mnm=rnd.choice([(0, 0), default.load_torque_mnm, (5, 0)]),
            sim_update_interval_dms=rnd.choice([1, 3, 7, 10, 100]),
        )
    if rnd.random() < 0.3:
        lower = rnd.randint(INT32_MIN, INT32_MAX - 1)
        upper = rnd.randint(lower + 1, INT32_MAX)
        motor = replace(motor, travel_lower_counts=lower, travel_upper_counts=upper)
    return motor


def random_interval_dms(rnd: random.Random) -> int:
    return rnd.choice([1, 2, 3, 4, 5, 6, 7, 10, 13, 100, 10000, rnd.randint(1, 10000)])


def device_vars(motor: MotorParams, gains: Gains, *, interval_dms: int = 10, scalar: int = 1,
                diag_n: int = 0, watchdog_ms: int = 0, fe_limit: int = 0, drive: int = 0,
                stepper: StepperParams | None = None) -> DeviceVars:
    stepper = stepper if stepper is not None else StepperParams()
    return DeviceVars(
        interval_dms=interval_dms, scalar=scalar, kp=sci(gains.kp), ki=sci(gains.ki),
        kd=sci(gains.kd), sim_update_interval_dms=motor.sim_update_interval_dms,
        source_voltage_v=sci(motor.source_voltage_v),
        torque_constant_mnm_per_a=sci(motor.torque_constant_mnm_per_a),
        winding_resistance_ohm=sci(motor.winding_resistance_ohm),
        counts_per_revolution=motor.counts_per_revolution,
        inertia_kg_m2=sci(motor.inertia_kg_m2),
        viscous_friction_unm_per_rad_s=sci(motor.viscous_friction_unm_per_rad_s),
        load_torque_mnm=sci(motor.load_torque_mnm),
        travel_lower_counts=motor.travel_lower_counts,
        travel_upper_counts=motor.travel_upper_counts,
        overtravel_counts=motor.overtravel_counts, diag_n=diag_n, watchdog_ms=watchdog_ms,
        fe_limit=fe_limit, drive=drive, full_steps=stepper.full_steps,
        microsteps=stepper.microsteps, pulse_ns=stepper.pulse_ns, setup_ns=stepper.setup_ns,
        holding_mnm=stepper.holding_mnm, detent_mnm=stepper.detent_mnm,
        corner_rpm=stepper.corner_rpm,
    )


def test_derived_motor_constants(lib: ctypes.CDLL) -> None:
    rnd = random.Random(37)
    bad = []
    for _ in range(cases(2)):
        motor = random_motor(rnd)
        tick_us = random_interval_dms(rnd) * 100
        want = derive_constants(motor, tick_us=tick_us)
        got = MotorConstantsC()
        lib.motor_derive_constants(ctypes.byref(device_vars(motor, Gains())), tick_us,
                                   ctypes.byref(got))
        if (got.steps, pair(got.drive), pair(got.friction_speed), pair(got.decay),
                pair(got.lag), got.tick_us, got.stop_low_micro, got.stop_high_micro) != (
                want.steps, want.drive, want.friction_speed, want.decay, want.lag_s,
                want.tick_us, want.stop_low_micro, want.stop_high_micro):
            bad.append((motor, tick_us, want))
    assert bad == []


def random_gains(rnd: random.Random) -> Gains:
    if rnd.random() < 0.4:
        return Gains()
    if rnd.random() < 0.3:
        return Gains(kp=(7, -3), ki=(1, 0), kd=(0, 0))   # the velocity-mode gains

    def gain() -> tuple[int, int]:
        return (rnd.choice([0, 1, 999, rnd.randint(0, 999)]),
                rnd.choice([rnd.randint(-12, 6), rnd.randint(-4, 0)]))
    return Gains(kp=gain(), ki=gain(), kd=gain())


@dataclass
class Setting:
    """The RAM variables that _copy_in reads."""

    motor: MotorParams
    gains: Gains
    interval_dms: int
    scalar: int
    diag_n: int
    watchdog_ms: int
    fe_limit: int
    drive: int = 0
    stepper: StepperParams = field(default_factory=StepperParams)

    def python_params(self) -> np.ndarray:
        device = Device(motor=self.motor, gains=self.gains, fast=False)
        device._interval_dms = self.interval_dms
        device._scalar = self.scalar
        device._diag_n = self.diag_n
        device._watchdog_ms = self.watchdog_ms
        device._fe_limit = self.fe_limit
        device._drive = self.drive
        device._stepper = self.stepper
        device._copy_in()
        return device._params.copy()

    def c_vars(self) -> DeviceVars:
        return device_vars(self.motor, self.gains, interval_dms=self.interval_dms,
                           scalar=self.scalar, diag_n=self.diag_n,
                           watchdog_ms=self.watchdog_ms, fe_limit=self.fe_limit,
                           drive=self.drive, stepper=self.stepper)


def random_stepper(rnd: random.Random) -> StepperParams:
    """A stepper within calls 45-47's ranges: mostly the default, sometimes anywhere."""
    if rnd.random() < 0.4:
        return StepperParams()
    holding = rnd.choice([1, 590, 100_000, rnd.randint(1, 100_000)])
    return StepperParams(
        full_steps=rnd.choice([1, 200, 400, 1000, rnd.randint(1, 1000)]),
        microsteps=rnd.choice([1, 16, 256, rnd.randint(1, 256)]),
        pulse_ns=rnd.choice([100, 2000, 1_000_000, rnd.randint(100, 1_000_000)]),
        setup_ns=rnd.choice([0, 1000, 1_000_000, rnd.randint(0, 1_000_000)]),
        holding_mnm=holding, detent_mnm=rnd.choice([0, holding, rnd.randint(0, holding)]),
        corner_rpm=rnd.choice([1, 760, 100_000, rnd.randint(1, 100_000)]),
    )


def random_setting(rnd: random.Random, *, drives: bool = True) -> Setting:
    """Random RAM variables; with ``drives``, a step drive one time in two and a random
    stepper (drawn after the rest, so that ``drives=False`` gives the settings of before)."""
    setting = Setting(
        motor=random_motor(rnd), gains=random_gains(rnd), interval_dms=random_interval_dms(rnd),
        scalar=rnd.choice([1, 1, 2, 3, 65535, rnd.randint(1, 65535)]),
        diag_n=rnd.choice([0, 0, 1, 2, 7, 1_000_000]),
        watchdog_ms=rnd.choice([0, 0, 1, 5, 600_000]),
        fe_limit=rnd.choice([0, 0, 1, 3, 50, INT32_MAX]),
    )
    if not drives:
        return setting
    stepper = random_stepper(rnd)
    drive = rnd.choice([0, 0, 1, 2])
    if drive and max_steps_per_tick(setting.interval_dms * 100, stepper.pulse_ns,
                                    stepper.setup_ns) < 1:
        stepper = StepperParams()   # calls 5, 44 and 46 refuse a step drive with no step a tick
    return replace(setting, drive=drive, stepper=stepper)


PARAM_FIELDS = [
    (core1.P_TICK_US, "tick_us"), (core1.P_SCALAR, "scalar"),
    (core1.P_INTEGRAL_LIMIT, "integral_limit"), (core1.P_WATCHDOG_US, "watchdog_us"),
    (core1.P_FE_LIMIT, "fe_limit"), (core1.P_DIAG_N, "diag_n"), (core1.P_STEPS, "steps"),
    (core1.P_LOWER, "lower"), (core1.P_UPPER, "upper"), (core1.P_STOP_LOW, "stop_low"),
    (core1.P_STOP_HIGH, "stop_high"), (core1.P_WINDOW, "window"),
    (core1.P_PROBE_SIDE, "probe_side"), (core1.P_PROBE_POSITION, "probe_position"),
    (core1.P_DRIVE, "drive_kind"), (core1.P_MAX_STEPS, "max_steps"), (core1.P_CYCLE, "cycle"),
    (core1.P_FULL, "full"), (core1.P_HOLDING, "holding"), (core1.P_DETENT, "detent"),
    (core1.P_CORNER, "corner"), (core1.P_LOAD_UNM, "load_unm"),
    (core1.P_ENCODER_CPR, "encoder_cpr"), (core1.P_PER_REV, "per_rev"),
]
PARAM_SCI_FIELDS = [
    (core1.P_KP_C, "kp"), (core1.P_KI_C, "ki_dt"), (core1.P_KD_C, "kd_dt"),
    (core1.P_VS_C, "vs"), (core1.P_DRIVE_C, "drive"), (core1.P_FRICTION_C, "friction"),
    (core1.P_DECAY_C, "decay"), (core1.P_LAG_C, "lag"), (core1.P_VISCOUS_C, "viscous"),
    (core1.P_ACCEL_C, "accel"),
]


def c_params(params: np.ndarray, lib: ctypes.CDLL) -> ServoParams:
    """servo_params_t from the Python's params array (and servo_params_finish)."""
    c = ServoParams()
    for index, name in PARAM_FIELDS:
        setattr(c, name, int(params[index]))
    for index, name in PARAM_SCI_FIELDS:
        setattr(c, name, Sci(int(params[index]), int(params[index + 1])))
    lib.servo_params_finish(ctypes.byref(c))
    return c


def params_mismatches(params: np.ndarray, c: ServoParams) -> list[str]:
    found = [name for index, name in PARAM_FIELDS if getattr(c, name) != int(params[index])]
    found += [name for index, name in PARAM_SCI_FIELDS
              if pair(getattr(c, name)) != (int(params[index]), int(params[index + 1]))]
    travel = Fraction(int(params[core1.P_TICK_US]), int(params[core1.P_STEPS]) * 10**6)
    if (c.travel_num, c.travel_den) != (travel.numerator, travel.denominator):
        found.append("travel")
    velocity = Fraction(10**6, int(params[core1.P_WINDOW]) * int(params[core1.P_TICK_US]))
    if (c.velocity_num, c.velocity_den) != (velocity.numerator, velocity.denominator):
        found.append("velocity")
    if c.reach != int(params[core1.P_FULL]) // 10**6:
        found.append("reach")
    if c.holding_corner != int(params[core1.P_HOLDING]) * int(params[core1.P_CORNER]):
        found.append("holding_corner")
    return found


def test_params_derive_is_copy_in(lib: ctypes.CDLL) -> None:
    rnd = random.Random(41)
    bad = []
    for _ in range(cases(1)):
        setting = random_setting(rnd)
        got = ServoParams()
        lib.servo_params_derive(ctypes.byref(setting.c_vars()), ctypes.byref(got))
        found = params_mismatches(setting.python_params(), got)
        if found:
            bad.append((setting, found))
    assert bad == []


def test_integral_limit_extremes(lib: ctypes.CDLL) -> None:
    """int(vs / ki_dt) clamped to 1..2^62: a tiny Ki caps, a huge one floors at 1."""
    limits = set()
    for ki in [(1, -12), (999, 6), (0, 0), (1, 0), (5, -9), (123, -6)]:
        for voltage in [(1, -12), (9999, 6), (12, 0)]:
            for interval in (1, 10, 10000):
                setting = Setting(replace(MotorParams(), source_voltage_v=voltage),
                                  replace(Gains(), ki=ki), interval, 1, 0, 0, 0)
                got = ServoParams()
                lib.servo_params_derive(ctypes.byref(setting.c_vars()), ctypes.byref(got))
                want = setting.python_params()
                assert params_mismatches(want, got) == []
                limits.add(got.integral_limit)
    assert {0, 1, 2**62} <= limits


def random_motor_step_case(rnd: random.Random) -> tuple[int, ...]:
    tick_us = random_interval_dms(rnd) * 100
    sim_us = rnd.choice([100, 1000, tick_us, rnd.randint(1, 10000) * 100])
    steps = -(-tick_us // sim_us)
    lower = rnd.choice([INT32_MIN, rnd.randint(INT32_MIN, 0)])
    upper = rnd.choice([INT32_MAX, rnd.randint(lower + 1, INT32_MAX)])
    stop_low = (lower - 200) * 10**6
    stop_high = (upper + 201) * 10**6 - 1
    theta = rnd.choice([stop_low, stop_high, rnd.randint(stop_low, stop_high),
                        rnd.randint(-10**9, 10**9)])
    theta = min(max(theta, stop_low), stop_high)
    omega = rnd.choice([0, 10**12, -(10**12), rnd.randint(-(10**12), 10**12),
                        rnd.randint(-(10**10), 10**10), rnd.randint(-1000, 1000)])
    drive = random_sci(rnd)
    if rnd.random() < 0.5:
        drive = (drive[0], rnd.randint(-3, 12)) if drive[0] else drive
    friction = random_sci(rnd)
    friction = (abs(friction[0]), rnd.randint(-6, 12)) if friction[0] else friction
    if rnd.random() < 0.2:
        friction = (abs(drive[0]), drive[1]) if drive[0] else (0, 0)
    decay = rnd.choice([(1000, -3), (rnd.randint(1000, 9999), rnd.randint(-60, -4))])
    lag = rnd.choice([(0, 0), (rnd.randint(1000, 9999), rnd.randint(-65, -4))])
    return (theta, omega, *drive, *friction, *decay, *lag, tick_us, steps, stop_low, stop_high)


def motor_step_mismatches(lib: ctypes.CDLL, step_cases: Sequence[tuple[int, ...]]
                          ) -> list[tuple[int, ...]]:
    found = []
    params = ServoParams()
    for case in step_cases:
        (theta, omega, drive_c, drive_e, friction_c, friction_e, decay_c, decay_e, lag_c, lag_e,
         tick_us, steps, stop_low, stop_high) = case
        want = motor_step(*case)
        params.friction = Sci(friction_c, friction_e)
        params.decay = Sci(decay_c, decay_e)
        params.lag = Sci(lag_c, lag_e)
        params.tick_us, params.steps = tick_us, steps
        params.window = 1
        params.stop_low, params.stop_high = stop_low, stop_high
        lib.servo_params_finish(ctypes.byref(params))
        c_theta, c_omega = c_i64(theta), c_i64(omega)
        lib.motor_step(ctypes.byref(c_theta), ctypes.byref(c_omega), Sci(drive_c, drive_e),
                       ctypes.byref(params))
        if (c_theta.value, c_omega.value) != want:
            found.append(case)
    return found


def test_motor_step(lib: ctypes.CDLL) -> None:
    rnd = random.Random(43)
    assert motor_step_mismatches(lib, [random_motor_step_case(rnd)
                                       for _ in range(cases(30))]) == []


def test_motor_step_on_derived_constants(lib: ctypes.CDLL) -> None:
    """Steps of real motors (derived constants, PID-range voltages) from rest to full speed."""
    rnd = random.Random(47)
    step_cases = []
    for _ in range(cases(1) // 3):
        motor = random_motor(rnd)
        tick_us = random_interval_dms(rnd) * 100
        k = derive_constants(motor, tick_us=tick_us)
        volts = rnd.choice([(1200, -2), (-1200, -2), random_sci(rnd)])
        volts = (volts[0], min(volts[1], 6))
        drive = scimath.sci_mul(*volts, *k.drive, 4)
        theta, omega = rnd.randint(-(10**12), 10**12), 0
        for _ in range(20):
            case = (theta, omega, *drive, *k.friction_speed, *k.decay, *k.lag_s, tick_us,
                    k.steps, k.stop_low_micro, k.stop_high_micro)
            step_cases.append(case)
            theta, omega = motor_step(*case)
    assert motor_step_mismatches(lib, step_cases) == []


# --- the stepper: its sine, encoder, step timing and integration step ---------------------


def entry_edge(rnd: random.Random, period: int) -> int:
    """An angle on or beside the boundary of a sine table entry (where
    ``(angle % period) * SINE_SIZE // period`` changes), some periods either way."""
    entry = rnd.randrange(SINE_SIZE)
    return rnd.randint(-5, 5) * period - (-entry * period // SINE_SIZE) + rnd.choice([-1, 0, 1])


def test_stepper_encoder_finer_than_the_microsteps_every_residue(lib: ctypes.CDLL) -> None:
    """The encoder's path without a division (counts a turn over microsteps a turn reduced
    to num / den with den a power of two and den <= num): every shaft of several whole
    periods of den either side of 0, and of 2^31 either way, for each such ratio."""
    bad = []
    for cpr, per_rev in ((4000, 3200), (1000, 1000), (1024, 512), (5000, 3200), (1, 1),
                         (3, 2), (255, 128), (2**20 + 1, 2**19), (1_000_000, 256_000)):
        g = math.gcd(cpr, per_rev)
        num, den = cpr // g, per_rev // g
        assert den <= num and den & (den - 1) == 0
        span = 4 * den + 3
        for base in (0, 2**31 + 201 - span, -(2**31) - 201 + span):
            for shaft in range(base - span, base + span + 1):
                if lib.stepper_encoder_microsteps(shaft, cpr, per_rev) != encoder_microsteps(
                        shaft, cpr, per_rev):
                    bad.append((shaft, cpr, per_rev))
    assert bad == []


def test_stepper_encoder_and_step_timing(lib: ctypes.CDLL) -> None:
    rnd = random.Random(107)
    bad: list[object] = []
    for _ in range(cases(20)):
        cpr = rnd.choice([1, 1920, 4000, 1_000_000, rnd.randint(1, 1_000_000)])
        per_rev = rnd.choice([1, 3200, 256_000, rnd.randint(1, 256_000)])
        shaft = rnd.choice([0, -1, 1, rnd.randint(-10**5, 10**5),
                            rnd.randint(-(2**31) - 201, 2**31 + 201)])
        if lib.stepper_encoder_microsteps(shaft, cpr, per_rev) != encoder_microsteps(
                shaft, cpr, per_rev):
            bad.append((shaft, cpr, per_rev))
        tick_us = random_interval_dms(rnd) * 100
        pulse = rnd.choice([100, 101, 104, 2000, 1_000_000, rnd.randint(100, 1_000_000)])
        setup = rnd.choice([0, 1, 8, 9, 1000, 1_000_000, rnd.randint(0, 1_000_000)])
        if lib.stepper_max_steps_per_tick(tick_us, pulse, setup) != max_steps_per_tick(
                tick_us, pulse, setup):
            bad.append((tick_us, pulse, setup))
    assert bad == []


def stepper_case_params(rnd: random.Random) -> tuple[ServoParams, tuple[int, ...]]:
    """Constants of a random stepper, motor and period, derived as core0 derives them: the
    C params and the Python's arguments after theta, omega, field and powered."""
    setting = random_setting(rnd)
    motor, stepper = setting.motor, setting.stepper
    tick_us = setting.interval_dms * 100
    k = derive_constants(motor, tick_us=tick_us)
    s = derive_stepper(stepper, tick_us=tick_us, substeps=k.steps,
                       inertia=scimath.SciNumber(*motor.inertia_kg_m2),
                       viscous_unm=scimath.SciNumber(*motor.viscous_friction_unm_per_rad_s),
                       load_mnm=scimath.SciNumber(*motor.load_torque_mnm))
    c = ServoParams()
    c.tick_us, c.steps, c.window = tick_us, k.steps, 1
    c.cycle, c.full, c.holding, c.detent = s.cycle, s.full, s.holding_unm, s.detent_unm
    c.corner, c.load_unm = s.corner, s.load_unm
    c.viscous, c.accel = Sci(*s.viscous), Sci(*s.accel)
    c.stop_low, c.stop_high = k.stop_low_micro, k.stop_high_micro
    return c, (s.cycle, s.full, s.holding_unm, s.detent_unm, s.corner, s.load_unm, *s.viscous,
               *s.accel, tick_us, k.steps, k.stop_low_micro, k.stop_high_micro)


def stepper_step_mismatches(lib: ctypes.CDLL, rnd: random.Random, count: int) -> list[object]:
    """Random shafts under random fields through a few sub-steps each, C against Python: the
    field (whole microsteps: the steps issued) and the shaft anywhere, near each other, or
    placed so that the field's angle or the detent's falls on or beside the edge of a sine
    table entry, both signs."""
    bad: list[object] = []
    micro = 10**6
    for _ in range(count):
        c, constants = stepper_case_params(rnd)
        lib.servo_params_finish(ctypes.byref(c))
        cycle, full, stop_low, stop_high = constants[0], constants[1], constants[-2], constants[-1]
        theta = rnd.choice([0, stop_low, stop_high, rnd.randint(-(10**12), 10**12),
                            rnd.randint(stop_low, stop_high), entry_edge(rnd, full)])
        omega = rnd.choice([0, 0, rnd.randint(-(10**10), 10**10), 10**13, -(10**13),
                            rnd.randint(-(10**13), 10**13)])
        for _ in range(6):
            count = theta // micro
            roll = rnd.random()
            if roll < 0.3:   # the field's angle on a table entry's edge
                field = count + rnd.randint(-3, 3)
                theta = min(max(field * micro - entry_edge(rnd, cycle), stop_low), stop_high)
            elif roll < 0.5:   # the detent's
                theta = min(max(theta - theta % full + entry_edge(rnd, full), stop_low),
                            stop_high)
                field = theta // micro + rnd.randint(-3 * full // micro, 3 * full // micro)
            else:
                field = count + rnd.choice([0, rnd.randint(-4 * full // micro, 4 * full // micro),
                                            rnd.randint(-(10**9), 10**9)])
            powered = rnd.choice([1, 1, 0])
            want = stepper_step(theta, omega, field * micro, powered, *constants)
            c_theta, c_omega = c_i64(theta), c_i64(omega)
            lib.stepper_step(ctypes.byref(c_theta), ctypes.byref(c_omega), field, powered,
                             ctypes.byref(c))
            if (c_theta.value, c_omega.value) != want:
                bad.append((theta, omega, field, powered, constants, want))
                break
            theta, omega = want
    return bad


def test_stepper_step(lib: ctypes.CDLL) -> None:
    assert stepper_step_mismatches(lib, random.Random(109), cases(12)) == []


# --- curve mode: the Hermite position and the player --------------------------------------


def random_segment(rnd: random.Random) -> tuple[int, int, int, int, int, int]:
    def position() -> int:
        return rnd.choice([INT32_MIN, INT32_MAX, 0, rnd.randint(INT32_MIN, INT32_MAX),
                           rnd.randint(-1000, 1000)])

    def tangent() -> int:
        return rnd.choice([-32768, 32767, 0, rnd.randint(-32768, 32767)])
    duration = rnd.choice([1, 2, 65535, 65534, rnd.randint(1, 65535), rnd.randint(1, 100)])
    d = duration * 1000
    elapsed = rnd.choice([0, d, 1, d - 1, d // 2, d // 3, rnd.randint(0, d)])
    return position(), position(), tangent(), tangent(), duration, elapsed


def tie_segments(rnd: random.Random, count: int) -> list[tuple[int, int, int, int, int, int]]:
    """Segments whose exact value is a half count, and their mirror images: at the middle of
    a segment with equal tangents the value is (p0 + p1) / 2, a tie when p0 + p1 is odd."""
    segments = []
    for _ in range(count):
        duration = rnd.randint(1, 65535)
        p0 = rnd.randint(INT32_MIN + 1, INT32_MAX)
        p1 = rnd.randint(INT32_MIN + 1, INT32_MAX - 1)
        p1 += (p0 + p1 + 1) % 2
        tangent = rnd.randint(-32767, 32767)
        segments.append((p0, p1, tangent, tangent, duration, duration * 500))
        segments.append((-p0, -p1, -tangent, -tangent, duration, duration * 500))
    return segments


def exact_position(p0: int, p1: int, m0: int, m1: int, duration: int, elapsed: int
                   ) -> Fraction:
    """The exact value of a segment, from the formula of usbmotion.hermite's docstring."""
    d = Fraction(duration * 1000)
    s = elapsed / d
    scale = Fraction(duration, 1024)
    return (p0 * (2 * s**3 - 3 * s**2 + 1) + p1 * (3 * s**2 - 2 * s**3)
            + m0 * scale * (s**3 - 2 * s**2 + s) + m1 * scale * (s**3 - s**2))


def hermite_mismatches(lib: ctypes.CDLL, segments: Sequence[tuple[int, ...]]) -> list[str]:
    found = []
    for segment in segments:
        got = lib.curve_hermite_position(*segment)
        want = hermite_position(*segment)
        if got != want:
            found.append(f"{segment}: C {got} Python {want}")
    return found


def test_hermite_position_random_and_extreme(lib: ctypes.CDLL) -> None:
    rnd = random.Random(53)
    segments = [random_segment(rnd) for _ in range(cases(40))]
    corners = [(p0, p1, m0, m1, duration, elapsed)
               for p0 in (INT32_MIN, INT32_MAX) for p1 in (INT32_MIN, INT32_MAX)
               for m0 in (-32768, 32767) for m1 in (-32768, 32767)
               for duration in (1, 65535)
               for elapsed in (duration * 1000 // 3, duration * 1000 * 2 // 3, 1,
                               duration * 1000 - 1)]
    assert hermite_mismatches(lib, segments + corners) == []


def test_hermite_position_rounds_ties_away_from_zero(lib: ctypes.CDLL) -> None:
    segments = tie_segments(random.Random(59), cases(2))
    assert all(exact_position(*s).denominator == 2 for s in segments)   # every one a tie
    assert hermite_mismatches(lib, segments) == []


@given(st.integers(INT32_MIN, INT32_MAX), st.integers(INT32_MIN, INT32_MAX),
       st.integers(-32768, 32767), st.integers(-32768, 32767), st.integers(1, 65535),
       st.floats(0.0, 1.0))
@fuzz_settings()
def test_hermite_position_hypothesis(lib: ctypes.CDLL, p0: int, p1: int, m0: int, m1: int,
                                     duration: int, fraction: float) -> None:
    elapsed = round(fraction * duration * 1000)
    assert hermite_mismatches(lib, [(p0, p1, m0, m1, duration, elapsed)]) == []


def random_keyframe(rnd: random.Random) -> Keyframe:
    return Keyframe(
        rnd.choice([1, 2, 3, 65535, rnd.randint(1, 50), rnd.randint(1, 65535)]),
        rnd.choice([INT32_MIN, INT32_MAX, rnd.randint(-5000, 5000),
                    rnd.randint(INT32_MIN, INT32_MAX)]),
        rnd.choice([-32768, 32767, 0, rnd.randint(-32768, 32767)]),
        rnd.choice([-32768, 32767, 0, rnd.randint(-32768, 32767)]),
    )


def keyframe_c(keyframe: Keyframe) -> KeyframeC:
    return KeyframeC(keyframe.duration_ms, keyframe.position_counts, keyframe.tangent_in,
                     keyframe.tangent_out)


def set_player(c: CurvePlayerC, player: CurvePlayer, head: int) -> None:
    """The C player holding the Python player's state, its ring starting at slot ``head``."""
    snapshot = player.snapshot()
    c.head = head
    c.count = len(snapshot.buffer)
    for i, keyframe in enumerate(snapshot.buffer):
        c.buffer[(head + i) % 8] = keyframe_c(keyframe)
    c.playing = snapshot.playing
    c.elapsed_us = snapshot.elapsed_us
    c.start_position = snapshot.start_position
    c.start_tangent = snapshot.start_tangent


def player_mismatches(c: CurvePlayerC, player: CurvePlayer) -> list[str]:
    snapshot = player.snapshot()
    held = [c.buffer[(c.head + i) % 8] for i in range(c.count)]
    held_keyframes = tuple(Keyframe(k.duration_ms, k.position_counts, k.tangent_in,
                                    k.tangent_out) for k in held)
    found = []
    if held_keyframes != snapshot.buffer:
        found.append("curve.buffer")
    for name in ("playing", "elapsed_us", "start_position", "start_tangent"):
        if getattr(c, name) != getattr(snapshot, name):
            found.append(f"curve.{name}")
    return found


def test_curve_player(lib: ctypes.CDLL) -> None:
    rnd = random.Random(61)
    bad = []
    for _ in range(cases(1) // 3):
        player = CurvePlayer()
        c = CurvePlayerC()
        set_player(c, player, rnd.randint(0, 7))
        tick_us = random_interval_dms(rnd) * 100
        desired = rnd.randint(INT32_MIN, INT32_MAX)
        for _ in range(60):
            roll = rnd.random()
            if roll < 0.25:
                keyframe = random_keyframe(rnd)
                if lib.curve_append(ctypes.byref(c), keyframe_c(keyframe)) != player.append(
                        keyframe):
                    bad.append("append")
            elif roll < 0.27:
                lib.curve_clear(ctypes.byref(c))
                player.clear(desired)
            elif roll < 0.29:
                lib.curve_interrupt(ctypes.byref(c))
                player.interrupt(desired)
            else:
                got = lib.curve_next_position(ctypes.byref(c), desired, tick_us)
                want = player.next_position(desired, tick_us)
                if got != want:
                    bad.append(f"position {got} {want}")
                desired = core1.wrap_int32(want)
            if lib.curve_queued(ctypes.byref(c)) != player.queued:
                bad.append("queued")
            bad += player_mismatches(c, player)
    assert bad == []


def play(lib: ctypes.CDLL, rnd: random.Random, tick_us: int, keyframes: Iterator[Keyframe],
         ticks: int, *, refill: float = 0.9) -> tuple[list[str], int]:
    """Play keyframes on both players tick by tick, appending with probability ``refill``
    between ticks (so that the buffer sometimes runs dry); the differences, and how many
    ticks the C player stepped (its cache of forward differences in use)."""
    player = CurvePlayer()
    c = CurvePlayerC()
    desired = rnd.randint(-1000, 1000)
    bad: list[str] = []
    stepped = 0
    for tick in range(ticks):
        if player.queued < 8 and rnd.random() < refill:
            keyframe = next(keyframes)
            player.append(keyframe)
            lib.curve_append(ctypes.byref(c), keyframe_c(keyframe))
        was_stepping = c.stepping
        got = lib.curve_next_position(ctypes.byref(c), desired, tick_us)
        want = player.next_position(desired, tick_us)
        stepped += was_stepping and c.stepping
        if got != want:
            bad.append(f"tick {tick} at {tick_us} us: C {got} Python {want}")
        bad += [f"tick {tick}: {name}" for name in player_mismatches(c, player)]
        desired = core1.wrap_int32(want)
        if bad:
            break
    return bad, stepped


def keyframe_stream(rnd: random.Random, *, extreme: bool) -> Iterator[Keyframe]:
    while True:
        if extreme:
            yield random_keyframe(rnd)
        else:
            yield Keyframe(rnd.choice([1, 2, 3, 5, 10, 37]), rnd.randint(-30000, 30000),
                           rnd.randint(-32768, 32767), rnd.randint(-32768, 32767))


@pytest.mark.parametrize("tick_us", [100, 200, 300, 700, 1000, 2500, 10000])
def test_curve_player_long_plays(lib: ctypes.CDLL, tick_us: int) -> None:
    """Many segments at each period: the stepped ticks equal the exact evaluation."""
    rnd = random.Random(tick_us)
    ticks = max(200, 40 * examples() // max(1, tick_us // 100))
    bad, stepped = play(lib, rnd, tick_us, keyframe_stream(rnd, extreme=False), ticks)
    assert bad == []
    assert stepped > ticks // 4 or tick_us >= 2500
    bad, _ = play(lib, rnd, tick_us, keyframe_stream(rnd, extreme=True), ticks // 4,
                  refill=0.5)
    assert bad == []


def test_curve_two_word_steps_either_side_of_their_bound(lib: ctypes.CDLL) -> None:
    """A segment's remainders step in two words while den = 1024 (1000 D)^3 is below 2^64
    (D up to 262 ms), in three from 263 ms: segments of both lengths, and a few short ones
    between, at the extremes of position and tangent, every tick against the Python's."""
    assert 1024 * 262_000**3 < 2**64 < 1024 * 263_000**3
    rnd = random.Random(263)

    def keyframes() -> Iterator[Keyframe]:
        while True:
            yield Keyframe(rnd.choice([262, 263, 262, 263, 1, 3]),
                           rnd.choice([INT32_MIN, INT32_MAX, rnd.randint(-5000, 5000),
                                       rnd.randint(INT32_MIN, INT32_MAX)]),
                           rnd.choice([-32768, 32767, 0, rnd.randint(-32768, 32767)]),
                           rnd.choice([-32768, 32767, 0, rnd.randint(-32768, 32767)]))

    for tick_us in (100, 300):
        bad, stepped = play(lib, rnd, tick_us, keyframes(), 12_000 * 100 // tick_us)
        assert bad == []
        assert stepped > 1000


def test_curve_player_appended_at_the_end_of_a_keyframe(lib: ctypes.CDLL) -> None:
    """A keyframe appended after the last one was reached exactly: the next tick finds a
    segment nobody prepared (evaluated exactly, then stepped)."""
    player = CurvePlayer()
    c = CurvePlayerC()
    first = Keyframe(1, 500, 1000, -2000)
    for keyframe in (first,):
        player.append(keyframe)
        lib.curve_append(ctypes.byref(c), keyframe_c(keyframe))
    positions = []
    for tick in range(40):
        if tick == 10:   # the tick after the exact end of the first keyframe
            keyframe = Keyframe(2, -700, 3000, 0)
            player.append(keyframe)
            lib.curve_append(ctypes.byref(c), keyframe_c(keyframe))
        got = lib.curve_next_position(ctypes.byref(c), 0, 100)
        assert got == player.next_position(0, 100)
        assert player_mismatches(c, player) == []
        positions.append(got)
    assert positions[10] == 500 and positions[30] == -700


def test_curve_step_overflow_falls_back_to_exact(lib: ctypes.CDLL) -> None:
    """A step that moves the position by 2^32 counts or more (from -2^31, overshooting
    both ends) leaves the forward differences for one exact evaluation."""
    h = 65_533_001
    segment = (INT32_MIN, INT32_MAX, -32768, -32768, 65535)
    change = exact_position(*segment, h + 1) - exact_position(*segment, 1)
    assert change >= 2**32   # the quotient of the step does not fit 32 bits
    player = CurvePlayer()
    c = CurvePlayerC()
    for keyframe in (Keyframe(65533, INT32_MIN, 0, -32768), Keyframe(65535, INT32_MAX,
                                                                      -32768, 0)):
        player.append(keyframe)
        lib.curve_append(ctypes.byref(c), keyframe_c(keyframe))
    for _ in range(4):
        got = lib.curve_next_position(ctypes.byref(c), INT32_MIN, h)
        assert got == player.next_position(INT32_MIN, h)
        assert player_mismatches(c, player) == []


# --- the servo tick -----------------------------------------------------------------------

SCALAR_STATE = [
    (core1.S_CLOCK, "clock"), (core1.S_ENABLE, "enable"), (core1.S_MODE, "mode"),
    (core1.S_FAULT, "fault"), (core1.S_FAULT_TICK, "fault_tick"), (core1.S_THETA, "theta"),
    (core1.S_OMEGA, "omega"), (core1.S_OFFSET, "offset"), (core1.S_ACTUAL, "actual"),
    (core1.S_COUNTS_POS, "counts_pos"), (core1.S_VELOCITY, "velocity"),
    (core1.S_DESIRED, "desired"), (core1.S_DESIRED_VEL, "desired_vel"),
    (core1.S_INTEGRAL, "integral"), (core1.S_HISTORY_POS, "history_pos"),
    (core1.S_FRESH, "fresh"), (core1.S_MOTION_LEFT, "motion_left"), (core1.S_START, "start"),
    (core1.S_SINCE_COMMAND_US, "since_command_us"),
    (core1.S_VELOCITY_MODE_US, "velocity_mode_us"), (core1.S_DIAG_LEFT, "diag_left"),
    (core1.S_LIMITS, "limits"), (core1.S_STATS_TICKS, "stats_ticks"),
    (core1.S_STATS_MAX, "stats_max"), (core1.S_STATS_MAX_TICK, "stats_max_tick"),
    (core1.S_STATS_SUM_SQ, "stats_sum_sq"), (core1.S_LAST_TAKE, "last_take"),
    (core1.S_DIAG_PEAK, "diag_peak"), (core1.S_PHASE, "phase"),
    (core1.S_LAST_STEPS, "last_steps"), (core1.S_VEL_ACC, "vel_acc"),
    (core1.S_DESIRED_PREV, "desired_prev"),
]
OUTPUT_STATE = [(core1.S_OUT_RECORDS, "records"), (core1.S_OUT_HEAD, "head"),
                (core1.S_OUT_NEXT, "next"), (core1.S_OUT_LAST, "last")]
"""The outputs' scalars: the Python's entries and the fields of servo_state_t's outputs."""
OUTPUT_RECORD_FIELDS = [(core1.OUT_TICK, "tick"), (core1.OUT_CHANGES, "changes")]
"""The entries of one pending record in the Python's ring (``core1.OUT_RECORD``) other than
the outputs' values, by the C field they are (the platform's form, ``pins``, is not the
Python's: the test's platform writes nothing)."""
EDGE_FIELDS = [(core1.EDGE_COUNT, "edges"), (core1.EDGE_CLOSED, "closed"),
               (core1.EDGE_POSITION, "position"), (core1.EDGE_TICK, "tick")]
HISTORY = core1.HISTORY_SLOTS


@dataclass
class PythonDevice:
    """core1's state as the Python device holds it: the arrays, the queue, the player."""

    state: np.ndarray
    params: np.ndarray
    queue: np.ndarray
    player: CurvePlayer

    def queue_values(self) -> list[int]:
        head = int(self.state[core1.S_QUEUE_HEAD])
        count = int(self.state[core1.S_QUEUE_COUNT])
        return [int(self.queue[(head + i) % QUEUE_CAPACITY]) for i in range(count)]

    def tick(self) -> list[tuple[int, ...]]:
        """One tick of servo_block, the curve fed as core0's _run_curve does; the records."""
        state = self.state
        values = np.zeros(0, dtype=np.int64)
        if state[core1.S_MODE] == core1.MODE_CURVE and core1.running(state):
            tick_us = int(self.params[core1.P_TICK_US])
            values = np.array([self.player.next_position(int(state[core1.S_DESIRED]), tick_us)],
                              dtype=np.int64)
        self.params[core1.P_DIAG_ROOM] = core1.DIAG_SLOTS
        state[core1.S_DIAG_COUNT] = 0
        state[core1.S_EVENTS] = 0
        assert core1.servo_block(state, self.params, self.queue, values, 1) == 1
        records: list[tuple[int, ...]] = []
        for i in range(int(state[core1.S_DIAG_COUNT])):
            base = core1.S_DIAG + i * core1.DIAG_RECORD
            clock, desired, actual, velocity, out_c, out_e, queued, peak = (
                int(v) for v in state[base: base + core1.DIAG_RECORD])
            if state[core1.S_MODE] == core1.MODE_CURVE:
                queued = self.player.queued
            records.append((1, clock, desired, actual, velocity, out_c, out_e, queued, peak))
        state[core1.S_DIAG_COUNT] = 0
        if int(state[core1.S_EVENTS]) & core1.EVENT_FAULT:
            records.append((2, int(state[core1.S_FAULT_TICK]), int(state[core1.S_FAULT])))
        return records


class CDevice:
    """The C side: servo_state_t, servo_params_t, the test platform's queue, the ring."""

    def __init__(self, lib: ctypes.CDLL, python: PythonDevice, *, head: int = 0) -> None:
        self.lib = lib
        self.state = ServoState()
        self.params = c_params(python.params, lib)
        self.ring = RecordRing()
        s, c = python.state, self.state
        for index, name in SCALAR_STATE:
            setattr(c, name, int(s[index]))
        c.out = Sci(int(s[core1.S_OUT_C]), int(s[core1.S_OUT_E]))
        for i in range(HISTORY):
            c.history[i] = int(s[core1.S_HISTORY + i])
            c.counts[i] = int(s[core1.S_COUNTS + i])
        for switch in range(2):
            base = core1.S_EDGES + switch * core1.EDGE_FIELDS
            for offset, name in EDGE_FIELDS:
                setattr(c.edges[switch], name, int(s[base + offset]))
        for index, name in OUTPUT_STATE:
            setattr(c.outputs, name, int(s[index]))
        for output in range(4):
            c.outputs.values.per_mille[output] = int(s[core1.S_OUTPUTS + output])
        for slot in range(16):
            base = core1.S_OUT_QUEUE + slot * core1.OUT_RECORD
            record = c.outputs.queue[slot]
            for offset, name in OUTPUT_RECORD_FIELDS:
                setattr(record, name, int(s[base + offset]))
            for output in range(4):
                record.values.per_mille[output] = int(s[base + core1.OUT_VALUES + output])
        set_player(c.curve, python.player, head)
        lib.mq_clear()
        for value in python.queue_values():
            assert lib.mq_try_add(value)

    def tick(self) -> list[tuple[int, ...]]:
        self.lib.servo_tick(ctypes.byref(self.state), ctypes.byref(self.params),
                            ctypes.byref(self.ring))
        records: list[tuple[int, ...]] = []
        ring = self.ring
        while ring.tail != ring.head:
            r = ring.slots[ring.tail % RING_SLOTS]
            ring.tail += 1
            if r.kind == 1:
                records.append((1, r.clock, r.desired, r.actual, r.velocity, r.out.c, r.out.e,
                                r.queued, r.peak))
            else:
                records.append((r.kind, r.clock, r.fault))
        return records

    def queue_values(self) -> list[int]:
        return [self.lib.mq_peek(i) for i in range(self.lib.mq_level())]


def state_mismatches(python: PythonDevice, c: CDevice) -> list[str]:
    """Every field of core1's state where the C differs from the Python (empty: equal)."""
    s, cs = python.state, c.state
    found = [name for index, name in SCALAR_STATE if getattr(cs, name) != int(s[index])]
    if pair(cs.out) != (int(s[core1.S_OUT_C]), int(s[core1.S_OUT_E])):
        found.append("out")
    found += [f"history[{i}]" for i in range(HISTORY)
              if cs.history[i] != int(s[core1.S_HISTORY + i])]
    found += [f"counts[{i}]" for i in range(HISTORY)
              if cs.counts[i] != int(s[core1.S_COUNTS + i])]
    for switch in range(2):
        base = core1.S_EDGES + switch * core1.EDGE_FIELDS
        found += [f"edges[{switch}].{name}" for offset, name in EDGE_FIELDS
                  if getattr(cs.edges[switch], name) != int(s[base + offset])]
    found += [f"outputs.{name}" for index, name in OUTPUT_STATE
              if getattr(cs.outputs, name) != int(s[index])]
    found += [f"outputs.values[{i}]" for i in range(4)
              if cs.outputs.values.per_mille[i] != int(s[core1.S_OUTPUTS + i])]
    for slot in range(16):
        base = core1.S_OUT_QUEUE + slot * core1.OUT_RECORD
        record = cs.outputs.queue[slot]
        found += [f"outputs.queue[{slot}].{name}" for offset, name in OUTPUT_RECORD_FIELDS
                  if getattr(record, name) != int(s[base + offset])]
        found += [f"outputs.queue[{slot}].values[{i}]" for i in range(4)
                  if record.values.per_mille[i] != int(s[base + core1.OUT_VALUES + i])]
    if c.queue_values() != python.queue_values():
        found.append("queue")
    found += player_mismatches(cs.curve, python.player)
    return found


def _pick(rnd: random.Random, *choices: object) -> object:
    return rnd.choice(choices)


def random_device(rnd: random.Random, setting: Setting) -> PythonDevice:
    """A Python core1 in a random state within the device's invariants, edges weighted."""
    params = setting.python_params()
    tick_us = int(params[core1.P_TICK_US])
    window = int(params[core1.P_WINDOW])
    scalar = int(params[core1.P_SCALAR])
    state = core1.new_state()
    mode = rnd.choice([1, 2, 3])
    stop_low, stop_high = int(params[core1.P_STOP_LOW]), int(params[core1.P_STOP_HIGH])
    theta = rnd.choice([rnd.randint(stop_low, stop_high), stop_low, stop_high,
                        rnd.randint(-(10**9), 10**9), 0])
    theta = min(max(theta, stop_low), stop_high)
    if rnd.random() < 0.3:   # near a switch
        edge = int(params[rnd.choice([core1.P_LOWER, core1.P_UPPER])])
        theta = min(max((edge + rnd.randint(-3, 3)) * 10**6 + rnd.randint(0, 10**6 - 1),
                        stop_low), stop_high)
    count = theta // 10**6
    offset = int(_pick(rnd, 0, 0, rnd.randint(INT32_MIN, INT32_MAX), INT32_MIN, INT32_MAX))
    actual = core1.wrap_int32(count + offset)
    if rnd.random() < 0.1:
        actual = rnd.randint(INT32_MIN, INT32_MAX)

    def near_int32(center: int, spread: int) -> int:
        return core1.wrap_int32(center + rnd.randint(-spread, spread))

    limit = int(params[core1.P_INTEGRAL_LIMIT])
    fields = {
        core1.S_CLOCK: rnd.choice([0, rnd.randint(0, 10**6), rnd.randint(0, 2**40)]),
        core1.S_ENABLE: rnd.choice([1, 1, 1, 0]),
        core1.S_MODE: mode,
        core1.S_FAULT: rnd.choice([0, 0, 0, 1, 2, 3, 4]),
        core1.S_FAULT_TICK: rnd.randint(0, 10**6),
        core1.S_THETA: theta,
        core1.S_OMEGA: rnd.choice([0, 10**12, -(10**12), rnd.randint(-(10**12), 10**12),
                                   rnd.randint(-(10**10), 10**10), rnd.randint(-10**6, 10**6)]),
        core1.S_OFFSET: offset,
        core1.S_ACTUAL: actual,
        core1.S_COUNTS_POS: rnd.randint(0, window - 1),
        core1.S_VELOCITY: rnd.choice([0, rnd.randint(-(10**7), 10**7),
                                      rnd.randint(-(2**42), 2**42)]),
        core1.S_DESIRED: rnd.choice([actual, near_int32(actual, 5), near_int32(actual, 5000),
                                     rnd.randint(INT32_MIN, INT32_MAX),
                                     core1.wrap_int32(actual + 2**31)]),
        core1.S_DESIRED_VEL: rnd.choice([0, rnd.randint(-20000, 20000), INT32_MIN, INT32_MAX]),
        core1.S_INTEGRAL: rnd.randint(-limit, limit) if rnd.random() < 0.8 else
        rnd.choice([limit, -limit, 0]),
        core1.S_HISTORY_POS: rnd.randint(0, window - 1),
        core1.S_FRESH: rnd.choice([0, 0, 1]),
        core1.S_OUT_C: 0, core1.S_OUT_E: 0,
        core1.S_MOTION_LEFT: rnd.randint(0, scalar),
        core1.S_START: rnd.choice([-1, -1, -1, 0, 1, 5, 2**31 - 1]),
        core1.S_SINCE_COMMAND_US: rnd.choice([0, rnd.randint(0, 10**7),
                                              core1.TIMER_CAP_US - rnd.randint(0, 3 * tick_us),
                                              int(params[core1.P_WATCHDOG_US]) - tick_us]),
        core1.S_VELOCITY_MODE_US: rnd.choice([0, rnd.randint(0, core1.VELOCITY_RESET_US - 1),
                                              core1.VELOCITY_RESET_US - tick_us,
                                              core1.VELOCITY_RESET_US - 2 * tick_us]),
        core1.S_DIAG_LEFT: rnd.randint(0, max(0, min(3, int(params[core1.P_DIAG_N])))),
        core1.S_LIMITS: rnd.choice([0, 1, 2, 3]),
        core1.S_STATS_TICKS: rnd.randint(0, 2**40),
        core1.S_STATS_MAX: rnd.choice([0, rnd.randint(0, 100), rnd.randint(0, 2**31)]),
        core1.S_STATS_MAX_TICK: rnd.randint(0, 2**40),
        core1.S_STATS_SUM_SQ: rnd.choice([0, rnd.randint(0, 2**40),
                                          core1.STATS_SUM_CAP - rnd.randint(0, 2**33),
                                          core1.STATS_SUM_CAP]),
        core1.S_LAST_TAKE: rnd.choice([-1, rnd.randint(0, 2**30)]),
        core1.S_DIAG_PEAK: rnd.choice([0, 0, rnd.randint(-100, 100), rnd.randint(-5000, 5000),
                                       INT32_MIN, INT32_MAX,
                                       rnd.randint(INT32_MIN, INT32_MAX)]),
    }
    if setting.drive:
        # a stepper: the driver's step counter near the shaft (or slipped cycles away, or
        # anywhere), its speed up to the model's bound, the velocity mode's remainder
        micro = 10**6
        full = int(params[core1.P_FULL]) // micro
        steps_near = count + rnd.choice([0, rnd.randint(-2 * full, 2 * full),
                                         rnd.randint(-40 * full, 40 * full)])
        fields[core1.S_PHASE] = rnd.choice([steps_near, steps_near,
                                            rnd.randint(-(2**40), 2**40)])
        fields[core1.S_LAST_STEPS] = rnd.randint(-int(params[core1.P_MAX_STEPS]),
                                                 int(params[core1.P_MAX_STEPS]))
        fields[core1.S_VEL_ACC] = rnd.randint(-micro + 1, micro - 1)
        fields[core1.S_OMEGA] = rnd.choice([0, 0, rnd.randint(-(10**9), 10**9),
                                            rnd.randint(-(10**13), 10**13), 10**13, -(10**13),
                                            rnd.randint(-(10**11), 10**11)])
        if setting.drive == core1.DRIVE_STEP_OPEN and rnd.random() < 0.7:
            actual = core1.wrap_int32(int(fields[core1.S_PHASE]) + offset)
            fields[core1.S_ACTUAL] = actual
    for index, value in fields.items():
        state[index] = value
    if state[core1.S_START] >= 0:
        state[core1.S_START] = int(state[core1.S_CLOCK]) + int(state[core1.S_START]) % 4 - 1
    if rnd.random() < 0.7:
        state[core1.S_LIMITS] = (int(count <= params[core1.P_LOWER])
                                 | 2 * int(count >= params[core1.P_UPPER]))
    out = random_sci(rnd)
    state[core1.S_OUT_C], state[core1.S_OUT_E] = out[0], min(max(out[1], -20), 20)
    spread = rnd.choice([5, 5000, 2**31])
    for i in range(HISTORY):
        state[core1.S_HISTORY + i] = rnd.randint(-spread, spread)
        state[core1.S_COUNTS + i] = rnd.choice([near_int32(actual, 20), actual,
                                                rnd.randint(INT32_MIN, INT32_MAX)])
    for switch in range(2):
        base = core1.S_EDGES + switch * core1.EDGE_FIELDS
        if rnd.random() < 0.5:
            state[base + core1.EDGE_COUNT] = rnd.choice([1, 2**32 - 1, rnd.randint(0, 2**32 - 1)])
            state[base + core1.EDGE_CLOSED] = rnd.randint(0, 1)
            state[base + core1.EDGE_POSITION] = rnd.randint(INT32_MIN, INT32_MAX)
            state[base + core1.EDGE_TICK] = rnd.randint(1, 2**40)
    for output in range(4):
        state[core1.S_OUTPUTS + output] = rnd.choice([0, 1000, rnd.randint(0, 1000)])
    state[core1.S_OUT_LAST] = rnd.choice([-1, rnd.randint(0, 2**30)])
    out_head = rnd.randint(0, 15)
    records = rnd.choice([0, 0, 1, 2, 3, 16])
    changes = [1] * records
    for _ in range(16 - records if records else 0):   # up to 16 changes in all
        if rnd.random() < 0.3:
            changes[rnd.randrange(records)] += 1
    tick = int(state[core1.S_CLOCK]) + rnd.randint(-4, 2)
    values = [int(v) for v in state[core1.S_OUTPUTS : core1.S_OUTPUTS + 4]]
    for k in range(records):   # in tick order, one record a tick, some due within a few
        tick = max(0, tick + rnd.choice([1, 1, 1, 2, rnd.randint(1, 5)])) if k else max(0, tick)
        for _ in range(changes[k]):
            values[rnd.randint(0, 3)] = rnd.choice([0, 1000, rnd.randint(0, 1000)])
        base = core1.S_OUT_QUEUE + (out_head + k) % 16 * core1.OUT_RECORD
        state[base + core1.OUT_TICK] = tick
        state[base + core1.OUT_CHANGES] = changes[k]
        state[base + core1.OUT_VALUES : base + core1.OUT_RECORD] = values
    state[core1.S_OUT_RECORDS] = records
    state[core1.S_OUT_HEAD] = out_head
    state[core1.S_OUT_NEXT] = (
        int(state[core1.S_OUT_QUEUE + out_head * core1.OUT_RECORD + core1.OUT_TICK])
        if records else core1.OUTPUT_NONE_PENDING)
    queue = np.zeros(QUEUE_CAPACITY, dtype=np.int64)
    head = rnd.randint(0, QUEUE_CAPACITY - 1)
    values = [rnd.choice([near_int32(actual, 50), rnd.randint(-20000, 20000), INT32_MIN,
                          INT32_MAX, rnd.randint(INT32_MIN, INT32_MAX)])
              for _ in range(rnd.choice([0, 0, 1, 3, 30]))]
    if rnd.random() < 0.05:
        values = [rnd.randint(-100, 100) for _ in range(QUEUE_CAPACITY)]
    for i, value in enumerate(values):
        queue[(head + i) % QUEUE_CAPACITY] = value
    state[core1.S_QUEUE_HEAD] = head
    state[core1.S_QUEUE_COUNT] = len(values)
    player = CurvePlayer()
    for _ in range(rnd.choice([0, 1, 2, 8])):
        player.append(random_keyframe(rnd) if rnd.random() < 0.3 else
                      Keyframe(rnd.randint(1, 30), near_int32(actual, 3000),
                               rnd.randint(-3000, 3000), rnd.randint(-3000, 3000)))
    if player.queued and rnd.random() < 0.5:
        first = player.snapshot().buffer[0]
        player.restore(replace(player.snapshot(), playing=True,
                               elapsed_us=rnd.randint(0, first.duration_ms * 1000 - 1),
                               start_position=near_int32(actual, 3000),
                               start_tangent=rnd.randint(-32768, 32767)))
    return PythonDevice(state, params, queue, player)


MOTOR_STEPS_PER_SCENARIO = 3000
"""The motor steps one scenario may cost (a 1 s period of 100 us steps is 10,000 a tick)."""


def tick_events(before: np.ndarray, after: np.ndarray, params: np.ndarray,
                records: Sequence[tuple[int, ...]], queued: tuple[int, int]) -> set[str]:
    """What one tick did, seen from the Python's state (to show the cases reach them)."""
    events = {f"fault {r[2]}" for r in records if r[0] == 2}
    events |= {"diagnostics"} if any(r[0] == 1 for r in records) else set()
    events |= {"a line's peak below 0" for r in records if r[0] == 1 and r[-1] < 0}
    if any(r[0] == 1 and r[-1] != 0 for r in records) and after[core1.S_DIAG_PEAK] == 0:
        events.add("the peak restarts after a line")
    if after[core1.S_VELOCITY_MODE_US] < before[core1.S_VELOCITY_MODE_US]:
        events.add("velocity reset")
    if any(after[core1.S_EDGES + i * core1.EDGE_FIELDS + core1.EDGE_COUNT]
           != before[core1.S_EDGES + i * core1.EDGE_FIELDS + core1.EDGE_COUNT] for i in (0, 1)):
        events.add("switch edge")
    if after[core1.S_QUEUE_COUNT] < before[core1.S_QUEUE_COUNT]:
        events.add("queue value taken")
    if queued[1] < queued[0]:
        events.add("keyframe reached")
    if after[core1.S_OUT_RECORDS] < before[core1.S_OUT_RECORDS]:
        if after[core1.S_FAULT] != before[core1.S_FAULT]:
            events.add("outputs off at a fault")
        elif before[core1.S_OUT_RECORDS] - after[core1.S_OUT_RECORDS] > 1:
            events.add("output records applied together")
        else:
            events.add("output change applied")
    if before[core1.S_START] >= 0 > after[core1.S_START]:
        events.add("start reached")
    if after[core1.S_STATS_SUM_SQ] == core1.STATS_SUM_CAP > before[core1.S_STATS_SUM_SQ]:
        events.add("statistics saturate")
    if after[core1.S_SINCE_COMMAND_US] == core1.TIMER_CAP_US:
        events.add("timer at its cap")
    limit = int(params[core1.P_INTEGRAL_LIMIT])
    if limit and abs(int(after[core1.S_INTEGRAL])) == limit:
        events.add("integral clamped")
    if (after[core1.S_OUT_C], after[core1.S_OUT_E]) in (
            (params[core1.P_VS_C], params[core1.P_VS_E]),
            (-params[core1.P_VS_C], params[core1.P_VS_E])) and after[core1.S_ENABLE] == 1:
        events.add("output saturated")
    if abs(int(after[core1.S_OMEGA])) >= 10**11:
        events.add("shaft near its speed bound")
    if after[core1.S_THETA] in (params[core1.P_STOP_LOW], params[core1.P_STOP_HIGH]):
        events.add("hard stop")
    if abs(int(after[core1.S_ACTUAL]) - int(before[core1.S_ACTUAL])) > 2**31:
        events.add("counter wraps")
    if int(params[core1.P_STEPS]) > 1:
        events.add("several motor steps")
    if after[core1.S_MODE] == core1.MODE_CURVE and after[core1.S_DESIRED] != before[
            core1.S_DESIRED]:
        events.add("curve moves")
    drive = int(params[core1.P_DRIVE])
    if drive:
        name = "open" if drive == core1.DRIVE_STEP_OPEN else "closed"
        steps = int(after[core1.S_LAST_STEPS])
        if steps:
            events.add(f"{name} loop issues steps")
        if steps and abs(steps) == int(params[core1.P_MAX_STEPS]):
            events.add(f"{name} loop at its most steps a tick")
        if abs(int(after[core1.S_OMEGA])) // 10**6 > int(params[core1.P_CORNER]):
            events.add("stepper above its corner speed")
        if after[core1.S_OMEGA] == 0 != before[core1.S_OMEGA]:
            events.add("stepper stops")
        if after[core1.S_MODE] == core1.MODE_VELOCITY and after[core1.S_ENABLE] == 1 and (
                after[core1.S_VEL_ACC] != before[core1.S_VEL_ACC]):
            events.add("stepper integrates the desired velocity")
        if after[core1.S_VELOCITY_MODE_US] < before[core1.S_VELOCITY_MODE_US]:
            events.add(f"{name} loop counter reset")
    return events


def run_scenario(lib: ctypes.CDLL, rnd: random.Random, ticks: int,
                 events: set[str] | None = None) -> list[str]:
    """One random device, ticked on both sides; the first differences found, or none."""
    return run_scenario_of(lib, rnd, random_setting(rnd), ticks, events)


def run_scenario_of(lib: ctypes.CDLL, rnd: random.Random, setting: Setting, ticks: int,
                    events: set[str] | None = None) -> list[str]:
    """A random device of ``setting``, ticked on both sides; the first differences found."""
    python = random_device(rnd, setting)
    c = CDevice(lib, python, head=rnd.randint(0, 7))
    found = state_mismatches(python, c)
    assert found == [], f"the copy into C differs: {found}"
    steps = max(1, int(python.params[core1.P_STEPS]))
    for tick in range(min(ticks, max(1, MOTOR_STEPS_PER_SCENARIO // steps))):
        if rnd.random() < 0.1 and python.state[core1.S_QUEUE_COUNT] < QUEUE_CAPACITY:
            value = rnd.randint(-3000, 3000)   # core0 adds between ticks
            python_push(python, value)
            lib.mq_try_add(value)
        before = python.state.copy()
        queued = python.player.queued
        want = python.tick()
        got = c.tick()
        if events is not None:
            events |= tick_events(before, python.state, python.params, want,
                                  (queued, python.player.queued))
        found = state_mismatches(python, c)
        if got != want:
            found.append(f"records {got} != {want}")
        if found:
            return [f"tick {tick} of {setting}: {found}"]
    return []


def python_push(python: PythonDevice, value: int) -> None:
    state = python.state
    count = int(state[core1.S_QUEUE_COUNT])
    python.queue[(int(state[core1.S_QUEUE_HEAD]) + count) % QUEUE_CAPACITY] = value
    state[core1.S_QUEUE_COUNT] = count + 1


@given(st.randoms(use_true_random=False))
@fuzz_settings()
def test_servo_tick_random_states(lib: ctypes.CDLL, rnd: random.Random) -> None:
    assert run_scenario(lib, rnd, 8) == []


def test_servo_tick_scenarios_reach_every_case(lib: ctypes.CDLL) -> None:
    """The random states reach every branch the comparison is meant to cover."""
    events: set[str] = set()
    rnd = random.Random(89)
    for _ in range(250):
        assert run_scenario(lib, rnd, 12, events) == []
    assert events >= {
        "fault 1", "fault 2", "fault 3", "diagnostics", "a line's peak below 0",
        "the peak restarts after a line", "velocity reset", "switch edge",
        "queue value taken", "keyframe reached", "start reached", "statistics saturate",
        "timer at its cap", "integral clamped", "output saturated",
        "shaft near its speed bound", "hard stop", "counter wraps", "several motor steps",
        "curve moves", "output change applied", "output records applied together",
        "outputs off at a fault", "open loop issues steps", "closed loop issues steps",
        "open loop at its most steps a tick", "closed loop at its most steps a tick",
        "stepper above its corner speed", "stepper stops",
        "stepper integrates the desired velocity", "open loop counter reset",
        "closed loop counter reset",
    }


STEPPER_MOTOR = replace(MotorParams(), inertia_kg_m2=(1, -5), load_torque_mnm=(20, 0),
                        counts_per_revolution=4000)
"""A NEMA 17 stepper's shaft with a small load, a 1000-line encoder on it (4000 counts)."""


def long_runs() -> Iterator[tuple[str, Setting, int]]:
    """Realistic runs: the default motor following moves in each mode at 1 and 10 kHz, and
    a stepper in both step drives (its integration step 100 us: ten sub-steps at 1 kHz)."""
    for interval_dms in (10, 1, 3):
        for mode in (1, 2, 3):
            gains = Gains(kp=(7, -3), ki=(1, 0), kd=(0, 0)) if mode == 2 else Gains()
            setting = Setting(MotorParams(), gains, interval_dms, 1, 1, 0, 0)
            yield f"mode {mode} at {interval_dms}", setting, mode
    for drive in (1, 2):
        for interval_dms in (10, 1):
            for mode in (1, 2, 3):
                setting = Setting(replace(STEPPER_MOTOR, sim_update_interval_dms=1), Gains(),
                                  interval_dms, 1, 1, 0, 0, drive=drive)
                yield f"drive {drive} mode {mode} at {interval_dms}", setting, mode


@pytest.mark.parametrize(("name", "setting", "mode"), list(long_runs()),
                         ids=[name for name, _, _ in long_runs()])
def test_servo_tick_long_runs(lib: ctypes.CDLL, name: str, setting: Setting, mode: int) -> None:
    """A few thousand ticks of an axis moving, with diagnostics and statistics on."""
    found = axis_run(lib, setting, mode, 1500)
    assert found == []


def axis_run(lib: ctypes.CDLL, setting: Setting, mode: int, ticks: int) -> list[object]:
    """``ticks`` ticks of an axis of ``setting`` moving in ``mode`` on both sides (a ramp of
    targets, velocities or keyframes), diagnostics and statistics on, the velocity mode's
    60 s reset 30 ticks in; the first difference, or none."""
    python = PythonDevice(core1.new_state(), setting.python_params(),
                          np.zeros(QUEUE_CAPACITY, dtype=np.int64), CurvePlayer())
    state = python.state
    state[core1.S_MODE] = mode
    state[core1.S_ENABLE] = 1
    state[core1.S_FRESH] = 1
    state[core1.S_DIAG_LEFT] = 1
    rnd = random.Random(mode)
    if mode == 3:
        for _ in range(8):
            python.player.append(Keyframe(rnd.randint(20, 200), rnd.randint(-3000, 3000),
                                          rnd.randint(-5000, 5000), rnd.randint(-5000, 5000)))
    if mode == 2:
        state[core1.S_VELOCITY_MODE_US] = core1.VELOCITY_RESET_US - 30 * int(
            python.params[core1.P_TICK_US])
    c = CDevice(lib, python)
    for tick in range(ticks):
        if mode != 3 and tick % 2 == 0 and python.state[core1.S_QUEUE_COUNT] < 50:
            value = (rnd.randint(-3000, 3000) if mode == 1 else rnd.randint(-8000, 8000))
            python_push(python, value)
            lib.mq_try_add(value)
        if mode == 3 and python.player.queued < 8 and rnd.random() < 0.02:
            keyframe = Keyframe(rnd.randint(20, 200), rnd.randint(-3000, 3000),
                                rnd.randint(-5000, 5000), rnd.randint(-5000, 5000))
            python.player.append(keyframe)
            lib.curve_append(ctypes.byref(c.state.curve), keyframe_c(keyframe))
        want = python.tick()
        got = c.tick()
        if got != want:
            return [f"{setting} tick {tick}: records {got} != {want}"]
        found = state_mismatches(python, c)
        if found:
            return [f"{setting} tick {tick}: {found}"]
    assert python.state[core1.S_STATS_TICKS] > 0 or mode == 2
    return []


# --- core0's changes of core1's state -----------------------------------------------------


def test_state_init(lib: ctypes.CDLL) -> None:
    for mode in (1, 2, 3):
        state = core1.new_state()
        state[core1.S_MODE] = mode
        python = PythonDevice(state, Setting(MotorParams(), Gains(), 10, 1, 0, 0, 0)
                              .python_params(), np.zeros(QUEUE_CAPACITY, dtype=np.int64),
                              CurvePlayer())
        c = CDevice(lib, python)
        ctypes.memset(ctypes.byref(c.state), 0x5a, ctypes.sizeof(c.state))
        lib.servo_state_init(ctypes.byref(c.state), mode)
        assert state_mismatches(python, c) == []
        assert c.state.curve.head == 0


def test_switches_and_shift_position(lib: ctypes.CDLL) -> None:
    rnd = random.Random(67)
    for _ in range(cases(1) // 3):
        setting = random_setting(rnd)
        python = random_device(rnd, setting)
        device = Device(motor=setting.motor, gains=setting.gains, fast=False)
        device._state[:] = python.state
        c = CDevice(lib, python)
        assert lib.servo_switches(ctypes.byref(c.state), ctypes.byref(c.params)) == (
            device._switches())
        shift = rnd.choice([0, 1, -1, INT32_MAX, INT32_MIN, 2**32 - 1, -(2**32) + 1,
                            rnd.randint(-(2**32), 2**32)])
        device._shift_position(shift)   # also clears the queue and the curve: not core1's
        lib.servo_shift_position(ctypes.byref(c.state), shift)
        python.state[:] = device._state
        python.state[core1.S_QUEUE_COUNT] = lib.mq_level()
        python.state[core1.S_QUEUE_HEAD] = 0
        python.queue[: lib.mq_level()] = c.queue_values()
        assert state_mismatches(python, c) == []


# --- the tests of the tests ---------------------------------------------------------------


def test_state_comparison_sees_one_count_in_any_field(lib: ctypes.CDLL) -> None:
    """Each field of core1's state, one count off on the C side, is reported by name."""
    python = random_device(random.Random(71), Setting(MotorParams(), Gains(), 10, 1, 1, 0, 0))
    python.player.append(Keyframe(5, 10, 20, 30))
    if not python.player.playing:
        python.player.next_position(0, 1000)
    c = CDevice(lib, python)
    assert state_mismatches(python, c) == []
    names = [name for _, name in SCALAR_STATE]
    for name in names:
        setattr(c.state, name, getattr(c.state, name) + 1)
        assert state_mismatches(python, c) == [name]
        setattr(c.state, name, getattr(c.state, name) - 1)
    perturbations: list[tuple[str, Callable[[int], None]]] = [
        ("out", lambda d: setattr(c.state.out, "e", c.state.out.e + d)),
        ("history[3]", lambda d: c.state.history.__setitem__(3, c.state.history[3] + d)),
        ("counts[9]", lambda d: c.state.counts.__setitem__(9, c.state.counts[9] + d)),
        ("edges[1].edges", lambda d: setattr(c.state.edges[1], "edges",
                                             c.state.edges[1].edges + d)),
        ("edges[0].tick", lambda d: setattr(c.state.edges[0], "tick", c.state.edges[0].tick + d)),
        ("outputs.next", lambda d: setattr(c.state.outputs, "next", c.state.outputs.next + d)),
        ("outputs.values[2]", lambda d: c.state.outputs.values.per_mille.__setitem__(
            2, c.state.outputs.values.per_mille[2] + d)),
        ("outputs.queue[4].changes", lambda d: setattr(
            c.state.outputs.queue[4], "changes", c.state.outputs.queue[4].changes + d)),
        ("outputs.queue[7].values[3]", lambda d: c.state.outputs.queue[7].values.per_mille
         .__setitem__(3, c.state.outputs.queue[7].values.per_mille[3] + d)),
        ("outputs.queue[15].tick", lambda d: setattr(c.state.outputs.queue[15], "tick",
                                                     c.state.outputs.queue[15].tick + d)),
        ("curve.elapsed_us", lambda d: setattr(c.state.curve, "elapsed_us",
                                               c.state.curve.elapsed_us + d)),
        ("curve.start_tangent", lambda d: setattr(c.state.curve, "start_tangent",
                                                  c.state.curve.start_tangent + d)),
        ("curve.buffer", lambda d: setattr(c.state.curve.buffer[c.state.curve.head],
                                           "tangent_in",
                                           c.state.curve.buffer[c.state.curve.head].tangent_in
                                           + d)),
    ]
    for name, perturb in perturbations:
        perturb(1)
        assert state_mismatches(python, c) == [name]
        perturb(-1)
    lib.mq_try_add(7)
    assert state_mismatches(python, c) == ["queue"]
    lib.mq_clear()
    for value in python.queue_values():
        lib.mq_try_add(value)
    assert state_mismatches(python, c) == []


@dataclass(frozen=True)
class Mutant:
    """A one-digit or one-count change of one source line, and a check that must see it."""

    name: str
    source: str
    original: str
    changed: str
    check: Callable[[ctypes.CDLL], list[object]]


def _check_sci(lib: ctypes.CDLL) -> list[object]:
    return list(sci_mismatches(lib, [(a, b) for x, y in THRESHOLD_PAIRS for a, b in ((x, y),
                                                                                 (y, x))]))


def _check_ties(lib: ctypes.CDLL) -> list[object]:
    return list(hermite_mismatches(lib, tie_segments(random.Random(73), 20)))


def _check_stepped_ties(lib: ctypes.CDLL) -> list[object]:
    """Segments from 0 to -1 and back at 10 kHz: stepped ticks land on exact halves."""
    def stream() -> Iterator[Keyframe]:
        while True:
            yield Keyframe(1, -1, 0, 0)
            yield Keyframe(1, 0, 0, 0)
    return list(play(lib, random.Random(97), 100, stream(), 400, refill=1.0)[0])


def _check_plays(lib: ctypes.CDLL) -> list[object]:
    """Segments one after the other at 10 kHz: prepared as they are appended, adopted at
    their start."""
    rnd = random.Random(101)
    return list(play(lib, rnd, 100, keyframe_stream(rnd, extreme=False), 2000)[0])


def _check_from_double(lib: ctypes.CDLL) -> list[object]:
    return list(from_double_mismatches(lib, boundary_doubles(random.Random(79), 50, (-20, 5))))


def _check_ticks(lib: ctypes.CDLL) -> list[object]:
    rnd = random.Random(83)
    found: list[object] = []
    for _ in range(60):
        found += run_scenario_of(lib, rnd, random_setting(rnd, drives=False), 12)
    return found


def _check_stepper(lib: ctypes.CDLL) -> list[object]:
    """The encoder, and the step with its sines on and beside their entries."""
    rnd = random.Random(113)
    found: list[object] = []
    for _ in range(400):
        shaft = rnd.randint(-10**6, 10**6)
        for cpr, per_rev in ((4000, 3200), (1000, 3200), (4000, 3000)):
            if lib.stepper_encoder_microsteps(shaft, cpr, per_rev) != encoder_microsteps(
                    shaft, cpr, per_rev):
                found.append(("encoder", shaft, cpr, per_rev))
    return found + stepper_step_mismatches(lib, rnd, 30)


def _check_stepper_ticks(lib: ctypes.CDLL) -> list[object]:
    """Step drives ticked from random states, then a stepper following moves in each step
    drive and mode with the 60 s reset of velocity mode within reach."""
    rnd = random.Random(127)
    found: list[object] = []
    for _ in range(60):
        setting = random_setting(rnd)
        if not setting.drive:
            setting = replace(setting, drive=rnd.choice([1, 2]), stepper=StepperParams())
        found += run_scenario_of(lib, rnd, setting, 12)
    for drive in (1, 2):
        for mode in (1, 2, 3):
            setting = Setting(replace(STEPPER_MOTOR, sim_update_interval_dms=1), Gains(), 10, 1,
                              1, 0, 0, drive=drive)
            found += axis_run(lib, setting, mode, 300)
    return found


MUTANTS = [
    Mutant("sci_mul threshold", "sci.h", "product >= 10000000 ||", "product > 10000000 ||",
           _check_sci),
    Mutant("hermite ties toward zero", "curve.c", "words_add(n, n, half);   /* |n| + den / 2 */",
           "words_add(n, n, half); n[0] -= 1u;", _check_ties),
    Mutant("stepped ties toward zero", "curve.c",
           "return q - ((r[0] | r[1] | r[2]) == 0 && q <= 0);",
           "return q - ((r[0] | r[1] | r[2]) == 0 && q < 0);",
           _check_stepped_ties),
    Mutant("prepared segment ends on the keyframe's out-tangent", "curve.c",
           "keyframe.tangent_in, keyframe.duration_ms};",
           "keyframe.tangent_out, keyframe.duration_ms};", _check_plays),
    Mutant("from_float boundary", "sci.c", "grid_value(middle, e) <= magnitude",
           "grid_value(middle, e) < magnitude", _check_from_double),
    Mutant("edge tick one count late", "servo.c", "edge->tick = s->clock + 1;",
           "edge->tick = s->clock + 2;", _check_ticks),
    Mutant("peak not restarted after a line", "servo.c", "            s->diag_peak = 0;\n",
           "", _check_ticks),
    Mutant("output change one tick late", "servo.c",
           "if (s->clock >= s->outputs.next) {", "if (s->clock > s->outputs.next) {",
           _check_ticks),
    Mutant("a later record due a tick early", "servo.c", "if (clock >= q->next) {",
           "if (clock + 1 >= q->next) {", _check_ticks),
    Mutant("a later record due a tick late", "servo.c", "if (clock >= q->next) {",
           "if (clock > q->next) {", _check_ticks),
    Mutant("the first of the due records' outputs", "servo.c",
           "        due = output_pop_late(q);\n", "        (void)output_pop_late(q);\n",
           _check_ticks),
    Mutant("outputs left on at a fault", "servo.c", "        outputs_off(s);\n",
           "        (void)outputs_off;\n", _check_ticks),
    Mutant("peak unsigned", "servo.c", "s->diag_peak = (int32_t)following;",
           "s->diag_peak = (int32_t)size;", _check_ticks),
    Mutant("the field's sine one entry on", "stepper.c",
           "table_sine[sci_udiv(rest << 2, sine_k)]",
           "table_sine[(sci_udiv(rest << 2, sine_k) + 1u) % TABLE_SINE_SIZE]", _check_stepper),
    Mutant("the detent's sine one entry on", "stepper.c",
           "table_sine[sci_udiv(detent_rest << 4, sine_k)]",
           "table_sine[(sci_udiv(detent_rest << 4, sine_k) + 1u) % TABLE_SINE_SIZE]",
           _check_stepper),
    Mutant("C's remainder (of the magnitude) for the sines' angles", "stepper.c",
           "return x < 0 && rest != 0u ? d - rest : rest;", "return rest;", _check_stepper),
    Mutant("C's remainder (of the magnitude) for power-of-two microsteps", "stepper.c",
           "        return (uint32_t)x & mask;",
           "        return (uint32_t)sci_magnitude64(x) & mask;", _check_stepper_ticks),
    Mutant("a finer encoder's microsteps not floored below zero", "stepper.c",
           "return shaft - (t != 0u);", "return shaft - (t != 0u && shaft >= 0);",
           _check_stepper),
    Mutant("encoder count truncated, not floored", "stepper.c",
           "if (shaft < 0 && q * den != low) {", "if (shaft < 0 && q * den != low && 0) {",
           _check_stepper),
    Mutant("closed loop leads a microstep more", "servo.c",
           "int32_t target = wrap_int32((int64_t)s->actual + ahead + sci_to_int(s->out));",
           "int32_t target = wrap_int32((int64_t)s->actual + ahead + sci_to_int(s->out) + 1);",
           _check_stepper_ticks),
    Mutant("the rotor's move taken as measured, beyond the command's", "servo.c",
           "ahead = moved < 0 ? 0 : (moved > wanted ? wanted : moved);",
           "ahead = moved < 0 ? 0 : moved;", _check_stepper_ticks),
    Mutant("a fault releases the stepper's driver", "servo.c",
           "int32_t powered = (s->enable == 1 || s->fault != FAULT_NONE) ? 1 : 0;",
           "int32_t powered = s->enable == 1 ? 1 : 0;", _check_stepper_ticks),
    Mutant("steps spread late over the sub-steps", "servo.c", "if (remainder >= steps) {",
           "if (remainder > steps) {", _check_stepper_ticks),
    Mutant("velocity reset leaves a stepper's desired position", "servo.c",
           "                s->desired = wrap_int32((int64_t)s->desired - s->actual);\n",
           "", _check_stepper_ticks),
]


def _mutant_sources(mutant: Mutant) -> Path:
    """The device sources with the mutant's one change, in a directory of their own."""
    directory = CACHE / "servo-mutants" / mutant.name.replace(" ", "-")
    directory.mkdir(parents=True, exist_ok=True)
    for path in DEVICE_SOURCES.glob("*.h"):
        text = path.read_text()
        if path.name == mutant.source:
            assert text.count(mutant.original) == 1, f"{mutant.original!r} not in {path.name}"
            text = text.replace(mutant.original, mutant.changed)
        (directory / path.name).write_text(text)
    for name in SOURCES:
        text = (DEVICE_SOURCES / name).read_text()
        if name == mutant.source:
            assert text.count(mutant.original) == 1, f"{mutant.original!r} not in {name}"
            text = text.replace(mutant.original, mutant.changed)
        (directory / name).write_text(text)
    return directory


@pytest.fixture(scope="module")
def mutant_libraries() -> dict[str, ctypes.CDLL]:
    """Every mutant built (two compilers at a time: each is a build of all the sources)."""
    def build_one(mutant: Mutant) -> ctypes.CDLL:
        return _build(f"servo-mutant-{mutant.name.replace(' ', '-')}", _mutant_sources(mutant))
    with ThreadPoolExecutor(max_workers=2) as pool:
        libraries = list(pool.map(build_one, MUTANTS))
    return {m.name: library for m, library in zip(MUTANTS, libraries, strict=True)}


@pytest.mark.parametrize("mutant", MUTANTS, ids=[m.name for m in MUTANTS])
def test_mutants_are_caught(lib: ctypes.CDLL, mutant_libraries: dict[str, ctypes.CDLL],
                            mutant: Mutant) -> None:
    """The check passes on the sources and fails on the sources with the one change."""
    assert mutant.check(lib) == []
    assert mutant.check(mutant_libraries[mutant.name]) != []


def test_decay_and_lag_are_bit_for_bit_the_pythons(lib: ctypes.CDLL) -> None:
    """Every ratio a motor can give, the halving boundary and the extremes: the same bits."""
    from usbmotion.device.motor import decay_and_lag  # noqa: PLC0415

    rng = random.Random(11)
    ratios = [1e-300, 1e-30, 1e-12, 1e-6, 0.0471, 0.25, 0.5, math.nextafter(0.5, 1.0), 0.75,
              1.0, 2.0, 37.5, 745.0, 1e5, 1e30, 1e300]
    ratios += [10.0 ** rng.uniform(-40.0, 40.0) for _ in range(5000)]
    decay, lag = ctypes.c_double(), ctypes.c_double()
    for ratio in ratios:
        tau = 10.0 ** rng.uniform(-38.0, 50.0)
        lib.motor_decay_and_lag(ratio, tau, ctypes.byref(decay), ctypes.byref(lag))
        assert (decay.value, lag.value) == decay_and_lag(ratio, tau), (ratio, tau)
        assert 0.0 <= decay.value <= 1.0
    lib.motor_decay_and_lag(0.0471, 0.02123, ctypes.byref(decay), ctypes.byref(lag))
    assert decay.value == pytest.approx(-math.expm1(-0.0471), rel=1e-15), "the series is expm1"
