"""What a front shows while the machine homes or runs: its state, the program line and
where each axis is."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from usbmotion.session.state import MachineState


@dataclass(frozen=True, slots=True)
class Progress:
    """One progress report of a homing or a run.

    Fields:
        state: the machine's state (Homing, Run).
        position_mm: axis -> position, mm: while running, the setpoint the devices have
            reached by the session's estimate; while homing, each axis's actual position
            as last read (device counts until its zero is set).
        line: the G-code line being executed (0: none, as while homing).
        done_s: program seconds done (0 while homing).
        total_s: program seconds in all (0 while homing).
        actual_mm: while running, axis -> where its encoder was at its last diagnostics
            line (up to the trace's period old), mm.
        following_error_mm: while running, axis -> actual minus commanded position at
            that line, mm.
    """

    state: MachineState
    position_mm: Mapping[str, float] = field(default_factory=dict)
    line: int = 0
    done_s: float = 0.0
    total_s: float = 0.0
    actual_mm: Mapping[str, float] = field(default_factory=dict)
    following_error_mm: Mapping[str, float] = field(default_factory=dict)

    def describe(self) -> str:
        """One line: ``Run  line 12  X 10.000  Y 5.000  Z 1.000 mm``."""
        parts = [self.state.value]
        if self.line:
            parts.append(f"line {self.line}")
        if self.position_mm:
            parts.append("  ".join(f"{axis} {mm:.3f}" for axis, mm in self.position_mm.items())
                         + " mm")
        return "  ".join(parts)
