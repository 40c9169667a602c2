"""Time synchronisation: zero the device clocks, measure their offsets, start together.

Each device counts servo ticks on its own clock. To start several motion queues on the
same instant the host

1. zeroes every device clock (call ``22 0``, sent to all devices back to back, so the
   ticks stay small and never wrap);
2. measures each clock against the host's by round trips (``22 -1``). A device reads its
   clock during the tick it reports, and (links being symmetric) at about the middle of
   the round trip, so each sample bounds from above the host time at which that clock
   read zero; the lowest bound from the round trips near the shortest one is the
   estimate. The samples are spread over one tick, so that one of them lands close to a
   tick boundary;
3. picks a start time comfortably ahead (a few round trips plus a margin), converts it to
   each device's own tick through its offset, and arms call 31 on every device: each
   queue starts consuming when its clock reaches its tick.

In virtual time with constant symmetric latencies the start is exact (the same world
tick on every device); in real time the skew is bounded by the round trips and one tick.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from usbmotion.clock import Clock
from usbmotion.errors import ArgumentError, StartMissedError
from usbmotion.host.device import DeviceClient
from usbmotion.protocol import CallNumber
from usbmotion.protocol.table import INT32_MAX

DEFAULT_SAMPLES = 8
"""Round trips per device when measuring its clock."""
DEFAULT_MARGIN_S = 0.05
"""Time between the last arming and the start, beyond four of the slowest round trips."""


@dataclass(frozen=True, slots=True)
class ClockSample:
    """One round trip: host send and receive times (seconds) and the device's clock (ticks)."""

    sent_s: float
    received_s: float
    ticks: int

    @property
    def rtt_s(self) -> float:
        """Round-trip time, seconds."""
        return self.received_s - self.sent_s


@dataclass(frozen=True, slots=True)
class ClockEstimate:
    """How one device's clock relates to the host's: ``ticks = offset_ticks + host_s / tick_s``.

    Fields:
        device: the device's name.
        tick_s: the device's servo period, seconds per tick.
        offset_ticks: the device's clock at host time 0, ticks (fractional).
        rtt_s: the round trip of the sample the estimate rests on, seconds.
        samples: how many round trips were measured.
    """

    device: str
    tick_s: float
    offset_ticks: float
    rtt_s: float
    samples: int

    def ticks_at(self, host_s: float) -> float:
        """The device's clock at host time ``host_s``, ticks."""
        return self.offset_ticks + host_s / self.tick_s

    def host_time_of(self, ticks: float) -> float:
        """The host time at which the device's clock reads ``ticks``, seconds."""
        return (ticks - self.offset_ticks) * self.tick_s


@dataclass(frozen=True, slots=True)
class DeviceStart:
    """The armed start of one device.

    Fields:
        estimate: its clock estimate.
        start_tick: the tick call 31 was armed with.
        start_s: when that tick comes, in host time by the estimate, seconds.
        confirmed_s: when the host had the device's confirmation of the arming, seconds.
    """

    estimate: ClockEstimate
    start_tick: int
    start_s: float
    confirmed_s: float


@dataclass(frozen=True, slots=True)
class SyncReport:
    """A synchronised start: what was measured and armed.

    Fields:
        start_s: the host time chosen for the start, seconds.
        devices: one entry per device, in the order given.
        estimated_skew_s: the spread of the devices' start times by their estimates
            (from rounding each start to a whole tick), seconds.
        skew_bound_s: the worst the spread can be, given each estimate's uncertainty
            (half its round trip plus one tick), seconds.
    """

    start_s: float
    devices: tuple[DeviceStart, ...]
    estimated_skew_s: float
    skew_bound_s: float

    @property
    def lead_s(self) -> float:
        """Time left between the last confirmation of arming and the start, seconds."""
        return self.start_s - max(d.confirmed_s for d in self.devices)

    def describe(self) -> str:
        """A few lines for a person: per device offset, round trip, tick; the skew."""
        lines = [
            f"{d.estimate.device}: rtt {d.estimate.rtt_s * 1e3:.3f} ms, offset"
            f" {d.estimate.offset_ticks:.3f} ticks, start tick {d.start_tick}"
            for d in self.devices
        ]
        lines.append(
            f"start skew: estimated {self.estimated_skew_s * 1e6:.0f} us,"
            f" bound {self.skew_bound_s * 1e6:.0f} us"
        )
        return "\n".join(lines)


def shared_clock(clients: Sequence[DeviceClient]) -> Clock:
    """The clock every client's link waits on.

    Raises:
        ArgumentError: no clients, or their links wait on different clocks (a simulated
            world and the wall clock, or two worlds): they cannot be synchronised.
    """
    if not clients:
        raise ArgumentError("no devices to synchronise", reason="clients")
    clocks = [c.link_clock for c in clients]
    if any(clock is not clocks[0] for clock in clocks):
        raise ArgumentError(
            "devices " + ", ".join(c.name for c in clients) + " wait on different clocks"
            " (virtual and wall, or two simulated worlds); they cannot start together",
            reason="clients",
        )
    return clocks[0]


def zero_clocks(clients: Sequence[DeviceClient]) -> None:
    """Zero every device clock (call ``22 0``), written back to back, then confirm each."""
    for client in clients:
        client.zero_clock()
    for client in clients:
        client.sync()


def measure_clock(
    client: DeviceClient, *, samples: int = DEFAULT_SAMPLES, tick_s: float | None = None
) -> ClockEstimate:
    """Estimate a device's clock offset from ``samples`` round trips of ``22 -1``.

    A reading of tick ``c`` is taken during that tick, so the device's clock started
    (read ``0``) at or before ``middle - c * tick`` for a reading taken at the middle of
    its round trip: every sample gives an upper estimate of the clock's origin, and the
    lowest of those from round trips near the shortest one is the estimate. One warm-up
    round trip comes first; the samples are spread over one tick (a pause of ``i /
    samples`` of a tick before sample ``i``), so that one of them lands close to a tick
    boundary.

    Parameters:
        client: the device.
        samples: round trips to measure (at least 1).
        tick_s: the device's servo period, seconds (queried with call 5 when not given).

    Raises:
        ArgumentError: ``samples`` < 1 or ``tick_s`` <= 0.
    """
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
        raise ArgumentError(f"samples {samples!r} must be an integer >= 1", reason="samples")
    if tick_s is None:
        tick_s = client.servo_interval_us() / 1e6
    if not (math.isfinite(tick_s) and tick_s > 0):
        raise ArgumentError(f"tick_s {tick_s!r} must be > 0", reason="tick_s")
    clock = client.link_clock
    client.clock()
    taken: list[ClockSample] = []
    for index in range(samples):
        clock.sleep(tick_s * index / samples)
        sent = clock.now()
        ticks = client.clock()
        taken.append(ClockSample(sent, clock.now(), ticks))
    best_rtt = min(sample.rtt_s for sample in taken)
    near = [sample for sample in taken if sample.rtt_s <= best_rtt + tick_s / 4]
    origin_s = min(
        sample.sent_s + sample.rtt_s / 2 - sample.ticks * tick_s for sample in near
    )
    return ClockEstimate(client.name, tick_s, -origin_s / tick_s, best_rtt, samples)


def measure_clocks(
    clients: Sequence[DeviceClient], *, samples: int = DEFAULT_SAMPLES
) -> tuple[ClockEstimate, ...]:
    """:func:`measure_clock` for each device, one after another."""
    shared_clock(clients)
    return tuple(measure_clock(client, samples=samples) for client in clients)


def arm_start(
    clients: Sequence[DeviceClient], estimates: Sequence[ClockEstimate], *, start_s: float
) -> SyncReport:
    """Arm call 31 on every device so its queue starts at host time ``start_s``.

    The start is moved forward to the next tick of the first device, so that every
    device's start tick is rounded from near a whole tick: devices whose clocks tick in
    step then start on the same tick even when their estimates differ by a fraction.

    Raises:
        ArgumentError: the lists differ in length, or a start tick is outside 0..2**31-1.
        StartMissedError: a device confirmed its arming only after its start tick may
            have passed (give a larger margin).
    """
    if len(clients) != len(estimates):
        raise ArgumentError(
            f"{len(clients)} devices but {len(estimates)} clock estimates", reason="estimates"
        )
    clock = shared_clock(clients)
    if estimates:
        first = estimates[0]
        start_s = first.host_time_of(math.ceil(first.ticks_at(start_s) - 1e-9))
    starts: list[DeviceStart] = []
    for client, estimate in zip(clients, estimates, strict=True):
        tick = round(estimate.ticks_at(start_s))
        if not 0 <= tick <= INT32_MAX:
            raise ArgumentError(
                f"{client.name}: start tick {tick!r} is out of range 0..{INT32_MAX};"
                " zero the clocks first", reason="start_tick",
            )
        client.start_at(tick)
        starts.append(DeviceStart(estimate, tick, estimate.host_time_of(tick), clock.now()))
    late = [d for d in starts if d.confirmed_s >= d.start_s]
    if late:
        names = ", ".join(d.estimate.device for d in late)
        raise StartMissedError(
            f"{names}: arming was confirmed only after the start time; the start may have"
            " passed before it was armed: give a larger margin",
            device=names, call=CallNumber.START_AT,
        )
    times = [d.start_s for d in starts]
    spread = max(times) - min(times)
    worst = max(d.estimate.rtt_s / 2 + d.estimate.tick_s for d in starts)
    return SyncReport(start_s, tuple(starts), spread, spread + 2 * worst)


def synchronise_start(
    clients: Sequence[DeviceClient],
    *,
    samples: int = DEFAULT_SAMPLES,
    margin_s: float = DEFAULT_MARGIN_S,
    zero: bool = True,
) -> SyncReport:
    """Zero the clocks, measure them, and arm every device to start on the same instant.

    The start is chosen ``4 + len(clients)`` of the slowest round trips plus ``margin_s`` after the
    measurements, so there is time to arm every device (and to fill the queues: give a
    larger margin when they are filled after arming).

    Parameters:
        clients: the devices.
        samples: round trips per device.
        margin_s: time beyond the round trips, seconds (>= 0).
        zero: zero the clocks first (call 22).

    Raises:
        ArgumentError: a bad argument, or clients on different clocks.
        StartMissedError: the start passed before a device was armed.
    """
    return _start(clients, None, samples=samples, margin_s=margin_s, zero=zero)


HOLD_S = 30.0
"""How far ahead :func:`start_filled` arms every device while its queue or curve takes its
first values: they wait there for the real start."""


def start_filled(
    clients: Sequence[DeviceClient],
    fill: Callable[[], None],
    *,
    samples: int = DEFAULT_SAMPLES,
    margin_s: float = DEFAULT_MARGIN_S,
    zero: bool = True,
) -> SyncReport:
    """Measure the clocks (zeroed first with ``zero``), hold every device (call 31 armed
    :data:`HOLD_S` ahead) while ``fill()`` gives each its first values, then arm every
    device to start on the same instant, ``4 + len(clients)`` of the slowest round trips
    plus ``margin_s`` ahead.

    Unlike :func:`synchronise_start` followed by the filling, a host held up while it fills
    (a loaded computer) only starts later: no device starts when its first values come,
    late and out of step with the others.

    Raises:
        ArgumentError: as :func:`synchronise_start`.
        StartMissedError: a device confirmed the real start only after its tick: one may
            have started on its own (what it was given is still in its queue or curve: the
            caller empties them).
    """
    return _start(clients, fill, samples=samples, margin_s=margin_s, zero=zero)


def _start(clients: Sequence[DeviceClient], fill: Callable[[], None] | None, *, samples: int,
           margin_s: float, zero: bool) -> SyncReport:
    """:func:`synchronise_start`, or with ``fill`` :func:`start_filled`."""
    if not (math.isfinite(margin_s) and margin_s >= 0):
        raise ArgumentError(f"margin_s {margin_s!r} must be >= 0", reason="margin_s")
    clock = shared_clock(clients)
    if zero:
        zero_clocks(clients)
    estimates = measure_clocks(clients, samples=samples)
    if fill is not None:
        arm_start(clients, estimates, start_s=clock.now() + HOLD_S)
        fill()
    lead_s = (4 + len(clients)) * max(e.rtt_s for e in estimates) + margin_s
    return arm_start(clients, estimates, start_s=clock.now() + lead_s)


def held_up(error: StartMissedError, *, what: str, again: str) -> StartMissedError:
    """``error`` told as a front says it: the host held up while it armed ``what``'s
    common start (the axes, the joints), each held where it stood, and ``again`` (what to
    do: run it again)."""
    return StartMissedError(
        f"{error.device}: the host was held up while it armed the {what}' common start (the"
        f" arming was confirmed only after the start tick): one may have started out of step"
        f" with the others, so each was held where it stood; {again}",
        device=error.device, call=error.call)
