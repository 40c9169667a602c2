"""What a sender meets on the simulated machine's grbl front, written to its terminal byte by
byte, where a front on a machine session could answer otherwise than grbl 1.1h: ``$X``
unlocks an unhomed machine to Idle, and lines after a program's M2 are taken (cncjs sends
its %wait, ``G4 P0.5``, after every program)."""

from __future__ import annotations

import os
import select
import time
import tty
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from tests.senders.helpers import served_real

pytestmark = pytest.mark.realtime


class _Terminal:
    """The sender's end of the front's pseudo-terminal."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        self.text = b""

    def exchange(self, data: bytes, *, until: bytes, timeout_s: float = 15.0) -> bytes:
        """Write ``data``; what came back up to and with ``until``."""
        os.write(self.fd, data)
        deadline = time.monotonic() + timeout_s
        while until not in self.text:
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"no {until!r} after {data!r}: {self.text!r}")
            if select.select([self.fd], [], [], min(left, 0.05))[0]:
                self.text += os.read(self.fd, 4096)
        answer, _, self.text = self.text.partition(until)
        return answer + until

    def close(self) -> None:
        os.close(self.fd)


@contextmanager
def _terminal(folder: Path) -> Iterator[_Terminal]:
    with served_real(folder) as real:
        terminal = _Terminal(real.server.path)
        try:
            terminal.exchange(b"", until=b"to unlock]\r\n")  # the banner on connecting
            terminal.exchange(b"\x18", until=b"to unlock]\r\n")
            yield terminal
        finally:
            terminal.close()


def test_unlock_before_homing_leaves_alarm(tmp_path: Path) -> None:
    with _terminal(tmp_path) as terminal:
        assert terminal.exchange(b"?", until=b">\r\n").startswith(b"<Alarm|")
        assert terminal.exchange(b"$X\n", until=b"ok\r\n") == b"[MSG:Caution: Unlocked]\r\nok\r\n"
        assert terminal.exchange(b"?", until=b">\r\n").startswith(b"<Idle|")


def test_lines_after_m2_are_taken(tmp_path: Path) -> None:
    with _terminal(tmp_path) as terminal:
        assert terminal.exchange(b"$H\n", until=b"ok\r\n") == b"ok\r\n"
        assert terminal.exchange(b"G0 X1\nM2\n", until=b"Pgm End]\r\nok\r\n")
        assert terminal.exchange(b"G4 P0.5\n", until=b"\r\n") == b"ok\r\n"
