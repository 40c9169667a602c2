"""The transient progress line a command shows on a terminal while the machine moves."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from usbmotion.session.live import LiveSnapshot


@contextmanager
def progress_line(enabled: bool) -> Iterator[Callable[[LiveSnapshot], None]]:
    """A transient progress line on a terminal's standard error (state, program line,
    positions), updated by the callback it yields; nothing when ``enabled`` is False or
    standard error is no terminal (then rich is not even imported)."""
    if not (enabled and sys.stderr.isatty()):
        yield lambda _update: None
        return
    from rich.progress import Progress as Bar  # noqa: PLC0415
    from rich.progress import SpinnerColumn, TextColumn  # noqa: PLC0415

    with Bar(SpinnerColumn(), TextColumn("{task.description}"), transient=True) as bar:
        task = bar.add_task("", total=None)

        def show(update: LiveSnapshot) -> None:
            bar.update(task, description=update.describe())

        yield show
