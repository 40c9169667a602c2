"""The RP2040 firmware (``build/firmware/usbmotion.uf2``) replaying sessions in the emulator.

:class:`EmulatedFirmware` plays a session of ``tests/firmware/sessions.py`` on one emulated
chip (``usbmotion.sim.firmware.EmulatedDevice``, deterministic): a fresh chip on blank flash,
bytes given at servo tick boundaries (the harness holds the timer while core0 handles them),
ticks run, power cycles on the same flash. Every line comes back with the tick its bytes
reached the host at, counted from the session's start as the Python's are.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest

from usbmotion.sim.firmware import (
    EmulatedDevice,
    OutputChunk,
    Span,
    default_uf2,
    emulator_dir,
)

from .sessions import NO_NEWLINE, Feed, Power, Printed, Run, Step

STACK_MARGIN = 256
"""Stack bytes a session must leave unused on each core (interrupts' frames vary)."""
SPANS_TICKS = b" <spans ticks %d-%d>"
"""Marks a line whose first byte and newline reached the host at different ticks."""


def missing() -> str | None:
    """Why the emulated firmware cannot run here (``make firmware`` builds it), or None."""
    if shutil.which("node") is None:
        return "node (Node.js 20) is not installed"
    if not (emulator_dir() / "node_modules" / "rp2040js").is_dir():
        return f"the emulator's packages are not installed in {emulator_dir()} (npm ci)"
    uf2 = default_uf2()
    if not uf2.is_file() or not uf2.with_suffix(".elf").is_file():
        return f"{uf2} is not built"
    return None


def require_emulator(why: str | None = None) -> None:
    """Skip the test when the emulated firmware cannot run here (``missing``, or ``why``);
    in CI, where ``make test`` builds everything first, fail it instead."""
    why = why or missing()
    if why is not None:
        message = f"{why}: `make firmware` builds the firmware and installs the emulator"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)


def emulated_driver() -> Iterator[EmulatedFirmware]:
    """A module fixture's body: one emulated chip (each session powers up a fresh one on
    blank flash), closed after the module."""
    require_emulator()
    firmware = EmulatedFirmware()
    yield firmware
    firmware.close()


class EmulatedFirmware:
    """One emulated RP2040 replaying sessions, one after the other, in one process."""

    def __init__(self, uf2: Path | None = None) -> None:
        self.device = EmulatedDevice(uf2 if uf2 is not None else default_uf2())
        self.spans: list[Span] = []
        """Every span of the last session (boot included), for the cost figures."""
        self.stack_high_water = [0, 0]
        """The most stack each core used in any session so far, bytes."""

    def close(self) -> None:
        """Stop the emulator process."""
        self.device.close()

    def replay(self, steps: Sequence[Step]) -> Printed:
        """The session on a fresh chip with blank flash: every line with its tick."""
        device = self.device
        span = device.power_up(erase_flash=True)
        spans = [span]
        base = 0  # ticks of the session before the last power cycle
        for step in steps:
            if isinstance(step, Feed):
                span = device.feed(step.data)
            elif isinstance(step, Run):
                span = device.run(step.ticks)
            elif isinstance(step, Power):
                base += span.tick
                span = device.power_cycle()
            spans.append(_rebased(span, base))
        self.spans = spans
        self.check_stacks()
        return printed_lines(spans)

    def check_stacks(self) -> None:
        """Each core used at most its stack less :data:`STACK_MARGIN` since power-up."""
        for core, usage in enumerate(self.device.stack_usage()):
            assert usage is not None, f"the ELF names no stack of core{core}"
            self.stack_high_water[core] = max(self.stack_high_water[core], usage.used)
            assert usage.used <= usage.size - STACK_MARGIN, (
                f"core{core} used {usage.used} of its {usage.size} stack bytes")


def _rebased(span: Span, base: int) -> Span:
    """The span with its ticks counted from the session's start."""
    if base == 0:
        return span
    return Span(tick=span.tick + base,
                output=tuple(OutputChunk(chunk.tick + base, chunk.data) for chunk in span.output),
                busy_cycles=span.busy_cycles, emulated_ns=span.emulated_ns)


def printed_lines(spans: Sequence[Span]) -> Printed:
    """The spans' output as lines, each with the tick its bytes reached the host at.

    A line whose bytes arrived over several ticks is kept with a marker naming them (so it
    differs from the Python's, which prints a line at one tick); a last line without its
    newline keeps :data:`~sessions.NO_NEWLINE`. A power cycle loses nothing here: the
    harness lets core0 finish printing before each request returns.
    """
    printed: Printed = []
    pending = bytearray()
    first_tick = 0
    for span in spans:
        for chunk in span.output:
            data = chunk.data
            start = 0
            while start < len(data):
                if not pending:
                    first_tick = chunk.tick
                end = data.find(b"\n", start)
                if end < 0:
                    pending += data[start:]
                    break
                pending += data[start:end]
                line = bytes(pending)
                if first_tick != chunk.tick:
                    line += SPANS_TICKS % (first_tick, chunk.tick)
                printed.append((first_tick, line))
                pending.clear()
                start = end + 1
    if pending:
        printed.append((first_tick, bytes(pending) + NO_NEWLINE))
    return printed


def recording_steps(chunks: Sequence[tuple[int, bytes]], *, after: int = 0) -> list[Step]:
    """A recorded session (``usbmotion.sim.firmware.read_recording``) as replay steps: each
    chunk fed at the tick boundary it arrived at, then ``after`` more ticks."""
    steps: list[Step] = []
    tick = 0
    for at, data in chunks:
        if at > tick:
            steps.append(Run(at - tick))
            tick = at
        steps.append(Feed(data))
    if after:
        steps.append(Run(after))
    return steps
