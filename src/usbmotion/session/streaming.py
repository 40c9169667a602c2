"""The device side of a run: every program axis's setpoints streamed into its device from a
common start tick, and the queued future replaced from a seam (call 38) when a stop, a hold,
an override or more moves change it.

A run gives the streams the rows it has made final (:meth:`RunStreams.release`); rows not
sent yet can still be revised; rows sent are replaced from a device tick just ahead of the
devices (:meth:`RunStreams.seam`), each device taking only what its queue has room for
(:meth:`usbmotion.host.stream.SetpointStream.replace_from`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from usbmotion.clock import is_paced
from usbmotion.errors import QueueUnderrunError, StartMissedError, UsbMotionError
from usbmotion.host.device import DeviceClient
from usbmotion.host.machine import Machine
from usbmotion.host.stream import SetpointStream, StreamProgress, run_streams
from usbmotion.host.timesync import SyncReport, held_up, start_filled
from usbmotion.session.rest import STOP_LEAD_S, wait_until_settled

START_MARGIN_S = 0.2
"""A run's common start tick, beyond the round trips that arm it."""
RESUME_MARGIN_S = 0.05
"""A resume's common start tick, beyond the round trips that arm it."""
PACED_LOW_WATER = 600
PACED_HIGH_WATER = 950
"""A run against the wall clock refills a queue when it is predicted to hold this few
values, up to that many: at the usual 1 kHz, 0.6 s of setpoints left for a host or a link
held up (on a loaded computer a pseudo-terminal's bytes were seen arrive 0.4 s late), in
batches of about 350."""
VIRTUAL_LOW_WATER = 300
VIRTUAL_HIGH_WATER = 900
"""In virtual time the devices wait for their host: batches of 600, half the exchanges."""
REJOIN_AHEAD_S = 0.1
"""How far beyond the row due now a queue that ran dry must have stood still for its
stream to be taken up again on schedule (the devices' clocks as the host estimates them,
and the answer's way back)."""
REPLACE_BATCH = 600
"""The most new values a replacement (call 38) carries; the streams send the rest."""


class RunStreams:
    """The streams of a run's program axes (see the module docstring).

    Parameters:
        machine: the machine; ``axes`` the program axes streamed, in the rows' order.
        period_s: the motion period; ``scalar`` servo ticks per motion period.
        on_progress: called after every service of a stream.
    """

    def __init__(self, machine: Machine, axes: Sequence[str], *, period_s: float,
                 scalar: int, on_progress: Callable[[StreamProgress], None] | None = None
                 ) -> None:
        self.machine = machine
        self.axes = list(axes)
        self.clients: list[DeviceClient] = [machine.axis(n).client for n in self.axes]
        self.period_s = period_s
        self.scalar = scalar
        self.tick_s = machine.config.servo_period_s
        self.on_progress = on_progress
        self.streams: dict[str, SetpointStream] = {}
        self.start_tick = 0
        """The device tick row 0 of the rows streamed is due on."""
        self.sync: SyncReport | None = None
        self.released = 0
        """How many rows the streams were given."""

    # --- starting ---------------------------------------------------------------------------

    def enable(self) -> None:
        """Every program axis with an empty queue, its servo enabled."""
        for client in self.clients:
            client.clear_queue()
            client.set_servo_enable(True)

    def start(self, fill: Callable[[], None], *, first: bool) -> SyncReport:
        """Every axis armed to start on one device tick once ``fill()`` (:meth:`open`, then
        :meth:`fill`) has given every device its first values, each device held meanwhile
        (:func:`usbmotion.host.timesync.start_filled`; the first start zeroes the clocks),
        a few of the slowest round trips and a margin ahead.

        Raises:
            StartMissedError: a device confirmed the start only after its tick (the host was
                held up): it may have started on its own, out of step, what it was given
                still queued (:meth:`hold_where_they_stand` is the way out).
        """
        self.sync = None  # until armed: a run that fails here has nothing to decelerate
        try:
            self.sync = start_filled(self.clients, fill, zero=first,
                                     margin_s=START_MARGIN_S if first else RESUME_MARGIN_S)
        except StartMissedError as error:
            raise held_up(error, what="axes", again="run it again") from error
        self.start_tick = self.sync.devices[0].start_tick
        return self.sync

    def hold_where_they_stand(self) -> None:
        """Every queue emptied at once, the servos on: an axis that was moving stops taking
        values and is held where its setpoint is (a start armed too late, a queue that ran
        dry: the axes' schedule is lost, so there is no path to decelerate along)."""
        for client in self.clients:
            client.clear_queue()

    def fill(self) -> None:
        """Every stream's first values queued (their devices held: :meth:`start`)."""
        for stream in self.streams.values():
            stream.service()

    def open(self, rows: npt.NDArray[np.int32], released: int) -> None:
        """New streams of the first ``released`` of ``rows`` (against the wall clock, with
        :data:`PACED_LOW_WATER` values queued at least)."""
        self.released = released
        paced = is_paced(self.machine.clock)
        for index, name in enumerate(self.axes):
            self.streams[name] = SetpointStream(
                self.machine.axis(name).client, rows[:released, index],
                period_s=self.period_s, verify=True, on_progress=self.on_progress,
                dry_is_late=True, low_water=PACED_LOW_WATER if paced else VIRTUAL_LOW_WATER,
                high_water=PACED_HIGH_WATER if paced else VIRTUAL_HIGH_WATER)

    # --- where the devices are ----------------------------------------------------------------

    @property
    def sent(self) -> int:
        """Rows every device has confirmed queued."""
        return min((stream.sent for stream in self.streams.values()), default=0)

    @property
    def all_sent(self) -> bool:
        """Every row given is confirmed queued on every device."""
        return all(stream.done_sending for stream in self.streams.values())

    def executed(self) -> int:
        """Rows the devices have probably executed."""
        return min((s.consumed_estimate for s in self.streams.values()), default=0)

    def device_tick(self) -> float:
        """The devices' clock now, by the synchronisation's estimate."""
        assert self.sync is not None, "not started"
        return self.sync.devices[0].estimate.ticks_at(self.machine.clock.now())

    def seam(self) -> tuple[int, int]:
        """The first row that can still be replaced, a device tick just ahead, and its
        tick (call 38 replaces the queued future from there)."""
        tick = math.ceil(self.device_tick() + STOP_LEAD_S / self.tick_s)
        index = min(max(0, -(-(tick - self.start_tick) // self.scalar)), self.sent)
        return index, max(tick, self.start_tick + index * self.scalar)

    def tick_of(self, row: int) -> int:
        """The device tick row ``row`` is due on."""
        return self.start_tick + row * self.scalar

    def queues(self) -> int:
        """The fullest device queue, asked now."""
        return max(client.queue_status()[0] for client in self.clients)

    # --- giving rows ---------------------------------------------------------------------------

    def release(self, rows: npt.NDArray[np.int32], limit: int) -> bool:
        """Give the streams rows up to ``limit``; True when there were new ones."""
        if limit <= self.released:
            return False
        for column, name in enumerate(self.axes):
            self.streams[name].extend(rows[self.released:limit, column])
        self.released = limit
        return True

    def revise(self, row: int, rows: npt.NDArray[np.int32], given: int) -> None:
        """Rows from ``row`` (none sent yet) become ``rows``; the streams have them up to
        ``given``."""
        for column, name in enumerate(self.axes):
            self.streams[name].revise(row, rows[:given - row, column])
        self.released = given

    def replace(self, tick: int, index: int, rows: npt.NDArray[np.integer], limit: int) -> None:
        """Every device's queued future from ``tick`` (row ``index``) replaced by ``rows``:
        up to :data:`REPLACE_BATCH` with call 38, as many as each queue has room for, the
        rest streamed after them; the streams are given rows up to ``limit``."""
        given = rows[:limit - index]
        for column, name in enumerate(self.axes):
            self.streams[name].replace_from(tick, index, given[:, column], most=REPLACE_BATCH)
        self.released = limit

    def stop(self, tick: int, index: int, rows: npt.NDArray[np.integer]) -> int:
        """Every device's queued future from ``tick`` (row ``index``) replaced by the stop
        ``rows`` (its last row at rest): in one call 50 each when they fit a queue beside
        what it keeps, every line sent before any answer is read (the stop reaches the
        devices together), so that a stop arriving late is delayed and not cut short; a longer
        stop as :meth:`replace` sends it. Returns how many value periods the latest device
        took it late (0: on time everywhere); the streams are given every row."""
        late = 0
        if any(len(rows) > stream.room_from(index) for stream in self.streams.values()):
            self.replace(tick, index, rows, index + len(rows))
            return late
        sent: list[tuple[str, int]] = []
        failure: Exception | None = None
        try:  # every device's line first, then the answers: the stop reaches them together
            for column, name in enumerate(self.axes):
                self.streams[name].send_stop(tick, index, rows[:, column])
                sent.append((name, column))
        finally:
            for name, column in sent:  # every answer read, even after a failure
                try:
                    late = max(late, self.streams[name].take_stop(index, rows[:, column]).late)
                except UsbMotionError as error:
                    failure = failure or error
        if failure is not None:
            raise failure
        self.released = index + len(rows)
        return late

    def stream(self, should_stop: Callable[[], bool], *, max_wait_s: float,
               sends_from: Callable[[], float] | None = None) -> None:
        """Service the streams until every row given is sent, or ``should_stop``
        (``sends_from``: as :func:`~usbmotion.host.stream.run_streams`). A queue that ran
        dry while its axis stood where it was meant to stand is taken up again on schedule
        (:meth:`rejoin_at_rest`).

        Raises:
            QueueUnderrunError: a queue ran dry while its axis was to move: its schedule,
                and the axes' lockstep, is lost.
        """
        while True:
            try:
                run_streams(list(self.streams.values()), should_stop=should_stop,
                            max_wait_s=max_wait_s, sends_from=sends_from)
                return
            except QueueUnderrunError as error:
                if not self.rejoin_at_rest(error):
                    raise

    def rejoin_at_rest(self, error: QueueUnderrunError) -> bool:
        """The stream whose queue ran dry (``error``) taken up again from a row already due
        (its device skips what is past), when its axis missed no motion: every row from
        the last it ran to :data:`REJOIN_AHEAD_S` beyond the one due now is where it stands;
        False otherwise."""
        stream = next((s for s in self.streams.values() if s.client.name == error.device),
                      None)
        if stream is None:
            return False
        now = math.floor(self.device_tick())
        index = min(max(stream.sent, (now - self.start_tick) // self.scalar), stream.total)
        ahead = math.ceil(REJOIN_AHEAD_S / (self.tick_s * self.scalar))
        return stream.rejoin_at_rest(self.tick_of(index), index, ahead=ahead,
                                     most=REPLACE_BATCH)

    # --- waiting for the devices ----------------------------------------------------------------

    def settle(self) -> None:
        """After the last setpoint: every axis settled (:func:`wait_until_settled`). The
        report's end position is read after it: what the machine then shows, to the
        count."""
        wait_until_settled(lambda: list(self.machine.status().values()), self.machine.clock)

    def drain(self, should_stop: Callable[[], bool], *, poll_s: float) -> None:
        """Until every row given is sent and every queue is empty (the machine executed
        them all), or ``should_stop``."""
        self.stream(should_stop, max_wait_s=poll_s)
        while not should_stop() and self.queues():
            self.machine.clock.sleep(poll_s)
