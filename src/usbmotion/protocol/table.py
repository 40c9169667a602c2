"""The command table: every executive call, defined once for the device and the host.

Each :class:`CallSpec` gives the call's number, name, supporting inputs with their allowed
ranges, the token tuple that turns it into a query, the reply it answers a query with, the
debug-flag strings of call 8, and the refusal it can answer. The device interprets lines
through this table; the host validates and encodes through it; ``PROTOCOL.md`` is generated
from it.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field

from usbmotion.protocol.names import CallNumber
from usbmotion.protocol.names import CallNumber as C

INT32_MIN = -(2**31)
INT32_MAX = 2**31 - 1
MAX_LINE_BYTES = 16384
"""Longest line the device buffers (bytes, no newline): a full queue fits in one call 1."""
QUEUE_CAPACITY = 1000
"""Motion queue capacity, in 32-bit values (seed 000)."""
CURVE_BUFFER_CAPACITY = 8
"""Keyframe buffer capacity (seed 001)."""
DEVICE_NAME_MAX = 25
"""Longest device name, in characters (seed 000)."""
DEFAULT_DEVICE_NAME = "GENERIC USB MOTION DEVICE"
OUTPUT_COUNT = 4
"""Outputs of call 42: 0 and 1 digital, 2 and 3 PWM."""
DIGITAL_OUTPUTS = 2
"""Outputs 0 .. DIGITAL_OUTPUTS - 1 are digital: only 0 or :data:`OUTPUT_FULL`."""
OUTPUT_FULL = 1000
"""An output's full value: per mille of full duty (a digital output's on)."""
OUTPUT_QUEUE_CAPACITY = 16
"""Pending output changes the device keeps (call 42)."""
STEP_CLOCK_HZ = 125_000_000
"""The clock step pulses are timed in (the RP2040's system clock): call 46's times are
rounded up to whole periods of it (8 ns)."""
STEP_PULSE_MIN_NS = 100
"""Shortest step pulse call 46 takes (a TMC2209 needs 100 ns high and low)."""


def step_periods(ns: int) -> int:
    """``ns`` nanoseconds in whole periods of the step clock (:data:`STEP_CLOCK_HZ`),
    rounded up."""
    return (ns * (STEP_CLOCK_HZ // 1_000_000) + 999) // 1000


def max_steps_per_tick(tick_us: int, pulse_ns: int, setup_ns: int) -> int:
    """The steps one servo tick of ``tick_us`` can issue (call 48's ``max_per_tick``): after
    the set-up, a pulse high and as long low each, in whole step-clock periods (call 46;
    0: not even one fits). The device issues at most this many; a host checks a machine's
    step rate against it."""
    room = tick_us * (STEP_CLOCK_HZ // 1_000_000) - step_periods(setup_ns)
    return max(0, room // (2 * step_periods(pulse_ns)))

_FIELD = re.compile(r"\{(\w+)\}")
REST_FIELDS = frozenset({"text", "values"})
"""Template fields that take the rest of the line rather than one integer."""


@dataclass(frozen=True, slots=True)
class Param:
    """One supporting input: a name with its unit, an inclusive range, and what it means."""

    name: str
    minimum: int
    maximum: int
    doc: str

    def check(self, value: int) -> str | None:
        """Return why ``value`` is not allowed, or ``None`` when it is."""
        if self.minimum <= value <= self.maximum:
            return None
        return f"{self.name} {value!r} is out of range {self.minimum}..{self.maximum}"


@dataclass(frozen=True, slots=True)
class Template:
    """A reply or debug line: literal words with ``{field}`` placeholders.

    A field named ``text`` or ``values`` takes the rest of the line (the device name,
    the values of call 1); every other field is one integer.
    """

    text: str
    fields: tuple[str, ...] = field(init=False, repr=False, compare=False)
    """Names of the placeholders, in order."""
    _positional: str = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "fields", tuple(_FIELD.findall(self.text)))
        object.__setattr__(self, "_positional", _FIELD.sub("{}", self.text))

    @property
    def head(self) -> str:
        """The literal text before the first placeholder (the reply's key)."""
        return self.text.split("{", 1)[0].rstrip()

    def format(self, *values: int | str) -> str:
        """Fill the placeholders in order."""
        if len(values) != len(self.fields):
            raise ValueError(
                f"template {self.text!r} takes {len(self.fields)} values, got {len(values)}"
            )
        return self._positional.format(*values)

    def int_line_format(self) -> bytes:
        """The whole line, newline included, as a ``bytes`` ``%`` format with ``%d`` for
        every placeholder: ``fmt % values`` gives what ``format`` of those integers gives,
        encoded, in one step (a device prints thousands of diagnostics lines this way).

        Raises:
            ValueError: a placeholder takes text, not an integer.
        """
        rest = [name for name in self.fields if name in REST_FIELDS]
        if rest:
            raise ValueError(f"template {self.text!r} takes text in {rest[0]!r}")
        return (self._positional.replace("%", "%%").replace("{}", "%d") + "\n").encode("ascii")

    def pattern(self) -> re.Pattern[str]:
        """A regular expression matching a whole line of this template."""
        parts: list[str] = []
        pos = 0
        for match in _FIELD.finditer(self.text):
            parts.append(re.escape(self.text[pos : match.start()]))
            parts.append("(.*)" if match.group(1) in REST_FIELDS else r"(-?\d+)")
            pos = match.end()
        parts.append(re.escape(self.text[pos:]))
        return re.compile("^" + "".join(parts) + "$")


@dataclass(frozen=True, slots=True)
class CallSpec:
    """One executive call.

    ``params`` are the fixed supporting inputs. A *counted* call (1, 18, 38) takes its
    fixed inputs ``params[:-1]`` (none for 1 and 18), then a count ``N`` (``params[-1]``),
    then ``N`` items each checked against ``item``.
    ``query`` is the input tuple that queries the call's value instead of setting it
    (``None`` in it matches any value), answered with ``query_reply``. ``debug`` maps a
    call-8 flag to the line the device prints when the call executes with that flag set.
    ``refusal`` is the line the device answers when the call cannot be carried out (queue
    or buffer full).
    """

    number: CallNumber
    summary: str
    params: tuple[Param, ...]
    item: Param | None = None
    query: tuple[int | None, ...] | None = None
    query_reply: Template | None = None
    debug: Mapping[int, Template] = field(default_factory=dict)
    refusal: str | None = None
    notes: str = ""

    @property
    def name(self) -> str:
        """The call's name (``STATUS``), as :class:`CallNumber` spells it."""
        return self.number.name

    @property
    def counted(self) -> bool:
        """True when the call takes a count followed by that many items."""
        return self.item is not None

    def is_query(self, args: tuple[int, ...]) -> bool:
        """True when ``args`` is this call's query form."""
        if self.query is None or len(args) != len(self.query):
            return False
        return all(q is None or q == a for q, a in zip(self.query, args, strict=True))

    def problem(self, args: tuple[int, ...]) -> tuple[str, str] | None:
        """Check ``args`` against the call: ``None`` if valid, else ``(kind, message)``.

        ``kind`` is ``"count"`` for a wrong number of inputs and ``"range"`` for a
        value outside its range.
        """
        if self.is_query(args):
            assert self.query is not None
            for wanted, param, value in zip(self.query, self.params, args, strict=False):
                why = param.check(value) if wanted is None else None
                if why is not None:
                    return ("range", why)
            return None
        if self.counted:
            assert self.item is not None
            lead = len(self.params) - 1
            if len(args) <= lead:
                first = "a count" if not lead else f"{lead} input{'s' * (lead != 1)} and a count"
                return ("count", f"call {self.number} ({self.name}) needs {first} first")
            for param, value in zip(self.params, args[: lead + 1], strict=False):
                why = param.check(value)
                if why is not None:
                    return ("range", why)
            count = args[lead]
            if len(args) != lead + 1 + count:
                return (
                    "count",
                    f"call {self.number} ({self.name}) announced {count} items"
                    f" but carries {len(args) - lead - 1}",
                )
            items = args[lead + 1 :]
            if items and (min(items) < self.item.minimum or max(items) > self.item.maximum):
                for value in items:
                    why = self.item.check(value)
                    if why is not None:
                        return ("range", why)
            return None
        if len(args) != len(self.params):
            want = len(self.params)
            return (
                "count",
                f"call {self.number} ({self.name}) takes {want} input{'s' * (want != 1)},"
                f" got {len(args)}",
            )
        for param, value in zip(self.params, args, strict=True):
            why = param.check(value)
            if why is not None:
                return ("range", why)
        return None


def _p(name: str, minimum: int, maximum: int, doc: str) -> Param:
    return Param(name, minimum, maximum, doc)


def _t(text: str) -> Template:
    return Template(text)


_GAIN_C = (0, 999, "coefficient, up to 3 significant digits")
_GAIN_E = (-12, 6, "decimal exponent")
_SCI_C = (1, 9999, "coefficient, up to 4 significant digits")
_SCI_E = (-12, 6, "decimal exponent")


def _gain(number: CallNumber, unit: str) -> CallSpec:
    key = number.name.removeprefix("SET_")
    word = key.removesuffix("_GAIN").capitalize()
    return CallSpec(
        number,
        f"{word} gain of the PID, C*10^E {unit}; halts core1, copies it in, resumes.",
        (_p("coefficient", *_GAIN_C), _p("exponent", *_GAIN_E)),
        query=(-1, 0),
        query_reply=_t(key + " {coefficient} {exponent}"),
        debug={1: _t(f"{word.upper()} GAIN MODIFIED TO {{coefficient}} {{exponent}}")},
    )


def _sim_sci(number: CallNumber, what: str, unit: str, *, zero: bool = False) -> CallSpec:
    key = number.name.removeprefix("SET_SIM_")
    low = 0 if zero else _SCI_C[0]
    return CallSpec(
        number,
        f"Simulated motor: {what}, C*10^E {unit}.",
        (
            _p("coefficient", low, _SCI_C[1], _SCI_C[2] + (", 0 for none" if zero else "")),
            _p("exponent", *_SCI_E),
        ),
        query=(-1, 0),
        query_reply=_t(f"SIM_{key} {{coefficient}} {{exponent}}"),
        debug={1: _t(f"SIM {key.replace('_', ' ')} MODIFIED TO {{coefficient}} {{exponent}}")},
    )


_REPLACEMENT = (
    _p("tick", 0, INT32_MAX, "device clock tick the first new value is for"),
    _p("count", 0, QUEUE_CAPACITY, "number of values that follow"),
)
"""Calls 38 and 50: the tick the new values start from and how many follow."""
_REPLACEMENT_ITEM = _p("value", INT32_MIN, INT32_MAX,
                       "setpoint: counts (mode 1) or counts/s (mode 2)")

CALLS: tuple[CallSpec, ...] = (
    CallSpec(
        C.ADD_SINGLE,
        "Add one integer (position in counts or velocity in counts/s) to the motion queue.",
        (_p("value", INT32_MIN, INT32_MAX, "setpoint: counts (mode 1) or counts/s (mode 2)"),),
        debug={1: _t("S0 {value}")},
        refusal="E0",
        notes="A full queue refuses the value with `E0` and keeps what it holds.",
    ),
    CallSpec(
        C.ADD_MULTIPLE,
        "Add N integers to the motion queue, all or none.",
        (_p("count", 1, QUEUE_CAPACITY, "number of values that follow"),),
        item=_p("value", INT32_MIN, INT32_MAX, "setpoint: counts (mode 1) or counts/s (mode 2)"),
        debug={1: _t("S0 {count} {values}"), 2: _t("ADDED {count} CRC {crc}")},
        refusal="E1",
        notes="If the queue cannot take all N values it takes none and answers `E1`. Debug flag"
        " 2 acknowledges a batch taken without echoing it: `crc` is the CRC-32 (zlib, IEEE"
        " 802.3) of the N values as 32-bit little-endian two's complement integers, which the"
        " host computes over what it sent (`usbmotion.protocol.values_crc32`).",
    ),
    CallSpec(
        C.MOTION_QUEUE,
        "Motion queue status: values queued and free slots.",
        (_p("query", -1, -1, "always -1"),),
        query=(-1,),
        query_reply=_t("MOTION_QUEUE {queued} {free}"),
    ),
    CallSpec(
        C.SET_SERVO_ENABLE,
        "Enable (1) or disable (0) the servo loop.",
        (_p("enable", 0, 1, "1 enables, 0 disables"),),
        query=(-1,),
        query_reply=_t("SERVO_ENABLE {value}"),
        debug={1: _t("SERVO ENABLE MODIFIED TO {value}")},
        notes="Enabling while a fault is latched is refused with `ERR 3 fault ...`;"
        " clear it with call 30 first.",
    ),
    CallSpec(
        C.CLEAR_MOTION_QUEUE,
        "Empty the motion queue; the last desired value is held.",
        (_p("zero", 0, 0, "always 0"),),
        debug={1: _t("MOTION QUEUE CLEARED")},
    ),
    CallSpec(
        C.SET_SERVO_UPDATE_INTERVAL,
        "Servo loop period in decimilliseconds (1 = 100 us = 10 kHz); clears the queue.",
        (_p("interval_dms", 1, 10000, "servo period in tenths of a millisecond"),),
        query=(-1,),
        query_reply=_t("SERVO_UPDATE_INTERVAL_US {value}"),
        debug={1: _t("SERVO LOOP INTERVAL MODIFIED TO {value} MICROSECONDS")},
        notes="Set in decimilliseconds, answered in microseconds, as seed 000 writes it.",
    ),
    CallSpec(
        C.SET_MOTION_UPDATE_INTERVAL_SCALAR,
        "Servo ticks per motion-queue value; clears the queue.",
        (_p("scalar", 1, 65535, "servo ticks between queue values"),),
        query=(-1,),
        query_reply=_t("MOTION_UPDATE_INTERVAL_SCALAR {value}"),
        debug={1: _t("MOTION UPDATE INTERVAL SCALAR MODIFIED TO {value}")},
    ),
    CallSpec(
        C.SET_CONTROL_MODE,
        "Control mode: 1 position (counts), 2 velocity (counts/s), 3 Hermite keyframes;"
        " clears the queue and the keyframe buffer.",
        (_p("mode", 1, 3, "1 position, 2 velocity, 3 curve"),),
        query=(-1,),
        query_reply=_t("CONTROL_MODE {value}"),
        debug={1: _t("Control Mode MODIFIED TO {value}")},
        notes="Seed 000's example `7 0` names no mode; 0 is refused.",
    ),
    CallSpec(
        C.SET_DEBUG_FLAG,
        "Set the debug flag of an executive call (0 = quiet; undefined values act as 0).",
        (
            _p("call", 0, 63, "the executive call whose flag is set"),
            _p("flag", -1, 255, "the flag value; -1 queries it"),
        ),
        query=(None, -1),
        query_reply=_t("DEBUG_FLAG {call} {flag}"),
        notes="`8 N -1` answers `DEBUG_FLAG N F`. Seed 000's example `6 0 1` means `8 0 1`.",
    ),
    _gain(C.SET_PROPORTIONAL_GAIN, "V per count"),
    _gain(C.SET_INTEGRAL_GAIN, "V per count-second"),
    _gain(C.SET_DERIVATIVE_GAIN, "V-seconds per count"),
    CallSpec(
        C.SET_SIM_UPDATE_INTERVAL,
        "Simulated motor: integration step in decimilliseconds (at most one servo period).",
        (_p("interval_dms", 1, 10000, "motor integration step in tenths of a millisecond"),),
        query=(-1,),
        query_reply=_t("SIM_UPDATE_INTERVAL_DMS {value}"),
        debug={1: _t("SIM UPDATE INTERVAL MODIFIED TO {value} DMS")},
    ),
    _sim_sci(C.SET_SIM_SOURCE_VOLTAGE, "source voltage, the PID output ceiling", "V"),
    _sim_sci(C.SET_SIM_TORQUE_CONSTANT, "torque constant (= back-EMF constant in SI)", "mNm/A"),
    _sim_sci(C.SET_SIM_WINDING_RESISTANCE, "winding resistance", "ohm"),
    CallSpec(
        C.SET_SIM_COUNTS_PER_REVOLUTION,
        "Simulated motor: encoder counts per output revolution (quadrature, x4).",
        (_p("counts", 1, 1_000_000, "counts per revolution"),),
        query=(-1,),
        query_reply=_t("SIM_COUNTS_PER_REVOLUTION {value}"),
        debug={1: _t("SIM COUNTS PER REVOLUTION MODIFIED TO {value}")},
    ),
    _sim_sci(C.SET_SIM_INERTIA, "rotor plus load inertia at the encoder shaft", "kg m^2"),
    CallSpec(
        C.SET_DEVICE_NAME,
        "Device name as N ASCII codes (32..126), written to flash.",
        (_p("length", 0, DEVICE_NAME_MAX, "number of characters"),),
        item=_p("character", 32, 126, "printable ASCII code"),
        query=(-1,),
        query_reply=_t("DEVICE_NAME {text}"),
        debug={1: _t("DEVICE NAME MODIFIED TO {text}")},
        notes="`18 0` erases the name: the device answers to the default name again.",
    ),
    CallSpec(
        C.SET_DEFAULT_CONTROL_MODE,
        "Control mode at power-up, written to flash.",
        (_p("mode", 1, 3, "1 position, 2 velocity, 3 curve"),),
        query=(-1,),
        query_reply=_t("DEFAULT_CONTROL_MODE {value}"),
        debug={1: _t("DEFAULT CONTROL MODE MODIFIED TO {value}")},
    ),
    CallSpec(
        C.STATUS,
        "Status in one line.",
        (_p("query", -1, -1, "always -1"),),
        query=(-1,),
        query_reply=_t(
            "STATUS {clock} {actual} {desired} {velocity} {queued} {enable} {mode}"
            " {limits} {fault}"
        ),
        notes="clock in servo ticks; actual, desired in counts; velocity in counts/s;"
        " limits is a bit mask (1 lower, 2 upper); fault is a fault code (0 none).",
    ),
    CallSpec(
        C.SET_DIAGNOSTICS_INTERVAL,
        "Print a diagnostics line every N servo ticks (0 = off).",
        (_p("ticks", 0, 1_000_000, "servo ticks between diagnostics lines"),),
        query=(-1,),
        query_reply=_t("DIAGNOSTICS_INTERVAL {value}"),
        debug={1: _t("DIAGNOSTICS INTERVAL MODIFIED TO {value}")},
        notes="Diagnostics line: `D <clock> <desired> <actual> <velocity> <output_mv> <queued>"
        " <peak>`, printed on the tick N ticks after the previous one (or after this call)."
        " `peak` is the following error (desired - actual, counts, wrapped to int32 as call"
        " 35 takes it) of the largest magnitude, with its sign, over every tick since the"
        " previous line, this line's tick included; of two ticks with the same magnitude the"
        " earlier one. It counts exactly the ticks call 35 counts (servo enabled in mode 1 or"
        " 3, an armed start reached) and is 0 when none was counted. It restarts after each"
        " line, when this call sets N (any N, 0 included: the next line covers the ticks"
        " after the call), when call 35 resets the statistics, and at power-up; nothing else"
        " restarts it (calls 22, 23 and 37 leave the following error as it was). A host so"
        " sees the peak of every tick, not of the sampled ones.",
    ),
    CallSpec(
        C.CLOCK,
        "Zero the device clock (0) for time synchronisation, or query it (-1).",
        (_p("zero", 0, 0, "0 zeroes the clock"),),
        query=(-1,),
        query_reply=_t("CLOCK {ticks}"),
        debug={1: _t("CLOCK ZEROED")},
    ),
    CallSpec(
        C.SET_POSITION,
        "Set the position counter to V: the same shift as call 37 by V minus the counter.",
        (_p("position", INT32_MIN, INT32_MAX, "counts"),),
        debug={1: _t("POSITION SET TO {value}")},
        notes="A change of coordinates, not of motion: the desired position, the counter's"
        " history and the latched switch edges (call 36) move with the counter, so the error,"
        " the measured velocity, the integrator and the derivative history are unchanged and"
        " the loop goes on as if nothing happened (a moving axis keeps moving, a holding one"
        " holds). The motion queue and the keyframe buffer are cleared: their values were in"
        " the old coordinates.",
    ),
    CallSpec(
        C.LIMITS,
        "Limit switches: 1 when pressed.",
        (_p("query", -1, -1, "always -1"),),
        query=(-1,),
        query_reply=_t("LIMITS {lower} {upper}"),
    ),
    CallSpec(
        C.APPEND_KEYFRAME,
        "Append a Hermite keyframe (curve mode): duration, position, in and out tangents.",
        (
            _p("duration_ms", 1, 65535, "time from the previous keyframe, ms"),
            _p("position", INT32_MIN, INT32_MAX, "counts"),
            _p("tangent_in", -32768, 32767, "counts per ms, signed 6:10 fixed point"),
            _p("tangent_out", -32768, 32767, "counts per ms, signed 6:10 fixed point"),
        ),
        debug={1: _t("KEYFRAME {duration_ms} {position} {tangent_in} {tangent_out}")},
        refusal="E25",
        notes="A full buffer refuses the keyframe with `E25` and keeps what it holds.",
    ),
    CallSpec(
        C.CLEAR_KEYFRAMES,
        "Empty the keyframe buffer; the curve holds its current position.",
        (_p("zero", 0, 0, "always 0"),),
        debug={1: _t("KEYFRAMES CLEARED")},
    ),
    CallSpec(
        C.CURVE_BUFFER,
        "Free keyframe slots.",
        (_p("query", -1, -1, "always -1"),),
        query=(-1,),
        query_reply=_t("CURVE_BUFFER {free}"),
    ),
    CallSpec(
        C.SET_WATCHDOG,
        "Watchdog: no command for this long while enabled disables the servo (0 = off).",
        (_p("timeout_ms", 0, 600_000, "milliseconds"),),
        query=(-1,),
        query_reply=_t("WATCHDOG_MS {value}"),
        debug={1: _t("WATCHDOG MODIFIED TO {value} MS")},
    ),
    CallSpec(
        C.SET_FOLLOWING_ERROR_LIMIT,
        "Following-error limit: a larger error disables the servo and sets a fault (0 = off).",
        (_p("counts", 0, INT32_MAX, "counts"),),
        query=(-1,),
        query_reply=_t("FOLLOWING_ERROR_LIMIT {value}"),
        debug={1: _t("FOLLOWING ERROR LIMIT MODIFIED TO {value}")},
    ),
    CallSpec(
        C.CLEAR_FAULT,
        "Clear a latched fault (0), or query it (-1).",
        (_p("zero", 0, 0, "0 clears the fault"),),
        query=(-1,),
        query_reply=_t("FAULT {code} {tick}"),
        debug={1: _t("FAULT CLEARED")},
        notes="Fault codes: 0 none, 1 watchdog, 2 following error, 3 limit switch, 4"
        " internal error, 5 encoder lost (the RP2040's absolute encoder on the pins).",
    ),
    CallSpec(
        C.START_AT,
        "Hold the motion queue until the device clock reaches tick T (synchronised start).",
        (_p("tick", 0, INT32_MAX, "device clock tick"),),
        query=(-1,),
        query_reply=_t("START_TICK {value}"),
        debug={1: _t("START TICK MODIFIED TO {value}")},
        notes="The query answers -1 when no start is armed.",
    ),
    _sim_sci(C.SET_SIM_VISCOUS_FRICTION, "viscous friction at the encoder shaft", "uNm per rad/s",
             zero=True),
    _sim_sci(C.SET_SIM_LOAD_TORQUE, "constant load torque opposing motion", "mNm", zero=True),
    CallSpec(
        C.SET_SIM_TRAVEL,
        "Simulated axis: travel range in counts; a switch closes at each end.",
        (
            _p("lower", INT32_MIN, INT32_MAX, "lower switch position, counts"),
            _p("upper", INT32_MIN, INT32_MAX, "upper switch position, counts"),
        ),
        query=(-1, -1),
        query_reply=_t("SIM_TRAVEL {lower} {upper}"),
        debug={1: _t("SIM TRAVEL MODIFIED TO {lower} {upper}")},
        notes="The travel is measured in motor counts from power-up (call 23 does not move it);"
        " lower must be below upper.",
    ),
    CallSpec(
        C.MOTION_STATS,
        "Motion statistics: reset them (0) or query them (-1).",
        (_p("reset", 0, 0, "0 resets the statistics"),),
        query=(-1,),
        query_reply=_t("MOTION_STATS {ticks} {max_error} {max_error_tick} {sum_sq_error}"
                       " {last_take_tick}"),
        debug={1: _t("MOTION STATS RESET")},
        notes="Counted on every servo tick the servo runs enabled in mode 1 or 3 (an armed start"
        " reached), since the last"
        " reset: `ticks` counted, the largest absolute following error (desired - actual,"
        " counts) and the clock tick it first occurred at, and the sum of the squared"
        " following errors (it stops at 2^62 instead of overflowing): the exact peak and RMS"
        " following error of a run (each diagnostics line carries the peak since the line"
        " before it: call 21). A reset also restarts the diagnostics line's peak."
        " `last_take_tick` is the clock tick that last took a value from the motion queue"
        " (-1: none since the reset); a reset keeps the clock.",
    ),
    CallSpec(
        C.SWITCH_EDGE,
        "The last edge of a limit switch, latched by core1 on the tick it happened.",
        (_p("switch", 1, 2, "1 lower, 2 upper"),),
        query=(None,),
        query_reply=_t("SWITCH_EDGE {switch} {edges} {closed} {position} {tick}"),
        notes="Always a query. On every servo tick the encoder shows a switch change state"
        " (closing or opening, in any mode, enabled or not) core1 latches the encoder counter"
        " and the clock of that tick: `edges` counts the switch's edges since power-up (modulo"
        " 2^32), `closed` is 1 when the last one closed the switch, `position` is the counter"
        " on that tick and `tick` the clock after it (as call 30 stamps a fault). The position"
        " is kept in the counter's current coordinates: calls 23 and 37 and the velocity-mode"
        " reset move it with the counter. Before the first edge: `0 0 0 0`. A host homes on"
        " this latch, not on when it saw the switch: the zero is exact to the count however"
        " late the host looks. Moving the travel with call 34 is no edge.",
    ),
    CallSpec(
        C.SHIFT_POSITION,
        "Shift the position counter by D counts (a change of coordinates; the loop goes on).",
        (_p("shift", INT32_MIN, INT32_MAX, "counts added to the counter"),),
        debug={1: _t("POSITION SHIFTED BY {value}")},
        notes="The counter, the desired position, the counter's history and the latched switch"
        " edges all move by D (wrapping as the int32 counter does): the following error, the"
        " measured velocity, the integrator and the derivative history are unchanged. Clears"
        " the motion queue and the keyframe buffer (their values were in the old"
        " coordinates). A host sets machine zero from a latched edge with one shift, exact"
        " whatever the axis does meanwhile: `37 (switch position - edge position)`.",
    ),
    CallSpec(
        C.REPLACE_FROM,
        "Replace the motion queue's future from device tick T with N values, in one step.",
        _REPLACEMENT,
        item=_REPLACEMENT_ITEM,
        debug={1: _t("REPLACED {kept} {skipped} {added} CRC {crc}")},
        refusal="E38",
        notes="What a host needs to stop, hold or change a motion already queued without a"
        " seam, whatever the link's latency. While the servo runs, every queued value is due"
        " on a known tick (the next one on the next motion update, then one every"
        " `motion_update_interval_scalar` ticks; with a start armed by call 31, from that"
        " tick). The device keeps the queued values due before tick T (`kept`), drops the"
        " rest, and appends the new values, value k being for tick T + k x scalar: those"
        " already past when the line arrives are dropped (`skipped`), so the first new value"
        " used is the one for the tick it is used on. With the servo disabled nothing is due:"
        " the queue is replaced whole. N = 0 only cuts the queue at T. If the result would not"
        " fit the queue it is refused with `E38` and nothing changes; refused in curve mode"
        " (like calls 0 and 1). Debug flag 1 acknowledges what was done: `added` = N -"
        " `skipped` and `crc` the CRC-32 of the added values, as call 1's flag 2.",
    ),
    CallSpec(
        C.SET_MOTOR,
        "Motor at power-up: the simulated one (0) or the one on the pins (1), written to flash.",
        (_p("motor", 0, 1, "0 the simulated motor, 1 the motor on the pins"),),
        query=(-1,),
        query_reply=_t("MOTOR {stored} {running}"),
        debug={1: _t("MOTOR MODIFIED TO {value}")},
        notes="Takes effect at the next power-up; blank flash is 0, so a bare board runs the"
        " simulated motor. `stored` is what the next power-up runs, `running` what runs now."
        " With the motor on the pins (firmware/README.md has the pin map) the encoder"
        " counter, the limit switches and their edge latch are the pins', the output drives"
        " the H-bridge, and calls 12-17 and 32-34 still set the simulated motor, which then"
        " does not run (call 13's supply voltage stays the output's ceiling and is the"
        " bridge's supply). A step drive (call 44) there issues its steps on STEP, DIR and"
        " EN and runs no simulated stepper: open loop its counter is the steps issued, closed"
        " loop the pins' encoder (call 16's counts per revolution in microsteps, or call"
        " 49's absolute angle). The Python device stores and answers the choice and always"
        " runs its simulated motor or stepper (it has no pins): its `running` is 0.",
    ),
    CallSpec(
        C.SET_SIM_PROBE,
        "Simulated axis: where the probe touches (a plate, a workpiece top): side and position.",
        (
            _p("side", 0, 2, "0 no probe surface, 1 the probe closes at or below position,"
               " 2 at or above it"),
            _p("position", INT32_MIN, INT32_MAX, "the surface, motor counts from power-up"),
        ),
        query=(-1, 0),
        query_reply=_t("SIM_PROBE {side} {position}"),
        debug={1: _t("SIM PROBE MODIFIED TO {side} {position}")},
        notes="The simulated probe input (call 41) closes on every tick the motor's count is at"
        " or beyond the surface on its side, and opens when it leaves it. Measured in motor"
        " counts from power-up like call 34's travel (call 23 does not move it). Power-up: no"
        " surface (0 0). Changing it is no edge: the input takes its new state at once."
        " With the motor on the pins the probe input is the probe pin's.",
    ),
    CallSpec(
        C.PROBE,
        "The probe input: its state now and its last edge, latched by core1 on the tick it"
        " happened.",
        (_p("query", -1, -1, "-1 queries"),),
        query=(-1,),
        query_reply=_t("PROBE {closed} {edges} {edge_closed} {position} {tick}"),
        notes="Always a query. `closed` is 1 while the probe touches. On every servo tick the"
        " probe input changes state (in any mode, enabled or not) core1 latches the encoder"
        " counter and the clock of that tick, as call 36 does for a limit switch: `edges`"
        " counts the probe's edges since power-up (modulo 2^32), `edge_closed` is 1 when the"
        " last one closed it, `position` is the counter on that tick (in the counter's current"
        " coordinates: calls 23 and 37 and the velocity-mode reset move it) and `tick` the"
        " clock after it. Before the first edge: `0 0 0 0`. A probing move stops when the host"
        " sees the edge; the contact position is the latched one, exact to the count however"
        " late the host looks.",
    ),
    CallSpec(
        C.SET_OUTPUT_AT,
        "Set an output (digital or PWM) to a value on a device clock tick: queued, exact to"
        " the tick.",
        (
            _p("output", 0, OUTPUT_COUNT - 1, "0 and 1 digital, 2 and 3 PWM"),
            _p("value", 0, OUTPUT_FULL, "per mille of full duty; a digital output takes 0"
               " or 1000"),
            _p("tick", 0, INT32_MAX, "device clock tick the output takes the value on"),
        ),
        debug={1: _t("OUTPUT {output} TO {value} AT {tick} FREE {free}")},
        refusal="E42",
        notes="The change is kept in a queue of 16 pending changes, in the order given, and"
        " applied by core1 at the start of the servo tick that begins with the clock (calls"
        " 20 and 22) at `tick`: the tick `31 tick` would start the motion on. A tick at or"
        " before the clock applies on the next servo tick. Changes for the same tick apply"
        " in the order given (the last one for an output wins). Outputs are on the clock,"
        " whatever the servo does: enabled or not, in any mode. A full queue refuses the"
        " change with `E42` and keeps what it holds. Refused with `ERR 42 ...`, nothing"
        " changed: a digital output (0, 1) given a value other than 0 or 1000; a tick before"
        " the last pending change's (the queue is in tick order); any change while a fault is"
        " latched (clear it with call 30 first). Debug flag 1 acknowledges a queued change"
        " with the free slots left. Every output is 0 at power-up; when a fault latches (any"
        " fault of the list above, an internal error included) every output goes to 0 on"
        " that tick and the pending changes are dropped, as a grbl alarm turns the spindle"
        " and coolant off. Zeroing the clock (call 22) drops the pending changes (their ticks"
        " were on the old clock) and leaves the outputs as they are. Calls 23 and 37 (a"
        " change of coordinates) change nothing here: outputs are on the clock, not the"
        " position. On the RP2040 (either motor) output 0 is GP13, 1 GP14 (high while 1000),"
        " 2 GP16 and 3 GP17 (PWM, high for `value` per mille of each period:"
        " firmware/README.md); the Python device keeps the values only.",
    ),
    CallSpec(
        C.OUTPUTS,
        "The outputs now, the pending changes and the tick of the last one applied; 1 also"
        " drops every pending change.",
        (_p("clear", 0, 1, "0 only queries, 1 drops every pending change first"),),
        query=(None,),
        query_reply=_t("OUTPUTS {out0} {out1} {out2} {out3} {pending} {last_change_tick}"),
        notes="Always answers. `out0` .. `out3` are the values the outputs hold now (0 .. 1000),"
        " `pending` the changes call 42 queued that are still to come, `last_change_tick` the"
        " clock at the start of the tick that applied the last change (its `tick`, or later"
        " when it was queued late; -1: none since power-up; a fault's zeroing is no change)."
        " `43 1` drops the pending changes and leaves the outputs as they are, as a host's"
        " feed hold or stop needs; the answer is then the state after the drop.",
    ),
    CallSpec(
        C.SET_DRIVE,
        "What the device drives: a DC motor (0), or a stepper driver's step and direction"
        " inputs, open loop (1) or closed loop (2).",
        (_p("drive", 0, 2, "0 DC motor, 1 stepper open loop, 2 stepper closed loop"),),
        query=(-1,),
        query_reply=_t("DRIVE {value}"),
        debug={1: _t("DRIVE MODIFIED TO {value}")},
        notes="Power-up: 0. Refused (`ERR 44 ...`) while the servo is enabled. A change is a"
        " change of motor: the queue and the keyframes are cleared, the position counter and"
        " the steps issued (call 48) start at 0, the simulated shaft at 0 at rest, and the PID"
        " afresh. With a stepper every position is in microsteps (the queue, the counter,"
        " calls 20, 23, 29, 34, 36, 37, 40 and 41) and every velocity in microsteps/s. Each"
        " servo tick the device issues the steps that take its step counter to the position"
        " it commands, at most call 48's `max_per_tick`, spread evenly over the tick"
        " (call 46). Open loop (1) the counter is the steps issued and the command is the"
        " desired position: the following error is what the step rate could not follow."
        " Closed loop (2) the counter is the encoder's (call 16's counts per revolution"
        " converted to microsteps, call 45) and the PID's output, in microsteps saturated at"
        " one full step, is the lead of the driver's field over the rotor: a torque command"
        " that never leads by more than the angle of the greatest torque, so a load beyond"
        " the motor's torque stalls the shaft rather than slipping it; the axis catches up"
        " once the load falls, and a following error beyond call 29's limit is fault 2, as"
        " on a DC axis. In velocity mode (2) a stepper integrates the desired velocity into the"
        " desired position every running tick (the same position loop follows it). The"
        " diagnostics line's `output` is the steps issued on its tick, in thousandths (the"
        " field a DC drive fills with millivolts).",
    ),
    CallSpec(
        C.SET_STEPPER,
        "Stepper: full steps per revolution and microsteps per full step.",
        (
            _p("full_steps", 1, 1000, "full steps per revolution (200: 1.8 degrees)"),
            _p("microsteps", 1, 256, "microsteps per full step, as set on the driver"),
        ),
        query=(-1, 0),
        query_reply=_t("STEPPER {full_steps} {microsteps}"),
        debug={1: _t("STEPPER MODIFIED TO {full_steps} {microsteps}")},
        notes="Power-up: 200 16. The closed loop's encoder counts (call 16) become microsteps"
        " through the microsteps per revolution (`full_steps` x `microsteps`); its output"
        " leads by at most `microsteps` (one full step); the simulated stepper's electrical"
        " cycle is 4 full steps. Clears the queue and the keyframes.",
    ),
    CallSpec(
        C.SET_STEP_TIMING,
        "Step pulse: its high time (the low time is at least as long) and the direction"
        " set-up time before the first pulse after a change of direction.",
        (
            _p("pulse_ns", STEP_PULSE_MIN_NS, 1_000_000, "ns high (and at least as long low)"),
            _p("setup_ns", 0, 1_000_000, "ns from a direction change to the next step edge"),
        ),
        query=(-1, 0),
        query_reply=_t("STEP_TIMING {pulse_ns} {setup_ns}"),
        debug={1: _t("STEP TIMING MODIFIED TO {pulse_ns} {setup_ns}")},
        notes="Power-up: 2000 1000 (within what an A4988, a DRV8825 and a TMC2209 need)."
        " Times are rounded up to whole periods of the 125 MHz step clock (8 ns). The steps"
        " one servo tick can issue: `max_per_tick` = (tick - set-up) // (2 x pulse), in those"
        " periods (call 48 answers it); a tick's steps start after the set-up and are spaced"
        " evenly over the rest of the tick. Refused when not even one step fits a tick.",
    ),
    CallSpec(
        C.SET_SIM_STEPPER,
        "Simulated stepper: holding torque, detent torque and the corner speed above which"
        " the driver's current, and so the torque, falls as 1/speed.",
        (
            _p("holding_mnm", 1, 100_000, "mNm at the rated current"),
            _p("detent_mnm", 0, 100_000, "mNm unpowered (no more than holding)"),
            _p("corner_rpm", 1, 100_000, "revolutions per minute"),
        ),
        query=(-1, 0, 0),
        query_reply=_t("SIM_STEPPER {holding_mnm} {detent_mnm} {corner_rpm}"),
        debug={1: _t("SIM STEPPER MODIFIED TO {holding_mnm} {detent_mnm} {corner_rpm}")},
        notes="Power-up: 590 20 760, a NEMA 17 2 A stepper (PROTOCOL.md, \"The simulated"
        " stepper\"). The simulated stepper runs with drives 1 and 2; calls 12 (integration"
        " step), 16 (its encoder), 17 (inertia), 32 and 33 (friction and load) and 34 (travel,"
        " in microsteps) set the rest of it.",
    ),
    CallSpec(
        C.STEPS,
        "Stepper: the steps issued since the drive was set, the last tick's, and the most a"
        " tick can issue.",
        (_p("query", -1, -1, "-1 queries"),),
        query=(-1,),
        query_reply=_t("STEPS {issued} {last} {max_per_tick}"),
        notes="Always a query. `issued` is the driver's step counter (signed: a step with the"
        " direction low counts -1; it wraps as an int32), the automation document's"
        " `pulses_sent` summed; `last` the signed steps of the last servo tick; `max_per_tick`"
        " what call 46's timing lets one tick issue at the current servo period. With the DC"
        " drive: 0 0 and the same `max_per_tick`.",
    ),
    CallSpec(
        C.SET_ENCODER,
        "The encoder: incremental (0, counting from power-up) or absolute within a turn (1,"
        " an AS5161-style magnetic encoder's PWM angle), and the simulated magnet's angle.",
        (
            _p("kind", 0, 1, "0 incremental (quadrature), 1 absolute within a turn (PWM)"),
            _p("angle", 0, 1_000_000, "simulated: the angle the encoder reads, in counts of"
               " the counter, when the simulated shaft is at 0"),
        ),
        query=(-1, 0),
        query_reply=_t("ENCODER {kind} {angle} {zero}"),
        debug={1: _t("ENCODER MODIFIED TO {kind} {angle}")},
        notes="Power-up: 0 0. Refused while the servo is enabled, and kind 1 on an open-loop"
        " stepper (drive 1: its counter is the steps issued, no encoder). An incremental"
        " encoder counts from 0 at power-up: where the axis stands is unknown until it"
        " homes. Kind 1 makes the counter, at once, the absolute angle within a turn (0 to"
        " a turn less one count: call 16's counts per revolution, or a closed-loop"
        " stepper's microsteps per revolution), and from then on it counts on across turns"
        " (the turns counted by the angle's overflow), as any counter: calls 23 and 37"
        " shift it. The queue and the keyframes are cleared. So a device with one knows"
        " where its axis stands within a turn before it moves; homing tells which turn"
        " (the host zeroes the axis at the turn boundary nearest the switch's edge, which"
        " repeats to the encoder's count however the switch repeats). The simulated magnet"
        " reads `angle` with the simulated shaft at 0 (where it happens to be mounted). On"
        " the RP2040 with the motor on the pins the encoder input is the PWM output of the"
        " encoder on the encoder's channel A pin (GP2), an AS5161-style 12-bit frame of 4351"
        " of its clock periods (128 high, the angle's code 0-4095 high, the rest low), read"
        " as high time over period (the sensor's clock tolerance cancels): 4096 positions a"
        " turn, the counter's angle floor(code x turn / 4096); the counter takes the angle"
        " from the first whole frame after this call (within two frames: 2.2 ms at 920 Hz),"
        " turns counted when the angle moves more than half a turn between frames, and"
        " `angle` is not used (the magnet is where it is). No whole frame for 5 ms: the count"
        " stands and a servo enabled on it latches fault 5 (encoder lost). The query's `zero`"
        " (kind 1) is where the turns begin in the counter's present coordinates: the"
        " counter value, within a turn (0 to a turn less one count), at which the encoder"
        " reads angle 0, so the absolute angle at any counter value c (a latched edge, the"
        " position now) is (c - zero) floored modulo a turn; calls 23 and 37 and the"
        " velocity-mode reset move it with the counter. With kind 0: 0.",
    ),
    CallSpec(
        C.STOP_FROM,
        "Replace the motion queue's future from device tick T with a motion to rest: as"
        " call 38, but a stop that comes late is delayed, never cut short.",
        _REPLACEMENT,
        item=_REPLACEMENT_ITEM,
        debug={1: _t("STOPPED {kept} {late} {added} {offset} CRC {crc}")},
        refusal="E50",
        notes="What a host sends to stop or hold an axis along its deceleration, or to ramp a"
        " velocity (a spindle's) to a new speed, however late the line arrives. On time (the"
        " first value's tick T not yet past: the next motion update is at or before T) it is"
        " call 38: the queued values due before T are kept"
        " (`kept`) and the new values follow, value k for tick T + k x scalar. Late (the"
        " host or the link stalled: the motion update that would take value 0 is already"
        " past), call 38 would drop the values already past and, when every one is past,"
        " leave the axis to stop dead from speed at the last value it took. Call 50 instead"
        " drops the whole queued future and starts the new values on the next motion update,"
        " `late` value periods (of `scalar` ticks) after T, all of them: in mode 1 each"
        " offset by `offset` = (the value the queue had due on that update, or the desired"
        " position when it had none) - value 0, so the axis goes on from where the old"
        " motion had it and decelerates as planned from there (its rest `offset` counts"
        " beyond the planned one); in mode 2 (velocities) not offset. A value that the"
        " offset would take outside int32 refuses the call with `E50` (nothing changes), as"
        " does a result that would not fit the queue, and curve mode (like calls 0, 1 and"
        " 38). With the servo disabled the queue is replaced whole. Debug flag 1"
        " acknowledges what was done: `late` 0 on time, `added` = N, `offset` 0 unless"
        " late, and `crc` the CRC-32 of the values as sent (before the offset).",
    ),
)
BY_NUMBER: Mapping[int, CallSpec] = {spec.number: spec for spec in CALLS}
BY_NAME: Mapping[str, CallSpec] = {spec.name: spec for spec in CALLS}

RESYNC_CALL = BY_NUMBER[C.SET_DEBUG_FLAG].params[0].maximum
"""The call whose debug flag marks a resynchronisation: the highest number call 8 takes,
a call the table does not define, so its flag prints nothing."""
assert RESYNC_CALL not in BY_NUMBER

HOMED_MARKER_CALL = RESYNC_CALL - 1
"""The undefined call whose debug flag (a RAM variable: it survives a host, not a power
cycle) a host sets once it has homed the device: a later host that reads it back knows the
counter still holds the machine coordinates homing gave it."""
assert HOMED_MARKER_CALL not in BY_NUMBER

REFUSALS: Mapping[str, int] = {
    spec.refusal: spec.number for spec in CALLS if spec.refusal is not None
}
"""Refusal line -> the call that gives it."""


DIAGNOSTICS = Template(
    "D {clock} {desired} {actual} {velocity} {output_mv} {queued} {peak}")
"""The line call 21 prints every N servo ticks; ``peak`` is the signed peak following error
since the previous line (call 21's notes)."""

ALARM = Template("ALARM {fault} {tick}")
"""The line the device prints, unasked, at the tick a fault latches (the fault code and
that tick, as call 30 reports them): the host learns of a fault without polling for it."""

ERR = Template("ERR {call} {text}")
"""The device's answer to a malformed line; ``call`` is ``?`` when it cannot be read."""


def spec(number: int) -> CallSpec:
    """The call with this number.

    Raises:
        KeyError: no such call.
    """
    return BY_NUMBER[number]
