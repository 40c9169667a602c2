"""How a command ends: its exit statuses, and one line on standard error when it fails."""

from __future__ import annotations

from typing import NoReturn

import typer

EXIT_COMPLETED = 0
EXIT_FAULT = 1
"""A device fault, a lost link, a failed homing, a port or machine that is busy."""
EXIT_BAD_INPUT = 2
"""Bad input (a usage error, an invalid program or machine file, a program that leaves the
travel): nothing moved."""
EXIT_INTERRUPTED = 130
"""Ctrl-C (SIGINT): every axis was brought to rest along its deceleration first."""
EXIT_TERMINATED = 143
"""SIGTERM: likewise."""


def fail(command: str, message: str, code: int) -> NoReturn:
    """Print ``usbmotion COMMAND: MESSAGE`` on standard error and exit with ``code``."""
    typer.echo(f"usbmotion {command}: {message}" if command else f"usbmotion: {message}",
               err=True)
    raise typer.Exit(code)


def os_problem(error: OSError) -> str:
    """What an operating-system error says, in words, without its ``[Errno N]`` and the
    quoted file name it carries: ``no such file``, ``permission denied``."""
    reason = error.strerror or str(error)
    return reason[:1].lower() + reason[1:] if reason[1:2].islower() else reason


def exit_code(reason: str) -> int:
    """The documented exit status of a run that ended for ``reason``."""
    from usbmotion.session.state import StopReason  # noqa: PLC0415 - keeps --help fast

    if reason == StopReason.COMPLETED.value:
        return EXIT_COMPLETED
    if reason.startswith(StopReason.USER.value):
        return EXIT_INTERRUPTED
    if reason.startswith(StopReason.TERMINATED.value):
        return EXIT_TERMINATED
    return EXIT_FAULT
