"""The device client: one typed, validated method per executive call.

The firmware trusts its host and validates nothing (seed 000); this client is the safety.
Every value is checked against the command table before a byte is sent, and an invalid
one raises a ``ValueError`` subclass naming the parameter, the value and the range.
Setters are confirmed: each is followed by a queue-status query, so an ``ERR`` the device
answers is raised here, attached to the call that caused it.
"""

from __future__ import annotations

import contextlib
import math
import random
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from usbmotion.clock import Clock
from usbmotion.errors import (
    ArgumentError,
    DeviceTimeoutError,
    ErrReplyError,
    LinkCorruptedError,
    OutOfRangeError,
    QueueFullError,
    UnexpectedReplyError,
)
from usbmotion.hermite import Keyframe
from usbmotion.host.transport import LineTransport
from usbmotion.protocol import (
    BY_NUMBER,
    FEW_DIAGNOSTICS,
    Alarm,
    ControlMode,
    Diagnostics,
    DiagnosticsBlock,
    Drive,
    EncoderSetting,
    MotionStats,
    Outputs,
    ProbeState,
    Replaced,
    Reply,
    ReplyKind,
    Status,
    Steps,
    SwitchEdge,
    encode_call,
    encode_counted,
    encode_device_name,
    parse_diagnostics,
    parse_diagnostics_lines,
    parse_reply,
    values_crc32,
)
from usbmotion.protocol import CallNumber as C
from usbmotion.protocol.replies import Stopped, read_replaced, read_stopped
from usbmotion.protocol.table import DIAGNOSTICS, HOMED_MARKER_CALL, RESYNC_CALL

GAIN_CALLS = (C.SET_PROPORTIONAL_GAIN, C.SET_INTEGRAL_GAIN, C.SET_DERIVATIVE_GAIN)
"""The PID's gain calls: kp, ki, kd."""

SIM_SCIENTIFIC_CALLS = (
    C.SET_SIM_SOURCE_VOLTAGE, C.SET_SIM_TORQUE_CONSTANT, C.SET_SIM_WINDING_RESISTANCE,
    C.SET_SIM_INERTIA, C.SET_SIM_VISCOUS_FRICTION, C.SET_SIM_LOAD_TORQUE,
)
"""The simulated motor's calls that take a value as 4 significant digits."""

HELD_LINES = 4096
"""The most diagnostics lines a client holds for a block listener
(:attr:`DeviceClient.on_diagnostics_block`) before it hands them over by itself."""
_DIAGNOSTICS_HEAD = DIAGNOSTICS.head.encode("ascii") + b" "
_QUEUE_QUERY = encode_call(C.MOTION_QUEUE, -1)
"""Call 2's query, the line behind every setter and batch."""
_INT64_MIN, _INT64_MAX = -(1 << 63), (1 << 63) - 1

_MARKERS = random.Random()
"""Draws the marker values: its own generator, seeded from the operating system, so a
program that seeds :mod:`random` does not make two hosts draw the same markers."""


def to_sci(value: float, *, digits: int, parameter: str) -> tuple[int, int]:
    """``value`` as ``(coefficient, exponent)`` with at most ``digits`` significant digits.

    The value is rounded to that many digits; zero is ``(0, 0)``.

    Raises:
        OutOfRangeError: NaN, infinite or negative where the table forbids it.
    """
    if not math.isfinite(value):
        raise OutOfRangeError(f"{parameter} {value!r} is not a finite number", reason=parameter)
    if value == 0:
        return (0, 0)
    exponent = math.floor(math.log10(abs(value))) - (digits - 1)
    coefficient = round(value / 10.0**exponent)
    if abs(coefficient) >= 10**digits:
        coefficient = round(coefficient / 10)
        exponent += 1
    return (coefficient, exponent)


def from_sci(coefficient: int, exponent: int) -> float:
    """The float value of ``coefficient * 10**exponent``."""
    return coefficient * 10.0**exponent


@dataclass(frozen=True, slots=True)
class AxisScale:
    """Units at the boundary: how many encoder counts make one millimetre."""

    counts_per_mm: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.counts_per_mm) and self.counts_per_mm > 0):
            raise ArgumentError(
                f"counts_per_mm {self.counts_per_mm!r} must be a finite number > 0",
                reason="counts_per_mm",
            )

    def to_counts(self, mm: float) -> int:
        """Millimetres to the nearest count."""
        return round(mm * self.counts_per_mm)

    def to_mm(self, counts: float) -> float:
        """Counts to millimetres."""
        return counts / self.counts_per_mm


class DeviceClient:
    """A USB Motion Device on a :class:`LineTransport`.

    Parameters:
        transport: the open link.
        name: how errors name the device (defaults to the link's label).
        timeout_s: how long to wait for a reply, on the link's clock.
        scale: counts per mm, for the ``*_mm`` helpers.
        on_diagnostics: called with each diagnostics line that arrives.
    """

    def __init__(
        self,
        transport: LineTransport,
        *,
        name: str = "",
        timeout_s: float = 1.0,
        scale: AxisScale | None = None,
        on_diagnostics: Callable[[Diagnostics], None] | None = None,
    ) -> None:
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ArgumentError(f"timeout_s {timeout_s!r} must be > 0", reason="timeout_s")
        self.transport = transport
        self.name = name or transport.label
        self.timeout_s = timeout_s
        self.scale = scale
        self.on_diagnostics = on_diagnostics
        self.refusals = 0
        self.debug_lines: list[Reply] = []
        self.alarms: list[Alarm] = []
        """Every ``ALARM`` line read so far, oldest first."""
        self.on_alarm: Callable[[Alarm], None] | None = None
        """Called with each ``ALARM`` line as it is read."""
        self.on_diagnostics_block: Callable[[DiagnosticsBlock], None] | None = None
        """While set (and :attr:`on_diagnostics` is not), diagnostics lines are held as they
        are read and handed to it in blocks by :meth:`deliver_diagnostics`."""
        self._held: list[bytes] = []
        self.stray_lines = 0
        """Lines :meth:`read_pending` found that no call was waiting for (dropped)."""
        self._acknowledging: set[int] = set()
        """The calls whose debug flag 1 (their acknowledgement) this client has set."""
        self._answer_owed = False
        """An answer did not come in time: it may still come, so the next exchange first
        brings the link back in step (:meth:`_realign`)."""

    @classmethod
    def open(cls, url: str, *, timeout_s: float = 1.0, name: str = "") -> DeviceClient:
        """Open a device by port path or URL (``sim://NAME`` included)."""
        return cls(LineTransport.open(url, label=name or url), name=name, timeout_s=timeout_s)

    # --- listeners -------------------------------------------------------------------------

    @contextlib.contextmanager
    def listening(
        self,
        *,
        diagnostics: Callable[[Diagnostics], None] | None = None,
        alarms: Callable[[Alarm], None] | None = None,
        diagnostics_block: Callable[[DiagnosticsBlock], None] | None = None,
    ) -> Iterator[DeviceClient]:
        """Hand diagnostics lines and ``ALARM`` lines to these callbacks while the block runs.

        The callbacks given replace the ones in place for the block only; on leaving it,
        however it is left, the previous ones are back. ``None`` leaves that kind of line
        to the callback already in place. ``diagnostics_block`` takes the diagnostics lines
        in blocks instead of one by one: they are held as they are read and handed over
        by :meth:`deliver_diagnostics` (those still held when the block ends, then).

        Raises:
            ArgumentError: both ``diagnostics`` and ``diagnostics_block`` were given.
        """
        if diagnostics is not None and diagnostics_block is not None:
            raise ArgumentError("listening takes diagnostics or diagnostics_block, not both",
                                reason="diagnostics")
        self.deliver_diagnostics()
        previous = (self.on_diagnostics, self.on_diagnostics_block, self.on_alarm)
        if diagnostics is not None:
            self.on_diagnostics, self.on_diagnostics_block = diagnostics, None
        if diagnostics_block is not None:
            self.on_diagnostics, self.on_diagnostics_block = None, diagnostics_block
        if alarms is not None:
            self.on_alarm = alarms
        try:
            yield self
        finally:
            try:
                self.deliver_diagnostics()
            finally:
                self.on_diagnostics, self.on_diagnostics_block, self.on_alarm = previous

    # --- plumbing ------------------------------------------------------------------------

    @property
    def link_clock(self) -> Clock:
        """The clock this device's link waits on (the wall clock, or a simulation's)."""
        return self.transport.clock

    def send(self, number: int, *args: int) -> None:
        """Validate and send one call without waiting for anything."""
        self.transport.write(encode_call(number, *args))

    def send_with_status(self, number: int, *args: int) -> None:
        """Send one call and a queue-status query behind it in the same write, without
        waiting: the status answer (:meth:`next_reply`) says the call has executed."""
        self.transport.write(encode_call(number, *args) + _QUEUE_QUERY)

    def send_counted_with_status(self, number: int, lead: Sequence[int],
                                 items: Sequence[int] | npt.NDArray[np.integer]) -> None:
        """As :meth:`send_with_status` for a counted call (``number``, ``lead``, the count
        and the ``items``: a batch of setpoints), its items checked and written as one
        array (:func:`~usbmotion.protocol.codec.encode_counted`)."""
        self.transport.write(encode_counted(number, lead, items) + _QUEUE_QUERY)

    def send_queue_query(self) -> None:
        """Call 2's query (the queue's level and room), without waiting: its answer is read
        by :meth:`next_reply`."""
        self.transport.write(_QUEUE_QUERY)

    def take_debug_lines(self, number: int) -> list[Reply]:
        """The debug lines of call ``number`` read so far (oldest first), no longer kept."""
        taken = [r for r in self.debug_lines if r.call == number]
        if taken:
            self.debug_lines = [r for r in self.debug_lines if r.call != number]
        return taken

    def take_aside(self, reply: Reply) -> bool:
        """Consume lines that are not answers (diagnostics, debug echoes, alarms).

        Returns True if the line was consumed.
        """
        if reply.kind is ReplyKind.DIAGNOSTICS:
            if self.on_diagnostics is not None:
                self.on_diagnostics(Diagnostics.from_values(reply.values))
            elif self.on_diagnostics_block is not None:
                self._held.append(reply.line.encode("ascii"))
            return True
        if reply.kind is ReplyKind.DEBUG:
            self.debug_lines.append(reply)
            return True
        if reply.kind is ReplyKind.ALARM:
            alarm = Alarm.from_values(reply.values)
            self.alarms.append(alarm)
            if self.on_alarm is not None:
                self.on_alarm(alarm)
            return True
        return False

    def read_pending(self) -> None:
        """Take in, without waiting or sending, every line that has arrived.

        For between exchanges, when no answer is awaited: diagnostics lines, debug lines
        and alarms are taken as :meth:`take_aside` does; any other line is an answer no
        call is waiting for (a late one, or a damaged line), counted in
        :attr:`stray_lines` and dropped.

        Raises:
            LinkLostError: the port is gone.
        """
        held = (self._held if self.on_diagnostics is None
                and self.on_diagnostics_block is not None else None)
        for line in self.transport.poll_lines():
            if held is not None and line[:2] == _DIAGNOSTICS_HEAD:
                held.append(line)
                continue
            values = parse_diagnostics(line)
            if values is not None:
                if self.on_diagnostics is not None:
                    self.on_diagnostics(Diagnostics.from_values(values))
                continue
            try:
                reply = parse_reply(line)
            except UnexpectedReplyError:
                self.stray_lines += 1
                continue
            if not self.take_aside(reply):
                self.stray_lines += 1
        if held is not None and len(held) >= HELD_LINES:
            self.deliver_diagnostics()

    def deliver_diagnostics(self) -> None:
        """Hand the diagnostics lines held for :attr:`on_diagnostics_block` to it, in one
        block, oldest first (nothing when none are held). A held line that is no diagnostics
        line after all is counted in :attr:`stray_lines` and dropped, as
        :meth:`read_pending` drops it."""
        lines = self._held
        if not lines:
            return
        self._held = []
        rows = parse_diagnostics_lines(lines) if len(lines) >= FEW_DIAGNOSTICS else None
        block = (DiagnosticsBlock(rows) if rows is not None
                 else DiagnosticsBlock(values=self._diagnostics_values(lines)))
        listener = self.on_diagnostics_block
        if listener is not None and len(block):
            listener(block)

    def _diagnostics_values(self, lines: list[bytes]) -> list[tuple[int, ...]]:
        """The values of ``lines`` read one by one (the stray ones counted and left out)."""
        kept: list[tuple[int, ...]] = []
        for line in lines:
            values = parse_diagnostics(line)
            if values is None:
                try:
                    reply = parse_reply(line)
                except UnexpectedReplyError:
                    reply = None
                if reply is None or reply.kind is not ReplyKind.DIAGNOSTICS:
                    self.stray_lines += 1
                    continue
                values = reply.values
            if min(values) >= _INT64_MIN and max(values) <= _INT64_MAX:
                kept.append(values)
            else:
                self.stray_lines += 1
        return kept

    def next_reply(self, timeout_s: float | None = None) -> Reply:
        """The next line that is not a diagnostics, debug or alarm line (those are taken
        aside as :meth:`take_aside` does): an answer, an ``ERR`` or a refusal.

        Parameters:
            timeout_s: how long to wait, on the link's clock (default: the reply timeout).

        Raises:
            DeviceTimeoutError: nothing within the timeout.
            UnexpectedReplyError: a line that is no reply of the protocol (it is consumed).
        """
        wait_s = self.timeout_s if timeout_s is None else timeout_s
        while True:
            try:
                line = self.transport.read_line(wait_s)
            except DeviceTimeoutError as error:
                raise DeviceTimeoutError(str(error), device=self.name) from error
            try:
                reply = parse_reply(line)
            except UnexpectedReplyError as error:
                raise UnexpectedReplyError(f"{self.name}: {error}") from error
            if not self.take_aside(reply):
                return reply

    def query(self, number: int, *args: int) -> Reply:
        """Send a query and return its answer.

        Raises:
            ErrReplyError: the device answered ``ERR``.
            DeviceTimeoutError: no answer in time (names the device and the call).
            UnexpectedReplyError: an answer that belongs to no query of this call.
        """
        self._realign()
        self.send(number, *args)
        return self._await_answer(number)

    def _realign(self) -> None:
        """After an answer that did not come in time, make sure it cannot be taken for the
        answer to a later call: send a marker (the debug flag of call :data:`RESYNC_CALL`
        set to a random value, queried, set back to 0) and read up to its answer, skipping
        the late answers before it. Diagnostics and alarm lines on the way are taken as
        always (unlike :meth:`resynchronise`, nothing is discarded unread).

        Raises:
            DeviceTimeoutError: the marker did not come back either (the link stays owed).
        """
        if not self._answer_owed:
            return
        value = _MARKERS.randint(1, 255)
        self.transport.write(encode_call(C.SET_DEBUG_FLAG, RESYNC_CALL, value)
                             + encode_call(C.SET_DEBUG_FLAG, RESYNC_CALL, -1)
                             + encode_call(C.SET_DEBUG_FLAG, RESYNC_CALL, 0))
        while True:
            try:
                reply = self.next_reply()
            except UnexpectedReplyError:
                self.stray_lines += 1
                continue
            except DeviceTimeoutError as error:
                raise DeviceTimeoutError(
                    f"{self.name}: no answer within {self.timeout_s:g} s, twice: the link is"
                    " stalled or the device is gone", device=self.name,
                    call=C.SET_DEBUG_FLAG) from error
            if (reply.kind is ReplyKind.QUERY and reply.call == C.SET_DEBUG_FLAG
                    and reply.values == (RESYNC_CALL, value)):
                self._answer_owed = False
                return
            self.stray_lines += 1

    def _await_answer(self, number: int, *, after_error: bool = False) -> Reply:
        """Read up to the answer of call ``number``.

        With ``after_error`` the answer is known to follow an ``ERR`` or a refusal
        (a setter sent with a sync query behind it): the first such line is raised
        only once the answer has been read, so the link stays in step.
        """
        failure: Exception | None = None
        while True:
            try:
                reply = self.next_reply()
            except DeviceTimeoutError as error:
                self._answer_owed = True
                raise DeviceTimeoutError(
                    f"{self.name}: no answer to call {number} within {self.timeout_s:g} s",
                    device=self.name, call=number,
                ) from error
            problem: Exception | None = None
            if reply.kind is ReplyKind.ERROR:
                problem = ErrReplyError(
                    f"{self.name}: device answered {reply.line!r}", device=self.name,
                    call=reply.call if reply.call is not None else number,
                )
            elif reply.kind is ReplyKind.REFUSAL:
                self.refusals += 1
                problem = QueueFullError(
                    f"{self.name}: device refused with {reply.key}", device=self.name,
                    call=reply.call,
                )
            elif reply.kind is ReplyKind.QUERY and reply.call == number:
                if failure is not None:
                    raise failure
                return reply
            else:
                problem = UnexpectedReplyError(
                    f"{self.name}: expected the answer to call {number}, got {reply.line!r}"
                )
            if not after_error:
                raise problem
            failure = failure or problem

    def command(self, number: int, *args: int) -> None:
        """Send a setter and confirm the device took it (an ``ERR`` raises here).

        Raises:
            OutOfRangeError: a value outside the call's range, the query form included
                (``-1`` queries, it does not set).
        """
        call_spec = BY_NUMBER.get(number)
        if call_spec is not None and call_spec.is_query(args):
            for param, value in zip(call_spec.params, args, strict=False):
                why = param.check(value)
                if why is not None:
                    raise OutOfRangeError(why, call=number, reason=why)
        self._confirm(encode_call(number, *args))

    def _confirm(self, line: bytes) -> Reply:
        """Send ``line`` with a queue-status query behind it, and read up to its answer: an
        ``ERR`` or a refusal the line caused is raised here, once the link is in step again.
        """
        self._realign()
        self.transport.write(line + _QUEUE_QUERY)
        return self._await_answer(C.MOTION_QUEUE, after_error=True)

    def sync(self) -> tuple[int, int]:
        """Wait until every call sent so far has been executed; returns (queued, free)."""
        return self.queue_status()

    def resynchronise(
        self,
        *,
        stop_diagnostics: bool = False,
        timeout_s: float | None = None,
        on_skipped: Callable[[bytes], None] | None = None,
    ) -> int:
        """Bring the link back in step: afterwards no line left from before is in the way.

        For a link taken over from a host that died or left, or one whose bytes were
        damaged: the next reply read is the answer to the next call sent. The input is
        discarded (the transport then drops up to the next newline: the tail of a line
        in flight), and in one write the device gets a newline (ending any partial line
        an earlier host left in its input), optionally ``21 0``, then ``2 -1`` (its
        answer is the line that may be dropped), then the marker: the debug flag of call
        :data:`RESYNC_CALL` set to a random value, queried and set back to 0. Every line
        up to the answer that carries that value is skipped: diagnostics, echoes, line
        tails, answers meant for another host, and the marker of an earlier
        resynchronisation still in flight (unless it drew the same value, 1 in 255).
        Skipped lines are not passed to ``on_diagnostics`` or kept as debug lines: they
        belong to whoever sent the calls.

        Parameters:
            stop_diagnostics: send ``21 0`` first, so no diagnostics line follows.
            timeout_s: how long the marker has to come back, on the link's clock
                (default: the reply timeout); the clock runs from the write, however
                many lines arrive meanwhile.
            on_skipped: called with each line skipped.

        Returns:
            How many lines were skipped (the answer to ``2 -1`` among them when it was
            not the line dropped).

        Raises:
            DeviceTimeoutError: the marker did not come back in time (names the device).
            LinkLostError: the port is gone.
        """
        wait_s = self.timeout_s if timeout_s is None else timeout_s
        if not (math.isfinite(wait_s) and wait_s > 0):
            raise ArgumentError(f"timeout_s {timeout_s!r} must be > 0", reason="timeout_s")
        value = _MARKERS.randint(1, 255)
        marker_spec = BY_NUMBER[C.SET_DEBUG_FLAG].query_reply
        assert marker_spec is not None
        marker = marker_spec.format(RESYNC_CALL, value).encode("ascii")
        transport = self.transport
        transport.discard_input()
        transport.write(
            b"\n"
            + (encode_call(C.SET_DIAGNOSTICS_INTERVAL, 0) if stop_diagnostics else b"")
            + encode_call(C.MOTION_QUEUE, -1)
            + encode_call(C.SET_DEBUG_FLAG, RESYNC_CALL, value)
            + encode_call(C.SET_DEBUG_FLAG, RESYNC_CALL, -1)
            + encode_call(C.SET_DEBUG_FLAG, RESYNC_CALL, 0)
        )
        deadline = transport.clock.now() + wait_s
        skipped = 0
        while True:
            left = deadline - transport.clock.now()
            line: bytes | None = None
            if left > 0:
                with contextlib.suppress(DeviceTimeoutError):
                    line = transport.read_line(left)
            if line is None:
                raise DeviceTimeoutError(
                    f"{self.name}: no answer to the resynchronising query"
                    f" `8 {RESYNC_CALL} -1` within {wait_s:g} s ({skipped} other lines"
                    " skipped)", device=self.name, call=C.SET_DEBUG_FLAG,
                )
            if line.strip() == marker:
                self._answer_owed = False
                return skipped
            skipped += 1
            if on_skipped is not None:
                on_skipped(line)

    # --- the motion queue ------------------------------------------------------------------

    def add_setpoint(self, value: int) -> None:
        """Call 0: queue one setpoint (counts or counts/s).

        Raises:
            QueueFullError: the device answered ``E0``.
        """
        self._confirm(encode_call(C.ADD_SINGLE, value))

    def add_setpoints(self, values: Sequence[int]) -> None:
        """Call 1: queue several setpoints, all or none.

        Raises:
            QueueFullError: the device answered ``E1`` (nothing was queued).
        """
        self._confirm(encode_counted(C.ADD_MULTIPLE, (), values))

    def replace_setpoints(self, values: Sequence[int]) -> tuple[int, int]:
        """Calls 4 and 1 in one exchange: empty the queue, then queue these values.

        Returns the queue status (queued, free) after both.

        Raises:
            QueueFullError: the device answered ``E1`` (nothing was queued).
        """
        queued, free = self._confirm(encode_call(C.CLEAR_MOTION_QUEUE, 0)
                                     + encode_counted(C.ADD_MULTIPLE, (), values)).values
        return queued, free

    def replace_from(self, tick: int,
                     values: Sequence[int] | npt.NDArray[np.integer]) -> Replaced:
        """Call 38: the queue's future from device tick ``tick`` becomes ``values``.

        Queued values due before ``tick`` are kept, value ``k`` is for tick ``tick + k x
        scalar``, and values already past when the line arrives are skipped: the motion
        changes from ``tick`` on without a seam. The device's acknowledgement (debug flag 1,
        set on first use) is checked against what was sent.

        Raises:
            QueueFullError: the device answered ``E38`` (nothing changed).
            LinkCorruptedError: the acknowledgement does not match the values sent.
        """
        self._send_acknowledged(C.REPLACE_FROM, tick, values)
        ack = self._await_acknowledged(C.REPLACE_FROM)
        replaced, crc = read_replaced(ack.values)
        if (replaced.added != len(values) - replaced.skipped
                or crc != values_crc32(values[replaced.skipped:])):
            raise self._misacknowledged(ack, values)
        return replaced

    def stop_from(self, tick: int,
                  values: Sequence[int] | npt.NDArray[np.integer]) -> Stopped:
        """Call 50: the queue's future from device tick ``tick`` becomes the stop
        ``values``, as :meth:`replace_from` does when the line comes in time; when it comes
        late, every value is used from the next motion update, offset (mode 1) so that the
        axis decelerates from where it had got to (:class:`Stopped` says how late, and by how
        much). The device's acknowledgement (debug flag 1, set on first use) is checked
        against what was sent.

        Raises:
            QueueFullError: the device answered ``E50`` (nothing changed).
            LinkCorruptedError: the acknowledgement does not match the values sent.
        """
        self.send_stop_from(tick, values)
        return self.stopped(values)

    def send_stop_from(self, tick: int,
                       values: Sequence[int] | npt.NDArray[np.integer]) -> None:
        """:meth:`stop_from`'s line, without waiting for its answer (:meth:`stopped` reads
        it): a stop sent to every device before any answer is read reaches them all at
        once, whatever the link's round trip.

        Raises:
            LinkLostError: the port is gone.
        """
        self._send_acknowledged(C.STOP_FROM, tick, values)

    def stopped(self, values: Sequence[int] | npt.NDArray[np.integer]) -> Stopped:
        """What the call 50 :meth:`send_stop_from` sent with ``values`` did.

        Raises:
            QueueFullError: the device answered ``E50`` (nothing changed).
            LinkCorruptedError: the acknowledgement does not match the values sent.
        """
        ack = self._await_acknowledged(C.STOP_FROM)
        stopped, crc = read_stopped(ack.values)
        if stopped.added != len(values) or crc != values_crc32(values):
            raise self._misacknowledged(ack, values)
        return stopped

    def _send_acknowledged(self, number: int, tick: int,
                           values: Sequence[int] | npt.NDArray[np.integer]) -> None:
        """Call ``number`` with a queue-status query behind it (its answer says the call
        has executed), its acknowledgement armed first."""
        if number not in self._acknowledging:
            self.set_debug_flag(number, 1)
            self._acknowledging.add(number)
        self.take_debug_lines(number)
        self._realign()
        self.transport.write(encode_counted(number, (tick,), values) + _QUEUE_QUERY)

    def _await_acknowledged(self, number: int) -> Reply:
        """The answer behind call ``number`` sent by :meth:`_send_acknowledged`, and the
        call's one acknowledgement."""
        self._await_answer(C.MOTION_QUEUE, after_error=True)
        acks = self.take_debug_lines(number)
        if len(acks) != 1:
            raise LinkCorruptedError(
                f"{self.name}: call {number} was acknowledged {len(acks)} times",
                device=self.name, call=number)
        return acks[0]

    def _misacknowledged(self, ack: Reply, values: Sequence[int] | npt.NDArray[np.integer],
                         ) -> LinkCorruptedError:
        return LinkCorruptedError(
            f"{self.name}: call {ack.call} acknowledged {ack.line!r}, which is not what was"
            f" sent ({len(values)} values)", device=self.name, call=ack.call)

    def queue_status(self) -> tuple[int, int]:
        """Call 2: (values queued, free slots)."""
        queued, free = self.query(C.MOTION_QUEUE, -1).values
        return queued, free

    def clear_queue(self) -> None:
        """Call 4: empty the motion queue."""
        self.command(C.CLEAR_MOTION_QUEUE, 0)

    # --- RAM variables --------------------------------------------------------------------

    def set_servo_enable(self, enable: bool) -> None:
        """Call 3: enable or disable the servo loop."""
        self.command(C.SET_SERVO_ENABLE, _flag(enable, "enable"))

    def servo_enabled(self) -> bool:
        """Call 3 query."""
        return self.query(C.SET_SERVO_ENABLE, -1).values[0] == 1

    def set_servo_interval_dms(self, interval_dms: int) -> None:
        """Call 5: servo period in tenths of a millisecond (1 = 10 kHz); clears the queue."""
        self.command(C.SET_SERVO_UPDATE_INTERVAL, interval_dms)

    def servo_interval_us(self) -> int:
        """Call 5 query: servo period in microseconds."""
        return self.query(C.SET_SERVO_UPDATE_INTERVAL, -1).values[0]

    def set_motion_scalar(self, scalar: int) -> None:
        """Call 6: servo ticks per queue value; clears the queue."""
        self.command(C.SET_MOTION_UPDATE_INTERVAL_SCALAR, scalar)

    def motion_scalar(self) -> int:
        """Call 6 query."""
        return self.query(C.SET_MOTION_UPDATE_INTERVAL_SCALAR, -1).values[0]

    def motion_period_s(self) -> float:
        """Seconds between queue values: servo period times the scalar."""
        return self.servo_interval_us() * self.motion_scalar() / 1e6

    def set_control_mode(self, mode: ControlMode | int) -> None:
        """Call 7: control mode; clears the queue and keyframes."""
        self.command(C.SET_CONTROL_MODE, int(_mode(mode, "mode")))

    def control_mode(self) -> ControlMode:
        """Call 7 query."""
        return ControlMode(self.query(C.SET_CONTROL_MODE, -1).values[0])

    def set_debug_flag(self, call: int, flag: int) -> None:
        """Call 8: set the debug flag of a call."""
        self.command(C.SET_DEBUG_FLAG, call, flag)

    def debug_flag(self, call: int) -> int:
        """Call 8 query."""
        return self.query(C.SET_DEBUG_FLAG, call, -1).values[1]

    def set_gains(self, *, kp: float, ki: float, kd: float) -> None:
        """Calls 9-11: PID gains (V/count, V/(count s), V s/count), 3 significant digits."""
        for number, value, label in ((C.SET_PROPORTIONAL_GAIN, kp, "kp"),
                                     (C.SET_INTEGRAL_GAIN, ki, "ki"),
                                     (C.SET_DERIVATIVE_GAIN, kd, "kd")):
            if value < 0:
                raise OutOfRangeError(f"{label} {value!r} is negative; gains are >= 0",
                                      reason=label)
            coefficient, exponent = to_sci(value, digits=3, parameter=label)
            self._check_range(number, (coefficient, exponent), label)
            self.command(number, coefficient, exponent)

    def gains(self) -> tuple[float, float, float]:
        """Calls 9-11 queries: (kp, ki, kd)."""
        return tuple(  # type: ignore[return-value]
            from_sci(*self.query(n, -1, 0).values) for n in GAIN_CALLS
        )

    def _check_range(self, number: C, args: tuple[int, ...], label: str) -> None:
        problem = BY_NUMBER[number].problem(args)
        if problem is not None:
            raise OutOfRangeError(f"{label}: {problem[1]}", call=number, reason=problem[1])

    def set_sim_interval_dms(self, interval_dms: int) -> None:
        """Call 12: simulated motor integration step, tenths of a millisecond."""
        self.command(C.SET_SIM_UPDATE_INTERVAL, interval_dms)

    def set_sim_value(self, number: C, value: float, *, label: str) -> None:
        """Calls 13-15, 17, 32, 33: a simulated-motor value as 4 significant digits."""
        if number not in SIM_SCIENTIFIC_CALLS:
            raise ArgumentError(
                f"call {number!r} is not a scientific simulated-motor call ("
                + ", ".join(f"{c.name} {int(c)}" for c in SIM_SCIENTIFIC_CALLS) + ")",
                reason="call",
            )
        coefficient, exponent = to_sci(value, digits=4, parameter=label)
        if coefficient == 0:
            exponent = 0
        self._check_range(number, (coefficient, exponent), label)
        self.command(number, coefficient, exponent)

    def sim_value(self, number: C) -> float:
        """Query a scientific simulated-motor value."""
        return from_sci(*self.query(number, -1, 0).values)

    def set_sim_counts_per_revolution(self, counts: int) -> None:
        """Call 16."""
        self.command(C.SET_SIM_COUNTS_PER_REVOLUTION, counts)

    def set_sim_travel(self, lower_counts: int, upper_counts: int) -> None:
        """Call 34: travel range with a limit switch at each end."""
        if lower_counts >= upper_counts:
            raise OutOfRangeError(
                f"travel lower {lower_counts!r} must be below upper {upper_counts!r}",
                call=C.SET_SIM_TRAVEL, reason="travel",
            )
        self.command(C.SET_SIM_TRAVEL, lower_counts, upper_counts)

    def sim_travel(self) -> tuple[int, int]:
        """Call 34 query."""
        lower, upper = self.query(C.SET_SIM_TRAVEL, -1, -1).values
        return lower, upper

    def set_sim_probe(self, side: int, position_counts: int) -> None:
        """Call 40: the simulated probe's surface: ``side`` 0 none, 1 the probe closes at or
        below ``position_counts`` (motor counts from power-up), 2 at or above it."""
        self.command(C.SET_SIM_PROBE, side, position_counts)

    def sim_probe(self) -> tuple[int, int]:
        """Call 40 query: (side, position counts)."""
        side, position = self.query(C.SET_SIM_PROBE, -1, 0).values
        return side, position

    # --- step/direction drives --------------------------------------------------------------

    def set_drive(self, drive: Drive | int) -> None:
        """Call 44: what the device drives (0 DC motor, 1 stepper open loop, 2 closed loop).

        A change is a change of motor: the position counter, the steps issued and the queue
        start afresh at 0. Refused (``ErrReplyError``) while the servo is enabled.
        """
        try:
            value = Drive(int(drive))
        except ValueError:
            raise OutOfRangeError(f"drive {drive!r} is not one of"
                                  f" {', '.join(f'{int(d)} ({d.words})' for d in Drive)}",
                                  call=C.SET_DRIVE, reason="drive") from None
        self.command(C.SET_DRIVE, int(value))

    def drive(self) -> Drive:
        """Call 44 query."""
        return Drive(self.query(C.SET_DRIVE, -1).values[0])

    def set_stepper(self, full_steps: int, microsteps: int) -> None:
        """Call 45: the stepper's full steps per revolution and the driver's microsteps per
        full step; clears the queue."""
        self._check_range(C.SET_STEPPER, (full_steps, microsteps), "stepper")
        self.command(C.SET_STEPPER, full_steps, microsteps)

    def stepper(self) -> tuple[int, int]:
        """Call 45 query: (full steps per revolution, microsteps per full step)."""
        full_steps, microsteps = self.query(C.SET_STEPPER, -1, 0).values
        return full_steps, microsteps

    def set_step_timing(self, pulse_ns: int, setup_ns: int) -> None:
        """Call 46: the step pulse's high time and the direction set-up time, ns."""
        self._check_range(C.SET_STEP_TIMING, (pulse_ns, setup_ns), "step timing")
        self.command(C.SET_STEP_TIMING, pulse_ns, setup_ns)

    def step_timing(self) -> tuple[int, int]:
        """Call 46 query: (pulse ns, set-up ns)."""
        pulse_ns, setup_ns = self.query(C.SET_STEP_TIMING, -1, 0).values
        return pulse_ns, setup_ns

    def set_sim_stepper(self, holding_mnm: int, detent_mnm: int, corner_rpm: int) -> None:
        """Call 47: the simulated stepper's holding and detent torque (mNm) and corner
        speed (rpm)."""
        self._check_range(C.SET_SIM_STEPPER, (holding_mnm, detent_mnm, corner_rpm),
                          "simulated stepper")
        self.command(C.SET_SIM_STEPPER, holding_mnm, detent_mnm, corner_rpm)

    def sim_stepper(self) -> tuple[int, int, int]:
        """Call 47 query: (holding mNm, detent mNm, corner rpm)."""
        holding, detent, corner = self.query(C.SET_SIM_STEPPER, -1, 0, 0).values
        return holding, detent, corner

    def steps(self) -> Steps:
        """Call 48: the steps issued since the drive was set, the last tick's, and the most
        one tick can issue."""
        return Steps.from_values(self.query(C.STEPS, -1).values)

    def set_encoder(self, kind: int, angle: int = 0) -> None:
        """Call 49: the encoder, incremental (0) or absolute within a turn (1), and the
        simulated magnet's angle (counts). Kind 1 makes the counter the absolute angle within
        a turn at once; clears the queue. Refused while the servo is enabled."""
        self._check_range(C.SET_ENCODER, (kind, angle), "encoder")
        self.command(C.SET_ENCODER, kind, angle)

    def encoder(self) -> EncoderSetting:
        """Call 49 query: the kind, the magnet's angle and where the turns begin."""
        return EncoderSetting.from_values(self.query(C.SET_ENCODER, -1, 0).values)

    # --- flash ------------------------------------------------------------------------------

    def set_name(self, name: str) -> None:
        """Call 18: write the device name to flash (up to 25 printable ASCII characters)."""
        self._confirm(encode_device_name(name))

    def device_name(self) -> str:
        """Call 18 query."""
        return self.query(C.SET_DEVICE_NAME, -1).text

    def set_default_mode(self, mode: ControlMode | int) -> None:
        """Call 19: control mode at power-up (flash)."""
        self.command(C.SET_DEFAULT_CONTROL_MODE, int(_mode(mode, "default mode")))

    def default_mode(self) -> ControlMode:
        """Call 19 query."""
        return ControlMode(self.query(C.SET_DEFAULT_CONTROL_MODE, -1).values[0])

    # --- status, clock, faults -----------------------------------------------------------------

    def status(self) -> Status:
        """Call 20."""
        return Status.from_values(self.query(C.STATUS, -1).values)

    def set_diagnostics_interval(self, ticks: int) -> None:
        """Call 21: a diagnostics line every ``ticks`` servo ticks (0 = off)."""
        self.command(C.SET_DIAGNOSTICS_INTERVAL, ticks)

    def diagnostics_interval(self) -> int:
        """Call 21 query: servo ticks between diagnostics lines (0 = off)."""
        return self.query(C.SET_DIAGNOSTICS_INTERVAL, -1).values[0]

    def zero_clock(self) -> None:
        """Call 22: zero the device clock (sent alone, not confirmed, for time sync)."""
        self.send(C.CLOCK, 0)

    def clock(self) -> int:
        """Call 22 query: device clock in servo ticks."""
        return self.query(C.CLOCK, -1).values[0]

    def set_position(self, counts: int) -> None:
        """Call 23: set the position counter to ``counts`` (a change of coordinates, as
        :meth:`shift_position`; clears the queue)."""
        self.command(C.SET_POSITION, counts)

    def shift_position(self, counts: int) -> None:
        """Call 37: add ``counts`` to the position counter (a change of coordinates: the
        desired position and the latched switch edges move with it, the loop goes on)."""
        self.command(C.SHIFT_POSITION, counts)

    def switch_edge(self, switch: int) -> SwitchEdge:
        """Call 36: the last edge of the lower (1) or upper (2) limit switch."""
        return SwitchEdge.from_values(self.query(C.SWITCH_EDGE, switch).values)

    def probe(self) -> ProbeState:
        """Call 41: the probe input now and its last edge."""
        return ProbeState.from_values(self.query(C.PROBE, -1).values)

    def set_output_at(self, output: int, value: int, tick: int) -> Outputs:
        """Call 42: output ``output`` (0, 1 digital; 2, 3 PWM) takes ``value`` (per mille of
        full duty: 0 or 1000 for a digital output) on device clock tick ``tick`` (one at or
        before the clock: the next tick). Confirmed with call 43 behind it in the same
        write.

        Returns the outputs after the change was queued (``free``: the changes still
        queueable).

        Raises:
            OutOfRangeError: ``output``, ``value`` or ``tick`` outside the call's range.
            QueueFullError: the device answered ``E42`` (16 changes pending; nothing
                changed).
            ErrReplyError: the device refused it (a digital output given another value
                than 0 or 1000, a tick before the last pending change's, a fault latched).
        """
        self._realign()
        self.transport.write(encode_call(C.SET_OUTPUT_AT, output, value, tick)
                             + encode_call(C.OUTPUTS, 0))
        return Outputs.from_values(self._await_answer(C.OUTPUTS, after_error=True).values)

    def outputs(self, *, clear: bool = False) -> Outputs:
        """Call 43: the outputs now, the pending changes and the tick of the last one
        applied; with ``clear`` the pending changes are dropped first (the outputs stay)."""
        return Outputs.from_values(self.query(C.OUTPUTS, _flag(clear, "clear")).values)

    def set_homed_marker(self, value: int) -> None:
        """Mark the device as homed since its power-up (the flag of :data:`HOMED_MARKER_CALL`,
        1..255; 0 clears the mark)."""
        self.set_debug_flag(HOMED_MARKER_CALL, value)

    def homed_marker(self) -> int:
        """The homed mark (0 after a power cycle or when never set)."""
        return self.debug_flag(HOMED_MARKER_CALL)

    def limits(self) -> tuple[bool, bool]:
        """Call 24: (lower pressed, upper pressed)."""
        lower, upper = self.query(C.LIMITS, -1).values
        return lower == 1, upper == 1

    def set_watchdog_ms(self, timeout_ms: int) -> None:
        """Call 28: disable the servo after this long without a command (0 = off)."""
        self.command(C.SET_WATCHDOG, timeout_ms)

    def watchdog_ms(self) -> int:
        """Call 28 query: the watchdog timeout, ms (0 = off)."""
        return self.query(C.SET_WATCHDOG, -1).values[0]

    def set_following_error_limit(self, counts: int) -> None:
        """Call 29: fault when |desired - actual| exceeds this (0 = off)."""
        self.command(C.SET_FOLLOWING_ERROR_LIMIT, counts)

    def following_error_limit(self) -> int:
        """Call 29 query: the following-error limit, counts (0 = off)."""
        return self.query(C.SET_FOLLOWING_ERROR_LIMIT, -1).values[0]

    def clear_fault(self) -> None:
        """Call 30."""
        self.command(C.CLEAR_FAULT, 0)

    def fault(self) -> tuple[int, int]:
        """Call 30 query: (fault code, tick it was set)."""
        code, tick = self.query(C.CLEAR_FAULT, -1).values
        return code, tick

    def reset_motion_stats(self) -> None:
        """Call 35 ``0``: start the motion statistics afresh (the clock is kept)."""
        self.command(C.MOTION_STATS, 0)

    def motion_stats(self) -> MotionStats:
        """Call 35 query: the following error and queue statistics since the last reset."""
        return MotionStats.from_values(self.query(C.MOTION_STATS, -1).values)

    def start_at(self, tick: int) -> None:
        """Call 31: hold the queue until the device clock reaches ``tick``."""
        self.command(C.START_AT, tick)

    def start_tick(self) -> int:
        """Call 31 query (-1 when no start is armed)."""
        return self.query(C.START_AT, -1).values[0]

    # --- curve mode -----------------------------------------------------------------------------

    def append_keyframe(self, keyframe: Keyframe) -> None:
        """Call 25 (curve mode).

        Raises:
            QueueFullError: the device answered ``E25``.
        """
        self._realign()
        self.transport.write(
            encode_call(C.APPEND_KEYFRAME, keyframe.duration_ms, keyframe.position_counts,
                        keyframe.tangent_in, keyframe.tangent_out) + encode_call(C.CURVE_BUFFER, -1)
        )
        self._await_answer(C.CURVE_BUFFER, after_error=True)

    def clear_keyframes(self) -> None:
        """Call 26."""
        self.command(C.CLEAR_KEYFRAMES, 0)

    def curve_free(self) -> int:
        """Call 27: free keyframe slots."""
        return self.query(C.CURVE_BUFFER, -1).values[0]

    # --- units ------------------------------------------------------------------------------------

    def _scale(self) -> AxisScale:
        if self.scale is None:
            raise ArgumentError(
                f"{self.name}: no axis scale set; give DeviceClient(scale=AxisScale(...))",
                reason="scale",
            )
        return self.scale

    def position_mm(self) -> float:
        """Actual position in mm (through the axis scale)."""
        return self._scale().to_mm(self.status().actual_counts)

    def set_position_mm(self, mm: float) -> None:
        """Set the actual position, in mm."""
        self.set_position(self._scale().to_counts(mm))

    def setpoints_from_mm(self, values_mm: Iterable[float]) -> list[int]:
        """Positions in mm to counts (or speeds in mm/s to counts/s)."""
        scale = self._scale()
        return [scale.to_counts(v) for v in values_mm]

    # --- lifetime ---------------------------------------------------------------------------------

    def close(self) -> None:
        """Close the link (safe twice)."""
        self.transport.close()

    def __enter__(self) -> DeviceClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _flag(value: bool, label: str) -> int:
    if not isinstance(value, bool):
        raise OutOfRangeError(f"{label} {value!r} must be True or False", reason=label)
    return int(value)


def _mode(value: ControlMode | int, label: str) -> ControlMode:
    if isinstance(value, bool) or not isinstance(value, int):
        raise OutOfRangeError(f"{label} {value!r} must be a ControlMode (1, 2 or 3)", reason=label)
    try:
        return ControlMode(value)
    except ValueError:
        raise OutOfRangeError(
            f"{label} {value!r} is not a control mode; allowed 1 (position), 2 (velocity),"
            " 3 (curve)", reason=label,
        ) from None


__all__ = [
    "GAIN_CALLS",
    "HELD_LINES",
    "HOMED_MARKER_CALL",
    "RESYNC_CALL",
    "SIM_SCIENTIFIC_CALLS",
    "Alarm",
    "AxisScale",
    "ControlMode",
    "DeviceClient",
    "Diagnostics",
    "DiagnosticsBlock",
    "MotionStats",
    "Outputs",
    "ProbeState",
    "Replaced",
    "Status",
    "Stopped",
    "SwitchEdge",
    "from_sci",
    "to_sci",
]
