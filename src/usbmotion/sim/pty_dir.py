"""Where ``usbmotion sim --pty`` announces its pseudo-terminals, so discovery finds the
devices on them (``usbmotion devices``, a machine file naming its devices): a link per
device in :func:`usbmotion.host.discovery.pty_dir`, which the host side reads
(:func:`usbmotion.host.discovery.announced_ptys`).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Sequence
from pathlib import Path

from usbmotion.host.discovery import pty_dir


@contextlib.contextmanager
def announced(paths: Sequence[str]) -> Iterator[None]:
    """While inside, ``paths`` (this process's terminals) are announced in :func:`pty_dir`.
    A folder that cannot be written announces nothing (serving goes on)."""
    folder = pty_dir()
    links: list[Path] = []
    try:
        try:
            folder.mkdir(parents=True, exist_ok=True, mode=0o700)
            for index, path in enumerate(paths):
                link = folder / f"{os.getpid()}-{index}"
                link.unlink(missing_ok=True)
                link.symlink_to(path)
                links.append(link)
        except OSError:
            pass
        yield
    finally:
        for link in links:
            with contextlib.suppress(OSError):
                link.unlink()
