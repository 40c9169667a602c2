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

from usbmotion.errors import LinkLostError, OutOfRangeError, QueueFullError
from usbmotion.hermite import Keyframe
from usbmotion.host.device import DeviceClient
from usbmotion.protocol import CURVE_BUFFER_CAPACITY, QUEUE_CAPACITY
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


class SetpointStream:
    """Stream integer setpoints (counts or counts/s) into one device's motion queue.

    Parameters:
        client: the device.
        values: the setpoints, in order; each must fit int32.
        period_s: seconds per consumed value (servo period times the scalar).
        low_water: refill when the queue is predicted to hold this many or fewer.
        high_water: fill up to this many.
        max_batch: most values in one call-1 line.
        on_progress: called after every batch.
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
        on_progress: ProgressCallback | None = None,
    ) -> None:
        if not (math.isfinite(period_s) and period_s > 0):
            raise OutOfRangeError(f"period_s {period_s!r} must be > 0", reason="period_s")
        if not 0 <= low_water < high_water <= QUEUE_CAPACITY:
            raise OutOfRangeError(
                f"watermarks low {low_water!r}, high {high_water!r} must satisfy"
                f" 0 <= low < high <= {QUEUE_CAPACITY}", reason="watermarks",
            )
        if not 1 <= max_batch <= QUEUE_CAPACITY:
            raise OutOfRangeError(
                f"max_batch {max_batch!r} is out of range 1..{QUEUE_CAPACITY}", reason="max_batch"
            )
        array = np.asarray(values)
        if array.ndim != 1:
            raise OutOfRangeError(f"values must be one-dimensional, got shape {array.shape}",
                                  reason="values")
        if array.size and (array.min() < INT32_MIN or array.max() > INT32_MAX):
            raise OutOfRangeError(
                f"a setpoint is outside int32 ({int(array.min())}..{int(array.max())})",
                reason="values",
            )
        if array.size and not np.issubdtype(array.dtype, np.integer):
            raise OutOfRangeError(f"setpoints must be integers, got dtype {array.dtype}",
                                  reason="values")
        self.client = client
        self._values = array.astype(np.int64)
        self.period_s = period_s
        self.low_water = low_water
        self.high_water = high_water
        self.max_batch = max_batch
        self.on_progress = on_progress
        self.sent = 0
        self.batches = 0
        self.refusals = 0
        self.status_queries = 0
        self._queued = 0
        self._status_time = client.transport.clock.now()
        self._min_queued = QUEUE_CAPACITY
        self._max_queued = 0
        self._started = self._status_time
        self._finished: float | None = None

    @property
    def total(self) -> int:
        """Number of setpoints in the stream."""
        return int(self._values.size)

    @property
    def done_sending(self) -> bool:
        """True once every value is confirmed queued on the device."""
        return self.sent >= self.total

    @property
    def consumed_estimate(self) -> int:
        """Values the device has probably executed by now (sent minus predicted queue)."""
        return self.sent - self._predicted(self._now())

    def _now(self) -> float:
        return self.client.transport.clock.now()

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
        queued, free = self.client.queue_status()
        self.status_queries += 1
        self._observe(queued)
        if queued > self.low_water and self.batches:
            return
        count = min(self.high_water - queued, free, self.max_batch, self.total - self.sent)
        if count <= 0:
            return
        batch = [int(v) for v in self._values[self.sent : self.sent + count]]
        try:
            self.client.add_setpoints(batch)
        except QueueFullError:
            self.refusals += 1
            return
        self.sent += count
        self.batches += 1
        queued_after, _ = self.client.queue_status()
        self.status_queries += 1
        self._observe(queued_after)

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
        self._status_time = client.transport.clock.now()
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
            self._status_time = self.client.transport.clock.now()
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
                CURVE_BUFFER_CAPACITY - self._free, self.client.transport.clock.now(),
            ))


def run_streams(
    streams: Sequence[SetpointStream | KeyframeStream],
    *,
    should_stop: Callable[[], bool] | None = None,
) -> None:
    """Service several streams until every value is confirmed queued.

    All streams must share one clock (the same virtual world, or the wall clock); between
    services this sleeps until the earliest stream wants attention.
    """
    if not streams:
        return
    clock = streams[0].client.transport.clock
    while True:
        if should_stop is not None and should_stop():
            return
        pending = [s for s in streams if not s.done_sending]
        if not pending:
            return
        now = clock.now()
        due = [s for s in pending if s.wake_time() <= now]
        for stream in due:
            stream.service()
        if not due:
            clock.sleep(min(s.wake_time() for s in pending) - now)


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
    clock = clients[0].transport.clock
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
