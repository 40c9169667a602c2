"""Streaming setpoints and keyframes into devices with flow control.

The device's motion queue holds 1000 values and consumes one every motion-update period
once enabled. A stream keeps it between a low and a high watermark: it predicts the
consumption from the period, wakes when the queue should be near the low watermark,
corrects the prediction with a queue-status query (call 2), and sends one batch (call 1)
sized from that fresh count, with a status query behind it in the same write. Because the
device only ever frees slots between the status and the batch, the batch always fits:
``E1`` never happens in normal operation. If it does (someone else filled the queue, the
device was reset), nothing was queued, so exactly that batch is sent again, in order.

Several streams share one clock through :func:`run_streams`, which sleeps until the
earliest stream needs service: in virtual time that advances every device together.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from usbmotion.clock import sleep_quiet
from usbmotion.errors import (
    ArgumentError,
    DeviceTimeoutError,
    LinkCorruptedError,
    LinkLostError,
    QueueFullError,
    QueueUnderrunError,
    UnexpectedReplyError,
)
from usbmotion.hermite import Keyframe
from usbmotion.host.device import DeviceClient, Stopped
from usbmotion.protocol import (
    CURVE_BUFFER_CAPACITY,
    QUEUE_CAPACITY,
    Reply,
    ReplyKind,
    values_crc32,
)
from usbmotion.protocol import CallNumber as C
from usbmotion.protocol.table import INT32_MAX, INT32_MIN


@dataclass(frozen=True, slots=True)
class StreamProgress:
    """Where a stream is: values sent and confirmed queued, the device queue, the time."""

    device: str
    sent: int
    total: int
    queued: int
    time_s: float


@dataclass(frozen=True, slots=True)
class StreamResult:
    """What a finished stream did."""

    device: str
    sent: int
    batches: int
    refusals: int
    status_queries: int
    min_queued: int
    max_queued: int
    started_s: float
    finished_s: float


ProgressCallback = Callable[[StreamProgress], None]

REPLACE_ROOM_MARGIN = 20
"""Values of the device's queue a replacement leaves free beyond those it predicts the
device keeps (the prediction may be a few values short)."""
RESYNC_ATTEMPTS = 5
"""Status queries tried before a stream gives up on a link that answers nothing readable."""


def _acknowledgement(reply: Reply) -> tuple[int, int] | None:
    """(count, CRC-32) of the batch a call-1 debug line says was queued, or None.

    ``ADDED N CRC c`` (debug flag 2, what a stream asks for) carries them; an echo
    ``S0 N v1 .. vN`` (flag 1) is reduced to them. None: not well formed.
    """
    if reply.key == "ADDED" and len(reply.values) == 2:
        return reply.values[0], reply.values[1]
    try:
        values = list(map(int, reply.text.split()))
    except ValueError:
        return None
    if not reply.values or len(values) != reply.values[0]:
        return None
    return len(values), values_crc32(values)


class SetpointStream:
    """Stream integer setpoints (counts or counts/s) into one device's motion queue.

    Parameters:
        client: the device.
        values: the setpoints, in order; each must fit int32.
        period_s: seconds per consumed value (servo period times the scalar).
        low_water: refill when the queue is predicted to hold this many or fewer.
        high_water: fill up to this many.
        max_batch: most values in one call-1 line.
        verify: have the device acknowledge every batch it queues with the batch's CRC-32
            (call 8 ``8 1 2`` is sent) and check it against the values sent, so values
            mangled on the link are caught, not executed silently.
        on_progress: called after every service.
        on_acknowledgement: with ``verify``, called with (count, CRC-32) of every batch the
            device acknowledges, as it is read.
        dry_is_late: a queue found empty after the first batch, while values are still to
            be sent, raises :class:`~usbmotion.errors.QueueUnderrunError` instead of being
            filled: the device stood still waiting, and would run what follows late (for
            values due on a schedule, as a run's are).
    """

    def __init__(
        self,
        client: DeviceClient,
        values: Sequence[int] | npt.NDArray[np.integer],
        *,
        period_s: float,
        low_water: int = 300,
        high_water: int = 900,
        max_batch: int = 600,
        verify: bool = False,
        on_progress: ProgressCallback | None = None,
        on_acknowledgement: Callable[[int, int], None] | None = None,
        dry_is_late: bool = False,
    ) -> None:
        if not (math.isfinite(period_s) and period_s > 0):
            raise ArgumentError(f"period_s {period_s!r} must be > 0", reason="period_s")
        if not 0 <= low_water < high_water <= QUEUE_CAPACITY:
            raise ArgumentError(
                f"watermarks low {low_water!r}, high {high_water!r} must satisfy"
                f" 0 <= low < high <= {QUEUE_CAPACITY}", reason="watermarks",
            )
        if not 1 <= max_batch <= QUEUE_CAPACITY:
            raise ArgumentError(
                f"max_batch {max_batch!r} is out of range 1..{QUEUE_CAPACITY}", reason="max_batch"
            )
        array = np.asarray(values)
        if array.ndim != 1:
            raise ArgumentError(f"values must be one-dimensional, got shape {array.shape}",
                                  reason="values")
        if array.size and (array.min() < INT32_MIN or array.max() > INT32_MAX):
            raise ArgumentError(
                f"a setpoint is outside int32 ({int(array.min())}..{int(array.max())})",
                reason="values",
            )
        if array.size and not np.issubdtype(array.dtype, np.integer):
            raise ArgumentError(f"setpoints must be integers, got dtype {array.dtype}",
                                  reason="values")
        self.client = client
        self._values = array.astype(np.int32)
        """The setpoints, held as 32-bit integers once checked (they fit the protocol's
        range by their type: a batch's text is checked without a pass over its values)."""
        self._total = int(self._values.size)
        self.period_s = period_s
        self.low_water = low_water
        self.high_water = high_water
        self.max_batch = max_batch
        self.on_progress = on_progress
        self.on_acknowledgement = on_acknowledgement
        self.verify = verify
        self.dry_is_late = dry_is_late
        self.sent = 0
        self.batches = 0
        self.refusals = 0
        self.errors = 0
        self.timeouts = 0
        self.garbled_lines = 0
        self.status_queries = 0
        self._ack: tuple[int, int] | None = None
        """(count, CRC-32) the device acknowledged for the batch in flight."""
        self._refused = False
        self._verify_armed = False
        self._failed_batches = 0
        self._errors_at_batch = 0
        self._queued = 0
        self._status_time = client.link_clock.now()
        self._min_queued = QUEUE_CAPACITY
        self._max_queued = 0
        self._started = self._status_time
        self._finished: float | None = None

    @property
    def total(self) -> int:
        """Number of setpoints in the stream."""
        return self._total

    @property
    def done_sending(self) -> bool:
        """True once every value is confirmed queued on the device."""
        return self.sent >= self._total

    @property
    def consumed_estimate(self) -> int:
        """Values the device has probably executed by now (sent minus predicted queue)."""
        return self.sent - self._predicted(self._now())

    def _now(self) -> float:
        return self.client.link_clock.now()

    def _predicted(self, now: float) -> int:
        consumed = int((now - self._status_time) / self.period_s)
        return max(0, self._queued - consumed)

    def _observe(self, queued: int) -> None:
        self._queued = queued
        self._status_time = self._now()
        self._min_queued = min(self._min_queued, queued) if self.sent else self._min_queued
        self._max_queued = max(self._max_queued, queued)

    def wake_time(self) -> float:
        """When this stream next needs service, on the link's clock."""
        if self.done_sending:
            return math.inf
        if self.batches == 0 and self.refusals == 0:
            return self._status_time
        above = self._queued - self.low_water
        return self._status_time + max(above, 1) * self.period_s

    def replace_from(self, tick: int, index: int,
                     values: Sequence[int] | npt.NDArray[np.integer], *,
                     most: int = QUEUE_CAPACITY) -> int:
        """Replace the device's queued future from device tick ``tick``, which is when value
        ``index`` of the stream is due, by ``values`` (call 38, atomic): the device keeps
        what is due before ``tick`` and takes as many of ``values`` (at most ``most``) as
        its queue has room for beside them; the stream sends the rest after, as usual.
        The room is estimated from the values the device is predicted to keep; a refusal
        (``E38``: nothing changed) is tried again with fewer, down to none, which always
        fits (it cuts the queue at ``tick``). Returns how many values the call carried.

        Raises:
            ArgumentError: ``index`` beyond the values.
            QueueFullError: refused even with no value (the device is not this stream's).
            LinkCorruptedError, DeviceTimeoutError, LinkLostError: as
                :meth:`DeviceClient.replace_from`; the stream's account is then unchanged.
        """
        array = np.asarray(values, dtype=np.int64)
        if not 0 <= index <= self.total:
            raise ArgumentError(f"replace_from index {index!r}: within 0 .. {self.total}",
                                reason="index")
        kept = max(0, index - self.consumed_estimate)
        count = max(0, min(array.size, most, QUEUE_CAPACITY - kept - REPLACE_ROOM_MARGIN))
        while True:
            try:
                replaced = self.client.replace_from(tick, array[:count])
            except QueueFullError:
                if count == 0:
                    raise
                count //= 2
                continue
            self.replace_future(index, array, sent=count,
                                queued=replaced.kept + replaced.added)
            return count

    def rejoin_at_rest(self, tick: int, index: int, *, ahead: int, most: int) -> bool:
        """After its queue ran dry (:class:`~usbmotion.errors.QueueUnderrunError`), while
        value ``index`` was due on device tick ``tick`` (at or before the device's clock):
        when every value it missed, from the last one its device ran through ``index +
        ahead``, is that same value (its axis stood where it was meant to stand), take the
        stream up again from ``index`` in one call 38, whose values already past are skipped,
        so that what follows runs on schedule, with at most ``most`` values; True. Otherwise
        False, nothing sent: the axis missed part of its motion, its schedule is lost.

        Raises:
            ArgumentError: ``index`` before the values sent or beyond the values.
            QueueFullError, LinkCorruptedError, DeviceTimeoutError, LinkLostError: as
                :meth:`DeviceClient.replace_from`; the stream's account is then unchanged.
        """
        if not self.sent <= index <= self.total:
            raise ArgumentError(f"rejoin_at_rest index {index!r}: within {self.sent} .."
                                f" {self.total}", reason="index")
        if not self.sent:
            return False
        missed = self._values[self.sent - 1 : index + ahead + 1]
        if np.any(missed != missed[0]):
            return False
        rest = self._values[index:]
        count = min(rest.size, most, QUEUE_CAPACITY - REPLACE_ROOM_MARGIN)
        replaced = self.client.replace_from(tick, rest[:count])
        self.replace_future(index, rest, sent=count, queued=replaced.kept + replaced.added)
        return True

    def room_from(self, index: int) -> int:
        """How many values a replacement from value ``index`` can carry beside those the
        device is predicted to keep (due before it), with :data:`REPLACE_ROOM_MARGIN` to
        spare."""
        return QUEUE_CAPACITY - REPLACE_ROOM_MARGIN - max(0, index - self.consumed_estimate)

    def send_stop(self, tick: int, index: int,
                  values: Sequence[int] | npt.NDArray[np.integer]) -> None:
        """Replace the device's queued future from device tick ``tick`` (when value
        ``index`` is due) by the stop ``values``, all in one call 50, which is delayed
        rather than cut short when it arrives late (:meth:`DeviceClient.stop_from`): its
        line alone, :meth:`take_stop` reading its answer, so that the stops of several
        devices all sent before any answer is read reach them together.

        Raises:
            ArgumentError: ``index`` beyond the values, or more values than a queue holds.
            LinkLostError: the port is gone.
        """
        array = np.asarray(values, dtype=np.int64)
        if not 0 <= index <= self.total or array.size > QUEUE_CAPACITY:
            raise ArgumentError(f"send_stop index {index!r} (of {self.total}) or"
                                f" {array.size} values (at most {QUEUE_CAPACITY})",
                                reason="index")
        self.client.send_stop_from(tick, array)

    def take_stop(self, index: int, values: Sequence[int] | npt.NDArray[np.integer]) -> Stopped:
        """What the stop :meth:`send_stop` sent did, taken into the stream's account: the
        stream's values from ``index`` become the values the device took (offset as it
        offset them).

        Raises:
            QueueFullError, LinkCorruptedError, DeviceTimeoutError, LinkLostError: as
                :meth:`DeviceClient.stopped`; the stream's account is then unchanged.
        """
        array = np.asarray(values, dtype=np.int64)
        stopped = self.client.stopped(array)
        self.replace_future(index, array + stopped.offset, sent=int(array.size),
                            queued=stopped.kept + stopped.added)
        return stopped

    def replace_future(self, index: int, values: Sequence[int] | npt.NDArray[np.integer],
                       *, sent: int, queued: int | None = None) -> None:
        """Take note that the device's queue was replaced from value ``index`` on (call 38,
        :meth:`DeviceClient.replace_from`) by the first ``sent`` of ``values``: the stream's
        values from ``index`` become ``values``, and streaming goes on after those sent.
        ``queued``: the queue's level the device's acknowledgement gives (kept plus added),
        so the stream's prediction of what the device executed stays exact.

        Raises:
            ArgumentError: ``index`` beyond the values, or ``sent`` beyond ``values``.
        """
        array = np.asarray(values, dtype=np.int64)
        if not 0 <= index <= self.total or not 0 <= sent <= array.size:
            raise ArgumentError(f"replace_future index {index!r} (of {self.total}) or sent"
                                f" {sent!r} (of {array.size}) out of range", reason="index")
        if not array.size or (array.min() >= INT32_MIN and array.max() <= INT32_MAX):
            array = array.astype(np.int32)  # else kept as given: sending it names the value
        self._values = np.concatenate((self._values[:index], array))
        self._total = int(self._values.size)
        self.sent = index + sent
        if queued is not None:
            self._observe(queued)
        self._finished = self._now() if self.done_sending else None

    def revise(self, index: int, values: Sequence[int] | npt.NDArray[np.integer]) -> None:
        """The values from ``index`` on, none of them sent yet, become ``values`` (a
        program still being written, planned again before they went out).

        Raises:
            ArgumentError: ``index`` before the first value not sent or beyond the values.
        """
        if not self.sent <= index <= self.total:
            raise ArgumentError(f"revise index {index!r}: within {self.sent} .. {self.total}"
                                " (values not sent yet)", reason="index")
        self._values = self._values[:index]
        self._total = index
        self.extend(values)

    def extend(self, values: Sequence[int] | npt.NDArray[np.integer]) -> None:
        """Append setpoints to the stream (a program still being written: they follow the
        last one given, in order).

        Raises:
            ArgumentError: a value outside int32.
        """
        array = np.asarray(values, dtype=np.int64)
        if array.size and (array.min() < INT32_MIN or array.max() > INT32_MAX):
            raise ArgumentError(
                f"a setpoint is outside int32 ({int(array.min())}..{int(array.max())})",
                reason="values")
        self._values = np.concatenate((self._values, array.astype(np.int32)))
        self._total = int(self._values.size)
        if array.size:
            self._finished = None

    def service(self) -> None:
        """Top the queue up if it is low; reports progress every time it is called.

        Raises:
            LinkLostError: the link vanished (``confirmed`` says how many values the device
                had confirmed queued).
        """
        if self.done_sending:
            return
        try:
            self._top_up()
        except LinkLostError as error:
            raise LinkLostError(
                f"{self.client.name}: link lost after {self.sent} of {self.total} setpoints"
                f" were confirmed queued: {error}",
                device=self.client.name, confirmed=self.sent,
            ) from error
        if self.on_progress is not None:
            self.on_progress(
                StreamProgress(self.client.name, self.sent, self.total, self._queued, self._now())
            )
        if self.done_sending:
            self._finished = self._now()

    def _top_up(self) -> None:
        if self.verify and not self._verify_armed:
            self.client.set_debug_flag(C.ADD_MULTIPLE, 2)
            self._verify_armed = True
        queued, free = self._status()
        if not queued and self.batches and self.dry_is_late:
            raise QueueUnderrunError(
                f"{self.client.name}: its motion queue ran dry with {self.total - self.sent}"
                f" setpoints still to send: the host fell behind it (held up longer than the"
                f" queue lasts) and the axis stood still; {self.sent} setpoints were confirmed",
                device=self.client.name, call=C.ADD_MULTIPLE, confirmed=self.sent)
        if queued > self.low_water + (self.high_water - self.low_water) // 10 and self.batches:
            return
        count = min(self.high_water - queued, free, self.max_batch, self.total - self.sent)
        if count <= 0:
            return
        chunk = self._values[self.sent : self.sent + count]
        if self._send_batch(chunk, crc=values_crc32(chunk)):
            self.sent += count
            self.batches += 1

    def _status(self) -> tuple[int, int]:
        """Queue status, asked again (after draining the link) when garbled or lost."""
        for _ in range(RESYNC_ATTEMPTS):
            self.client.send_queue_query()
            self.status_queries += 1
            answer = self._exchange()
            if answer is not None:
                self._observe(answer[0])
                return answer
            self._drain()
        raise DeviceTimeoutError(
            f"{self.client.name}: no readable queue status after {RESYNC_ATTEMPTS} tries"
            f" ({self.garbled_lines} garbled lines); {self.sent} setpoints confirmed",
            device=self.client.name, call=C.MOTION_QUEUE,
        )

    def _send_batch(self, batch: npt.NDArray[np.integer], *, crc: int) -> bool:
        """Send one call-1 batch with a status query behind it; True if the device took it.

        With ``verify`` the device acknowledges every batch it takes with its count and
        CRC-32 (debug flag 2 of call 1), which must equal those of what was sent
        (``crc``), so a batch mangled on the way is caught and a lost answer is recovered
        from: after draining the link, an acknowledgement says the batch was taken, none
        says it was not. Without ``verify`` a batch counts as
        taken unless ``E1`` or ``ERR`` came back, and a lost answer is an error.

        Raises:
            LinkCorruptedError: the acknowledged count or CRC differs from the batch's, or
                unreadable lines came back in its place.
            DeviceTimeoutError: the answer was lost and, without ``verify``, whether the
                batch was taken cannot be known.
        """
        self._ack = None
        self._refused = False
        self._errors_at_batch = self.errors
        garbled_before = self.garbled_lines
        self.client.send_counted_with_status(C.ADD_MULTIPLE, (), batch)
        self.status_queries += 1
        answer = self._exchange()
        if answer is not None:
            self._observe(answer[0])
        else:
            self._drain()
            if not self.verify:
                raise DeviceTimeoutError(
                    f"{self.client.name}: the answer to a batch of {len(batch)} setpoints was"
                    f" lost, so whether it was queued is unknown; {self.sent} setpoints were"
                    " confirmed (stream with verify=True to recover from this)",
                    device=self.client.name, call=C.ADD_MULTIPLE,
                )
            self._status()
        if self._ack is None and self.garbled_lines > garbled_before:
            raise LinkCorruptedError(
                f"{self.client.name}: {self.garbled_lines - garbled_before} unreadable line(s)"
                f" came back after a batch of {len(batch)} setpoints, so whether it was queued"
                f" cannot be known: the link is corrupting bytes; {self.sent} setpoints were"
                " confirmed", device=self.client.name, call=C.ADD_MULTIPLE, confirmed=self.sent,
            )
        if self._ack is not None:
            if self._ack != (len(batch), crc):
                raise LinkCorruptedError(
                    f"{self.client.name}: the device queued values other than those sent"
                    f" (setpoints {self.sent}..{self.sent + len(batch) - 1}): the link is"
                    f" corrupting bytes; {self.sent} setpoints were confirmed intact",
                    device=self.client.name, call=C.ADD_MULTIPLE, confirmed=self.sent,
                )
            self._failed_batches = 0
            return True
        if self.verify or self._refused:
            self._failed_batches += 1
            if self._failed_batches >= RESYNC_ATTEMPTS and not self.refusals_only():
                raise LinkCorruptedError(
                    f"{self.client.name}: {self._failed_batches} batches in a row were damaged"
                    f" on the link and not queued; {self.sent} setpoints were confirmed",
                    device=self.client.name, call=C.ADD_MULTIPLE, confirmed=self.sent,
                )
            return False
        return True

    def refusals_only(self) -> bool:
        """True when the last batch was turned away only by ``E1`` (a full queue, no damage)."""
        return self.errors == self._errors_at_batch and self._ack is None and not self.verify

    def _exchange(self) -> tuple[int, int] | None:
        """Read up to the next queue-status answer.

        Returns None when the answer did not come but a mangled line did (an ``ERR`` or an
        unreadable line: the query was probably swallowed by a damaged line), so the
        caller can resynchronise.

        Raises:
            DeviceTimeoutError: nothing came at all (a stalled or dead link).
        """
        errors, garbled = self.errors, self.garbled_lines
        while True:
            try:
                reply = self._read(self.client.timeout_s)
            except DeviceTimeoutError as error:
                self.timeouts += 1
                if self.errors > errors or self.garbled_lines > garbled:
                    return None
                raise DeviceTimeoutError(
                    f"{self.client.name}: no answer within {self.client.timeout_s:g} s: the"
                    f" link is stalled or gone; {self.sent} setpoints were confirmed",
                    device=self.client.name, call=C.MOTION_QUEUE,
                ) from error
            answer = self._account(reply)
            if answer is not None:
                return answer

    def _drain(self) -> None:
        """Read whatever is still on its way, until the link is quiet."""
        quiet_s = min(self.client.timeout_s, 0.25)
        while True:
            try:
                reply = self._read(quiet_s)
            except DeviceTimeoutError:
                return
            self._account(reply)

    def _read(self, timeout_s: float) -> Reply | None:
        """The client's next answer (None for an unreadable line, counted as garbled); the
        batch acknowledgements read on the way are taken in whatever happens.

        Raises:
            DeviceTimeoutError: nothing came within ``timeout_s``.
        """
        try:
            return self.client.next_reply(timeout_s)
        except UnexpectedReplyError:
            self.garbled_lines += 1
            return None
        finally:
            for ack in self.client.take_debug_lines(C.ADD_MULTIPLE):
                echo = _acknowledgement(ack)
                if echo is None:
                    self.garbled_lines += 1
                else:
                    self._ack = echo
                    if self.on_acknowledgement is not None:
                        self.on_acknowledgement(*echo)

    def _account(self, reply: Reply | None) -> tuple[int, int] | None:
        """Account for one answer; return (queued, free) if it is a queue-status answer."""
        if reply is None:
            return None
        if reply.kind is ReplyKind.REFUSAL and reply.call == C.ADD_MULTIPLE:
            self.refusals += 1
            self.client.refusals += 1
            self._refused = True
            return None
        if reply.kind is ReplyKind.ERROR:
            self.errors += 1
            self._refused = True
            return None
        if (reply.kind is ReplyKind.QUERY and reply.call == C.MOTION_QUEUE
                and len(reply.values) == 2):
            return reply.values[0], reply.values[1]
        self.garbled_lines += 1
        return None

    def result(self) -> StreamResult:
        """What the stream did so far."""
        return StreamResult(
            self.client.name, self.sent, self.batches, self.refusals, self.status_queries,
            self._min_queued if self.batches else 0, self._max_queued, self._started,
            self._finished if self._finished is not None else self._now(),
        )


class KeyframeStream:
    """Stream Hermite keyframes into one device's 8-slot curve buffer (curve mode).

    Each group sent is at most the free slots the device last reported; slots only free
    up in between, so ``E25`` never happens in normal operation.
    """

    def __init__(
        self,
        client: DeviceClient,
        keyframes: Sequence[Keyframe],
        *,
        on_progress: ProgressCallback | None = None,
    ) -> None:
        self.client = client
        self.keyframes = list(keyframes)
        self.on_progress = on_progress
        self.sent = 0
        self.batches = 0
        self.refusals = 0
        self.status_queries = 0
        self._free = CURVE_BUFFER_CAPACITY
        self._status_time = client.link_clock.now()
        self._started = self._status_time

    @property
    def total(self) -> int:
        """Number of keyframes."""
        return len(self.keyframes)

    @property
    def done_sending(self) -> bool:
        """True once every keyframe is in the device's buffer."""
        return self.sent >= self.total

    def wake_time(self) -> float:
        """When to look again: now if there was room, else after the shortest pending segment."""
        if self.done_sending:
            return math.inf
        if self._free > 0 or self.batches == 0:
            return self._status_time
        pending = self.keyframes[max(0, self.sent - CURVE_BUFFER_CAPACITY) : self.sent]
        shortest_s = min((k.duration_ms for k in pending), default=1) / 1000.0
        return self._status_time + max(shortest_s / 2, 0.001)

    def service(self) -> None:
        """Send as many keyframes as there are free slots."""
        if self.done_sending:
            return
        try:
            self._free = self.client.curve_free()
            self.status_queries += 1
            self._status_time = self.client.link_clock.now()
            while self._free > 0 and not self.done_sending:
                try:
                    self.client.append_keyframe(self.keyframes[self.sent])
                except QueueFullError:
                    self.refusals += 1
                    self._free = 0
                    break
                self.sent += 1
                self._free -= 1
            self.batches += 1
        except LinkLostError as error:
            raise LinkLostError(
                f"{self.client.name}: link lost after {self.sent} of {self.total} keyframes"
                f" were confirmed: {error}", device=self.client.name, confirmed=self.sent,
            ) from error
        if self.on_progress is not None:
            self.on_progress(StreamProgress(
                self.client.name, self.sent, self.total,
                CURVE_BUFFER_CAPACITY - self._free, self.client.link_clock.now(),
            ))


def run_streams(
    streams: Sequence[SetpointStream | KeyframeStream],
    *,
    should_stop: Callable[[], bool] | None = None,
    max_wait_s: float = 0.05,
    sends_from: Callable[[], float] | None = None,
) -> None:
    """Service several streams until every value is confirmed queued.

    ``should_stop`` is asked at least every ``max_wait_s`` (a fault check, Ctrl-C);
    ``sends_from`` says the earliest time (on the streams' clock) it may send to a device
    itself, unless something unforeseen asks it to (without it: at any time).

    All streams must share one clock (the same virtual world, or the wall clock); between
    services this sleeps until the earliest stream wants attention (promising the clock
    quiet until then: :func:`usbmotion.clock.sleep_quiet`).
    """
    if not streams:
        return
    clock = streams[0].client.link_clock
    while True:
        if should_stop is not None and should_stop():
            return
        now = clock.now()
        wake = math.inf
        due: list[SetpointStream | KeyframeStream] = []
        pending = False
        for stream in streams:
            if stream.done_sending:
                continue
            pending = True
            stream_wake = stream.wake_time()
            if stream_wake <= now:
                due.append(stream)
            elif stream_wake < wake:
                wake = stream_wake
        if not pending:
            return
        for stream in due:
            stream.service()
        if not due:
            if should_stop is None:
                clock.sleep(wake - now)
                continue
            quiet = min(wake, sends_from()) if sends_from is not None else now
            sleep_quiet(clock, min(wake, now + max_wait_s) - now, quiet_until=quiet)


def wait_until_drained(
    clients: Sequence[DeviceClient],
    *,
    period_s: float,
    poll_s: float = 0.05,
    should_stop: Callable[[], bool] | None = None,
) -> None:
    """Wait until every client's motion queue is empty (the last value is being executed)."""
    if not clients:
        return
    clock = clients[0].link_clock
    left = list(clients)
    while left:
        if should_stop is not None and should_stop():
            return
        queued_most = 0
        still: list[DeviceClient] = []
        for client in left:
            queued, _ = client.queue_status()
            if queued:
                still.append(client)
                queued_most = max(queued_most, queued)
        left = still
        if left:
            clock.sleep(max(poll_s, queued_most * period_s))
