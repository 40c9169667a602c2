"""Opening the machine a command acts on, every failure answered in one line.

A machine file that is missing, unreadable or invalid ends the command with status 2
(bad input: nothing was opened); a port that is missing or busy, a refused connection, a
device that is not found or does not answer ends it with status 1 (a device or link
fault). Either way the line names the file or the port, never a traceback.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

import typer

from usbmotion.cli.exits import EXIT_FAULT, fail
from usbmotion.cli.signals import stop_on_signals
from usbmotion.errors import UsbMotionError

if TYPE_CHECKING:
    from usbmotion.host.config import MachineConfig
    from usbmotion.host.machine import Machine
    from usbmotion.session import MachineSession

SIMULATED_NOTE = (
    "Without --machine, the command acts on the built-in simulated machine, which lives"
    " only as long as the command: each command finds it fresh (unhomed, at its start"
    " positions). Point --machine at a file whose axes are ports, socket:// URLs of"
    " usbmotion sim --tcp or terminals of usbmotion sim --pty to act on devices that stay."
)
"""What the help of a command acting on a machine says about the default one."""


@contextmanager
def opened_machine(config: MachineConfig, command: str) -> Iterator[Machine]:
    """The machine's links opened and resynchronised, nothing configured or cleared (so
    what the devices hold is what a command reads); closed on leaving. A link that
    cannot be opened or a device that does not answer ends the command with status 1."""
    try:
        if any(axis.is_simulated for axis in config.axes):
            from usbmotion.sim.machine import connect_machine  # noqa: PLC0415

            machine = connect_machine(config)
        else:
            from usbmotion.host.machine import Machine  # noqa: PLC0415 - no simulator

            machine = Machine.connect(config)
    except (UsbMotionError, OSError) as error:
        fail(command, str(error), EXIT_FAULT)
    with machine:
        yield machine


def connect_any(config: MachineConfig, *, realtime: bool = False) -> MachineSession:
    """A machine session on ``config``'s machine: its simulated devices in a world of
    their own (in real time with ``realtime``), or its devices on their links; the
    simulator is imported only for a simulated machine.

    Raises:
        UsbMotionError, OSError: connecting failed.
    """
    if config.is_simulated:
        from usbmotion.sim.machine import connect_session  # noqa: PLC0415
        from usbmotion.sim.world import SimWorld  # noqa: PLC0415

        return connect_session(config, world=SimWorld(realtime=True) if realtime else None)
    from usbmotion.session import MachineSession  # noqa: PLC0415 - no simulator

    return MachineSession.connect(config)


def connect_live(config: MachineConfig) -> tuple[MachineSession, Callable[[], None] | None]:
    """A machine session for a front that an operator drives while it waits (the grbl
    front, the web dashboard): a simulated machine in real time, its world kept in step
    with the wall clock by the second value (the operator's ``on_idle``; None for devices
    on their links).

    Raises:
        UsbMotionError, OSError: connecting failed.
    """
    if config.is_simulated:
        from usbmotion.sim.machine import connect_session  # noqa: PLC0415
        from usbmotion.sim.world import SimWorld  # noqa: PLC0415

        world = SimWorld(realtime=True)
        return connect_session(config, world=world), world.keep_pace
    from usbmotion.session import MachineSession  # noqa: PLC0415 - no simulator

    return MachineSession.connect(config), None


@contextmanager
def taken_over(config: MachineConfig, command: str) -> Iterator[MachineSession]:
    """A machine session on the machine, taken over as ``usbmotion run`` takes it (faults
    an earlier host left read and cleared, the machine file's settings sent); its notices
    printed; closed on leaving. Failing to connect ends the command with status 1."""
    try:
        session = connect_any(config)
    except (UsbMotionError, OSError) as error:
        fail(command, str(error), EXIT_FAULT)
    with session:
        for notice in session.notices:
            typer.echo(f"notice: {notice}", err=True)
        yield session


def act_on_session(config: MachineConfig, command: str,
                   action: Callable[[MachineSession], int]) -> None:
    """Take the machine over, run ``action`` on its session (Ctrl-C and SIGTERM bring it to
    rest along its deceleration), then shut the session down (servos off, the machine left
    homed for the next command); end the command with the action's exit status, or a
    fault's if the shutdown failed."""
    with taken_over(config, command) as session, stop_on_signals(session):
        code = action(session)
        try:
            session.shutdown()
        except UsbMotionError as error:
            typer.echo(f"usbmotion {command}: {error}", err=True)
            code = code or EXIT_FAULT
    if code:
        raise typer.Exit(code)
