"""The machine session: the state, position and program of a connected machine, operated.

:class:`MachineSession` is what ``usbmotion run``, the console and every front drive.
"""

from usbmotion.session.report import (
    AxisResult,
    FaultRecord,
    IgnoredWordRecord,
    RunReport,
    Trace,
    describe,
)
from usbmotion.session.session import (
    MachineSession,
    Prepared,
    home_position_mm,
    homed_mark,
    plan_gcode,
    planner_inputs,
    trace_period_s,
)
from usbmotion.session.state import TRANSITIONS, MachineState, StopReason, check_transition

__all__ = [
    "TRANSITIONS",
    "AxisResult",
    "FaultRecord",
    "IgnoredWordRecord",
    "MachineSession",
    "MachineState",
    "Prepared",
    "RunReport",
    "StopReason",
    "Trace",
    "check_transition",
    "describe",
    "home_position_mm",
    "homed_mark",
    "plan_gcode",
    "planner_inputs",
    "trace_period_s",
]
