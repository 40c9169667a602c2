"""The coolant and laser outputs of a run, each change on the device tick its move starts on.

A program's output changes (:class:`~usbmotion.motion.gcode.OutputChange`: ``M7``/``M8``/
``M9``, and on a laser machine ``M3``/``M4``/``M5`` with ``S``) apply from the first move at
or after their line. The run streams rows of setpoints, row ``r`` due on device tick
``start + r x scalar``; :class:`RunOutputs` turns the rows since the last start into the
value of each output on each row, and each change of value into a change queued on the
output's device for that tick (call 42: every axis's device shares the synchronised clock,
so the output changes on exactly the tick the move's first setpoint is taken). A laser is
off during rapids and dwells; with ``M4`` its power follows the path speed of the rows
(the speed the axes are told on each tick) over the move's feed, in steps of
:data:`DYNAMIC_STEP` per mille at most every :data:`DYNAMIC_ROWS_S`.

A device queues 16 changes: those due within :data:`LEAD_S` are sent at each look, as its
queue has room. A seam (an override, a hold's deceleration, a resume, more lines of a fed
program) drops the pending changes (call 43) and queues them again from the new rows; a
hold or a stop turns the laser off at once (grbl's laser mode), and a fault on a device
turns its outputs off on the fault's tick.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from usbmotion.host.config import OutputsConfig
from usbmotion.host.device import DeviceClient
from usbmotion.motion.gcode import OutputChange
from usbmotion.motion.planner import Plan, SegmentKind
from usbmotion.session.legs import Legs
from usbmotion.session.report import OutputRecord

LEAD_S = 1.0
"""How far ahead of the devices' clock output changes are queued, s."""
DYNAMIC_STEP = 10
"""A dynamic laser's power changes in steps of this many per mille at least."""
DYNAMIC_ROWS_S = 0.005
"""... and at most this often, s."""


@dataclass(frozen=True, slots=True)
class QueuedChange:
    """One change as a device takes it: output ``name`` to ``value`` on ``tick`` (row
    ``row`` of the rows since the last start)."""

    name: str
    row: int
    tick: int
    value: int


def nominal_speeds(plan: Plan, velocity_mm_s: list[float]) -> npt.NDArray[np.float64]:
    """Each segment's nominal path speed: its feed, at most what every axis may do along
    its direction (grbl's programmed rate); one more entry (1) for after the end."""
    unit = np.abs(np.asarray(plan.unit, dtype=np.float64))
    limits = np.asarray(velocity_mm_s, dtype=np.float64)[: unit.shape[1]] if len(plan) else (
        np.zeros(0))
    with np.errstate(divide="ignore"):
        reach = np.where(unit > 1e-12, limits / np.maximum(unit, 1e-12), np.inf).min(
            axis=1) if len(plan) else np.zeros(0)
    speeds = np.minimum(np.asarray(plan.feed_mm_s, dtype=np.float64), reach)
    return np.append(speeds, 1.0)


def segment_values(plan: Plan, changes: tuple[OutputChange, ...], name: str
                   ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
    """Output ``name``'s value on each segment of ``plan`` (the last change at or before
    the segment's line; a laser 0 on rapids and dwells), and whether it is dynamic there.
    One more entry for after the last segment (the program's end)."""
    count = len(plan)
    values = np.zeros(count + 1, dtype=np.int64)
    dynamic = np.zeros(count + 1, dtype=bool)
    lines = np.asarray(plan.line, dtype=np.int64)
    for change in changes:
        if change.output != name:
            continue
        first = int(np.searchsorted(lines, change.line, side="left")) if count else 0
        values[first:] = change.value
        dynamic[first:] = change.dynamic
    if name == "laser" and count:
        feeding = (plan.kind == SegmentKind.LINEAR) | (plan.kind == SegmentKind.ARC)
        values[:count][~feeding] = 0
        values[count] = 0
    return values, dynamic


class RunOutputs:
    """A run's outputs (see the module docstring).

    Parameters:
        config: the machine's ``[outputs]``.
        clients: axis -> its device's client.
        changes: the program's output changes.
        period_s: the motion period, s.
    """

    def __init__(self, config: OutputsConfig, clients: Mapping[str, DeviceClient],
                 changes: tuple[OutputChange, ...], *, period_s: float) -> None:
        self.config = config
        self.clients = {name: clients[pin.axis] for name, pin in config.pins.items()}
        self.devices = list({id(c): c for c in self.clients.values()}.values())
        """Each device carrying an output, once."""
        self.changes = changes
        self.period_s = period_s
        self.queued: list[QueuedChange] = []
        """The changes of the rows since the last start, in tick order."""
        self.sent = 0
        """How many of :attr:`queued` went to their devices."""
        self.applied: list[QueuedChange] = []
        """Every change sent, in order (what the devices were told)."""
        self._free: dict[int, int] = {}
        self._shown: dict[str, int] = {}
        self._cursor = 0

    def rebuild(self, legs: Legs, *, start_tick: int, scalar: int, from_row: int) -> None:
        """The changes from row ``from_row`` on, from the rows since the last start: the
        pending ones dropped on the devices first."""
        now: dict[int, tuple[int, ...]] = {}
        for client in self.devices:
            now[id(client)] = client.outputs(clear=True).values
        self._free.clear()
        if not self.applied:
            self._shown = {name: now[id(self.clients[name])][pin.output]
                           for name, pin in self.config.pins.items()}
        self._forget_after(start_tick + from_row * scalar)
        plan = legs.plan
        rows = np.arange(legs.count, dtype=np.float64)
        segments = legs.segments(rows) if legs.count else np.zeros(0, dtype=np.int64)
        segments = np.where(segments < 0, len(plan), segments)
        speed = self._speeds(legs)
        nominal = nominal_speeds(plan, [limit.velocity_mm_s for limit in legs.limits])
        queued: list[QueuedChange] = []
        for name in self.config.pins:
            values, dynamic = segment_values(plan, self.changes, name)
            per_row = values[segments]
            if name == "laser" and dynamic.any():
                per_row = self._dynamic(per_row, dynamic[segments], nominal[segments], speed)
            pin = self.config.pins[name]
            before = (per_row[from_row - 1] if from_row > 0
                      else now[id(self.clients[name])][pin.output])
            tail = per_row[from_row:]
            if not tail.size:
                continue
            edges = np.flatnonzero(np.diff(tail, prepend=before) != 0)
            queued += [QueuedChange(name, from_row + int(i), start_tick
                                    + (from_row + int(i)) * scalar, int(tail[i]))
                       for i in edges]
        queued.sort(key=lambda change: (change.tick, change.name))
        self.queued = queued
        self.sent = 0

    def _speeds(self, legs: Legs) -> npt.NDArray[np.float64]:
        """The path speed of each row (mm/s), from the trapezoid of the leg's segment it is
        sampled from: the speed the axes are told on its tick, without the counts'
        quantisation."""
        count = legs.count
        out = np.zeros(count)
        bounds = [first for first, _ in legs.legs[1:]] + [count]
        for (first, leg), end in zip(legs.legs, bounds, strict=True):
            plan = leg.plan
            if end <= first or not len(plan):
                continue
            t = (np.arange(first, end) - first) * self.period_s
            at = np.clip(np.searchsorted(plan.start_time_s, t, side="right") - 1, 0,
                         len(plan) - 1)
            tau = t - plan.start_time_s[at]
            accel = plan.accel_mm_s2[at]
            t_accel, t_cruise = plan.t_accel_s[at], plan.t_cruise_s[at]
            v_cruise = plan.v_cruise_mm_s[at]
            speed = np.where(tau < t_accel, plan.v_entry_mm_s[at] + accel * tau,
                             np.where(tau < t_accel + t_cruise, v_cruise,
                                      v_cruise - accel * (tau - t_accel - t_cruise)))
            speed = np.where(plan.kind[at] == SegmentKind.DWELL, 0.0, speed)
            out[first:end] = np.maximum(speed, 0.0)
        return out

    def _dynamic(self, per_row: npt.NDArray[np.int64], dynamic: npt.NDArray[np.bool_],
                 nominal: npt.NDArray[np.float64],
                 speed: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
        """grbl's M4: the power times the speed over the move's nominal speed (its feed,
        at most what the axes may do along it), in steps of :data:`DYNAMIC_STEP`,
        changed at most every :data:`DYNAMIC_ROWS_S`."""
        share = np.minimum(1.0, speed / np.maximum(nominal, 1e-9))
        scaled = np.floor(per_row * share / DYNAMIC_STEP) * DYNAMIC_STEP
        out = np.where(dynamic & (per_row > 0), scaled, per_row).astype(np.int64)
        every = max(1, round(DYNAMIC_ROWS_S / self.period_s))
        if every > 1:
            index = np.arange(out.size)
            mark = (index % every == 0) | ~dynamic | (per_row == 0)
            out = out[np.maximum.accumulate(np.where(mark, index, 0))]
        return out

    def service(self, now_tick: float, *, tick_s: float) -> None:
        """Send the changes due within :data:`LEAD_S` that their devices have room for."""
        horizon = now_tick + LEAD_S / tick_s
        while self.sent < len(self.queued):
            change = self.queued[self.sent]
            if change.tick > horizon:
                return
            client = self.clients[change.name]
            key = id(client)
            if self._free.get(key, 1) <= 0:
                self._free[key] = client.outputs().free
                if self._free[key] <= 0:
                    return
            pin = self.config.pins[change.name]
            value = change.value if pin.output >= 2 else (1000 if change.value else 0)
            answer = client.set_output_at(pin.output, value, max(0, change.tick))
            self._free[key] = answer.free
            self.applied.append(change)
            self.sent += 1

    def finish(self, plan: Plan, *, tick: int) -> None:
        """The run's end: each output to its value after the program's last change (0
        after an ``M2``: LinuxCNC and grbl switch coolant and laser off), where the last
        change sent left it otherwise."""
        for name, pin in self.config.pins.items():
            values, _ = segment_values(plan, self.changes, name)
            end = int(values[-1])
            told = [change.value for change in self.applied if change.name == name]
            if told and told[-1] == end:
                continue
            if not told and end == 0:
                continue
            value = end if pin.output >= 2 else (1000 if end else 0)
            self.clients[name].set_output_at(pin.output, value, max(0, tick))
            self.applied.append(QueuedChange(name, -1, tick, end))

    def _forget_after(self, tick: int) -> None:
        """The changes sent for after ``tick`` were dropped on their devices (call 43 1):
        they never happen."""
        kept = [change for change in self.applied if change.tick <= tick]
        if len(kept) != len(self.applied):
            self.applied = kept
            self._cursor = min(self._cursor, len(kept))

    def values_at(self, tick: float) -> dict[str, int]:
        """Each output's value on device tick ``tick`` (ticks only go forward)."""
        applied = self.applied
        while self._cursor < len(applied) and applied[self._cursor].tick <= tick:
            change = applied[self._cursor]
            self._shown[change.name] = change.value
            self._cursor += 1
        return dict(self._shown)

    def records(self) -> tuple[OutputRecord, ...]:
        """Each output's changes as the run's report gives them."""
        records = []
        for name in self.config.pins:
            told = [change.value for change in self.applied if change.name == name]
            records.append(OutputRecord(name, len(told), max(told, default=0),
                                        told[-1] if told else 0))
        return tuple(records)

    def off_now(self, names: tuple[str, ...], *, tick: int) -> None:
        """Outputs ``names`` off from device tick ``tick`` (a hold, a stop), the pending
        changes dropped."""
        for client in self.devices:
            client.outputs(clear=True)
        self._free.clear()
        self._forget_after(tick)
        self.queued = []
        self.sent = 0
        for name in names:
            if name in self.config.pins:
                pin = self.config.pins[name]
                self.clients[name].set_output_at(pin.output, 0, max(0, tick))
                self.applied.append(QueuedChange(name, -1, tick, 0))


def laser_names(config: OutputsConfig | None) -> tuple[str, ...]:
    """The outputs a hold turns off: the laser (coolant runs on through a hold)."""
    return tuple(name for name in ("laser",) if config is not None and name in config.pins)


__all__ = ["DYNAMIC_ROWS_S", "DYNAMIC_STEP", "LEAD_S", "QueuedChange", "RunOutputs",
           "laser_names", "segment_values"]
