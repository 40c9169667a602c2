"""The ``usbmotion`` command run in the test's own process, for command lines refused
before anything runs (the same code as in a process of its own)."""

from __future__ import annotations

from typer.testing import CliRunner

from usbmotion.cli.main import app


def invoke(*args: str) -> tuple[int, str, str]:
    """``usbmotion ARGS`` in this process: exit status, stdout, stderr (an exception other
    than the exit fails the test)."""
    result = CliRunner().invoke(app, list(args))
    assert not isinstance(result.exception, Exception) or isinstance(
        result.exception, SystemExit), result.exception
    return result.exit_code, result.stdout, result.stderr
