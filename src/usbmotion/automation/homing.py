"""Homing: drive each axis onto its lower limit switch and call that position zero.

The inputs and outputs are the seed's: limit switches in, target velocities out, in
human units (mm, mm/s). :class:`MoveAxisHome` homes one axis; :class:`Home` homes several,
all together or in a configured order (e.g. Z first, then X and Y together).
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
    Fault,
    FaultKind,
    Incomplete,
    Transition,
)
from usbmotion.errors import OutOfRangeError


@dataclass(frozen=True, slots=True)
class LimitSwitchState:
    """The two limit switches of one axis."""

    at_lower_limit: bool = False
    at_upper_limit: bool = False


class HomingInputs(Protocol):
    """What homing reads."""

    def limit_switches(self, axis: str) -> LimitSwitchState | None:
        """The axis's switches, or ``None`` if there is no such axis."""
        ...

    def position_mm(self, axis: str) -> float:
        """The axis's actual position."""
        ...


class HomingOutputs(Protocol):
    """What homing drives."""

    def set_target_velocity(self, axis: str, velocity_mm_s: float) -> None:
        """Move the axis at this velocity (0 stops it)."""
        ...

    def zero_position(self, axis: str) -> None:
        """Call the axis's present position zero (call 23)."""
        ...


class _Phase(Enum):
    APPROACH = "approach"
    BACK_OFF = "back off"
    SLOW_APPROACH = "slow approach"
    DONE = "done"


class MoveAxisHome:
    """Home one axis onto its lower limit switch.

    With ``backoff_mm == 0`` this is the seed's sequence: move toward the lower switch at
    ``homing_speed_mm_s``; the lower switch stops the axis, zeroes it and completes; the
    upper switch first is a fault. With ``backoff_mm > 0`` the first touch is followed by
    backing off until the switch opens and ``backoff_mm`` is cleared, then a slow
    re-approach at ``slow_speed_mm_s``, so the zero is taken at a low, repeatable speed.

    Parameters:
        axis: the axis name.
        homing_speed_mm_s: approach speed (> 0).
        slow_speed_mm_s: re-approach and back-off speed (> 0; default a tenth of the
            approach speed).
        backoff_mm: distance to back off after the first touch (0 = no re-approach).
    """

    def __init__(
        self,
        axis: str,
        homing_speed_mm_s: float,
        *,
        slow_speed_mm_s: float | None = None,
        backoff_mm: float = 0.0,
    ) -> None:
        _positive(homing_speed_mm_s, "homing_speed_mm_s")
        slow = homing_speed_mm_s / 10 if slow_speed_mm_s is None else slow_speed_mm_s
        _positive(slow, "slow_speed_mm_s")
        if not (math.isfinite(backoff_mm) and backoff_mm >= 0):
            raise OutOfRangeError(f"backoff_mm {backoff_mm!r} must be >= 0", reason="backoff_mm")
        self.axis = axis
        self.homing_speed_mm_s = homing_speed_mm_s
        self.slow_speed_mm_s = slow
        self.backoff_mm = backoff_mm
        self._phase = _Phase.APPROACH
        self._backoff_start_mm = 0.0

    @property
    def phase(self) -> str:
        """Where the sequence is: approach, back off, slow approach, done."""
        return self._phase.value

    def stop(self, outputs: HomingOutputs) -> None:
        """Stop the axis (used when another axis faults)."""
        if self._phase is not _Phase.DONE:
            outputs.set_target_velocity(self.axis, 0.0)
            self._phase = _Phase.DONE

    def _finish(self, outputs: HomingOutputs, result: Transition) -> Transition:
        outputs.set_target_velocity(self.axis, 0.0)
        self._phase = _Phase.DONE
        return result

    def _zero_here(self, outputs: HomingOutputs) -> Transition:
        """Stop on the lower switch, call the position zero and complete."""
        outputs.set_target_velocity(self.axis, 0.0)
        outputs.zero_position(self.axis)
        self._phase = _Phase.DONE
        return Complete

    def poll(self, inputs: HomingInputs, outputs: HomingOutputs) -> Transition:
        """One step of homing."""
        if self._phase is _Phase.DONE:
            return Complete
        switches = inputs.limit_switches(self.axis)
        if switches is None:
            self._phase = _Phase.DONE
            return Fault.axis_not_found(self.axis)
        if switches.at_upper_limit:
            return self._finish(outputs, Fault.unexpected_upper_limit(self.axis))
        if self._phase is _Phase.APPROACH:
            if not switches.at_lower_limit:
                outputs.set_target_velocity(self.axis, -self.homing_speed_mm_s)
                return Incomplete
            if self.backoff_mm == 0:
                return self._zero_here(outputs)
            self._phase = _Phase.BACK_OFF
            self._backoff_start_mm = inputs.position_mm(self.axis)
        if self._phase is _Phase.BACK_OFF:
            travelled = inputs.position_mm(self.axis) - self._backoff_start_mm
            if switches.at_lower_limit or travelled < self.backoff_mm:
                if switches.at_lower_limit and travelled > 3 * self.backoff_mm + 1.0:
                    return self._finish(
                        outputs,
                        Fault(FaultKind.LIMIT_NOT_RELEASED, self.axis,
                              f"still closed {travelled:.3f} mm off the switch"),
                    )
                outputs.set_target_velocity(self.axis, self.slow_speed_mm_s)
                return Incomplete
            self._phase = _Phase.SLOW_APPROACH
        if not switches.at_lower_limit:
            outputs.set_target_velocity(self.axis, -self.slow_speed_mm_s)
            return Incomplete
        return self._zero_here(outputs)


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
            raise OutOfRangeError(f"homing order {order!r} names an axis twice", reason="order")
        stages: list[AutomationSequence[HomingInputs, HomingOutputs]] = [
            All([make(name) for name in group]) for group in groups
        ]
        self._inner: Chain[HomingInputs, HomingOutputs] = Chain(stages)

    def poll(self, inputs: HomingInputs, outputs: HomingOutputs) -> Transition:
        """One step of homing every axis."""
        return self._inner.poll(inputs, outputs)

    def stop(self, outputs: HomingOutputs) -> None:
        """Stop whatever is moving."""
        self._inner.stop(outputs)


def _positive(value: float, name: str) -> None:
    if not (math.isfinite(value) and value > 0):
        raise OutOfRangeError(f"{name} {value!r} must be a finite number > 0", reason=name)
