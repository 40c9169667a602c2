"""The machine session: the state, position and program of a connected machine, operated.

:class:`MachineSession` is what ``usbmotion run``, the console and every front drive.
"""

from usbmotion.session.homing import home_position_mm, homed_mark
from usbmotion.session.live import LiveSnapshot
from usbmotion.session.planning import Prepared, plan_gcode, planner_inputs
from usbmotion.session.report import AxisResult, FaultRecord, IgnoredWordRecord, RunReport, Trace
from usbmotion.session.report_text import describe
from usbmotion.session.session import MachineSession
from usbmotion.session.state import TRANSITIONS, MachineState, StopReason, check_transition
from usbmotion.session.watch import trace_period_s

__all__ = [
    "TRANSITIONS",
    "AxisResult",
    "FaultRecord",
    "IgnoredWordRecord",
    "LiveSnapshot",
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
