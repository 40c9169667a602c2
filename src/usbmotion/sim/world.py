"""A virtual-time world: simulated devices ticking in lock-step, and the links to them.

All devices of a world share one clock, like devices wired to the seed's external clock
line. Time only moves when something asks it to: :meth:`SimWorld.advance_to`, or a host
waiting on a :class:`SimLink` (through :class:`VirtualClock`). Each device is run in
blocks up to its next event, so a quiet device costs little per simulated second.

A host that promises to send nothing until a later time (``VirtualClock.sleep_quiet``)
lets the world run its devices ahead of the clock to that time in one block each, two at
once on two cores; what they print reaches the host at its own tick. Input that comes
before the promised time after all takes the device back to the clock from a checkpoint
(:class:`RewindableDevice`) and runs those ticks again, so the devices do exactly what they
do run only up to the clock (``tests/test_sim_ahead.py``).

With ``realtime=True`` the world never runs ahead of the wall clock: advancing sleeps
until the wall clock catches up, so a simulated machine moves at the speed of a real one.
It may fall behind while its host computes (time passes only when the host waits on a
device); it catches up at most :data:`REALTIME_SLACK_S` of that, and the rest is time the
world stood still, never a silence of the host its devices would see (a watchdog running
out, queues running dry, because the machine running the simulation was busy).
"""

from __future__ import annotations

import os
import queue
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Protocol, cast, runtime_checkable

from usbmotion.errors import ArgumentError, NoSuchDeviceError

REALTIME_SLACK_S = 0.05
"""How far a real-time world may lag the wall clock and still catch up (running its
devices without sleeping); a longer lag is time it stood still."""
_CORES = os.cpu_count() or 1
HELPER_IDLE_S = 0.05
"""How long the helper thread devices run on waits for more work before it ends."""


class _Helper:
    """One daemon thread that runs what it is given, started on demand and ended after
    :data:`HELPER_IDLE_S` without work (a world between runs leaves no thread behind)."""

    def __init__(self) -> None:
        self._work: queue.SimpleQueue[tuple[Callable[[], None], Future[None]]] = (
            queue.SimpleQueue())
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()

    def submit(self, action: Callable[[], None]) -> Future[None]:
        """Run ``action`` on the helper thread; its future."""
        future: Future[None] = Future()
        with self._lock:
            self._work.put((action, future))
            if self._thread is None:
                self._thread = threading.Thread(target=self._loop, name="usbmotion-world",
                                                daemon=True)
                self._thread.start()
        return future

    def _loop(self) -> None:
        while True:
            try:
                action, future = self._work.get(timeout=HELPER_IDLE_S)
            except queue.Empty:
                with self._lock:
                    if self._work.empty():
                        self._thread = None
                        return
                continue
            try:
                action()
            except BaseException as error:  # handed to the waiting caller
                future.set_exception(error)
            else:
                future.set_result(None)


_helper = _Helper()


MAX_AHEAD_US = 500_000
"""The furthest a virtual-time world runs a device ahead of its clock in one block (when
its host promises quiet: :meth:`SimWorld.advance_to`)."""
IDLE_STEP_S = 0.25
"""The most :meth:`SimWorld.keep_pace` moves a real-time world at once: an idle host calls
it every 0.1 s or so, a longer gap since the world last moved is the host computing."""


class SimulatedDevice(Protocol):
    """What the world needs of a device (``usbmotion.device.Device`` provides it)."""

    @property
    def name(self) -> str: ...

    @property
    def tick_us(self) -> int: ...

    def feed(self, data: bytes) -> None: ...

    def run(self, ticks: int) -> None: ...

    def take_timed_output(self) -> list[tuple[int, bytes]]: ...

    def ticks_until_event(self, *, diagnostics: bool = True) -> int | None: ...


@runtime_checkable
class RewindableDevice(SimulatedDevice, Protocol):
    """A device the world can run ahead of its clock (``usbmotion.device.Device``)."""

    def checkpoint(self) -> object: ...

    def rewind(self, checkpoint: object) -> None: ...


@dataclass(slots=True)
class LinkFaults:
    """Faults injected on a link, host to device and back (for reliability tests).

    ``drop_every`` drops every Nth byte written by the host (0 = never); ``corrupt_every``
    flips a bit of every Nth byte read by the host; ``stalled`` holds every byte in both
    directions until cleared; ``disconnected`` makes the link raise on the next use.
    """

    drop_every: int = 0
    corrupt_every: int = 0
    stalled: bool = False
    disconnected: bool = False
    _written: int = 0
    _read: int = 0

    def outgoing(self, data: bytes) -> bytes:
        """Host to device: drop what the fault says."""
        if not self.drop_every:
            return data
        kept = bytearray()
        for byte in data:
            self._written += 1
            if self._written % self.drop_every:
                kept.append(byte)
        return bytes(kept)

    def incoming(self, data: bytes) -> bytes:
        """Device to host: corrupt what the fault says."""
        if not self.corrupt_every:
            return data
        out = bytearray(data)
        for i in range(len(out)):
            self._read += 1
            if self._read % self.corrupt_every == 0:
                out[i] ^= 0x20
        return bytes(out)


@dataclass(slots=True)
class _Member:
    device: SimulatedDevice
    time_us: int = 0
    inbox: deque[tuple[int, bytes]] = field(default_factory=deque)
    links: list[SimLink] = field(default_factory=list)
    ahead_from: tuple[int, object] | None = None
    """While the device has run ahead of the world's clock: when it started to, and its
    checkpoint then."""
    rewindable: bool = False
    """Whether the device can be run ahead (:class:`RewindableDevice`)."""
    parallel: bool = False
    """Whether running the device ahead runs compiled code beside other work (a device
    whose ``fast`` is True: the kernel releases the interpreter's lock)."""


class SimLink:
    """One host's connection to one device of a world: bytes with a latency each way.

    Host to device bytes arrive ``latency_us`` later and are interpreted at the first
    servo tick boundary at or after that time; device output reaches the host
    ``latency_us`` after the tick it was printed on.
    """

    def __init__(self, world: SimWorld, key: str, *, latency_us: int = 0) -> None:
        if latency_us < 0:
            raise ArgumentError(f"latency_us {latency_us!r} is negative; it must be >= 0",
                                reason="latency_us")
        self.world = world
        self.key = key
        self.latency_us = latency_us
        self.faults = LinkFaults()
        self._outbox: deque[tuple[int, bytes]] = deque()
        self.closed = False

    @property
    def device(self) -> SimulatedDevice:
        """The device at the other end."""
        return self.world.device(self.key)

    def write(self, data: bytes) -> None:
        """Send bytes to the device."""
        data = self.faults.outgoing(data)
        if data:
            self.world._deliver(self.key, self.world.time_us + self.latency_us, data)

    def _push(self, time_us: int, data: bytes) -> None:
        self._outbox.append((time_us + self.latency_us, data))

    def available(self) -> int:
        """Bytes the host can read now."""
        if self.faults.stalled:
            return 0
        now = self.world.time_us
        total = 0
        for due, data in self._outbox:
            if due > now:
                break
            total += len(data)
        return total

    def receive(self, size: int) -> bytes:
        """Take up to ``size`` bytes that have arrived by now."""
        if self.faults.stalled:
            return b""
        now = self.world.time_us
        outbox = self._outbox
        if outbox and len(outbox[0][1]) <= size and outbox[0][0] <= now and (
                len(outbox) == 1 or outbox[1][0] > now):  # one chunk, taken whole
            return self.faults.incoming(outbox.popleft()[1])
        out = bytearray()
        while self._outbox and self._outbox[0][0] <= now and len(out) < size:
            due, data = self._outbox.popleft()
            room = size - len(out)
            if len(data) > room:
                self._outbox.appendleft((due, data[room:]))
                data = data[:room]
            out += data
        return self.faults.incoming(bytes(out))

    def receive_all(self) -> bytes:
        """Take every byte that has arrived by now."""
        outbox = self._outbox
        faults = self.faults
        if not outbox or faults.stalled:
            return b""
        now = self.world._time_us
        if outbox[0][0] > now:
            return b""
        data = outbox.popleft()[1]
        if outbox and outbox[0][0] <= now:
            parts = [data]
            while outbox and outbox[0][0] <= now:
                parts.append(outbox.popleft()[1])
            data = b"".join(parts)
        return faults.incoming(data) if faults.corrupt_every else data

    def discard_input(self) -> None:
        """Drop everything the device sent that the host has not read (what a device run
        ahead of the world's clock printed later than now stays to come)."""
        now, latency = self.world.time_us, self.latency_us
        self._outbox = deque(item for item in self._outbox if item[0] - latency > now)

    def _drop_after(self, time_us: int) -> None:
        """Forget what the device printed after ``time_us`` (it is being run again)."""
        latency = self.latency_us
        if self._outbox and self._outbox[-1][0] - latency > time_us:
            self._outbox = deque(item for item in self._outbox if item[0] - latency <= time_us)

    def next_arrival_us(self) -> int | None:
        """When the next byte for the host arrives, if one is on its way."""
        return self._outbox[0][0] if self._outbox else None

    def close(self) -> None:
        """Detach from the device (safe twice)."""
        if not self.closed:
            self.closed = True
            self.world._detach(self)


def ready(device: SimulatedDevice) -> None:
    """Load now what a device would load at its first motion (the compiled kernel of a
    :class:`usbmotion.device.Device`: ``load_kernel``): a world that keeps pace with the wall
    clock, or a server whose clients wait on it, cannot stand still for it then."""
    load = getattr(device, "load_kernel", None)
    if load is not None:
        load()


class SimWorld:
    """Devices on one virtual clock, in microseconds since the world was made."""

    def __init__(self, *, realtime: bool = False) -> None:
        self._members: dict[str, _Member] = {}
        self._time_us = 0
        self.realtime = realtime
        self._wall_origin = time.monotonic()
        self.run_ahead = True
        """Whether devices may run ahead of the clock when the host promises quiet (off:
        every tick runs only once the clock reaches it, for what watches ticks as they
        run: :class:`usbmotion.sim.recording.ExecutedRecorder`)."""
        self.rewinds = 0
        """How often a device run ahead of the clock was taken back to it (input came
        before the time its host promised: :meth:`advance_to`)."""
        self.clock = VirtualClock(self)
        """The world's one clock: every port onto its devices waits on this object, so
        links share a clock exactly when they share a world."""

    @property
    def time_us(self) -> int:
        """The world's clock, microseconds."""
        return self._time_us

    @property
    def keys(self) -> tuple[str, ...]:
        """The keys of the devices in this world."""
        return tuple(self._members)

    def add(self, device: SimulatedDevice, *, key: str | None = None) -> str:
        """Put a device into the world (its clock starts now); returns its key.

        Raises:
            ValueError: the key (by default the device name) is taken.
        """
        key = device.name if key is None else key
        if key in self._members:
            raise ArgumentError(f"device key {key!r} is already in this world", reason="key")
        rewindable = isinstance(device, RewindableDevice)
        if self.realtime:
            ready(device)
        self._members[key] = _Member(
            device, time_us=self._time_us, rewindable=rewindable,
            parallel=rewindable and getattr(device, "fast", False) is True and _CORES > 1)
        return key

    def device(self, key: str) -> SimulatedDevice:
        """The device with this key.

        Raises:
            KeyError: no such device (the message lists the keys there are).
        """
        member = self._members.get(key)
        if member is None:
            raise NoSuchDeviceError(
                f"no simulated device {key!r}; this world has {sorted(self._members)}")
        self._rewind(member)
        return member.device

    def connect(self, key: str, *, latency_us: int = 0) -> SimLink:
        """Open a link to a device."""
        member = self._members.get(key)
        if member is None:
            self.device(key)
            raise AssertionError("unreachable")
        link = SimLink(self, key, latency_us=latency_us)
        member.links.append(link)
        return link

    def _detach(self, link: SimLink) -> None:
        member = self._members.get(link.key)
        if member is not None and link in member.links:
            member.links.remove(link)

    def _deliver(self, key: str, due_us: int, data: bytes) -> None:
        member = self._members[key]
        self._rewind(member)
        if due_us <= self._time_us and not member.inbox:
            self._catch_up(member, self._time_us)
            member.device.feed(data)
            self._collect(member)
        else:
            member.inbox.append((due_us, data))

    def _collect(self, member: _Member) -> None:
        tick_us = member.device.tick_us
        for ticks_ago, out in member.device.take_timed_output():
            for link in member.links:
                link._push(member.time_us - ticks_ago * tick_us, out)

    def _run(self, member: _Member, ticks: int) -> None:
        """Run a device ``ticks`` ticks in one go: its output is stamped with its ticks."""
        device = member.device
        device.run(ticks)
        member.time_us += ticks * device.tick_us
        self._collect(member)

    def _catch_up(self, member: _Member, target_us: int, quiet_until_us: int = 0) -> None:
        """Run a device's whole ticks up to ``target_us``, delivering its inbox on time;
        with no input due before ``quiet_until_us``, on to that in the same block."""
        while True:
            tick = member.device.tick_us
            if member.inbox and member.inbox[0][0] <= target_us:
                due, data = member.inbox[0]
                if due > member.time_us:
                    self._run(member, -(-(due - member.time_us) // tick))
                member.inbox.popleft()
                member.device.feed(data)
                self._collect(member)
                continue
            ahead = min(quiet_until_us, target_us + MAX_AHEAD_US)
            if (ahead > target_us and not member.inbox and member.ahead_from is None
                    and member.rewindable and self.run_ahead and not self.realtime
                    and (ahead - member.time_us) // tick > (target_us - member.time_us) // tick):
                member.ahead_from = (member.time_us,
                                     cast(RewindableDevice, member.device).checkpoint())
                self._run(member, (ahead - member.time_us) // tick)
            elif target_us - member.time_us >= tick:
                self._run(member, (target_us - member.time_us) // tick)
            return

    def _rewind(self, member: _Member) -> None:
        """A device run ahead of the world's clock back to it (to the last tick at or
        before it), before it takes input or is looked at: from its checkpoint, the ticks up
        to now run again (printing what they printed before, already delivered) and what it
        printed later is forgotten. A device that is not ahead is left as it is."""
        if member.ahead_from is None:
            return
        started, checkpoint = member.ahead_from
        member.ahead_from = None
        if member.time_us <= self._time_us:
            return
        device = cast(RewindableDevice, member.device)
        device.rewind(checkpoint)
        self.rewinds += 1
        tick = device.tick_us
        ticks = (self._time_us - started) // tick
        if ticks:
            device.run(ticks)
            device.take_timed_output()
        member.time_us = started + ticks * tick
        for link in member.links:
            link._drop_after(member.time_us)

    def advance_to(self, target_us: int, *, quiet_until_us: int = 0) -> None:
        """Move the world's clock forward to ``target_us`` (never back).

        ``quiet_until_us``: the host will send nothing before then (a promise that lets a
        virtual-time world run its devices ahead that far in one block, up to
        :data:`MAX_AHEAD_US`: what they print reaches the host at its time, and input that
        comes earlier after all takes the device back to the world's clock first,
        running again the ticks up to it; what the devices do is the same either way).
        """
        for member in self._members.values():
            if member.ahead_from is not None and member.time_us <= target_us:
                member.ahead_from = None  # the clock reaches where it ran ahead to
        if target_us <= self._time_us:
            return
        if self.realtime:
            lag = target_us / 1e6 - (time.monotonic() - self._wall_origin)
            if lag > 0:
                time.sleep(lag)
            elif lag < -REALTIME_SLACK_S:  # the host was busy: the world stood still
                self._wall_origin -= lag + REALTIME_SLACK_S
        behind = [m for m in self._members.values() if m.time_us < target_us]
        if (len(behind) > 1 and quiet_until_us > target_us and self.run_ahead
                and not self.realtime and all(m.parallel for m in behind)):
            self._catch_up_together(deque(behind), target_us, quiet_until_us)
        else:
            for member in behind:
                self._catch_up(member, target_us, quiet_until_us)
        self._time_us = target_us

    def _catch_up_together(self, behind: deque[_Member], target_us: int,
                           quiet_until_us: int) -> None:
        """:meth:`_catch_up` each device, this thread and a worker taking the next one in
        turn: devices share nothing, and a compiled kernel runs without the interpreter's
        lock, so two blocks run at once on two cores. What each device does is its own
        either way; this returns once every one is done."""

        def drain() -> None:
            while True:
                try:
                    member = behind.popleft()
                except IndexError:
                    return
                self._catch_up(member, target_us, quiet_until_us)

        helper = _helper.submit(drain)
        try:
            drain()
        finally:
            if sys.exc_info()[0] is not None:
                behind.clear()  # leaving on an error: the worker ends after its device
            helper.result()

    def keep_pace(self) -> None:
        """A real-time world: move its clock up to the wall clock now (a host that is idle
        calls this now and then, so the devices live in real time between its commands;
        a virtual-time world does nothing)."""
        if self.realtime:
            behind_s = time.monotonic() - self._wall_origin - self._time_us / 1e6
            if behind_s > IDLE_STEP_S:
                self._wall_origin += behind_s - IDLE_STEP_S
            self.advance_to(int((time.monotonic() - self._wall_origin) * 1e6))

    def advance(self, duration_us: int) -> None:
        """Move the world's clock forward by ``duration_us``."""
        self.advance_to(self._time_us + duration_us)

    def next_output_us(self, key: str) -> int | None:
        """The earliest time the device ``key`` may print or receive something, if any."""
        member = self._members[key]
        times: list[int] = []
        if member.inbox:
            times.append(member.inbox[0][0])
        event = member.device.ticks_until_event()
        if event is not None:
            times.append(member.time_us + max(1, event) * member.device.tick_us)
        return min(times) if times else None

    def wait_for(self, link: SimLink, timeout_us: int) -> bool:
        """Advance until ``link`` has bytes for the host or ``timeout_us`` passes.

        Returns True when bytes are there.
        """
        deadline = self._time_us + timeout_us
        while True:
            if link.available():
                return True
            if self._time_us >= deadline:
                return False
            candidates = [deadline]
            arrival = link.next_arrival_us()
            if arrival is not None and not link.faults.stalled:
                candidates.append(arrival)
            event = self.next_output_us(link.key)
            if event is not None:
                candidates.append(event + link.latency_us)
            self.advance_to(max(self._time_us + 1, min(candidates)))


class VirtualClock:
    """A :class:`~usbmotion.clock.Clock` whose sleeping advances a world."""

    def __init__(self, world: SimWorld) -> None:
        self.world = world

    @property
    def paced(self) -> bool:
        """Whether sleeping takes wall time: a real-time world's does, a virtual-time
        world's returns once its devices have run (:func:`usbmotion.clock.is_paced`)."""
        return self.world.realtime

    def now(self) -> float:
        """The world's time in seconds."""
        return self.world.time_us / 1e6

    def sleep(self, seconds: float) -> None:
        """Advance the world by ``seconds`` (rounded up to a microsecond)."""
        if seconds > 0:
            self.world.advance(max(1, round(seconds * 1e6)))

    def sleep_quiet(self, seconds: float, *, quiet_until: float) -> None:
        """As :meth:`sleep`, the caller promising to send nothing to a device before
        ``quiet_until`` (this clock's seconds): the devices may run ahead to it at once
        (:meth:`SimWorld.advance_to`)."""
        if seconds > 0:
            world = self.world
            world.advance_to(world.time_us + max(1, round(seconds * 1e6)),
                             quiet_until_us=int(min(quiet_until * 1e6, 2.0**62)))
