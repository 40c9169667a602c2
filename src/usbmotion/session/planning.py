"""Planning a program for a machine: G-code interpreted and planned from a start position
with the machine's limits, and checked against every axis's travel (soft limits).

A program moves the machine's linear axes (X Y Z U V W, those it has, in that order: its
*program axes*); it is read in the dialect the machine file names unless the caller names
another.

Pure functions and a frozen dataclass: no device, no clock. Where the machine stands (the
start) is the session's to say (:meth:`MachineSession.start_position_mm`).
"""

from __future__ import annotations

from dataclasses import dataclass

from usbmotion.errors import ConfigError
from usbmotion.host.config import AxisConfig, MachineConfig
from usbmotion.motion.dialects import Dialect, dialect_named
from usbmotion.motion.gcode import GCodeProgram, MachineAxes, Pauses, parse_gcode
from usbmotion.motion.limits import AxisLimits, PlannerConfig, check_travel, settled_band_mm
from usbmotion.motion.moves import AXIS_ORDER, ROTARY_AXES, Point
from usbmotion.motion.offsets import NO_OFFSETS, WorkOffsets
from usbmotion.motion.planner import Plan, plan_moves
from usbmotion.motion.plunges import plunge_warnings, rapid_plunges
from usbmotion.motion.resume import resume_from_line
from usbmotion.motion.tools import NO_TOOLS, ToolTable
from usbmotion.session.homing import home_position_mm


@dataclass(frozen=True, slots=True)
class Prepared:
    """A program interpreted and planned from a start position, checked against the travel.

    ``start_mm`` is where the plan starts (one coordinate per axis of ``axes``, the
    program axes); ``homed`` whether that is a homed position (soft limits checked) or the
    devices' own counts (not homed, not checked). ``offsets`` are the work offsets the
    program started with (``program.offsets`` those it leaves). ``warnings`` are what
    :func:`prepare_program` found risky that does not stop the program (a rapid into the
    stock: :func:`usbmotion.motion.plunges.rapid_plunges`), in words, for the run to show
    before it starts and keep in its report's notes.
    """

    program: GCodeProgram
    plan: Plan
    start_mm: Point
    homed: bool
    offsets: WorkOffsets = NO_OFFSETS
    warnings: tuple[str, ...] = ()

    @property
    def axes(self) -> str:
        """The program axes: the letters of the plan's columns."""
        return self.plan.axes


def program_axes(config: MachineConfig) -> str:
    """The letters of the machine's axes, in LinuxCNC's X Y Z A B C U V W order: the axes a
    program moves.

    Raises:
        ConfigError: the machine has no linear axis (a program needs one: X, Y, Z, U, V or
            W).
    """
    names = config.axis_names
    axes = "".join(letter for letter in AXIS_ORDER if letter in names)
    if not any(letter not in ROTARY_AXES for letter in axes):
        raise ConfigError(
            f"{config.path}: G-code programs move a linear axis (X, Y, Z, U, V or W) besides"
            f" any rotary one; this machine has {', '.join(config.axis_names)}",
            path=str(config.path), key="axes",
        )
    return axes


def machine_axes(config: MachineConfig) -> MachineAxes:
    """What the interpreter needs of the machine: its program axes, where homing leaves
    them, the order it homes them in, and its spindle's top speed.

    Raises:
        ConfigError: as :func:`program_axes`.
    """
    axes = program_axes(config)
    order = tuple(
        group for group in ("".join(name for name in names if name in axes)
                            for names in config.homing_order) if group)
    ordered = "".join(order)
    if order and len(ordered) != len(axes):
        order = (*order, "".join(a for a in axes if a not in ordered))
    return MachineAxes(axes=axes,
                       home_mm=tuple(home_position_mm(config.axis(a)) for a in axes),
                       homing_order=order,
                       wrapped="".join(a for a in axes if config.axis(a).wrapped),
                       spindle_max_rpm=config.spindle.max_rpm if config.spindle else 0.0,
                       outputs=tuple(config.outputs.pins) if config.outputs else (),
                       laser_max_s=config.outputs.laser_max_s if config.outputs else 1000.0)


def machine_dialect(config: MachineConfig, dialect: Dialect | None = None) -> Dialect:
    """``dialect`` when given, else the machine file's."""
    return dialect if dialect is not None else dialect_named(config.dialect)


def prepare_program(config: MachineConfig, text: str, *, file: str, start_mm: Point,
                    homed: bool, dialect: Dialect | None = None, tools: ToolTable = NO_TOOLS,
                    offsets: WorkOffsets | None = None, pauses: Pauses = Pauses.NONE,
                    from_line: int | None = None) -> Prepared:
    """Interpret and plan a program for a machine from ``start_mm`` with a tool table and
    work offsets (machine coordinates result); a homed start is also checked against every
    axis's travel, and every program for rapids into the stock (``Prepared.warnings``).
    With ``from_line``, the program runs from that line (:func:`plan_gcode`).

    Raises:
        GCodeError, PlanningError: as :func:`plan_gcode`.
        ArgumentError: as :func:`plan_gcode`.
        SoftLimitError: a move leaves an axis's travel (names the line, the axis, the
            coordinate and the limit).
        ConfigError: the machine has no linear axis.
    """
    offsets = offsets or NO_OFFSETS
    program, plan = plan_gcode(config, text, file=file, start_mm=start_mm, dialect=dialect,
                               tools=tools, offsets=offsets, pauses=pauses,
                               from_line=from_line)
    if homed:
        axes = plan_axes(config)
        check_travel(plan.vertices_mm, plan.line, [a.travel_mm for a in axes],
                     axes=tuple(plan.axes),
                     band_mm=settled_band_mm([a.counts_per_mm for a in axes]))
    warnings = plunge_warnings(rapid_plunges(program, plan))
    if from_line is not None:
        warnings = (f"run from line {from_line}: the lines before it set the modes, offsets"
                    " and tool without moving; the re-entry went up to the safe height, over"
                    " and down to where the program stands there", *warnings)
    return Prepared(program, plan, start_mm, homed, offsets, warnings)


def plan_gcode(config: MachineConfig, text: str, *, file: str = "<string>",
               start_mm: Point | None = None, dialect: Dialect | None = None,
               tools: ToolTable = NO_TOOLS, offsets: WorkOffsets | None = None,
               pauses: Pauses = Pauses.NONE, from_line: int | None = None,
               ) -> tuple[GCodeProgram, Plan]:
    """Interpret and plan a program for a machine from ``start_mm`` (zeros when not
    given), in ``dialect`` or the machine file's (pure: no machine is needed;
    :meth:`MachineSession.prepare` adds where the machine stands and soft limits).

    With ``from_line``, the whole program is interpreted from ``start_mm`` (the lines
    before it move nothing but set the modal state, offsets and tool), and the run joins it
    at that line by a safe re-entry (:mod:`usbmotion.motion.resume`): up to where homing
    leaves Z, over, and down at the program's feed (a tenth of Z's top speed when no feed
    move follows).

    Raises:
        GCodeError, PlanningError: as :meth:`MachineSession.prepare`.
        ArgumentError: ``from_line`` is not a line of the program or no move follows it.
        ConfigError: the machine has no linear axis.
    """
    limits, planner, _ = planner_inputs(config)
    axes = machine_axes(config)
    program = parse_gcode(text, file=file, start=start_mm, machine=axes,
                          dialect=machine_dialect(config, dialect), tools=tools,
                          offsets=offsets, pauses=pauses)
    if from_line is not None:
        here = start_mm if start_mm is not None else (0.0,) * len(axes.axes)
        z = axes.axes.find("Z")
        safe_z = None if z < 0 or axes.home_mm is None else axes.home_mm[z]
        z_speed = config.axis("Z").max_velocity_mm_s if z >= 0 else limits[0].velocity_mm_s
        program = resume_from_line(program, from_line, here=here, safe_z_mm=safe_z,
                                   descent_feed_mm_min=z_speed * 60.0 / 10.0)
    return program, plan_moves(program.moves, limits, planner, start=start_mm,
                               axes=axes.axes)


def plan_axes(config: MachineConfig) -> list[AxisConfig]:
    """The configs of the axes a program moves (:func:`program_axes`), in that order.

    Raises:
        ConfigError: the machine has no linear axis.
    """
    return [config.axis(name) for name in program_axes(config)]


def planner_inputs(config: MachineConfig) -> tuple[list[AxisLimits], PlannerConfig, list[float]]:
    """Per-axis limits, planner settings and counts per mm of the program axes.

    Raises:
        ConfigError: the machine has no linear axis.
    """
    axes = plan_axes(config)
    limits = [AxisLimits(a.max_velocity_mm_s, a.max_accel_mm_s2) for a in axes]
    planner = PlannerConfig(
        junction_deviation_mm=config.junction_deviation_mm,
        arc_tolerance_mm=config.arc_tolerance_mm,
    )
    return limits, planner, [a.counts_per_mm for a in axes]
