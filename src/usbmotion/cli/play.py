"""``usbmotion play``: a joint trajectory file played on a robot's joints."""

from __future__ import annotations

import signal
import sys
from pathlib import Path
from types import FrameType
from typing import Annotated

import typer

from usbmotion.cli.connect import connect_any
from usbmotion.cli.exits import (
    EXIT_BAD_INPUT,
    EXIT_COMPLETED,
    EXIT_FAULT,
    EXIT_INTERRUPTED,
    EXIT_TERMINATED,
)
from usbmotion.cli.machines import MachineOption, load_machine
from usbmotion.errors import ArgumentError, ConfigError, StopRequestedError, UsbMotionError


def play(
    trajectory: Annotated[Path, typer.Argument(
        help="The joint trajectory: CSV (header time_s,<joint>,...) or JSON ({\"joints\":"
        " [...], \"points\": [[time_s, value, ...], ...]}).", show_default=False)],
    machine: MachineOption = None,
    realtime: Annotated[bool, typer.Option(
        "--realtime", help="Pace a simulated robot by the wall clock.")] = False,
) -> None:
    """Play a joint trajectory on a robot's joints (the machine file's [joints]).

    Homes the robot if it is not homed, moves every joint of the trajectory to its first
    point (the time-optimal jerk-limited move), then plays it through the devices' curve
    mode from one start tick for every device; prints how each joint followed (its peak
    following error, every servo tick) and where it ended.

    A trajectory that leaves a joint's range or exceeds its speed or acceleration is
    refused before anything moves. Ctrl-C or SIGTERM stops along the path (the joints
    decelerate on the trajectory's own curve); a second one stops at once.

    Exit status: 0 played to its end; 1 a device fault or a failed homing; 2 the file or
    the machine file is invalid (nothing moved); 130 Ctrl-C, 143 SIGTERM.
    """
    from usbmotion.robot import JointTrajectory, Robot, check_limits  # noqa: PLC0415

    try:
        config = load_machine(machine)
        path = trajectory
        planned = JointTrajectory.load(path)
        joints = {joint.name: joint for joint in config.joints}
        if not joints:
            raise ArgumentError(f"{config.path} names no joints: give --machine a robot's"
                                " file, with [joints.<name>] tables (examples/robot-arm.toml)",
                                reason="joints")
        check_limits(planned, joints)
    except (ConfigError, ArgumentError) as error:
        typer.echo(f"usbmotion play: {error}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    except OSError as error:
        typer.echo(f"usbmotion play: cannot read {error.filename!r}: {error.strerror}",
                   err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    try:
        session = connect_any(config, realtime=realtime)
    except (UsbMotionError, OSError) as error:
        typer.echo(f"usbmotion play: {error}", err=True)
        raise typer.Exit(EXIT_FAULT) from None
    code = EXIT_COMPLETED
    with session:
        robot = Robot(session.machine)
        reasons = {signal.SIGINT: "interrupted by the user", signal.SIGTERM: "terminated"}
        asked: list[str] = []

        def on_signal(signum: int, frame: FrameType | None) -> None:
            reason = reasons.get(signal.Signals(signum), "interrupted by the user")
            if asked:
                session.machine.stop()  # a second one: at once
            asked.append(reason)
            robot.stop(reason)

        previous = {sig: signal.signal(sig, on_signal) for sig in reasons}
        try:
            homing_s = 0.0 if session.is_homed else session.home()
            typer.echo(f"homing         {homing_s:.3f} s")
            first = dict(zip(planned.joints, planned.positions[0].tolist(), strict=True))
            robot.move_to(first)
            report = robot.play(planned)
            typer.echo(f"played         {path.name}: {', '.join(planned.joints)},"
                       f" {planned.duration_s:.3f} s, every device from tick"
                       f" {report.start_tick}, {report.keyframes} keyframes each")
            for name in planned.joints:
                joint = joints[name]
                peak = report.peak_error_counts[name]
                typer.echo(f"  {name:<12} peak following error {peak} counts"
                           f" ({peak / joint.counts_per_unit:.4f} {joint.unit}),"
                           f" ended at {report.end[name]:.4f} {joint.unit}")
            typer.echo("result         completed")
        except StopRequestedError as error:
            code = EXIT_TERMINATED if error.reason == "terminated" else EXIT_INTERRUPTED
            stopped = getattr(error, "report", None)
            where = f" at {stopped.stopped_at_s:.3f} s of the trajectory" if stopped else ""
            typer.echo(f"STOPPED ({error.reason}){where}, every joint at rest on its path")
        except ArgumentError as error:
            typer.echo(f"usbmotion play: {error}", err=True)
            code = EXIT_BAD_INPUT
        except UsbMotionError as error:
            typer.echo(f"usbmotion play: {error}", err=True)
            session.machine.stop()
            code = EXIT_FAULT
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        try:
            session.shutdown()
        except UsbMotionError as error:
            typer.echo(f"usbmotion play: {error}", err=True)
            code = max(code, EXIT_FAULT) if code == EXIT_COMPLETED else code
    sys.stdout.flush()
    raise typer.Exit(code)
