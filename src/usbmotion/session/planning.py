"""Planning a program for a machine: G-code interpreted and planned from a start position
with the machine's limits, and checked against every axis's travel (soft limits).

Pure functions and a frozen dataclass: no device, no clock. Where the machine stands (the
start) is the session's to say (:meth:`MachineSession.start_position_mm`).
"""

from __future__ import annotations

from dataclasses import dataclass

from usbmotion.errors import ConfigError
from usbmotion.host.config import AxisConfig, MachineConfig
from usbmotion.motion.gcode import GCodeProgram, parse_gcode
from usbmotion.motion.limits import AxisLimits, PlannerConfig, check_travel
from usbmotion.motion.offsets import NO_OFFSETS, WorkOffsets
from usbmotion.motion.planner import Plan, plan_moves
from usbmotion.motion.tools import NO_TOOLS, ToolTable
from usbmotion.session.report import PLAN_AXES


@dataclass(frozen=True, slots=True)
class Prepared:
    """A program interpreted and planned from a start position, checked against the travel.

    ``start_mm`` is where the plan starts (X, Y, Z); ``homed`` whether that is a homed
    position (soft limits checked) or the devices' own counts (not homed, not checked).
    ``offsets`` are the work offsets the program started with (``program.offsets`` those it
    leaves).
    """

    program: GCodeProgram
    plan: Plan
    start_mm: tuple[float, float, float]
    homed: bool
    offsets: WorkOffsets = NO_OFFSETS


def prepare_program(config: MachineConfig, text: str, *, file: str,
                    start_mm: tuple[float, float, float], homed: bool,
                    tools: ToolTable = NO_TOOLS,
                    offsets: WorkOffsets | None = None) -> Prepared:
    """Interpret and plan a program for a machine from ``start_mm`` with a tool table and
    work offsets (machine coordinates result); a homed start is also checked against every
    axis's travel.

    Raises:
        GCodeError, PlanningError: as :func:`plan_gcode`.
        SoftLimitError: a move leaves an axis's travel (names the line, the axis, the
            coordinate and the limit).
        ConfigError: the machine lacks an X, Y or Z axis.
    """
    offsets = offsets or WorkOffsets()
    program, plan = plan_gcode(config, text, file=file, start_mm=start_mm, tools=tools,
                               offsets=offsets)
    if homed:
        check_travel(plan.vertices_mm, plan.line, [a.travel_mm for a in plan_axes(config)],
                     axes=PLAN_AXES)
    return Prepared(program, plan, start_mm, homed, offsets)


def plan_gcode(config: MachineConfig, text: str, *, file: str = "<string>",
               start_mm: tuple[float, float, float] = (0.0, 0.0, 0.0),
               tools: ToolTable = NO_TOOLS, offsets: WorkOffsets | None = None,
               ) -> tuple[GCodeProgram, Plan]:
    """Interpret and plan a program for a machine from ``start_mm`` (pure: no machine is
    needed; :meth:`MachineSession.prepare` adds where the machine stands and soft limits).

    Raises:
        GCodeError, PlanningError: as :meth:`MachineSession.prepare`.
        ConfigError: the machine lacks an X, Y or Z axis.
    """
    limits, planner, _ = planner_inputs(config)
    program = parse_gcode(text, file=file, start=start_mm, tools=tools, offsets=offsets)
    return program, plan_moves(program.moves, limits, planner, start=start_mm)


def plan_axes(config: MachineConfig) -> list[AxisConfig]:
    """The configs of the axes a program moves: X, Y and Z.

    Raises:
        ConfigError: the machine lacks an X, Y or Z axis.
    """
    planner_inputs(config)
    return [config.axis(name) for name in PLAN_AXES]


def planner_inputs(config: MachineConfig) -> tuple[list[AxisLimits], PlannerConfig, list[float]]:
    """Per-axis limits, planner settings and counts per mm of X, Y, Z from a machine config.

    Raises:
        ConfigError: the machine lacks an X, Y or Z axis.
    """
    missing = [name for name in PLAN_AXES if name not in config.axis_names]
    if missing:
        raise ConfigError(
            f"{config.path}: G-code programs need axes X, Y and Z; missing {', '.join(missing)}",
            path=str(config.path), key="axes",
        )
    axes = [config.axis(name) for name in PLAN_AXES]
    limits = [AxisLimits(a.max_velocity_mm_s, a.max_accel_mm_s2) for a in axes]
    planner = PlannerConfig(
        junction_deviation_mm=config.junction_deviation_mm,
        arc_tolerance_mm=config.arc_tolerance_mm,
    )
    return limits, planner, [a.counts_per_mm for a in axes]
