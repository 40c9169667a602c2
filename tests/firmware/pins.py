"""The firmware on an emulated chip whose pins drive a motor outside it.

:class:`PinsChip` runs ``firmware/emulator/control.js`` and adds its requests for the pins:
``motor`` wires a DC motor, encoder and switches to the chip (``lib/pins.js`` MotorWorld),
``world`` reads that world, ``sweep`` steps the encoder pins alone at a set rate.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

from usbmotion.sim.firmware import default_uf2, emulator_dir


class PinsChip:
    """One emulated chip in deterministic mode, with blank flash, on its pins or not."""

    def __init__(self, *, pins: bool, uf2: Path | None = None) -> None:
        self._process = subprocess.Popen(
            ["node", str(emulator_dir() / "control.js")], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, text=True, encoding="latin-1")
        self.request(cmd="load", uf2=str(uf2 or default_uf2()))
        self.request(cmd="power_up", erase_flash=True)
        if pins:
            self.feed("39 1\n")
            self.request(cmd="power_cycle")

    def request(self, **request: Any) -> dict[str, Any]:
        """One request; its reply (raises AssertionError on a refusal)."""
        assert self._process.stdin is not None and self._process.stdout is not None
        self._process.stdin.write(json.dumps(request) + "\n")
        self._process.stdin.flush()
        reply: dict[str, Any] = json.loads(self._process.stdout.readline())
        assert reply.get("ok"), reply
        return reply

    @staticmethod
    def lines(reply: dict[str, Any]) -> list[tuple[int, str]]:
        """The lines a span printed, each with the tick it was printed at."""
        out: list[tuple[int, str]] = []
        for tick, text in reply["output"]:
            out.extend((tick, line) for line in text.splitlines())
        return out

    def feed(self, text: str) -> list[str]:
        """Lines at the present tick; the lines printed."""
        return [line for _, line in self.lines(self.request(cmd="feed", data=text))]

    def run(self, ticks: int) -> list[str]:
        """``ticks`` servo ticks; the lines printed."""
        return [line for _, line in self.lines(self.request(cmd="run", ticks=ticks))]

    def status(self) -> list[int]:
        """Call 20's fields."""
        (line,) = self.feed("20 -1\n")
        return [int(word) for word in line.split()[1:]]

    def close(self) -> None:
        """Stop the emulator."""
        if self._process.poll() is None:
            assert self._process.stdin is not None
            self._process.stdin.close()
            self._process.wait(timeout=10)

    def __enter__(self) -> PinsChip:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
