"""Typed replies: the lines a device answers, as records with named fields.

Each record is built from its template in the command table by field name (``STATUS
{clock} {actual} ...``), never by position: a reply format changes in one place, the table,
and a record whose template no longer carries a field it reads fails at import.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from usbmotion.errors import UnexpectedReplyError
from usbmotion.protocol.names import CallNumber, ControlMode, fault_words
from usbmotion.protocol.table import (
    ALARM,
    BY_NUMBER,
    DIAGNOSTICS,
    OUTPUT_COUNT,
    OUTPUT_QUEUE_CAPACITY,
    Template,
)


def _reply_template(number: CallNumber) -> Template:
    template = BY_NUMBER[number].query_reply
    assert template is not None, f"call {number.name} answers no query"
    return template


def _debug_template(number: CallNumber, flag: int) -> Template:
    return BY_NUMBER[number].debug[flag]


def _checked(template: Template, *wanted: str) -> Template:
    """``template``, once it is known to carry every field a record reads from it."""
    missing = [name for name in wanted if name not in template.fields]
    if missing:
        raise AssertionError(f"reply format {template.text!r} lacks fields {missing}")
    return template


_STATUS = _checked(_reply_template(CallNumber.STATUS), "clock", "actual", "desired",
                   "velocity", "queued", "enable", "mode", "limits", "fault")
_DIAGNOSTICS = _checked(DIAGNOSTICS, "clock", "desired", "actual", "velocity", "output_mv",
                        "queued", "peak")
_DIAGNOSTICS_ORDER = ("clock", "desired", "actual", "velocity", "output_mv", "queued", "peak")
if tuple(_DIAGNOSTICS.fields) != _DIAGNOSTICS_ORDER:
    raise AssertionError(f"reply format {DIAGNOSTICS.text!r}: fields not in the order"
                         f" {_DIAGNOSTICS_ORDER} that Diagnostics declares them")
_DIAGNOSTICS_FIELDS = len(_DIAGNOSTICS_ORDER)
"""A ``D`` line's fields are :class:`Diagnostics`'s, in its order."""
_CLOCK, _DESIRED, _ACTUAL, _QUEUED, _PEAK = (
    _DIAGNOSTICS_ORDER.index(name) for name in ("clock", "desired", "actual", "queued", "peak"))
_ALARM = _checked(ALARM, "fault", "tick")
_SWITCH_EDGE = _checked(_reply_template(CallNumber.SWITCH_EDGE), "switch", "edges", "closed",
                        "position", "tick")
_PROBE = _checked(_reply_template(CallNumber.PROBE), "closed", "edges", "edge_closed",
                  "position", "tick")
_OUTPUT_FIELDS = tuple(f"out{output}" for output in range(OUTPUT_COUNT))
_OUTPUTS = _checked(_reply_template(CallNumber.OUTPUTS), *_OUTPUT_FIELDS, "pending",
                    "last_change_tick")
_MOTION_STATS = _checked(_reply_template(CallNumber.MOTION_STATS), "ticks", "max_error",
                         "max_error_tick", "sum_sq_error", "last_take_tick")
_STEPS = _checked(_reply_template(CallNumber.STEPS), "issued", "last", "max_per_tick")
_ENCODER = _checked(_reply_template(CallNumber.SET_ENCODER), "kind", "angle", "zero")
REPLACED = _checked(_debug_template(CallNumber.REPLACE_FROM, 1), "kept", "skipped", "added",
                    "crc")
"""Call 38's acknowledgement (debug flag 1) and the fields it carries."""

STOPPED = _checked(_debug_template(CallNumber.STOP_FROM, 1), "kept", "late", "added",
                   "offset", "crc")
"""Call 50's acknowledgement (debug flag 1) and the fields it carries."""


def _read(template: Template, values: Sequence[int]) -> Mapping[str, int]:
    """The values of a line of ``template`` by field name.

    Raises:
        UnexpectedReplyError: the values are not as many as the template's fields.
    """
    if len(values) != len(template.fields):
        raise UnexpectedReplyError(
            f"{template.head}: {len(values)} values for the {len(template.fields)} fields of"
            f" {template.text!r}")
    return dict(zip(template.fields, values, strict=True))


LOWER_SWITCH = 1
"""Call 36's number for the lower limit switch, and its bit in the status mask."""
UPPER_SWITCH = 2
"""Call 36's number for the upper limit switch, and its bit in the status mask."""


@dataclass(frozen=True, slots=True)
class Status:
    """The device's one-line status (call 20)."""

    clock: int
    actual_counts: int
    desired_counts: int
    velocity_counts_s: int
    queued: int
    enabled: bool
    mode: ControlMode
    lower_limit: bool
    upper_limit: bool
    fault: int

    @classmethod
    def from_values(cls, values: Sequence[int]) -> Status:
        """The status from the values of a ``STATUS`` line."""
        v = _read(_STATUS, values)
        return cls(
            clock=v["clock"], actual_counts=v["actual"], desired_counts=v["desired"],
            velocity_counts_s=v["velocity"], queued=v["queued"], enabled=v["enable"] == 1,
            mode=ControlMode(v["mode"]), lower_limit=bool(v["limits"] & LOWER_SWITCH),
            upper_limit=bool(v["limits"] & UPPER_SWITCH), fault=v["fault"],
        )

    @property
    def fault_name(self) -> str:
        """The fault in words (``none`` when there is none)."""
        return fault_words(self.fault)


@dataclass(frozen=True, slots=True)
class Diagnostics:
    """One diagnostics line (call 21)."""

    clock: int
    desired: int
    """Counts (mode 1 and 3), or counts/s (mode 2: the desired velocity)."""
    actual_counts: int
    velocity_counts_s: int
    output_mv: int
    queued: int
    """Values in the motion queue, or keyframes buffered in mode 3."""
    peak_error_counts: int
    """The following error (desired - actual) of the largest magnitude, signed, over every
    tick the statistics (call 35) counted since the previous line, this line's tick
    included; 0 when none was counted."""

    @classmethod
    def from_values(cls, values: Sequence[int]) -> Diagnostics:
        """The record from the values of a ``D`` line."""
        if len(values) == _DIAGNOSTICS_FIELDS:  # the line's fields are the record's, in order
            return cls(*values)
        v = _read(_DIAGNOSTICS, values)
        return cls(clock=v["clock"], desired=v["desired"], actual_counts=v["actual"],
                   velocity_counts_s=v["velocity"], output_mv=v["output_mv"],
                   queued=v["queued"], peak_error_counts=v["peak"])


FEW_DIAGNOSTICS = 8
"""Fewer diagnostics lines than this are read and taken one by one rather than as arrays:
numpy's cost per call is more than a few lines' in Python."""


class DiagnosticsBlock:
    """Diagnostics lines of one device, oldest first: one row per line of the line's fields
    in :class:`Diagnostics`'s order (converted by numpy in one pass), or the lines' values
    as read one by one (a few lines: :data:`FEW_DIAGNOSTICS`); each field also as an array
    with one value per line.

    Parameters:
        rows: the rows, as an array (n, 7).
        values: instead, the values of each line.
    """

    __slots__ = ("_rows", "_values")

    def __init__(self, rows: npt.NDArray[np.int64] | None = None, *,
                 values: Sequence[tuple[int, ...]] = ()) -> None:
        self._rows = rows
        self._values = values

    def __len__(self) -> int:
        return len(self._values) if self._rows is None else int(self._rows.shape[0])

    @property
    def rows(self) -> npt.NDArray[np.int64]:
        """One row per line, the line's fields in :class:`Diagnostics`'s order."""
        if self._rows is None:
            self._rows = np.array(self._values, dtype=np.int64).reshape(
                len(self._values), _DIAGNOSTICS_FIELDS)
        return self._rows

    @property
    def clock(self) -> npt.NDArray[np.int64]:
        """Each line's device clock, ticks."""
        return self.rows[:, _CLOCK]

    @property
    def desired(self) -> npt.NDArray[np.int64]:
        """Each line's desired position, counts (counts/s in mode 2)."""
        return self.rows[:, _DESIRED]

    @property
    def actual_counts(self) -> npt.NDArray[np.int64]:
        """Each line's measured position, counts."""
        return self.rows[:, _ACTUAL]

    @property
    def queued(self) -> npt.NDArray[np.int64]:
        """Each line's queue level (keyframes buffered in mode 3)."""
        return self.rows[:, _QUEUED]

    @property
    def peak_error_counts(self) -> npt.NDArray[np.int64]:
        """Each line's signed peak following error since the line before, counts."""
        return self.rows[:, _PEAK]

    def lines(self) -> list[Diagnostics]:
        """Each line as a :class:`Diagnostics`, oldest first."""
        values = self._values if self._rows is None else self._rows.tolist()
        return [Diagnostics(*line) for line in values]


@dataclass(frozen=True, slots=True)
class Alarm:
    """An ``ALARM`` line: the device latched a fault and said so unasked."""

    fault: int
    tick: int

    @classmethod
    def from_values(cls, values: Sequence[int]) -> Alarm:
        """The alarm from the values of an ``ALARM`` line."""
        v = _read(_ALARM, values)
        return cls(fault=v["fault"], tick=v["tick"])

    @property
    def fault_name(self) -> str:
        """The fault's name (``following error``, ``limit switch``, ...)."""
        return fault_words(self.fault)


@dataclass(frozen=True, slots=True)
class SwitchEdge:
    """Call 36: the last edge of one limit switch, latched by the device on its tick.

    ``edges`` counts the switch's edges since power-up (modulo 2**32; 0: none yet),
    ``closed`` says whether the last one closed it, ``position_counts`` is the counter on
    that tick (in the counter's current coordinates) and ``tick`` the clock after it.
    """

    switch: int
    edges: int
    closed: bool
    position_counts: int
    tick: int

    @classmethod
    def from_values(cls, values: Sequence[int]) -> SwitchEdge:
        """The edge from the values of a ``SWITCH_EDGE`` line."""
        v = _read(_SWITCH_EDGE, values)
        return cls(switch=v["switch"], edges=v["edges"], closed=v["closed"] == 1,
                   position_counts=v["position"], tick=v["tick"])


@dataclass(frozen=True, slots=True)
class Steps:
    """Call 48: a step/direction drive's step counter.

    ``issued`` is the driver's step counter since the drive was set (signed, wrapping as an
    int32), ``last`` the signed steps of the last servo tick, ``max_per_tick`` the most one
    tick can issue with the driver's timing (call 46) at the servo period.
    """

    issued: int
    last: int
    max_per_tick: int

    @classmethod
    def from_values(cls, values: Sequence[int]) -> Steps:
        """The step counter from the values of a ``STEPS`` line."""
        v = _read(_STEPS, values)
        return cls(issued=v["issued"], last=v["last"], max_per_tick=v["max_per_tick"])


@dataclass(frozen=True, slots=True)
class EncoderSetting:
    """Call 49: the encoder's kind (0 incremental, 1 absolute within a turn), the simulated
    magnet's angle, and ``zero``: with an absolute encoder, the counter value (within a turn)
    at which the encoder reads angle 0, in the counter's present coordinates; the absolute
    angle of any counter value ``c`` is ``(c - zero) % turn``.
    """

    kind: int
    angle: int
    zero: int

    @property
    def absolute(self) -> bool:
        """True for an absolute encoder."""
        return self.kind == 1

    @classmethod
    def from_values(cls, values: Sequence[int]) -> EncoderSetting:
        """The setting from the values of an ``ENCODER`` line."""
        v = _read(_ENCODER, values)
        return cls(kind=v["kind"], angle=v["angle"], zero=v["zero"])


@dataclass(frozen=True, slots=True)
class ProbeState:
    """Call 41: the probe input now and its last edge, latched by the device on its tick.

    ``closed`` is True while the probe touches; ``edges`` counts its edges since power-up
    (modulo 2**32; 0: none yet), ``edge_closed`` says whether the last one closed it,
    ``position_counts`` is the counter on that tick (in the counter's current coordinates)
    and ``tick`` the clock after it.
    """

    closed: bool
    edges: int
    edge_closed: bool
    position_counts: int
    tick: int

    @classmethod
    def from_values(cls, values: Sequence[int]) -> ProbeState:
        """The state from the values of a ``PROBE`` line."""
        v = _read(_PROBE, values)
        return cls(closed=v["closed"] == 1, edges=v["edges"], edge_closed=v["edge_closed"] == 1,
                   position_counts=v["position"], tick=v["tick"])


@dataclass(frozen=True, slots=True)
class Outputs:
    """Call 43: the outputs now and the changes call 42 queued that are still to come.

    ``values`` holds each output's value (0 .. 1000, per mille of full duty; outputs 0 and
    1 are digital: 0 or 1000), ``pending`` the changes still queued, ``last_change_tick``
    the device clock at the start of the tick that applied the last change (-1: none since
    power-up).
    """

    values: tuple[int, ...]
    pending: int
    last_change_tick: int

    @classmethod
    def from_values(cls, values: Sequence[int]) -> Outputs:
        """The state from the values of an ``OUTPUTS`` line."""
        v = _read(_OUTPUTS, values)
        return cls(values=tuple(v[name] for name in _OUTPUT_FIELDS), pending=v["pending"],
                   last_change_tick=v["last_change_tick"])

    @property
    def free(self) -> int:
        """Changes call 42 can still queue."""
        return OUTPUT_QUEUE_CAPACITY - self.pending


@dataclass(frozen=True, slots=True)
class Replaced:
    """What call 38 did: queued values kept (due before the tick), new values skipped
    (already past when the line arrived) and added."""

    kept: int
    skipped: int
    added: int


@dataclass(frozen=True, slots=True)
class Stopped:
    """What call 50 did: queued values kept (due before the tick), the value periods the
    stop came late (0: on time), the values added (all of them) and the counts each was
    offset by (mode 1, late: where the axis had got to), so the axis rests that far beyond
    the stop's last value."""

    kept: int
    late: int
    added: int
    offset: int


@dataclass(frozen=True, slots=True)
class MotionStats:
    """Call 35: the device's own account of how it followed, tick by tick, since a reset.

    Counted on every servo tick the servo ran enabled in position or curve mode (after any
    armed start): ``ticks`` of them, the largest absolute following error and the clock
    tick it first occurred at, the sum of the squared errors, and the clock tick that last
    took a value from the motion queue (-1: none).
    """

    ticks: int
    max_error_counts: int
    max_error_tick: int
    sum_sq_error: int
    last_take_tick: int

    @classmethod
    def from_values(cls, values: Sequence[int]) -> MotionStats:
        """The statistics from the values of a ``MOTION_STATS`` line."""
        v = _read(_MOTION_STATS, values)
        return cls(ticks=v["ticks"], max_error_counts=v["max_error"],
                   max_error_tick=v["max_error_tick"], sum_sq_error=v["sum_sq_error"],
                   last_take_tick=v["last_take_tick"])

    @property
    def rms_error_counts(self) -> float:
        """Root mean square following error over the ticks counted, counts (0 with none)."""
        return math.sqrt(self.sum_sq_error / self.ticks) if self.ticks else 0.0


def read_stopped(values: Sequence[int]) -> tuple[Stopped, int]:
    """Call 50's acknowledgement: what it did, and the CRC-32 of the values as sent."""
    v = _read(STOPPED, values)
    return (Stopped(kept=v["kept"], late=v["late"], added=v["added"], offset=v["offset"]),
            v["crc"])


def read_replaced(values: Sequence[int]) -> tuple[Replaced, int]:
    """Call 38's acknowledgement: what it did, and the CRC-32 of the values it added."""
    v = _read(REPLACED, values)
    return Replaced(kept=v["kept"], skipped=v["skipped"], added=v["added"]), v["crc"]
