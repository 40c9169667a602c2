"""Fuzz the device interpreter: random sessions of lines, silences and power cycles.

Each session goes to two devices. Device A takes whole lines, one at a time, and is checked
against the per-line model of ``tests/device/test_robustness.py`` (a malformed or refused
line is one ``ERR`` and changes nothing; a valid call changes only what it may). Device B
takes the same bytes cut at random points and runs the same servo ticks in random pieces:
it must end every step in exactly A's state with exactly A's output, so neither how USB
splits the bytes nor how the simulation slices time changes what the firmware does.

After every step the invariants a machine relies on are checked:

- nothing escapes the device, and no wire input ever causes fault 4 (an internal error);
- every line the device prints parses as a reply;
- variables stay in range: queue 0..1000, keyframes 0..8, mode 1..3, position int32, the
  PID output within the source voltage, 0 V while disabled;
- a latched fault means the servo is off;
- time: ``run(n)`` advances the clock by exactly ``n`` ticks;
- the watchdog: a servo still enabled after a silence has heard a command within its
  timeout;
- the following-error limit: a servo still enabled in modes 1 and 3 is within its limit;
- the limit switches read what the shaft position says;
- a step drive issues at most call 48's steps a tick (its diagnostics output, steps x 1000).
"""

from __future__ import annotations

from dataclasses import dataclass

from hypothesis import given
from hypothesis import strategies as st

from device.test_robustness import _check_line, _integer_lines
from usbmotion.device import Device
from usbmotion.device.core1 import wrap_int32
from usbmotion.device.motor import MICRO, sci_value
from usbmotion.device.stepper import max_steps_per_tick
from usbmotion.errors import ProtocolError
from usbmotion.protocol import (
    CALLS,
    CURVE_BUFFER_CAPACITY,
    QUEUE_CAPACITY,
    FaultCode,
    ReplyKind,
    parse_call,
    parse_reply,
)
from usbmotion.protocol.table import INT32_MAX, INT32_MIN

from .budget import fuzz_settings, hang_guard

MOTOR_STEPS_PER_EXAMPLE = 400_000
"""Budget of simulated motor integration steps per session (keeps an example short when
the random lines chose a 1 s servo tick integrated in 100 us steps)."""


class _Recording(Device):
    """A device that keeps a copy of everything taken from its output."""

    def __init__(self) -> None:
        super().__init__()
        self.taken = bytearray()

    def take_output(self) -> bytes:
        data = super().take_output()
        self.taken += data
        return data

    def take_recorded(self) -> bytes:
        data = bytes(self.taken)
        self.taken.clear()
        return data


@dataclass(frozen=True, slots=True)
class Lines:
    """Feed these lines (no newlines inside); B gets them cut at ``cuts``."""

    lines: tuple[bytes, ...]
    cuts: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class Silence:
    """Run ``ticks`` servo ticks with no input; B runs them in ``pieces``."""

    ticks: int
    pieces: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class PowerCycle:
    """Restart the device (flash kept)."""


Step = Lines | Silence | PowerCycle

_MOTION = st.sampled_from([
    (b"3 1", b"0 500"),
    (b"3 1", b"1 3 -200 0 200"),
    (b"7 2", b"3 1", b"1 2 4000 4000"),
    (b"29 40", b"3 1", b"0 100000"),
    (b"34 -50 50", b"3 1", b"0 80"),
    (b"28 5", b"3 1"),
    (b"7 3", b"3 1", b"25 200 400 0 0", b"25 100 -100 512 -512"),
    (b"23 2147483600", b"3 1", b"0 -2147483546"),
    (b"40 1 -100", b"3 1", b"0 -300"),
    (b"42 2 500 0", b"42 0 1000 40", b"42 3 75 41", b"29 30", b"3 1", b"0 2000"),
    (b"44 1", b"3 1", b"0 500"),
    (b"44 2", b"3 1", b"1 3 -200 0 200"),
    (b"44 1", b"17 1 -5", b"12 1", b"7 2", b"3 1", b"1 2 4000 -4000"),
    (b"44 2", b"17 1 -5", b"16 4000", b"12 1", b"3 1", b"0 3200"),
    (b"44 2", b"17 1 -5", b"33 700 0", b"29 60", b"3 1", b"0 800"),
    (b"44 1", b"17 1 -5", b"34 -50 50", b"3 1", b"0 80"),
    (b"44 2", b"7 3", b"3 1", b"25 200 400 0 0", b"25 100 -100 512 -512"),
    (b"45 400 8", b"46 100 0", b"47 300 300 100"),
])
"""Short scripts that make the device move, so silences exercise the servo and faults: the
DC motor's, and a stepper's in both step drives (call 44 when the servo is off; 17 1 -5 is
a NEMA 17 rotor's inertia, 12 1 integrates it in 100 us steps)."""

_TICKS = st.one_of(
    st.integers(0, 30),
    st.integers(0, 3000),
    st.sampled_from([59_999, 60_000, 60_001]),
)


@st.composite
def _lines_step(draw: st.DrawFn) -> Lines:
    if draw(st.integers(0, 3)) == 0:
        lines = draw(_MOTION)
    else:
        lines = tuple(draw(st.lists(_integer_lines(), min_size=1, max_size=4)))
    size = sum(len(line) + 1 for line in lines)
    cuts = tuple(sorted(set(draw(st.lists(st.integers(1, max(1, size - 1)), max_size=4)))))
    return Lines(lines, cuts)


@st.composite
def _silence(draw: st.DrawFn) -> Silence:
    ticks = draw(_TICKS)
    marks = sorted(set(draw(st.lists(st.integers(0, ticks), max_size=3))))
    pieces: list[int] = []
    previous = 0
    for mark in [*marks, ticks]:
        pieces.append(mark - previous)
        previous = mark
    return Silence(ticks, tuple(pieces))


_STEP: st.SearchStrategy[Step] = st.one_of(
    _lines_step(), _lines_step(), _silence(), st.just(PowerCycle())
)


def _feed_cut(device: Device, data: bytes, cuts: tuple[int, ...]) -> None:
    position = 0
    for cut in (*cuts, len(data)):
        device.feed(data[position:cut])
        position = cut


def _run_pieces(device: Device, pieces: tuple[int, ...]) -> None:
    for piece in pieces:
        device.run(piece)


def _same(a: Device, b: Device) -> None:
    assert a.state == b.state
    assert a.settings == b.settings
    assert a.queue_values() == b.queue_values()
    assert a.keyframes() == b.keyframes()


def _check_output(data: bytes) -> None:
    text = data.decode("ascii")
    assert text == "" or text.endswith("\n")
    for line in text.splitlines():
        assert "internal error" not in line, line
        parse_reply(line)


def _check_state(device: Device) -> None:
    state = device.state
    assert 0 <= state.queued <= QUEUE_CAPACITY
    assert 0 <= state.keyframes <= CURVE_BUFFER_CAPACITY
    assert state.enable in (0, 1)
    assert state.mode in (1, 2, 3)
    assert 0 <= state.limits <= 3
    assert state.fault in (FaultCode.NONE, FaultCode.WATCHDOG, FaultCode.FOLLOWING_ERROR,
                           FaultCode.LIMIT_SWITCH), "fault 4 is an internal error"
    if state.fault != FaultCode.NONE:
        assert state.enable == 0, "a latched fault leaves the servo off"
    else:
        assert state.fault_tick == 0
    if state.enable == 0:
        assert state.output_mv == 0, "no drive while disabled"
    for value in (state.actual, state.desired):
        assert INT32_MIN <= value <= INT32_MAX
    assert state.start_tick == -1 or 0 <= state.start_tick <= INT32_MAX


def _check_after_silence(device: Device, since_command_us: int) -> None:
    """Checks that hold once at least one tick has run since the last line."""
    state = device.state
    settings = device.settings
    if settings.drive:   # a step drive's output is the tick's steps (x 1000 in millis)
        stepper = settings.stepper
        ceiling_mv = 1000.0 * max_steps_per_tick(device.tick_us, stepper.pulse_ns,
                                                 stepper.setup_ns)
    else:
        ceiling_mv = float(sci_value(settings.motor.source_voltage_v)) * 1000
    assert abs(state.output_mv) <= ceiling_mv + 1
    watchdog_us = settings.watchdog_ms * 1000
    if state.enable == 1 and watchdog_us > 0:
        assert since_command_us < watchdog_us, "the watchdog let a silent host keep the servo"
    limit = settings.following_error_limit
    if state.enable == 1 and state.mode != 2 and limit > 0:
        assert abs(wrap_int32(state.desired - state.actual)) <= limit
    count = state.shaft_micro_counts // MICRO
    expected = (count <= settings.motor.travel_lower_counts) | (
        (count >= settings.motor.travel_upper_counts) << 1
    )
    assert state.limits == expected


def _is_command(line: bytes) -> bool:
    try:
        parse_call(line)
    except ProtocolError:
        return False
    return True


def _motor_steps(device: Device) -> int:
    return max(1, device.motor_constants.steps)


@fuzz_settings()
@given(st.lists(_STEP, min_size=1, max_size=8))
def test_random_sessions_keep_every_invariant(steps: list[Step]) -> None:
    a = _Recording()
    b = Device()
    since_command_us = 0
    budget = MOTOR_STEPS_PER_EXAMPLE
    with hang_guard():
        for step in steps:
            if isinstance(step, Lines):
                for line in step.lines:
                    _check_line(a, line)
                    if _is_command(line):
                        since_command_us = 0
                _feed_cut(b, b"".join(line + b"\n" for line in step.lines), step.cuts)
            elif isinstance(step, Silence):
                cost = _motor_steps(a)
                ticks = min(step.ticks, budget // cost)
                pieces = step.pieces if ticks == step.ticks else (ticks,)
                budget -= ticks * cost
                clock = a.clock
                a.run(ticks)
                _run_pieces(b, pieces)
                assert a.clock == clock + ticks
                since_command_us += ticks * a.tick_us
                a.take_output()
                if ticks > 0:
                    _check_after_silence(a, since_command_us)
            else:
                a.take_output()
                a.take_recorded()
                b.take_output()
                a.restart()
                b.restart()
                since_command_us = 0
            printed = a.take_recorded()
            _check_output(printed)
            assert b.take_output() == printed
            _same(a, b)
            _check_state(a)


@fuzz_settings()
@given(st.lists(_STEP, min_size=1, max_size=6))
def test_every_query_answers_one_reply_after_any_session(steps: list[Step]) -> None:
    device = Device()
    budget = MOTOR_STEPS_PER_EXAMPLE
    with hang_guard():
        for step in steps:
            if isinstance(step, Lines):
                _feed_cut(device, b"".join(line + b"\n" for line in step.lines), step.cuts)
            elif isinstance(step, Silence):
                ticks = min(step.ticks, budget // _motor_steps(device))
                budget -= ticks * _motor_steps(device)
                device.run(ticks)
            else:
                device.restart()
        _check_output(device.take_output())
        for spec in CALLS:
            if spec.query is None:
                continue
            args = tuple(param.maximum if q is None else q
                         for q, param in zip(spec.query, spec.params, strict=True))
            device.feed(" ".join(map(str, (spec.number, *args))).encode("ascii") + b"\n")
            lines = device.take_output().decode("ascii").splitlines()
            assert len(lines) == 1, (spec.number, lines)
            reply = parse_reply(lines[0])
            assert reply.kind is ReplyKind.QUERY, lines
            assert reply.call == spec.number, lines
