"""Homing: find each axis's reference switch the way real controllers do, and zero on it.

The cycle is grbl's, for a servo axis whose device latches the encoder count on the tick a
switch changes (call 36), so the zero does not depend on when the host looked:

1. **seek**: toward the switch at the seek speed, at most ``search_mm`` (a fault naming the
   axis and the distance when no switch closes);
2. **back off**: away at the slow speed until the switch has opened and ``backoff_mm`` is
   cleared (a fault when it does not open);
3. **locate**: back toward it at the slow speed until it closes again: the device's latched
   count of that closing edge is the reference; the axis goes on a little into the switch
   (``LOCATE_INTO_MM``) before it stops, so it does not rest on the edge;
4. **pull off**: the outputs zero the axis from that latched count, once, and move it
   ``pull_off_mm`` off the switch in position mode; a switch still closed then is a fault
   (with no pull-off the axis rests on its switch, as in the seed's sequence).

Every change of speed is a ramp at the axis's acceleration (the outputs' business), and each
phase waits for the axis to come to rest before the next one starts.

The inputs and outputs are the seed's, in human units (mm, mm/s) and in the homing
orientation: toward the switch is negative and that switch is the "lower" one, whichever
end of the axis it really is (:class:`~usbmotion.automation.device_io.DeviceHomingIO`
turns an axis that homes upward around). :class:`MoveAxisHome` homes one axis;
:class:`Home` homes several, all together or in a configured order (Z first, say).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Protocol

from usbmotion.automation.sequence import (
    All,
    AutomationSequence,
    Chain,
    Complete,
    Failure,
    FailureKind,
    Incomplete,
    Transition,
)
from usbmotion.errors import ArgumentError

LOCATE_INTO_MM = 0.05
"""How far past the latched edge the slow locate goes before it stops: the axis then rests
inside the switch, not on its edge, where the position loop's dither of a count would open
and close it again (and a switch closing in position mode is a fault)."""
LOCATE_SCALE = 5.0
"""How far the back-off and the slow locate may go, in back-off distances (plus 1 mm),
before the switch is declared stuck or lost (grbl's locate scalar)."""


@dataclass(frozen=True, slots=True)
class LimitSwitchState:
    """The two limit switches of one axis (in the homing orientation)."""

    at_lower_limit: bool = False
    at_upper_limit: bool = False


@dataclass(frozen=True, slots=True)
class SwitchEdgeReading:
    """The device's latch of the homing switch: ``edges`` counted since power-up, whether
    the last one closed it, and where the axis was on that tick (mm, homing orientation)."""

    edges: int
    closed: bool
    position_mm: float


class HomingInputs(Protocol):
    """What homing reads."""

    def limit_switches(self, axis: str) -> LimitSwitchState | None:
        """The axis's switches, or ``None`` if there is no such axis."""
        ...

    def position_mm(self, axis: str) -> float:
        """The axis's actual position."""
        ...

    def switch_edge(self, axis: str) -> SwitchEdgeReading:
        """The latched last edge of the switch the axis homes onto."""
        ...

    def at_rest(self, axis: str) -> bool:
        """True once what was last commanded has played out and the axis stands still."""
        ...


class HomingOutputs(Protocol):
    """What homing drives."""

    def set_target_velocity(self, axis: str, velocity_mm_s: float) -> None:
        """Ramp the axis to this velocity (0 stops it along its deceleration)."""
        ...

    def zero_and_pull_off(self, axis: str, edge: SwitchEdgeReading, pull_off_mm: float) -> None:
        """Set machine zero from the latched ``edge`` (once) and move ``pull_off_mm`` off the
        switch along a planned move."""
        ...


class Phase(Enum):
    """Where one axis's homing is."""

    SEEK = "seek"
    SEEK_STOP = "seek stop"
    BACK_OFF = "back off"
    BACK_OFF_STOP = "back-off stop"
    LOCATE = "locate"
    LOCATE_STOP = "locate stop"
    PULL_OFF = "pull off"
    DONE = "done"


class MoveAxisHome:
    """Home one axis onto its switch (see the module docstring for the cycle).

    Parameters:
        axis: the axis name.
        homing_speed_mm_s: seek speed (> 0).
        slow_speed_mm_s: back-off and locate speed (> 0; default a tenth of the seek speed).
        backoff_mm: how far to back off the switch before the slow locate (0: the seek's own
            edge is the reference, as in the seed's sequence).
        search_mm: the longest seek (> 0; default unbounded, which a machine never uses:
            the session passes 1.5 x the travel).
        pull_off_mm: how far the axis ends off the switch (>= 0).

    Raises:
        ArgumentError: a speed or distance out of its range.
    """

    def __init__(
        self,
        axis: str,
        homing_speed_mm_s: float,
        *,
        slow_speed_mm_s: float | None = None,
        backoff_mm: float = 0.0,
        search_mm: float = math.inf,
        pull_off_mm: float = 0.0,
    ) -> None:
        _positive(homing_speed_mm_s, "homing_speed_mm_s")
        slow = homing_speed_mm_s / 10 if slow_speed_mm_s is None else slow_speed_mm_s
        _positive(slow, "slow_speed_mm_s")
        _not_negative(backoff_mm, "backoff_mm")
        _not_negative(pull_off_mm, "pull_off_mm")
        if math.isnan(search_mm) or search_mm <= 0:
            raise ArgumentError(f"search_mm {search_mm!r} must be > 0", reason="search_mm")
        self.axis = axis
        self.homing_speed_mm_s = homing_speed_mm_s
        self.slow_speed_mm_s = slow
        self.backoff_mm = backoff_mm
        self.search_mm = search_mm
        self.pull_off_mm = pull_off_mm
        self._phase = Phase.SEEK
        self._started = False
        self._mark_mm = 0.0
        """Where the current phase started (seek, back off, locate), mm."""
        self._edges = 0
        """The switch's edge count when the current phase started."""
        self._reference: SwitchEdgeReading | None = None
        self._phase_seen: Phase | None = None
        self.seen_closed_mm: float | None = None
        """Where the axis was at the poll that first saw the switch close on the edge it
        was zeroed on: where a host that zeroes on what it polls would have put the zero."""

    @property
    def phase(self) -> str:
        """Where the sequence is: seek, back off, locate, pull off, done, ..."""
        return self._phase.value

    @property
    def reference(self) -> SwitchEdgeReading | None:
        """The latched edge the axis was zeroed on, once it has been."""
        return self._reference

    def stop(self, outputs: HomingOutputs) -> None:
        """Stop the axis along its deceleration (used when another axis faults, or the
        operator interrupts); the sequence is over."""
        if self._phase is not Phase.DONE:
            outputs.set_target_velocity(self.axis, 0.0)
            self._phase = Phase.DONE

    def _fault(self, outputs: HomingOutputs, fault: Failure) -> Transition:
        outputs.set_target_velocity(self.axis, 0.0)
        self._phase = Phase.DONE
        return fault

    def _begin(self, phase: Phase, inputs: HomingInputs) -> None:
        self._phase = phase
        self._mark_mm = inputs.position_mm(self.axis)
        self._edges = inputs.switch_edge(self.axis).edges

    def poll(self, inputs: HomingInputs, outputs: HomingOutputs) -> Transition:
        """One step of homing."""
        if self._phase is Phase.DONE:
            return Complete
        switches = inputs.limit_switches(self.axis)
        if switches is None:
            self._phase = Phase.DONE
            return Failure.axis_not_found(self.axis)
        if switches.at_upper_limit:
            return self._fault(outputs, Failure.unexpected_upper_limit(self.axis))
        if not self._started:
            self._started = True
            self._begin(Phase.SEEK, inputs)
        phase = self._phase
        if phase is Phase.SEEK:
            return self._seek(inputs, outputs, switches)
        if phase is Phase.BACK_OFF:
            return self._back_off(inputs, outputs, switches)
        if phase is Phase.LOCATE:
            return self._locate(inputs, outputs, switches)
        if not inputs.at_rest(self.axis):
            return Incomplete
        if phase is Phase.SEEK_STOP:
            if self.backoff_mm == 0:
                return self._zero(inputs, outputs)
            self._begin(Phase.BACK_OFF, inputs)
            outputs.set_target_velocity(self.axis, self.slow_speed_mm_s)
            return Incomplete
        if phase is Phase.BACK_OFF_STOP:
            self._begin(Phase.LOCATE, inputs)
            outputs.set_target_velocity(self.axis, -self.slow_speed_mm_s)
            return Incomplete
        if phase is Phase.LOCATE_STOP:
            return self._zero(inputs, outputs)
        # PULL_OFF: the planned move has played out.
        self._phase = Phase.DONE
        if switches.at_lower_limit and self.pull_off_mm > 0:
            return Failure(FailureKind.LIMIT_NOT_RELEASED, self.axis,
                         f"still closed {self.pull_off_mm:g} mm off the switch after homing")
        return Complete

    def _seek(self, inputs: HomingInputs, outputs: HomingOutputs,
              switches: LimitSwitchState) -> Transition:
        if switches.at_lower_limit:
            self.seen_closed_mm = inputs.position_mm(self.axis)
            outputs.set_target_velocity(self.axis, 0.0)
            self._phase = Phase.SEEK_STOP
            return Incomplete
        travelled = self._mark_mm - inputs.position_mm(self.axis)
        if travelled > self.search_mm:
            return self._fault(outputs, Failure(
                FailureKind.SWITCH_NOT_FOUND, self.axis,
                f"no switch within {self.search_mm:g} mm of the seek (travelled"
                f" {travelled:.3f} mm); check the switch, its wiring and homing.direction"))
        outputs.set_target_velocity(self.axis, -self.homing_speed_mm_s)
        return Incomplete

    def _back_off(self, inputs: HomingInputs, outputs: HomingOutputs,
                  switches: LimitSwitchState) -> Transition:
        position = inputs.position_mm(self.axis)
        if switches.at_lower_limit:
            travelled = position - self._mark_mm
            if travelled > LOCATE_SCALE * self.backoff_mm + 1.0:
                return self._fault(outputs, Failure(
                    FailureKind.LIMIT_NOT_RELEASED, self.axis,
                    f"still closed {travelled:.3f} mm off the switch"))
            outputs.set_target_velocity(self.axis, self.slow_speed_mm_s)
            return Incomplete
        edge = inputs.switch_edge(self.axis)
        opened_at = edge.position_mm if (edge.edges != self._edges and not edge.closed) else (
            self._mark_mm)
        if position - opened_at < self.backoff_mm:
            outputs.set_target_velocity(self.axis, self.slow_speed_mm_s)
            return Incomplete
        outputs.set_target_velocity(self.axis, 0.0)
        self._phase = Phase.BACK_OFF_STOP
        return Incomplete

    def _locate(self, inputs: HomingInputs, outputs: HomingOutputs,
                switches: LimitSwitchState) -> Transition:
        edge = inputs.switch_edge(self.axis)
        if switches.at_lower_limit or (edge.edges != self._edges and edge.closed):
            position = inputs.position_mm(self.axis)
            if self.seen_closed_mm is None or self._phase_seen != Phase.LOCATE:
                self.seen_closed_mm = position
                self._phase_seen = Phase.LOCATE
            if edge.closed and position > edge.position_mm - LOCATE_INTO_MM:
                outputs.set_target_velocity(self.axis, -self.slow_speed_mm_s)
                return Incomplete
            outputs.set_target_velocity(self.axis, 0.0)
            self._phase = Phase.LOCATE_STOP
            return Incomplete
        travelled = self._mark_mm - inputs.position_mm(self.axis)
        reach = LOCATE_SCALE * self.backoff_mm + 1.0
        if travelled > reach:
            return self._fault(outputs, Failure(
                FailureKind.SWITCH_NOT_FOUND, self.axis,
                f"the switch did not close again within {reach:g} mm of the slow locate"))
        outputs.set_target_velocity(self.axis, -self.slow_speed_mm_s)
        return Incomplete

    def _zero(self, inputs: HomingInputs, outputs: HomingOutputs) -> Transition:
        edge = inputs.switch_edge(self.axis)
        if not edge.closed or edge.edges == 0:
            return self._fault(outputs, Failure(
                FailureKind.SWITCH_NOT_FOUND, self.axis,
                "the device latched no closing edge of the switch"))
        self._reference = edge
        outputs.zero_and_pull_off(self.axis, edge, self.pull_off_mm)
        self._phase = Phase.PULL_OFF
        return Incomplete


HomingGroup = str | Sequence[str]


class Home:
    """Home several axes: all together, or group by group in a given order.

    ``order`` lists axis names or groups of names: ``["Z", ["X", "Y"]]`` homes Z first,
    then X and Y together. By default every axis of ``axes`` homes at once, as in the
    seed. ``make`` builds the one-axis sequence for a name.
    """

    def __init__(
        self,
        axes: Sequence[str],
        make: Callable[[str], MoveAxisHome],
        *,
        order: Sequence[HomingGroup] | None = None,
    ) -> None:
        groups: list[list[str]] = []
        if order is None:
            groups = [list(axes)]
        else:
            for group in order:
                groups.append([group] if isinstance(group, str) else list(group))
        named = [name for group in groups for name in group]
        if len(set(named)) != len(named):
            raise ArgumentError(f"homing order {order!r} names an axis twice", reason="order")
        self.axes: dict[str, MoveAxisHome] = {name: make(name) for name in named}
        """The one-axis sequences, by axis name."""
        stages: list[AutomationSequence[HomingInputs, HomingOutputs]] = [
            All([self.axes[name] for name in group]) for group in groups
        ]
        self._inner: Chain[HomingInputs, HomingOutputs] = Chain(stages)

    def poll(self, inputs: HomingInputs, outputs: HomingOutputs) -> Transition:
        """One step of homing every axis."""
        return self._inner.poll(inputs, outputs)

    def stop(self, outputs: HomingOutputs) -> None:
        """Stop whatever is moving, along its deceleration."""
        self._inner.stop(outputs)


def _positive(value: float, name: str) -> None:
    if not (math.isfinite(value) and value > 0):
        raise ArgumentError(f"{name} {value!r} must be a finite number > 0", reason=name)


def _not_negative(value: float, name: str) -> None:
    if not (math.isfinite(value) and value >= 0):
        raise ArgumentError(f"{name} {value!r} must be a finite number >= 0", reason=name)
