"""``usbmotion jog``: an incremental jog, planned and run as a one-move program in machine
coordinates (G53)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Annotated

import typer

from usbmotion.cli.connect import SIMULATED_NOTE, act_on_session
from usbmotion.cli.exits import EXIT_BAD_INPUT, EXIT_COMPLETED, EXIT_FAULT, exit_code, fail
from usbmotion.cli.machines import MachineOption, load_machine
from usbmotion.cli.progress import progress_line
from usbmotion.cli.status import home_reporting
from usbmotion.errors import (
    ConfigError,
    PlanningError,
    UsbMotionError,
)

if TYPE_CHECKING:
    from usbmotion.host.config import MachineConfig
    from usbmotion.session import MachineSession


def jog(
    steps: Annotated[list[str], typer.Argument(
        help="AXIS DISTANCE pairs, mm: X 10, or X10 Y-2.5.", show_default=False)],
    feed: Annotated[float, typer.Option(
        "--feed", "-f", help="Feed, mm/min (each axis also keeps to its max_velocity_mm_s).",
        show_default=False)],
    machine: MachineOption = None,
    no_home: Annotated[bool, typer.Option(
        "--no-home", help="Do not home a machine that is not homed: jog in the devices' own"
        " counts, without soft limits.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress line.")] = False,
    continuous: Annotated[bool, typer.Option(
        "--continuous", "-c", help="Jog on in the direction the distances give (their signs,"
        " their sizes weighting the axes) until Ctrl-C or the first soft limit on the way.",
    )] = False,
) -> None:
    """Move axes by these distances at a feed, within the soft limits.

    The distances are in machine coordinates (a G53 move: work and tool offsets do not
    apply) from where the axes stand; the move is planned with each axis's acceleration.
    With --continuous the jog goes on in that direction until Ctrl-C, which brings every
    axis to rest along its deceleration (exit 0), or until the first soft limit on its way.

    A jog that would leave an axis's travel (the soft limits) is refused naming the axis
    and the limit, and nothing moves. A machine that is not homed is homed first, as
    usbmotion run does (or, with --no-home, jogged in the devices' own counts). The jog
    is a one-move program: while it runs a progress line shows the state, the line and
    the positions; Ctrl-C or SIGTERM brings every axis to rest along its deceleration.

    Exit status: 0 jogged; 1 a device fault, a lost link, a failed homing, or a port that
    could not be opened; 2 bad pairs or feed, a jog that leaves the travel, or a bad
    machine file (nothing moved); 130 interrupted by Ctrl-C, 143 by SIGTERM.
    """
    config = load_machine(machine, "jog")
    from usbmotion.session.operator import parse_steps  # noqa: PLC0415 - quick --help

    try:
        moves = parse_steps(steps)
    except ValueError as error:
        fail("jog", str(error), EXIT_BAD_INPUT)
    from usbmotion.session.planning import program_axes  # noqa: PLC0415

    try:
        axes = program_axes(config)
    except ConfigError as error:
        fail("jog", str(error), EXIT_BAD_INPUT)
    other = [letter for letter in moves if letter not in axes]
    if other:
        fail("jog", f"cannot jog {', '.join(other)}: a jog moves {', '.join(axes)} of"
             f" {config.path}", EXIT_BAD_INPUT)
    if not (math.isfinite(feed) and feed > 0):
        fail("jog", f"--feed {feed!r} must be a speed > 0 mm/min", EXIT_BAD_INPUT)
    if continuous and no_home:
        fail("jog", "--continuous runs to the soft limits: it needs a homed machine, not"
             " --no-home", EXIT_BAD_INPUT)
    act_on_session(config, "jog", lambda session: _jog(
        session, moves, feed, no_home=no_home, quiet=quiet, continuous=continuous))


jog.__doc__ = f"{jog.__doc__}\n    {SIMULATED_NOTE}\n"


def travel_problem(config: MachineConfig, start_mm: dict[str, float],
                   moves: dict[str, float]) -> str | None:
    """Why jogging ``moves`` from ``start_mm`` leaves an axis's travel, or None."""
    for letter, distance in moves.items():
        lower, upper = config.axis(letter).travel_mm
        target = start_mm[letter] + distance
        if target < lower - 1e-9 or target > upper + 1e-9:
            side, limit = ("lower", lower) if target < lower else ("upper", upper)
            return (f"axis {letter} to {target:.3f} mm ({distance:+.3f} from"
                    f" {start_mm[letter]:.3f}) is beyond its {side} limit {limit:.3f} mm"
                    f" (travel {lower:g}..{upper:g} mm); nothing moved")
    return None


def _jog(session: MachineSession, moves: dict[str, float], feed_mm_min: float, *,
         no_home: bool, quiet: bool, continuous: bool = False) -> int:
    from usbmotion.motion.dialects import Dialect  # noqa: PLC0415
    from usbmotion.session.planning import program_axes  # noqa: PLC0415

    config = session.config
    if not (no_home or session.is_homed):
        typer.echo("the machine is not homed: homing first", err=True)
        _, code = home_reporting("jog", session, None, quiet=quiet)
        if code:
            return code
    if continuous:
        return _jog_on(session, moves, feed_mm_min, quiet=quiet)
    try:
        start_mm, homed = session.start_position_mm(unhomed=no_home)
    except UsbMotionError as error:
        typer.echo(f"usbmotion jog: {error}", err=True)
        return EXIT_FAULT
    axes = program_axes(config)
    start = dict(zip(axes, start_mm, strict=True))
    if homed:
        problem = travel_problem(config, start, moves)
        if problem is not None:
            typer.echo(f"usbmotion jog: {problem}", err=True)
            return EXIT_BAD_INPUT
    words = " ".join(f"{letter}{start[letter] + distance:.6f}"
                     for letter, distance in moves.items())
    text = f"G90 G21 G94\nG53 G1 {words} F{feed_mm_min:.6f}\nM2\n"
    try:
        prepared = session.prepare("jog", text=text, unhomed=no_home,
                                   dialect=Dialect.LINUXCNC)
    except PlanningError as error:
        typer.echo(f"usbmotion jog: {error}; nothing moved", err=True)
        return EXIT_BAD_INPUT
    try:
        with progress_line(not quiet) as show:
            report, _ = session.run(prepared, on_progress=show)
    except UsbMotionError as error:
        typer.echo(f"usbmotion jog: {error}", err=True)
        return EXIT_FAULT
    where = session.positions_mm()
    at = "  ".join(f"{name} {where[name]:.3f}" for name in axes)
    frame = "machine coordinates" if homed else "device counts, not homed"
    if report.completed:
        moved = ", ".join(f"{letter} {distance:+.3f}" for letter, distance in moves.items())
        typer.echo(f"jogged {moved} mm at {feed_mm_min:g} mm/min in"
                   f" {report.executed_time_s:.2f} s: {at} mm ({frame})")
        return EXIT_COMPLETED
    typer.echo(f"usbmotion jog: stopped: {report.stop_reason}; at {at} mm ({frame})", err=True)
    return exit_code(report.stop_reason) or EXIT_FAULT


def _jog_on(session: MachineSession, directions: dict[str, float], feed_mm_min: float, *,
            quiet: bool) -> int:
    """A continuous jog until Ctrl-C (a jog cancel) or the soft limit."""
    from usbmotion.session.state import StopReason  # noqa: PLC0415

    try:
        with progress_line(not quiet) as show:
            report = session.jog(directions, feed_mm_min=feed_mm_min, continuous=True,
                                 on_progress=show)
    except PlanningError as error:
        typer.echo(f"usbmotion jog: {error}; nothing moved", err=True)
        return EXIT_BAD_INPUT
    except UsbMotionError as error:
        typer.echo(f"usbmotion jog: {error}", err=True)
        return EXIT_FAULT
    where = session.positions_mm()
    at = "  ".join(f"{name} {where[name]:.3f}" for name in where)
    if report.completed:
        typer.echo(f"jogged to the soft limit: {at} mm (machine coordinates)")
        return EXIT_COMPLETED
    if report.stop_reason in (StopReason.USER.value, StopReason.JOG_CANCELLED.value):
        session.clear_stop_request()
        typer.echo(f"jog stopped along its deceleration ({report.stop_distance_mm:.3f} mm):"
                   f" {at} mm (machine coordinates)")
        return EXIT_COMPLETED
    typer.echo(f"usbmotion jog: stopped: {report.stop_reason}; at {at} mm", err=True)
    return exit_code(report.stop_reason) or EXIT_FAULT
