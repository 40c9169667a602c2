"""``usbmotion status`` and ``usbmotion home``: what the machine is doing, and homing it."""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated

import typer

from usbmotion.cli.connect import SIMULATED_NOTE, act_on_session, opened_machine
from usbmotion.cli.exits import EXIT_BAD_INPUT, EXIT_FAULT, exit_code, fail
from usbmotion.cli.machines import MachineOption, load_machine
from usbmotion.cli.progress import progress_line
from usbmotion.errors import SequenceFaultError, StopRequestedError, UsbMotionError

if TYPE_CHECKING:
    from usbmotion.automation.device_io import MachineZero
    from usbmotion.host.device import AxisScale
    from usbmotion.host.machine import Machine
    from usbmotion.session import MachineSession


def status(machine: MachineOption = None) -> None:
    """Print the state, position, servo, switches and latched fault of every axis.

    What the devices hold is read and nothing changed: a latched fault is reported, not
    cleared.

    An axis is in Alarm with a latched fault, Run while its servo is on with setpoints
    queued, else Idle; the machine is in the worst of its axes' states. Positions are
    machine coordinates on a homed axis (its device carries this machine file's homed
    mark), the device's own counts scaled to mm otherwise.

    Exit status: 0 read; 1 a port could not be opened or a device did not answer; 2 a bad
    machine file.
    """
    config = load_machine(machine, "status")
    with opened_machine(config, "status") as opened:
        try:
            lines = describe_status(opened)
        except UsbMotionError as error:
            fail("status", str(error), EXIT_FAULT)
    for line in lines:
        typer.echo(line)


status.__doc__ = f"{status.__doc__}\n    {SIMULATED_NOTE}\n"


def describe_status(machine: Machine) -> list[str]:
    """The lines ``usbmotion status`` prints for a connected machine."""
    from usbmotion.protocol import FaultCode, fault_words  # noqa: PLC0415
    from usbmotion.session import MachineState, homed_mark  # noqa: PLC0415

    rows: list[tuple[str, ...]] = []
    states: list[MachineState] = []
    notes: list[str] = []
    for name, axis in machine.axes.items():
        client = axis.client
        state = client.status()
        code, tick = client.fault()
        homed = client.homed_marker() == homed_mark(machine.config, axis.config)
        if code != FaultCode.NONE:
            axis_state, fault = MachineState.ALARM, f"{code} {fault_words(code)} at tick {tick}"
        else:
            axis_state = (MachineState.RUN if state.enabled and state.queued
                          else MachineState.IDLE)
            fault = "none"
        states.append(axis_state)
        switches = [side for side, closed in (("lower", state.lower_limit),
                                              ("upper", state.upper_limit)) if closed]
        unit = "deg" if axis.config.rotary else "mm"
        rows.append((
            name, axis_state.value, "yes" if homed and code == FaultCode.NONE else "no",
            f"{axis.scale.to_mm(state.actual_counts):.3f} {unit}",
            f"{axis.scale.to_mm(state.desired_counts - state.actual_counts):.3f} {unit}",
            "on" if state.enabled else "off", client.control_mode().word, str(state.queued),
            ",".join(switches) or "open", fault))
        absolute = axis.config.absolute_encoder
        if absolute is not None and not homed:
            setting = client.encoder()
            if setting.absolute:
                angle = absolute.angle_counts(state.actual_counts, setting.zero)
                degrees = 360.0 * angle / absolute.turn_counts
                notes.append(
                    f"{name}: not homed; its absolute encoder reads {degrees:.1f} deg of its"
                    f" turn ({axis.scale.to_mm(angle):.3f} {unit} past the turn's start):"
                    " homing names the turn")
            else:
                notes.append(
                    f"{name}: the machine file's encoder is absolute, the device's is not set"
                    " up yet (the next home, run or jog sets it)")
    worst = next((s for s in (MachineState.ALARM, MachineState.RUN) if s in states),
                 MachineState.IDLE)
    homed_all = all(row[2] == "yes" for row in rows)
    header = ("axis", "state", "homed", "position", "error", "servo", "mode", "queued",
              "switches", "fault")
    widths = [max(len(row[i]) for row in (header, *rows)) for i in range(len(header))]
    table = ["  ".join(cell.ljust(width) for cell, width in zip(row, widths, strict=True))
             .rstrip() for row in (header, *rows)]
    return [f"{machine.config.name}: {worst.value}, {'homed' if homed_all else 'not homed'}",
            *table, *notes]


def home(
    axes: Annotated[list[str] | None, typer.Argument(
        help="The axes to home (X Y, or XY); every axis when omitted.",
        show_default=False)] = None,
    machine: MachineOption = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress line.")] = False,
) -> None:
    """Home every axis, or those named, and leave them homed for the next command.

    grbl's cycle, in the machine file's homing order; the axes are left at their home
    positions with their servos off.

    While homing, a progress line shows the state and each axis's position. Ctrl-C or
    SIGTERM brings every axis to rest along its deceleration (a second Ctrl-C stops at
    once).

    Exit status: 0 homed; 1 homing failed (a switch not found, a device fault or lost
    link) or a port could not be opened; 2 an unknown axis or a bad machine file; 130
    interrupted by Ctrl-C, 143 by SIGTERM.
    """
    config = load_machine(machine, "home")
    letters = [letter.upper() for word in (axes or []) for letter in word.replace(",", "")]
    unknown = [letter for letter in letters if letter not in config.axis_names]
    if unknown:
        fail("home", f"no axis {', '.join(map(repr, unknown))}; {config.path} has"
             f" {', '.join(config.axis_names)}", EXIT_BAD_INPUT)
    chosen = list(dict.fromkeys(letters)) or None
    act_on_session(config, "home", lambda session: _home(session, chosen, quiet=quiet))


home.__doc__ = f"{home.__doc__}\n    {SIMULATED_NOTE}\n"


def home_reporting(command: str, session: MachineSession, axes: list[str] | None, *,
                   quiet: bool) -> tuple[float, int]:
    """Home ``axes`` (all when ``None``) with a progress line; the seconds it took and 0, or
    0.0 and the command's exit status once a stop or a failure has been said."""
    try:
        with progress_line(not quiet) as show:
            return session.home(axes=axes, on_progress=show), 0
    except StopRequestedError as error:
        typer.echo(f"usbmotion {command}: stopped while homing: {error.reason}", err=True)
        return 0.0, exit_code(error.reason)
    except SequenceFaultError as error:
        typer.echo(f"usbmotion {command}: homing failed: {error}", err=True)
        return 0.0, EXIT_FAULT
    except UsbMotionError as error:
        typer.echo(f"usbmotion {command}: {error}", err=True)
        return 0.0, EXIT_FAULT


def _home(session: MachineSession, axes: list[str] | None, *, quiet: bool) -> int:
    seconds, code = home_reporting("home", session, axes, quiet=quiet)
    if code:
        return code
    homed = axes or list(session.machine.axes)
    where = session.positions_mm()
    at = "  ".join(f"{name} {where[name]:.3f}" for name in homed)
    typer.echo(f"homed {', '.join(homed)} in {seconds:.1f} s: {at} mm (machine coordinates)")
    for name in homed:
        zero = session.zeroes.get(name)
        if zero is not None and zero.turn_counts:
            typer.echo(absolute_zero_words(name, zero, session.machine.axis(name).scale))
    return 0


def absolute_zero_words(name: str, zero: MachineZero, scale: AxisScale) -> str:
    """How homing named an absolute encoder's turn: the boundary the zero is on, the
    switch's edge from it, and the margin a switch's repeatability has before the
    neighbouring turn would be taken."""
    turn_mm = zero.turn_counts / scale.counts_per_mm
    edge_mm = zero.edge_from_turn_counts / scale.counts_per_mm
    margin_mm = turn_mm / 2 - abs(edge_mm)
    switch_mm = scale.to_mm(zero.edge_counts + zero.shift_counts - zero.edge_from_turn_counts)
    words = (f"{name}: absolute encoder: {switch_mm:.3f} mm is the turn boundary nearest the"
             f" switch, whose edge read {switch_mm + edge_mm:.3f} mm (a turn is"
             f" {turn_mm:.3f} mm; a switch that repeats within {margin_mm:.3f} mm names the"
             " same turn)")
    if margin_mm < turn_mm / 8:
        words += ("; the edge is close to halfway between turns: move the switch or turn the"
                  " encoder's magnet by a quarter turn")
    return words
