"""core0 and the device as a whole: the command interpreter over a virtual-time servo loop.

:class:`Device` is one USB Motion Device. Bytes from USB go in through :meth:`Device.feed`
(any split); each complete line is interpreted at once, at the current servo tick, through
the protocol table, and its replies are queued for :meth:`Device.take_output`. Time only
moves in :meth:`Device.run`, by whole servo ticks of core1, so a test or a simulation
decides every tick.

Error policy (STYLE.md rule 6): a malformed line is answered with one ``ERR <call>
<reason>`` line and changes nothing; a call the table accepts but the device state refuses
(travel ends crossed, enabling with a fault latched, a flash write failing) answers ``ERR
<call> <reason>`` and changes nothing; an unexpected exception while carrying out a call is
answered ``ERR <call> internal error ...``, latches fault 4 and disables the servo, and the
device keeps serving. Nothing escapes :meth:`Device.feed`.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from usbmotion.device import core1
from usbmotion.device.core1 import (
    DYNAMIC_FIELDS,
    MODE_CURVE,
    MODE_POSITION,
    MODE_VELOCITY,
    IntArray,
    idle_advance,
    running,
    servo_block,
    ticks_to_scheduled_event,
    wrap_int32,
)
from usbmotion.device.curve import CurvePlayer
from usbmotion.device.flash import Flash, FlashContents, MemoryFlash
from usbmotion.device.kernel import BlockFunction, block_function, requested, use_kernel
from usbmotion.device.kernel import load as load_kernel
from usbmotion.device.kernel import loaded as kernel_loaded
from usbmotion.device.motor import (
    DIGITS,
    MICRO,
    MotorConstants,
    MotorParams,
    SciPair,
    derive_constants,
    sci_value,
)
from usbmotion.device.stepper import StepperParams, derive_stepper, max_steps_per_tick
from usbmotion.errors import DeviceParameterError, EmptyLineError, FlashError, ProtocolError
from usbmotion.hermite import Keyframe
from usbmotion.protocol.codec import (
    Call,
    LineSplitter,
    Overlong,
    format_err,
    parse_call,
    values_crc32,
)
from usbmotion.protocol.names import Drive, FaultCode, fault_words
from usbmotion.protocol.table import (
    ALARM,
    BY_NUMBER,
    DIAGNOSTICS,
    DIGITAL_OUTPUTS,
    ERR,
    INT32_MAX,
    INT32_MIN,
    MAX_LINE_BYTES,
    OUTPUT_COUNT,
    OUTPUT_FULL,
    OUTPUT_QUEUE_CAPACITY,
    QUEUE_CAPACITY,
)
from usbmotion.scimath import SciNumber, sci_to_int

DEFAULT_INTERVAL_DMS = 10
"""Servo period at power-up: 10 dms = 1000 us (seed 000)."""
DEFAULT_SCALAR = 1
"""Motion update interval scalar at power-up (seed 000)."""
_CURVE_CHUNK = 4096
_SETTLE_CHUNK = 256
_DYNAMIC_INDEX = np.array(DYNAMIC_FIELDS, dtype=np.intp)
"""``DYNAMIC_FIELDS`` as an index array (taken before and after a probing tick)."""
_DIAGNOSTICS_LINE = DIAGNOSTICS.int_line_format()
REFERENCE_BLOCK_TICKS = 64
"""Before the kernel is loaded, a fast device runs a block of at most this many ticks on the
reference (a query's answer takes a tick or so); a longer one loads the kernel."""
REFERENCE_TICKS = 4096
"""And at most this many ticks in all (about 25 ms of the reference's time)."""
_INTEGRAL_CAP = 1 << 62


def _check_gain(call: int, field_name: str, value: object) -> SciPair:
    if not (isinstance(value, tuple) and len(value) == 2):
        raise DeviceParameterError(
            f"{field_name} {value!r} is not a (coefficient, exponent) pair of ints"
        )
    for param, item in zip(BY_NUMBER[call].params, value, strict=True):
        if isinstance(item, bool) or not isinstance(item, int):
            raise DeviceParameterError(f"{field_name} {param.name} {item!r} is not an int")
        why = param.check(item)
        if why is not None:
            raise DeviceParameterError(f"{field_name}: {why}")
    return value


@dataclass(frozen=True, slots=True)
class Gains:
    """PID gains as the protocol carries them: ``(coefficient, exponent)``, value C*10**E.

    The defaults give a well-damped position loop on the default motor (PROTOCOL.md,
    "The simulated motor"). Coefficients 0..999 (3 significant digits), exponents -12..6.

    Raises:
        DeviceParameterError: a gain outside the range of its call (9, 10 or 11).
    """

    kp: SciPair = (1, 0)
    """Proportional gain, V per count (mode 2: V per count/s)."""
    ki: SciPair = (1, 0)
    """Integral gain, V per count-second (mode 2: V per count)."""
    kd: SciPair = (7, -3)
    """Derivative gain, V-seconds per count (mode 2: V-s per count/s)."""

    def __post_init__(self) -> None:
        _check_gain(9, "kp", self.kp)
        _check_gain(10, "ki", self.ki)
        _check_gain(11, "kd", self.kd)


@dataclass(frozen=True, slots=True)
class DeviceState:
    """A snapshot of the device for tests and tools (read :attr:`Device.state`)."""

    clock: int
    """Servo ticks since power-up or the last ``22 0``."""
    actual: int
    """Encoder counter, counts (int32)."""
    desired: int
    """Desired position, counts (modes 1 and 3)."""
    desired_velocity: int
    """Desired velocity, counts/s (mode 2)."""
    velocity: int
    """Encoder counts over the last millisecond (at least one tick), counts/s."""
    queued: int
    """Values in the motion queue."""
    keyframes: int
    """Keyframes in the curve buffer."""
    enable: int
    mode: int
    limits: int
    """Bit 1: lower switch closed; bit 2: upper switch closed."""
    fault: int
    fault_tick: int
    integrator: int
    """The PID's integral sum, error units times ticks."""
    output_mv: int
    """Last PID output, millivolts."""
    shaft_micro_counts: int
    """Motor shaft position from power-up, micro-counts (not wrapped)."""
    shaft_speed_micro_counts_s: int
    """Motor shaft speed, micro-counts/s."""
    start_tick: int
    """Armed start tick, or -1."""
    tick_us: int


@dataclass(frozen=True, slots=True)
class DeviceSettings:
    """Every variable a call sets: the RAM variables, the flash variables and debug flags."""

    servo_update_interval_us: int
    motion_update_interval_scalar: int
    control_mode: int
    gains: Gains
    motor: MotorParams
    drive: int
    """Call 44: what the device drives."""
    encoder: tuple[int, int]
    """Call 49: the encoder's kind and the simulated magnet's angle."""
    stepper: StepperParams
    """Calls 45-47: the stepper, its driver's timing and the simulated stepper."""
    diagnostics_interval: int
    watchdog_ms: int
    following_error_limit: int
    start_tick: int
    debug_flags: tuple[tuple[int, int], ...]
    """``(call, flag)`` for every flag that is not 0, by call."""
    name: str
    default_control_mode: int
    flash_writes: int


@dataclass(frozen=True, slots=True)
class Checkpoint:
    """What running a device changes, at one moment (:meth:`Device.checkpoint`)."""

    state: IntArray
    params: IntArray
    settle_left: int
    curve: object
    output: bytes
    stamps: tuple[tuple[int, int], ...]
    fed: int


def _frozen(array: IntArray) -> IntArray:
    """A read-only copy of ``array``, made through its bytes: ``array.copy()`` of more than
    500 values lets go of the interpreter's lock, and a device run beside another thread
    (``usbmotion.sim.world``) then waits to take it back."""
    return np.frombuffer(array.tobytes(), dtype=array.dtype)


class _RefusedError(Exception):
    """A call the table accepts but the device state refuses: answered ``ERR <call> ...``."""


class Device:
    """One simulated USB Motion Device, advanced in virtual time.

    Parameters:
        flash: where the flash variables persist (default: a fresh :class:`MemoryFlash`).
        motor: the simulated motor's power-up parameters (default :class:`MotorParams`).
        gains: the PID gains at power-up (default :class:`Gains`).
        fast: run core1 as the compiled kernel (True), as the reference Python (False),
            or (None) as :func:`usbmotion.device.kernel.use_kernel` decides: the kernel
            when numba is installed, unless ``USBMOTION_KERNEL=0``. Both are bit-for-bit
            equal. Asked for by name (True, or ``USBMOTION_KERNEL=1``), the kernel is
            loaded (or compiled) when the device is made; chosen for numba's presence
            (None), when a device of the process first runs a block of more than
            :data:`REFERENCE_BLOCK_TICKS` ticks, or :data:`REFERENCE_TICKS` in short
            blocks (:meth:`load_kernel` loads it at once): until then the reference runs
            the short blocks that answering queries takes, so a command that moves nothing
            never waits for the kernel's loading (about 0.3 s).

    Raises:
        DeviceParameterError: a parameter of the wrong type, or ``fast=True`` without
            numba.

    The device powers up as the seed says: position 0, RAM defaults (servo period 1000 us,
    scalar 1, servo disabled), control mode from flash.
    """

    def __init__(
        self,
        *,
        flash: Flash | None = None,
        motor: MotorParams | None = None,
        gains: Gains | None = None,
        fast: bool | None = None,
    ) -> None:
        if flash is not None and not isinstance(flash, Flash):
            raise DeviceParameterError(f"flash {flash!r} is not a Flash")
        if motor is not None and not isinstance(motor, MotorParams):
            raise DeviceParameterError(f"motor {motor!r} is not a MotorParams")
        if gains is not None and not isinstance(gains, Gains):
            raise DeviceParameterError(f"gains {gains!r} is not a Gains")
        self._fast = use_kernel(fast)
        self._block: BlockFunction | None = None
        """The kernel's block function once this device has asked for it (it is the same
        for the process's life)."""
        self._reference_ticks = 0
        """Ticks this fast device ran on the reference before the kernel was loaded."""
        if requested(fast):
            self.load_kernel()  # asked for by name: loaded (or compiled) now
        self._flash: Flash = flash if flash is not None else MemoryFlash()
        self._power_up_motor = motor if motor is not None else MotorParams()
        self._power_up_gains = gains if gains is not None else Gains()
        self._splitter = LineSplitter(max_bytes=MAX_LINE_BYTES)
        self._output = bytearray()
        self._stamps: list[tuple[int, int]] = []
        """Where in ``_output`` a run of lines printed at one tick starts: (offset, tick)."""
        self._clock_base = 0
        """Ticks since the device was made minus ``S_CLOCK`` (the clock is zeroed by call 22
        and by a restart; output is stamped on this unbroken count)."""
        self._handlers: dict[int, Callable[[Call], None]] = {
            number: getattr(self, f"_call_{number}") for number in BY_NUMBER
        }
        self._empty = np.zeros(0, dtype=np.int64)
        self._fed = 0
        """Pieces of input taken (:meth:`feed`): a checkpoint is only rewound to with none
        taken since."""
        self._power_up()

    # --- power -------------------------------------------------------------------------

    def _power_up(self) -> None:
        contents = self._flash.read()
        self._state: IntArray = core1.new_state()
        self._params: IntArray = core1.new_params()
        self._queue: IntArray = np.zeros(QUEUE_CAPACITY, dtype=np.int64)
        self._curve = CurvePlayer()
        self._debug: dict[int, int] = {}
        self._interval_dms = DEFAULT_INTERVAL_DMS
        self._scalar = DEFAULT_SCALAR
        self._gains = self._power_up_gains
        self._motor = self._power_up_motor
        self._drive = int(Drive.DC)
        self._stepper = StepperParams()
        self._encoder = (0, 0)
        self._diag_n = 0
        self._watchdog_ms = 0
        self._fe_limit = 0
        self._probe_side = 0
        self._probe_position = 0
        self._state[core1.S_MODE] = contents.default_control_mode
        self._settle_left = 0
        self._copy_in()
        self._state[core1.S_LIMITS] = self._switches()
        self._state[core1.S_PROBE] = self._probe()

    def restart(self) -> None:
        """Power cycle: RAM defaults, position 0, servo disabled; flash is kept.

        Unread output and any partial input line are lost, as when USB drops.
        """
        self._output.clear()
        self._stamps.clear()
        self._splitter.reset()
        self._fed += 1
        self._clock_base += self.clock
        self._power_up()

    # --- public API ----------------------------------------------------------------------

    @property
    def name(self) -> str:
        """The device name (from flash, or the default name)."""
        return self._flash.read().device_name

    @property
    def clock(self) -> int:
        """The device clock: servo ticks since power-up or the last ``22 0``."""
        return int(self._state[core1.S_CLOCK])

    @property
    def desired(self) -> int:
        """The desired position now, counts (:attr:`state`'s ``desired``, without the
        whole snapshot: a recorder reads it after every tick)."""
        return int(self._state[core1.S_DESIRED])

    @property
    def tick_us(self) -> int:
        """The servo period (``servo_update_interval_us``), microseconds."""
        return self._interval_dms * 100

    @property
    def fast(self) -> bool:
        """True when core1 runs as the compiled kernel, False on the reference path."""
        return self._fast

    @property
    def flash(self) -> Flash:
        """The device's flash store."""
        return self._flash

    @property
    def motor_constants(self) -> MotorConstants:
        """The motor integration constants core1 runs with now."""
        return self._motor_constants

    def feed(self, data: bytes) -> None:
        """Take bytes from USB; complete lines are interpreted at once, at this tick.

        Never raises for any content: malformed lines are answered ``ERR``.

        Raises:
            TypeError: ``data`` is not bytes-like.
        """
        if not isinstance(data, bytes | bytearray | memoryview):
            raise TypeError(f"data {data!r} is not bytes")
        self._fed += 1
        for line in self._splitter.feed(bytes(data)):
            if isinstance(line, Overlong):
                self._print(
                    ERR.format("?", f"line longer than {MAX_LINE_BYTES} bytes")
                )
            else:
                self._interpret(line)

    def run(self, ticks: int) -> None:
        """Advance core1 by exactly ``ticks`` servo ticks.

        Raises:
            DeviceParameterError: ``ticks`` is not an int >= 0.
        """
        if isinstance(ticks, bool) or not isinstance(ticks, int) or ticks < 0:
            raise DeviceParameterError(f"ticks {ticks!r} is not an int >= 0")
        remaining = ticks
        while remaining > 0:
            try:
                done = self._run_some(remaining)
            except Exception as error:
                self._internal_fault("?", "in the servo loop", error)
                idle_advance(self._state, self._params, remaining)
                return
            remaining -= done

    def checkpoint(self) -> Checkpoint:
        """Everything :meth:`run` changes, now: :meth:`rewind` returns to it. A simulation
        that runs a device ahead of its host's clock keeps one, to take the device back
        when input arrives for a tick it already ran (``usbmotion.sim.world``)."""
        return Checkpoint(_frozen(self._state), _frozen(self._params), self._settle_left,
                          self._curve.snapshot(), bytes(self._output), tuple(self._stamps),
                          self._fed)

    def rewind(self, checkpoint: Checkpoint) -> None:
        """Return to ``checkpoint``: the ticks run since it are undone, as if never run
        (what they printed too), so the same ticks run again print the same lines.

        Raises:
            DeviceParameterError: input was fed since the checkpoint (running is undone,
                never a call), or it is not one of this device's checkpoints.
        """
        if not isinstance(checkpoint, Checkpoint) or checkpoint.fed != self._fed:
            raise DeviceParameterError(
                "a device rewinds only to a checkpoint with no input fed since it")
        self._state[:] = checkpoint.state
        self._params[:] = checkpoint.params
        self._settle_left = checkpoint.settle_left
        self._curve.restore(checkpoint.curve)  # type: ignore[arg-type]
        self._output[:] = checkpoint.output
        self._stamps[:] = checkpoint.stamps

    def take_output(self) -> bytes:
        """Everything the device printed since the last call (ASCII lines ending in ``\\n``)."""
        data = bytes(self._output)
        self._output.clear()
        self._stamps.clear()
        return data

    def take_timed_output(self) -> list[tuple[int, bytes]]:
        """As :meth:`take_output`, in runs of lines each with how many ticks ago it printed.

        A block of servo ticks prints its diagnostics lines when it ends; each is stamped
        with the tick it belongs to, so a simulation can deliver it at its own time.
        """
        if not self._stamps:
            return []
        now = self._ticks()
        data = bytes(self._output)
        stamps = self._stamps
        ends = [offset for offset, _ in stamps[1:]]
        ends.append(len(data))
        runs = [(now - stamp, data[offset:end])
                for (offset, stamp), end in zip(stamps, ends, strict=True)]
        self._output.clear()
        stamps.clear()
        return runs

    def ticks_until_event(self, *, diagnostics: bool = True) -> int | None:
        """Ticks until the device next prints or changes state on its own, or None.

        ``run(n)`` with ``n`` below the answer prints nothing and changes no variable a
        query reports except the clock, the motion of the servo and the queue being drawn
        down. Counted: the next diagnostics line, a pending output change coming due (call
        42), the watchdog expiring, an armed start being reached, the motion queue running
        dry, a keyframe being reached (its slot frees), the velocity-mode counter reset.
        Faults that the motion itself causes (following error, a limit switch closing) are
        not predicted. With ``diagnostics`` False the diagnostics lines are not counted:
        ``run`` goes through them in one block and stamps each line with its tick (see
        :meth:`take_timed_output`).
        """
        event = ticks_to_scheduled_event(self._state, self._params, diagnostics=diagnostics)
        if self._state[core1.S_MODE] == MODE_CURVE and self._state[core1.S_ENABLE] == 1:
            reach = self._curve.ticks_until_reached(self.tick_us)
            if reach is not None:
                start = int(self._state[core1.S_START])
                delay = max(0, start - self.clock) if start >= 0 else 0
                reach += delay
                event = reach if event is None else min(event, reach)
        return event

    @property
    def state(self) -> DeviceState:
        """A snapshot of the device now."""
        s = self._state
        return DeviceState(
            clock=int(s[core1.S_CLOCK]),
            actual=int(s[core1.S_ACTUAL]),
            desired=int(s[core1.S_DESIRED]),
            desired_velocity=int(s[core1.S_DESIRED_VEL]),
            velocity=int(s[core1.S_VELOCITY]),
            queued=int(s[core1.S_QUEUE_COUNT]),
            keyframes=self._curve.queued,
            enable=int(s[core1.S_ENABLE]),
            mode=int(s[core1.S_MODE]),
            limits=int(s[core1.S_LIMITS]),
            fault=int(s[core1.S_FAULT]),
            fault_tick=int(s[core1.S_FAULT_TICK]),
            integrator=int(s[core1.S_INTEGRAL]),
            output_mv=self._output_mv(),
            shaft_micro_counts=int(s[core1.S_THETA]),
            shaft_speed_micro_counts_s=int(s[core1.S_OMEGA]),
            start_tick=int(s[core1.S_START]),
            tick_us=self.tick_us,
        )

    @property
    def settings(self) -> DeviceSettings:
        """Every variable the calls set, now."""
        contents = self._flash.read()
        return DeviceSettings(
            servo_update_interval_us=self.tick_us,
            motion_update_interval_scalar=self._scalar,
            control_mode=int(self._state[core1.S_MODE]),
            gains=self._gains,
            motor=self._motor,
            drive=self._drive,
            encoder=self._encoder,
            stepper=self._stepper,
            diagnostics_interval=self._diag_n,
            watchdog_ms=self._watchdog_ms,
            following_error_limit=self._fe_limit,
            start_tick=int(self._state[core1.S_START]),
            debug_flags=tuple(sorted((c, f) for c, f in self._debug.items() if f != 0)),
            name=contents.device_name,
            default_control_mode=contents.default_control_mode,
            flash_writes=contents.writes,
        )

    def queue_values(self) -> tuple[int, ...]:
        """The values in the motion queue, oldest first."""
        return tuple(self._queued(int(self._state[core1.S_QUEUE_COUNT])))

    def _queued(self, count: int) -> list[int]:
        """The first ``count`` values in the motion queue, oldest first."""
        head = int(self._state[core1.S_QUEUE_HEAD])
        values: list[int] = self._queue.take(range(head, head + count), mode="wrap").tolist()
        return values

    def keyframes(self) -> tuple[Keyframe, ...]:
        """The keyframes in the curve buffer, oldest first."""
        return self._curve.snapshot().buffer

    # --- core1 ---------------------------------------------------------------------------

    def load_kernel(self) -> None:
        """Load the compiled kernel now, if this device runs it (a device in a world that
        keeps pace with the wall clock cannot stand still for the loading at its first
        motion). A device whose numba does not import after all runs the reference."""
        if self._fast and not kernel_loaded() and load_kernel() is None:
            self._fast = False

    def _servo_block(self, ticks: int) -> BlockFunction:
        """core1's block function for a block of ``ticks``: the kernel, once loaded; a short
        block before that runs the reference, bit for bit the same."""
        if self._block is not None:
            return self._block
        if self._fast and not kernel_loaded():
            if ticks <= REFERENCE_BLOCK_TICKS and self._reference_ticks < REFERENCE_TICKS:
                self._reference_ticks += ticks
                return servo_block
            self.load_kernel()
        if not self._fast:
            return servo_block
        self._block = block_function()
        return self._block

    def _run_some(self, limit: int) -> int:
        state = self._state
        tick_us = self.tick_us
        start = int(state[core1.S_START])
        clock = int(state[core1.S_CLOCK])
        enabled = state[core1.S_ENABLE] == 1
        if enabled and start > clock:
            limit = min(limit, start - clock)
        mode = int(state[core1.S_MODE])
        self._params[core1.P_DIAG_ROOM] = 1 if mode == MODE_CURVE else core1.DIAG_SLOTS
        consuming = running(state)
        if mode == MODE_CURVE and consuming and (self._curve.playing or self._curve.queued):
            return self._run_curve(min(limit, _CURVE_CHUNK), tick_us)
        busy = consuming and mode != MODE_CURVE and state[core1.S_QUEUE_COUNT] > 0
        if busy or self._settle_left > 0:
            n = min(limit, self._settle_left)
            if busy:
                event = ticks_to_scheduled_event(state, self._params, diagnostics=False)
                n = min(limit, event or limit)
            done = self._servo_block(n)(state, self._params, self._queue, self._empty, n)
            self._settle_left = max(0, self._settle_left - done)
            self._after_block()
            return done
        before = state.take(_DYNAMIC_INDEX)
        done = self._servo_block(1)(state, self._params, self._queue, self._empty, 1)
        events = int(state[core1.S_EVENTS])
        self._after_block()
        if (events != 0 or not (state.take(_DYNAMIC_INDEX) == before).all()
                or not self._rings_settled()):
            self._settle_left = _SETTLE_CHUNK
            return done
        quiet = limit - done
        event = ticks_to_scheduled_event(state, self._params, diagnostics=False)
        if event is not None:
            quiet = min(quiet, event - 1)
        full = core1.ticks_to_full_records(state, self._params)
        if full is not None:
            quiet = min(quiet, full)
        if quiet > 0:
            idle_advance(state, self._params, quiet)
            self._after_block()
            done += quiet
        return done

    def _rings_settled(self) -> bool:
        """True when the counter history (and, while enabled, the error history) holds one
        value over the window: then a tick that changed nothing changes nothing next time
        either (a ring still holding an older value would bring it round later)."""
        state = self._state
        window = int(self._params[core1.P_WINDOW])
        counts = state[core1.S_COUNTS : core1.S_COUNTS + window]
        if not (counts == counts[0]).all():
            return False
        if state[core1.S_ENABLE] != 1:
            return True
        errors = state[core1.S_HISTORY : core1.S_HISTORY + window]
        return bool((errors == errors[0]).all())

    def _run_curve(self, n: int, tick_us: int) -> int:
        curve = self._curve
        snapshot = curve.snapshot()
        first_desired = int(self._state[core1.S_DESIRED])
        desired = first_desired
        values = np.empty(n, dtype=np.int64)
        for i in range(n):
            position = curve.next_position(desired, tick_us)
            values[i] = position
            desired = wrap_int32(position)
        done = self._servo_block(n)(self._state, self._params, self._queue, values, n)
        if done < n:
            curve.restore(snapshot)
            desired = first_desired
            for i in range(done):
                curve.next_position(desired, tick_us)
                desired = wrap_int32(int(values[i]))
        self._after_block()
        return done

    def _after_block(self) -> None:
        """Print the diagnostics lines core1 recorded during the block, each at its tick,
        then the alarm of a fault that latched (the block ends at that tick)."""
        state = self._state
        events = int(state[core1.S_EVENTS])
        state[core1.S_EVENTS] = 0
        if int(state[core1.S_DIAG_COUNT]):
            self._print_diagnostics()
        if events & core1.EVENT_FAULT:
            self._print_alarm()

    def _print_alarm(self) -> None:
        state = self._state
        tick = int(state[core1.S_FAULT_TICK])
        self._print(ALARM.format(int(state[core1.S_FAULT]), tick),
                    ticks_ago=max(0, int(state[core1.S_CLOCK]) - tick))

    def _print_diagnostics(self) -> None:
        """Each record core1 kept as its line, stamped with its own tick (as :meth:`_print`
        would print it, in one ``%`` format a line)."""
        state = self._state
        count = int(state[core1.S_DIAG_COUNT])
        state[core1.S_DIAG_COUNT] = 0
        curve_queued = self._curve.queued if state[core1.S_MODE] == MODE_CURVE else None
        start = core1.S_DIAG
        records = state[start : start + count * core1.DIAG_RECORD].tolist()
        output, stamps, clock_base = self._output, self._stamps, self._clock_base
        for base in range(0, len(records), core1.DIAG_RECORD):
            tick, desired, actual, velocity, out_c, out_e, queued, peak = records[
                base : base + core1.DIAG_RECORD
            ]
            stamp = clock_base + tick
            if not stamps or stamps[-1][1] != stamp:
                stamps.append((len(output), stamp))
            output += _DIAGNOSTICS_LINE % (
                tick, desired, actual, velocity, sci_to_int(out_c, out_e + 3),
                queued if curve_queued is None else curve_queued, peak)

    # --- core0: lines --------------------------------------------------------------------

    def _ticks(self) -> int:
        """Ticks since the device was made (never zeroed)."""
        return int(self._state[core1.S_CLOCK]) + self._clock_base

    def _print(self, line: str, *, ticks_ago: int = 0) -> None:
        stamp = self._ticks() - ticks_ago
        if not self._stamps or self._stamps[-1][1] != stamp:
            self._stamps.append((len(self._output), stamp))
        self._output += line.encode("ascii", errors="backslashreplace") + b"\n"

    def _interpret(self, line: bytes) -> None:
        try:
            call = parse_call(line)
        except EmptyLineError:
            return
        except ProtocolError as error:
            self._print(format_err(error))
            return
        except Exception as error:
            self._internal_fault("?", "while parsing", error)
            return
        self._state[core1.S_SINCE_COMMAND_US] = 0
        try:
            self._handlers[call.number](call)
        except _RefusedError as refusal:
            self._print(ERR.format(call.number, str(refusal)))
        except Exception as error:
            self._internal_fault(str(call.number), "", error)

    def _internal_fault(self, call: str, where: str, error: BaseException) -> None:
        state = self._state
        state[core1.S_FAULT] = FaultCode.INTERNAL
        state[core1.S_FAULT_TICK] = state[core1.S_CLOCK]
        state[core1.S_ENABLE] = 0
        state[core1.S_OUT_C] = 0
        state[core1.S_OUT_E] = 0
        core1.outputs_off(state)
        detail = " ".join(f"{type(error).__name__}: {error}".split())[:200]
        reason = f"internal error{' ' + where if where else ''} ({detail}); fault 4 latched"
        self._print(ERR.format(call, reason))
        self._print_alarm()

    def _debug_line(self, number: int, *values: int | str) -> None:
        template = BY_NUMBER[number].debug.get(self._debug.get(number, 0))
        if template is not None:
            self._print(template.format(*values))

    def _reply(self, number: int, *values: int | str) -> None:
        template = BY_NUMBER[number].query_reply
        assert template is not None
        self._print(template.format(*values))

    # --- core0: copying variables into core1 ---------------------------------------------

    def _copy_in(self) -> None:
        """Halt core1, copy every RAM variable it uses into its params, resume."""
        params = self._params
        tick_us = self.tick_us
        dt_s = SciNumber.from_int(tick_us, digits=DIGITS) * SciNumber(1, -6)
        kp = sci_value(self._gains.kp)
        ki_dt = sci_value(self._gains.ki) * dt_s
        window = min(core1.HISTORY_SLOTS, max(1, 1000 // tick_us))
        kd_dt = sci_value(self._gains.kd) / (dt_s * SciNumber.from_int(window, digits=DIGITS))
        vs = sci_value(self._motor.source_voltage_v)
        stepper = self._stepper
        if self._drive == Drive.STEP_CLOSED:
            vs = SciNumber.from_int(stepper.microsteps, digits=DIGITS)  # one full step
        if ki_dt.coefficient == 0:
            integral_limit = 0
        else:
            integral_limit = max(1, min(_INTEGRAL_CAP, int(vs / ki_dt)))
        constants = derive_constants(self._motor, tick_us=tick_us)
        self._motor_constants = constants
        motor = self._motor
        steps = derive_stepper(stepper, tick_us=tick_us, substeps=constants.steps,
                               inertia=sci_value(motor.inertia_kg_m2),
                               viscous_unm=sci_value(motor.viscous_friction_unm_per_rad_s),
                               load_mnm=sci_value(motor.load_torque_mnm))
        values = {
            core1.P_TICK_US: tick_us,
            core1.P_SCALAR: self._scalar,
            core1.P_KP_C: kp.coefficient,
            core1.P_KP_E: kp.exponent,
            core1.P_KI_C: ki_dt.coefficient,
            core1.P_KI_E: ki_dt.exponent,
            core1.P_KD_C: kd_dt.coefficient,
            core1.P_KD_E: kd_dt.exponent,
            core1.P_VS_C: vs.coefficient,
            core1.P_VS_E: vs.exponent,
            core1.P_INTEGRAL_LIMIT: integral_limit,
            core1.P_WATCHDOG_US: self._watchdog_ms * 1000,
            core1.P_FE_LIMIT: self._fe_limit,
            core1.P_DIAG_N: self._diag_n,
            core1.P_STEPS: constants.steps,
            core1.P_DRIVE_C: constants.drive[0],
            core1.P_DRIVE_E: constants.drive[1],
            core1.P_FRICTION_C: constants.friction_speed[0],
            core1.P_FRICTION_E: constants.friction_speed[1],
            core1.P_DECAY_C: constants.decay[0],
            core1.P_DECAY_E: constants.decay[1],
            core1.P_LAG_C: constants.lag_s[0],
            core1.P_LAG_E: constants.lag_s[1],
            core1.P_LOWER: self._motor.travel_lower_counts,
            core1.P_UPPER: self._motor.travel_upper_counts,
            core1.P_STOP_LOW: constants.stop_low_micro,
            core1.P_STOP_HIGH: constants.stop_high_micro,
            core1.P_WINDOW: window,
            core1.P_PROBE_SIDE: self._probe_side,
            core1.P_PROBE_POSITION: self._probe_position,
            core1.P_DRIVE: self._drive,
            core1.P_MAX_STEPS: steps.max_steps,
            core1.P_CYCLE: steps.cycle,
            core1.P_FULL: steps.full,
            core1.P_HOLDING: steps.holding_unm,
            core1.P_DETENT: steps.detent_unm,
            core1.P_CORNER: steps.corner,
            core1.P_LOAD_UNM: steps.load_unm,
            core1.P_VISCOUS_C: steps.viscous[0],
            core1.P_VISCOUS_E: steps.viscous[1],
            core1.P_ACCEL_C: steps.accel[0],
            core1.P_ACCEL_E: steps.accel[1],
            core1.P_ENCODER_CPR: motor.counts_per_revolution,
            core1.P_PER_REV: stepper.microsteps_per_revolution,
        }
        for index, value in values.items():
            params[index] = value

    def _switches(self) -> int:
        count = int(self._state[core1.S_THETA]) // MICRO
        bits = 0
        if count <= self._motor.travel_lower_counts:
            bits |= 1
        if count >= self._motor.travel_upper_counts:
            bits |= 2
        return bits

    def _probe(self) -> int:
        """The simulated probe input where the motor stands (call 40's surface)."""
        count = int(self._state[core1.S_THETA]) // MICRO
        return core1.probe_closed(count, self._probe_side, self._probe_position)

    # --- core0: shared actions -----------------------------------------------------------

    def _clear_queue(self) -> None:
        self._state[core1.S_QUEUE_HEAD] = 0
        self._state[core1.S_QUEUE_COUNT] = 0

    def _clear_curve(self) -> None:
        self._curve.clear(int(self._state[core1.S_DESIRED]))

    def _reset_controller(self) -> None:
        """Start the PID afresh from where the shaft is: integrator 0, no derivative kick."""
        state = self._state
        state[core1.S_INTEGRAL] = 0
        state[core1.S_FRESH] = 1
        state[core1.S_MOTION_LEFT] = 0
        state[core1.S_DESIRED] = state[core1.S_ACTUAL]
        state[core1.S_DESIRED_PREV] = state[core1.S_ACTUAL]
        state[core1.S_DESIRED_VEL] = 0
        state[core1.S_VEL_ACC] = 0
        self._curve.interrupt(int(state[core1.S_ACTUAL]))

    def _push(self, values: tuple[int, ...] | IntArray) -> int:
        """Append to the queue ring; returns the slot of the first value."""
        state = self._state
        count = int(state[core1.S_QUEUE_COUNT])
        tail = (int(state[core1.S_QUEUE_HEAD]) + count) % QUEUE_CAPACITY
        first = min(len(values), QUEUE_CAPACITY - tail)
        self._queue[tail : tail + first] = values[:first]
        self._queue[: len(values) - first] = values[first:]
        state[core1.S_QUEUE_COUNT] = count + len(values)
        return tail

    def _refuse_in_curve_mode(self) -> None:
        if self._state[core1.S_MODE] == MODE_CURVE:
            raise _RefusedError(
                "curve mode (3) plays keyframes (call 25), not queue values;"
                " change the mode with call 7"
            )

    def _desired_reported(self) -> int:
        if self._state[core1.S_MODE] == MODE_VELOCITY:
            return int(self._state[core1.S_DESIRED_VEL])
        return int(self._state[core1.S_DESIRED])

    def _queued_reported(self) -> int:
        if self._state[core1.S_MODE] == MODE_CURVE:
            return self._curve.queued
        return int(self._state[core1.S_QUEUE_COUNT])

    def _output_mv(self) -> int:
        return sci_to_int(int(self._state[core1.S_OUT_C]), int(self._state[core1.S_OUT_E]) + 3)

    def _set_motor(self, **changes: object) -> None:
        try:
            motor = replace(self._motor, **changes)  # type: ignore[arg-type]
        except DeviceParameterError as error:
            raise _RefusedError(str(error)) from error
        self._motor = motor
        self._copy_in()

    # --- the calls -----------------------------------------------------------------------

    def _call_0(self, call: Call) -> None:
        self._refuse_in_curve_mode()
        if self._state[core1.S_QUEUE_COUNT] >= QUEUE_CAPACITY:
            self._print("E0")
            return
        self._push(call.args)
        self._debug_line(0, call.args[0])

    def _call_1(self, call: Call) -> None:
        self._refuse_in_curve_mode()
        values = call.args[1:] if call.items is None else call.items
        if int(self._state[core1.S_QUEUE_COUNT]) + len(values) > QUEUE_CAPACITY:
            self._print("E1")
            return
        tail = self._push(values)
        flag = self._debug.get(1, 0)
        if flag == 1:
            self._debug_line(1, len(values), " ".join(map(str, values)))
        elif flag == 2:
            first = min(len(values), QUEUE_CAPACITY - tail)
            crc = zlib.crc32(self._queue[tail : tail + first].astype("<i4").tobytes())
            crc = zlib.crc32(self._queue[: len(values) - first].astype("<i4").tobytes(), crc)
            self._debug_line(1, len(values), crc)

    def _replacement_timing(self, tick: int) -> tuple[int, int]:
        """Calls 38 and 50 from device tick ``tick``: the queued values due before it
        (kept), and how many value periods the first new value's tick is already past (0:
        on time). With the servo disabled nothing is due: (0, 0)."""
        state = self._state
        if state[core1.S_ENABLE] != 1:
            return 0, 0
        clock = int(state[core1.S_CLOCK])
        start = int(state[core1.S_START])
        first = max(start, clock) if start >= 0 else clock + int(state[core1.S_MOTION_LEFT])
        scalar = self._scalar
        queued = int(state[core1.S_QUEUE_COUNT])
        return (min(queued, max(0, -(-(tick - first) // scalar))),
                max(0, -(-(first - tick) // scalar)))

    def _call_38(self, call: Call) -> None:
        self._refuse_in_curve_mode()
        tick, count = call.args[0], call.args[1]
        values = call.args[2:]
        kept, late = self._replacement_timing(tick)
        skipped = min(count, late)
        added = values[skipped:]
        if kept + len(added) > QUEUE_CAPACITY:
            self._print("E38")
            return
        self._keep_then_add(kept, added)
        if self._debug.get(38, 0) == 1:
            self._debug_line(38, kept, skipped, len(added), values_crc32(added))

    def _call_50(self, call: Call) -> None:
        self._refuse_in_curve_mode()
        state = self._state
        tick = call.args[0]
        values = call.args[2:]
        kept, late = self._replacement_timing(tick)
        offset = 0
        if late and values and state[core1.S_MODE] == MODE_POSITION:
            due = (int(self._queue[int(state[core1.S_QUEUE_HEAD])]) if state[core1.S_QUEUE_COUNT]
                   else int(state[core1.S_DESIRED]))
            offset = due - values[0]
        added = [value + offset for value in values]
        if (kept + len(added) > QUEUE_CAPACITY
                or (offset and not INT32_MIN <= min(added) <= max(added) <= INT32_MAX)):
            self._print("E50")
            return
        self._keep_then_add(kept, added)
        if self._debug.get(50, 0) == 1:
            self._debug_line(50, kept, late, len(added), offset, values_crc32(values))

    def _keep_then_add(self, kept: int, added: Sequence[int]) -> None:
        """Calls 38 and 50: the queue becomes its first ``kept`` values, then ``added``."""
        kept_values = self._queued(min(kept, int(self._state[core1.S_QUEUE_COUNT])))
        self._clear_queue()
        self._push((*kept_values, *added))

    def _call_2(self, call: Call) -> None:
        queued = int(self._state[core1.S_QUEUE_COUNT])
        self._reply(2, queued, QUEUE_CAPACITY - queued)

    def _call_3(self, call: Call) -> None:
        state = self._state
        if call.is_query:
            self._reply(3, int(state[core1.S_ENABLE]))
            return
        enable = call.args[0]
        if enable == 1 and state[core1.S_ENABLE] == 0:
            fault = int(state[core1.S_FAULT])
            if fault != FaultCode.NONE:
                raise _RefusedError(
                    f"fault {fault} ({fault_words(fault)}) is latched;"
                    " clear it with call 30 before enabling"
                )
            self._reset_controller()
            state[core1.S_ENABLE] = 1
        elif enable == 0:
            state[core1.S_ENABLE] = 0
            state[core1.S_OUT_C] = 0
            state[core1.S_OUT_E] = 0
        self._debug_line(3, enable)

    def _call_4(self, call: Call) -> None:
        self._clear_queue()
        self._debug_line(4)

    def _call_5(self, call: Call) -> None:
        if call.is_query:
            self._reply(5, self.tick_us)
            return
        state = self._state
        if self._drive != Drive.DC and self._max_steps(call.args[0] * 100) < 1:
            raise _RefusedError(self._no_step_fits(call.args[0] * 100))
        self._interval_dms = call.args[0]
        self._clear_queue()
        self._clear_curve()
        state[core1.S_FRESH] = 1
        state[core1.S_COUNTS : core1.S_COUNTS + core1.HISTORY_SLOTS] = state[core1.S_ACTUAL]
        state[core1.S_COUNTS_POS] = 0
        self._copy_in()
        self._debug_line(5, self.tick_us)

    def _call_6(self, call: Call) -> None:
        if call.is_query:
            self._reply(6, self._scalar)
            return
        self._scalar = call.args[0]
        self._clear_queue()
        self._state[core1.S_MOTION_LEFT] = 0
        self._copy_in()
        self._debug_line(6, self._scalar)

    def _call_7(self, call: Call) -> None:
        state = self._state
        if call.is_query:
            self._reply(7, int(state[core1.S_MODE]))
            return
        mode = call.args[0]
        self._clear_queue()
        state[core1.S_MODE] = mode
        state[core1.S_VELOCITY_MODE_US] = 0
        self._reset_controller()
        self._clear_curve()
        self._debug_line(7, mode)

    def _call_8(self, call: Call) -> None:
        number, flag = call.args
        if call.is_query:
            self._reply(8, number, self._debug.get(number, 0))
            return
        self._debug[number] = flag

    def _gain_call(self, call: Call, field_name: str) -> None:
        number = call.number
        if call.is_query:
            self._reply(number, *getattr(self._gains, field_name))
            return
        coefficient, exponent = call.args
        self._gains = replace(self._gains, **{field_name: (coefficient, exponent)})
        self._copy_in()
        self._debug_line(number, coefficient, exponent)

    def _call_9(self, call: Call) -> None:
        self._gain_call(call, "kp")

    def _call_10(self, call: Call) -> None:
        self._gain_call(call, "ki")

    def _call_11(self, call: Call) -> None:
        self._gain_call(call, "kd")

    def _motor_call(self, call: Call, field_name: str) -> None:
        number = call.number
        if call.is_query:
            value = getattr(self._motor, field_name)
            if isinstance(value, tuple):
                self._reply(number, *value)
            else:
                self._reply(number, value)
            return
        value = call.args if len(call.args) == 2 else call.args[0]
        self._set_motor(**{field_name: value})
        self._debug_line(number, *call.args)

    def _call_12(self, call: Call) -> None:
        self._motor_call(call, "sim_update_interval_dms")

    def _call_13(self, call: Call) -> None:
        self._motor_call(call, "source_voltage_v")

    def _call_14(self, call: Call) -> None:
        self._motor_call(call, "torque_constant_mnm_per_a")

    def _call_15(self, call: Call) -> None:
        self._motor_call(call, "winding_resistance_ohm")

    def _call_16(self, call: Call) -> None:
        self._motor_call(call, "counts_per_revolution")

    def _call_17(self, call: Call) -> None:
        self._motor_call(call, "inertia_kg_m2")

    def _call_18(self, call: Call) -> None:
        if call.is_query:
            self._reply(18, self.name)
            return
        name = "".join(chr(code) for code in call.args[1:])
        self._write_flash(name=name)
        self._debug_line(18, self.name)

    def _call_19(self, call: Call) -> None:
        if call.is_query:
            self._reply(19, self._flash.read().default_control_mode)
            return
        self._write_flash(default_control_mode=call.args[0])
        self._debug_line(19, call.args[0])

    def _call_39(self, call: Call) -> None:
        if call.is_query:
            self._reply(39, self._flash.read().motor, 0)  # no pins: always simulated
            return
        self._write_flash(motor=call.args[0])
        self._debug_line(39, call.args[0])

    def _write_flash(self, **changes: str | int) -> FlashContents:
        try:
            return self._flash.write(**changes)  # type: ignore[arg-type]
        except FlashError as error:
            raise _RefusedError(f"flash write failed, value unchanged: {error}") from error

    def _call_20(self, call: Call) -> None:
        s = self._state
        self._reply(
            20,
            int(s[core1.S_CLOCK]),
            int(s[core1.S_ACTUAL]),
            self._desired_reported(),
            int(s[core1.S_VELOCITY]),
            self._queued_reported(),
            int(s[core1.S_ENABLE]),
            int(s[core1.S_MODE]),
            int(s[core1.S_LIMITS]),
            int(s[core1.S_FAULT]),
        )

    def _call_21(self, call: Call) -> None:
        if call.is_query:
            self._reply(21, self._diag_n)
            return
        self._diag_n = call.args[0]
        self._state[core1.S_DIAG_LEFT] = self._diag_n
        self._state[core1.S_DIAG_PEAK] = 0
        self._copy_in()
        self._debug_line(21, self._diag_n)

    def _call_22(self, call: Call) -> None:
        if call.is_query:
            self._reply(22, self.clock)
            return
        self._clock_base += self.clock
        self._state[core1.S_CLOCK] = 0
        core1.drop_pending_outputs(self._state)  # their ticks were on the old clock
        self._debug_line(22)

    def _call_35(self, call: Call) -> None:
        state = self._state
        if call.is_query:
            self._reply(
                35,
                int(state[core1.S_STATS_TICKS]),
                int(state[core1.S_STATS_MAX]),
                int(state[core1.S_STATS_MAX_TICK]),
                int(state[core1.S_STATS_SUM_SQ]),
                int(state[core1.S_LAST_TAKE]),
            )
            return
        for index in (core1.S_STATS_TICKS, core1.S_STATS_MAX, core1.S_STATS_MAX_TICK,
                      core1.S_STATS_SUM_SQ, core1.S_DIAG_PEAK):
            state[index] = 0
        state[core1.S_LAST_TAKE] = -1
        self._debug_line(35)

    def _shift_position(self, shift: int) -> None:
        """Calls 23 and 37: move the counter's coordinates by ``shift``; the loop goes on."""
        state = self._state
        state[core1.S_OFFSET] = wrap_int32(int(state[core1.S_OFFSET]) + shift)
        state[core1.S_ACTUAL] = wrap_int32(int(state[core1.S_ACTUAL]) + shift)
        state[core1.S_DESIRED] = wrap_int32(int(state[core1.S_DESIRED]) + shift)
        state[core1.S_DESIRED_PREV] = wrap_int32(int(state[core1.S_DESIRED_PREV]) + shift)
        for slot in range(core1.S_COUNTS, core1.S_COUNTS + core1.HISTORY_SLOTS):
            state[slot] = wrap_int32(int(state[slot]) + shift)
        core1.shift_edges(state, shift)
        self._clear_queue()
        self._clear_curve()

    def _call_23(self, call: Call) -> None:
        position = call.args[0]
        self._shift_position(position - int(self._state[core1.S_ACTUAL]))
        self._debug_line(23, position)

    def _call_36(self, call: Call) -> None:
        switch = call.args[0]
        base = core1.S_EDGES + (switch - 1) * core1.EDGE_FIELDS
        edge = self._state[base : base + core1.EDGE_FIELDS].tolist()
        self._reply(36, switch, *edge)

    def _call_37(self, call: Call) -> None:
        self._shift_position(call.args[0])
        self._debug_line(37, call.args[0])

    def _call_24(self, call: Call) -> None:
        limits = int(self._state[core1.S_LIMITS])
        self._reply(24, limits & 1, (limits >> 1) & 1)

    def _call_25(self, call: Call) -> None:
        if self._state[core1.S_MODE] != MODE_CURVE:
            raise _RefusedError("keyframes play in curve mode only; select it with call 7 3")
        duration_ms, position, tangent_in, tangent_out = call.args
        if not self._curve.append(Keyframe(duration_ms, position, tangent_in, tangent_out)):
            self._print("E25")
            return
        self._debug_line(25, duration_ms, position, tangent_in, tangent_out)

    def _call_26(self, call: Call) -> None:
        self._clear_curve()
        self._debug_line(26)

    def _call_27(self, call: Call) -> None:
        self._reply(27, self._curve.free)

    def _call_28(self, call: Call) -> None:
        if call.is_query:
            self._reply(28, self._watchdog_ms)
            return
        self._watchdog_ms = call.args[0]
        self._copy_in()
        self._debug_line(28, self._watchdog_ms)

    def _call_29(self, call: Call) -> None:
        if call.is_query:
            self._reply(29, self._fe_limit)
            return
        self._fe_limit = call.args[0]
        self._copy_in()
        self._debug_line(29, self._fe_limit)

    def _call_30(self, call: Call) -> None:
        state = self._state
        if call.is_query:
            self._reply(30, int(state[core1.S_FAULT]), int(state[core1.S_FAULT_TICK]))
            return
        state[core1.S_FAULT] = FaultCode.NONE
        state[core1.S_FAULT_TICK] = 0
        self._debug_line(30)

    def _call_31(self, call: Call) -> None:
        if call.is_query:
            self._reply(31, int(self._state[core1.S_START]))
            return
        self._state[core1.S_START] = call.args[0]
        self._debug_line(31, call.args[0])

    def _call_32(self, call: Call) -> None:
        self._motor_call(call, "viscous_friction_unm_per_rad_s")

    def _call_33(self, call: Call) -> None:
        self._motor_call(call, "load_torque_mnm")

    def _call_34(self, call: Call) -> None:
        if call.is_query:
            self._reply(34, self._motor.travel_lower_counts, self._motor.travel_upper_counts)
            return
        lower, upper = call.args
        if lower >= upper:
            raise _RefusedError(f"lower end {lower} must be below upper end {upper}")
        self._set_motor(travel_lower_counts=lower, travel_upper_counts=upper)
        self._state[core1.S_LIMITS] = self._switches()
        self._debug_line(34, lower, upper)

    def _call_40(self, call: Call) -> None:
        if call.is_query:
            self._reply(40, self._probe_side, self._probe_position)
            return
        self._probe_side, self._probe_position = call.args
        self._copy_in()
        self._state[core1.S_PROBE] = self._probe()  # a moved surface is no edge
        self._debug_line(40, self._probe_side, self._probe_position)

    def _call_41(self, call: Call) -> None:
        state = self._state
        base = core1.S_PROBE_EDGE
        edge = state[base : base + core1.EDGE_FIELDS].tolist()
        self._reply(41, int(state[core1.S_PROBE]), *edge)

    def _call_44(self, call: Call) -> None:
        state = self._state
        if call.is_query:
            self._reply(44, self._drive)
            return
        if state[core1.S_ENABLE] == 1:
            raise _RefusedError("the servo is enabled: disable it (call 3 0) before changing"
                                " what it drives")
        drive = call.args[0]
        if drive != Drive.DC and self._max_steps(self.tick_us) < 1:
            raise _RefusedError(self._no_step_fits(self.tick_us))
        self._drive = drive
        for index in (core1.S_THETA, core1.S_OMEGA, core1.S_OFFSET, core1.S_ACTUAL,
                      core1.S_VELOCITY, core1.S_PHASE, core1.S_LAST_STEPS, core1.S_DESIRED):
            state[index] = 0
        state[core1.S_COUNTS : core1.S_COUNTS + core1.HISTORY_SLOTS] = 0
        state[core1.S_COUNTS_POS] = 0
        self._clear_queue()
        self._clear_curve()
        self._reset_controller()
        self._copy_in()
        state[core1.S_LIMITS] = self._switches()
        state[core1.S_PROBE] = self._probe()
        self._debug_line(44, drive)

    def _max_steps(self, tick_us: int, stepper: StepperParams | None = None) -> int:
        stepper = stepper if stepper is not None else self._stepper
        return max_steps_per_tick(tick_us, stepper.pulse_ns, stepper.setup_ns)

    def _no_step_fits(self, tick_us: int, stepper: StepperParams | None = None) -> str:
        stepper = stepper if stepper is not None else self._stepper
        return (f"a {tick_us} us tick fits no step pulse of {stepper.pulse_ns} ns after a"
                f" {stepper.setup_ns} ns set-up (call 46)")

    def _call_45(self, call: Call) -> None:
        if call.is_query:
            self._reply(45, self._stepper.full_steps, self._stepper.microsteps)
            return
        full_steps, microsteps = call.args
        self._stepper = replace(self._stepper, full_steps=full_steps, microsteps=microsteps)
        self._clear_queue()
        self._clear_curve()
        self._copy_in()
        self._debug_line(45, full_steps, microsteps)

    def _call_46(self, call: Call) -> None:
        if call.is_query:
            self._reply(46, self._stepper.pulse_ns, self._stepper.setup_ns)
            return
        pulse_ns, setup_ns = call.args
        stepper = replace(self._stepper, pulse_ns=pulse_ns, setup_ns=setup_ns)
        if self._max_steps(self.tick_us, stepper) < 1:
            raise _RefusedError(self._no_step_fits(self.tick_us, stepper))
        self._stepper = stepper
        self._copy_in()
        self._debug_line(46, pulse_ns, setup_ns)

    def _call_47(self, call: Call) -> None:
        stepper = self._stepper
        if call.is_query:
            self._reply(47, stepper.holding_mnm, stepper.detent_mnm, stepper.corner_rpm)
            return
        holding, detent, corner = call.args
        if detent > holding:
            raise _RefusedError(f"detent torque {detent} mNm is more than the holding torque"
                                f" {holding} mNm")
        self._stepper = replace(stepper, holding_mnm=holding, detent_mnm=detent,
                                corner_rpm=corner)
        self._copy_in()
        self._debug_line(47, holding, detent, corner)

    def _call_49(self, call: Call) -> None:
        state = self._state
        if call.is_query:
            kind, angle = self._encoder
            zero = 0
            if kind == 1:
                zero = (int(state[core1.S_OFFSET]) - angle) % self._encoder_turn()
            self._reply(49, kind, angle, zero)
            return
        if state[core1.S_ENABLE] == 1:
            raise _RefusedError("the servo is enabled: disable it (call 3 0) before changing"
                                " its encoder")
        kind, angle = call.args
        if kind == 1 and self._drive == Drive.STEP_OPEN:
            raise _RefusedError("an open-loop stepper (drive 1) counts its steps: it has no"
                                " encoder to read")
        self._encoder = (kind, angle)
        if kind == 1:
            source = wrap_int32(int(state[core1.S_ACTUAL]) - int(state[core1.S_OFFSET]))
            self._shift_position((source + angle) % self._encoder_turn()
                                 - int(state[core1.S_ACTUAL]))
        self._debug_line(49, kind, angle)

    def _encoder_turn(self) -> int:
        """Call 49: one turn of the encoder, in counts of the counter."""
        if self._drive == Drive.STEP_CLOSED:
            return self._stepper.microsteps_per_revolution
        return self._motor.counts_per_revolution

    def _call_48(self, call: Call) -> None:
        state = self._state
        self._reply(48, wrap_int32(int(state[core1.S_PHASE])), int(state[core1.S_LAST_STEPS]),
                    self._max_steps(self.tick_us))

    def _call_42(self, call: Call) -> None:
        state = self._state
        output, value, tick = call.args
        fault = int(state[core1.S_FAULT])
        if fault != FaultCode.NONE:
            raise _RefusedError(
                f"fault {fault} ({fault_words(fault)}) is latched;"
                " clear it with call 30 before setting an output"
            )
        if output < DIGITAL_OUTPUTS and value not in (0, OUTPUT_FULL):
            raise _RefusedError(
                f"output {output} is digital: value {value} must be 0 or {OUTPUT_FULL}")
        records = int(state[core1.S_OUT_RECORDS])
        head = int(state[core1.S_OUT_HEAD])
        last = -1
        last_tick = 0
        if records > 0:
            last = core1.S_OUT_QUEUE + (head + records - 1) % OUTPUT_QUEUE_CAPACITY * (
                core1.OUT_RECORD)
            last_tick = int(state[last + core1.OUT_TICK])
            if tick < last_tick:
                raise _RefusedError(
                    f"tick {tick} is before the last pending change's tick {last_tick}")
        pending = core1.pending_outputs(state)
        if pending >= OUTPUT_QUEUE_CAPACITY:
            self._print("E42")
            return
        if last < 0 or tick != last_tick:
            # a new record: the outputs as the last record leaves them (or as they are now)
            base = core1.S_OUT_QUEUE + (head + records) % OUTPUT_QUEUE_CAPACITY * (
                core1.OUT_RECORD)
            before = core1.S_OUTPUTS if last < 0 else last + core1.OUT_VALUES
            state[base + core1.OUT_VALUES : base + core1.OUT_RECORD] = (
                state[before : before + OUTPUT_COUNT])
            state[base + core1.OUT_TICK] = tick
            state[base + core1.OUT_CHANGES] = 0
            if records == 0:
                state[core1.S_OUT_NEXT] = tick
            state[core1.S_OUT_RECORDS] = records + 1
            last = base
        state[last + core1.OUT_VALUES + output] = value
        state[last + core1.OUT_CHANGES] += 1
        self._debug_line(42, output, value, tick, OUTPUT_QUEUE_CAPACITY - pending - 1)

    def _call_43(self, call: Call) -> None:
        state = self._state
        if call.args[0] == 1:
            core1.drop_pending_outputs(state)
        values = state[core1.S_OUTPUTS : core1.S_OUTPUTS + OUTPUT_COUNT].tolist()
        self._reply(43, *values, core1.pending_outputs(state), int(state[core1.S_OUT_LAST]))


__all__ = [
    "MODE_CURVE",
    "MODE_POSITION",
    "MODE_VELOCITY",
    "Device",
    "DeviceSettings",
    "DeviceState",
    "Gains",
]
