"""Where ``usbmotion sim --pty`` announces its pseudo-terminals, so ``usbmotion devices``
finds them: serial port listings do not include pseudo-terminals, and probing every
``/dev/pts/N`` would write into other programs' terminals.

While it serves, each server keeps a symbolic link per device in the folder
:func:`pty_dir` (``$USBMOTION_PTY_DIR``, else ``$XDG_RUNTIME_DIR/usbmotion/ptys``, else
``/tmp/usbmotion-UID/ptys``), named ``PID-INDEX`` and pointing at the terminal. Links of a
server that died without removing them are ignored and removed.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path


def pty_dir() -> Path:
    """The folder of the announced pseudo-terminals."""
    explicit = os.environ.get("USBMOTION_PTY_DIR")
    if explicit:
        return Path(explicit)
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime:
        return Path(runtime) / "usbmotion" / "ptys"
    return Path(tempfile.gettempdir()) / f"usbmotion-{os.getuid()}" / "ptys"


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


def announced_ptys() -> list[str]:
    """The terminals live servers announced, in the order they were announced; stale
    links (their server gone, or their terminal) are removed."""
    folder = pty_dir()
    try:
        links = sorted(folder.iterdir(), key=_order)
    except OSError:
        return []
    found: list[str] = []
    for link in links:
        try:
            target = os.readlink(link)
        except OSError:
            continue
        if _alive(link.name) and Path(target).exists():
            found.append(target)
        else:
            with contextlib.suppress(OSError):
                link.unlink()
    return found


def _order(link: Path) -> tuple[int, int, str]:
    pid, _, index = link.name.partition("-")
    return (int(pid), int(index), "") if pid.isdigit() and index.isdigit() else (0, 0, link.name)


def _alive(name: str) -> bool:
    pid = name.partition("-")[0]
    if not pid.isdigit():
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
