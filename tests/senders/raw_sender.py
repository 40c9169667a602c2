"""A character-counting grbl sender on a pseudo-terminal, as bCNC and grbl's own
``simple_stream.py`` stream: a line goes out while the bytes not yet acknowledged fit
grbl's 128-byte receive buffer; every reply and status report is kept with when it came."""

from __future__ import annotations

import collections
import os
import re
import threading
import time
import tty
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

RX_BUFFER_BYTES = 128
_MPOS = re.compile(r"MPos:([-0-9.,]+)")
_FS = re.compile(r"FS:([-0-9.]+),")


@dataclass(frozen=True, slots=True)
class Report:
    """One status report: when it came (monotonic s), the state, MPos and FS; and when the
    ``?`` it answers was sent (``asked_s``): the front made it between the two."""

    at_s: float
    state: str
    mpos: tuple[float, ...]
    feed_mm_min: float
    text: str
    asked_s: float


def parse_report(at_s: float, text: str, asked_s: float | None = None) -> Report:
    """A ``<...>`` status report, parsed (``asked_s``: when its ``?`` went; else ``at_s``)."""
    state = text[1:].split("|", 1)[0]
    mpos = _MPOS.search(text)
    fs = _FS.search(text)
    return Report(at_s, state, tuple(float(v) for v in mpos.group(1).split(","))
                  if mpos else (), float(fs.group(1)) if fs else 0.0, text,
                  at_s if asked_s is None else asked_s)


@dataclass
class RawSender:
    """The sender on the terminal at ``path`` (see the module docstring)."""

    path: str
    replies: list[tuple[float, str]] = field(default_factory=list)
    reports: list[Report] = field(default_factory=list)
    acks: list[float] = field(default_factory=list)
    """When each ``ok`` or ``error`` came."""

    def __post_init__(self) -> None:
        self._fd = os.open(self.path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self._fd)
        self._lock = threading.Lock()
        self._asked: collections.deque[float] = collections.deque()
        """When each ``?`` not answered yet was sent (the front answers each with one
        report, in order)."""
        self._stop = threading.Event()
        self._reader = threading.Thread(target=self._read, name="raw-sender", daemon=True)
        self._reader.start()
        self._poller: threading.Thread | None = None

    def _read(self) -> None:
        pending = b""
        while not self._stop.is_set():
            try:
                data = os.read(self._fd, 4096)
            except OSError:
                return
            if not data:
                return
            pending += data
            while b"\n" in pending:
                raw, pending = pending.split(b"\n", 1)
                text = raw.strip().decode("ascii", "replace")
                if not text:
                    continue
                now = time.monotonic()
                with self._lock:
                    if text.startswith("<"):
                        asked = self._asked.popleft() if self._asked else None
                        self.reports.append(parse_report(now, text, asked))
                    else:
                        self.replies.append((now, text))
                        if text == "ok" or text.startswith("error"):
                            self.acks.append(now)

    def send(self, data: str | bytes) -> None:
        """Write ``data`` as it is."""
        raw = data.encode("ascii") if isinstance(data, str) else data
        with self._lock:
            self._asked.extend([time.monotonic()] * raw.count(b"?"))
        os.write(self._fd, raw)

    def wait(self, condition: Callable[[], bool], *, timeout_s: float, what: str) -> None:
        """Until ``condition()``; fail naming ``what`` (and the last replies) otherwise."""
        deadline = time.monotonic() + timeout_s
        while not condition():
            if time.monotonic() > deadline:
                with self._lock:
                    last = self.replies[-5:], self.reports[-2:]
                raise AssertionError(f"{what} did not happen within {timeout_s} s; last: {last}")
            time.sleep(0.005)

    def command(self, line: str, *, timeout_s: float = 60.0) -> str:
        """Send one line and wait for its ``ok`` or ``error``; the reply."""
        with self._lock:
            before = len(self.acks)
        self.send(line + "\n")
        self.wait(lambda: len(self.acks) > before, timeout_s=timeout_s, what=f"{line}'s answer")
        with self._lock:
            replies = [text for _, text in self.replies if text == "ok" or
                       text.startswith("error")]
        return replies[before]

    def reset_and_home(self) -> None:
        """Soft reset (the banner), then ``$H``."""
        with self._lock:
            before = len(self.replies)
        self.send(b"\x18")
        self.wait(lambda: any(text.startswith("Grbl") for _, text in self.replies[before:]),
                  timeout_s=10, what="the banner")
        assert self.command("$H", timeout_s=90) == "ok"

    def stream(self, lines: list[str], *, timeout_s: float) -> list[float]:
        """Stream ``lines`` counting characters; when each was acknowledged."""
        with self._lock:
            first = len(self.acks)
        sizes: list[int] = []
        sent = 0
        deadline = time.monotonic() + timeout_s
        while True:
            with self._lock:
                acked = len(self.acks) - first
            if acked >= len(lines):
                break
            if time.monotonic() > deadline:
                raise AssertionError(f"{acked} of {len(lines)} lines acknowledged in"
                                     f" {timeout_s} s; last: {self.replies[-3:]}")
            in_flight = sum(sizes[acked:sent])
            while sent < len(lines) and in_flight + len(lines[sent]) + 1 <= RX_BUFFER_BYTES - 1:
                self.send(lines[sent] + "\n")
                sizes.append(len(lines[sent]) + 1)
                in_flight += sizes[-1]
                sent += 1
            time.sleep(0.001)
        with self._lock:
            return self.acks[first:first + len(lines)]

    @contextmanager
    def polling(self, period_s: float = 0.1) -> Iterator[None]:
        """``?`` every ``period_s`` while inside."""
        done = threading.Event()

        def poll() -> None:
            while not done.wait(period_s):
                self.send(b"?")

        thread = threading.Thread(target=poll, name="raw-sender-poll", daemon=True)
        thread.start()
        try:
            yield
        finally:
            done.set()
            thread.join(timeout=5)

    def errors(self) -> list[str]:
        """Every ``error:`` and ``ALARM:`` line received."""
        with self._lock:
            return [text for _, text in self.replies if text.startswith(("error", "ALARM"))]

    def close(self) -> None:
        """Stop reading and close the terminal (safe twice)."""
        self._stop.set()
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
        self._reader.join(timeout=5)
