"""What a grbl sender and the console are shown comes from the session's live model, fed
by the devices: in real time, on the built-in simulated machine and on devices served by
``usbmotion sim --pty 3``. Polled at 10 Hz during a move, the status report follows the
axis, never backward and never further than the axis can have gone since the move was sent;
``FS`` is the speed the encoders measure; a hold reports where the machine came to rest; a
sender's ``ok`` follows the machine (at most 16 lines ahead of the one executing); a
streamed engraving of short moves runs to its end on its own path with both cores
loaded."""

from __future__ import annotations

import itertools
import re
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from tests.programs.engraving import engraving
from tests.reliability.bench import bench_machine, served
from tests.senders.helpers import (
    executing_lines,
    fast_homing_machine,
    most_lines_ahead,
    path_deviation,
    served_real,
)
from tests.senders.raw_sender import RawSender

from usbmotion.console import Console
from usbmotion.grbl.server import GrblServer
from usbmotion.grbl.session_machine import SessionMachine
from usbmotion.host.config import load_config
from usbmotion.session import MachineSession
from usbmotion.session.operator import Operator
from usbmotion.session.planning import plan_gcode
from usbmotion.session.state import MachineState
from usbmotion.sim.machine import connect_session
from usbmotion.sim.world import REALTIME_SLACK_S, SimWorld

pytestmark = pytest.mark.realtime

POLL_S = 0.1
FEED_MM_MIN = 600.0
"""10 mm/s."""


@dataclass
class Front:
    """A machine session served as a grbl controller on a pseudo-terminal."""

    path: str
    session: MachineSession
    operator: Operator

    def device_mm(self) -> dict[str, float]:
        """Every axis's encoder, read from its device on the operator's worker (after
        what it is doing), mm."""
        read: list[dict[str, float]] = []
        machine = self.session.machine
        self.operator.do(lambda: read.append({
            name: machine.axis(name).scale.to_mm(status.actual_counts)
            for name, status in machine.status().items()}))
        assert self.operator.wait_idle(30)
        return read[0]


@contextmanager
def _front(tmp_path: Path, where: str) -> Iterator[Front]:
    if where == "built-in":
        with served_real(tmp_path) as real:
            yield Front(real.server.path, real.session, real.operator)
        return
    with served(tmp_path / "flash") as paths:
        config = load_config(bench_machine(tmp_path, paths, watchdog_ms=1250))
        with MachineSession.connect(config) as session:
            operator = Operator(session, file="<grbl>")
            front = SessionMachine(operator)
            try:
                front.start()
                with GrblServer(front) as server:
                    server.start()
                    yield Front(server.path, session, operator)
            finally:
                front.close()
                operator.close()
                session.shutdown()


@contextmanager
def _sender(path: str) -> Iterator[RawSender]:
    sender = RawSender(path)
    try:
        yield sender
    finally:
        sender.close()


@pytest.mark.parametrize("where", ["built-in", "served"])
def test_status_polls_follow_the_encoders_and_a_hold_shows_where_it_rests(
        tmp_path: Path, where: str) -> None:
    with _front(tmp_path, where) as front, _sender(front.path) as sender:
        sender.reset_and_home()
        start = sender.reports[-1].mpos if sender.reports else (0.0, 0.0, 0.0)
        with sender.polling(POLL_S):
            sent_s = time.monotonic()
            assert sender.command(f"G90 G1 X{start[0] + 30:.3f} F{FEED_MM_MIN:g}") == "ok"
            sender.wait(lambda: any(r.state == "Run" and r.mpos[0] > start[0] + 15
                                    for r in sender.reports), timeout_s=10, what="half way")
            sender.send(b"!")
            sender.wait(lambda: sender.reports[-1].state == "Hold:0", timeout_s=5,
                        what="Hold:0")
            time.sleep(3 * POLL_S)
        cruising = [r for r in sender.reports if r.state == "Run"
                    and start[0] + 2 < r.mpos[0] < start[0] + 14]
        assert len(cruising) >= 8, cruising
        speed_mm_s = FEED_MM_MIN / 60.0
        for report in cruising:
            # Measured, not sent: the axis cannot be further than the feed takes it from
            # the moment the move went out (the setpoints the host sends run ahead of it).
            # A real-time simulated world starved of its host catches up at most
            # REALTIME_SLACK_S of the time lost, without sleeping.
            gone_s = report.at_s - sent_s + REALTIME_SLACK_S
            assert report.mpos[0] - start[0] <= speed_mm_s * gone_s + 0.01, (
                "no further than the axis can have gone", round(gone_s, 3), report.text)
            assert report.feed_mm_min == pytest.approx(FEED_MM_MIN, rel=0.05), report.text
        advanced = 0
        for before, after in itertools.pairwise(cruising):
            assert after.mpos[0] >= before.mpos[0], ("never backward", before.text, after.text)
            advanced += after.mpos[0] > before.mpos[0]
        # A report shows the encoders the host last read; a host starved of both cores
        # reads late, and a real-time simulated world it runs stands still meanwhile (its
        # devices take no time the host did not give them): polls answered in that while
        # report the same encoders, truly (make test's busy lanes: 6 of 11 pairs advanced
        # once). The reports still follow the axis through the cruise.
        assert advanced >= 4, (advanced, [r.text for r in cruising])
        held = [r for r in sender.reports if r.state == "Hold:0"]
        assert len(held) >= 2, held
        sender.send(b"\x18")
        sender.wait(lambda: any(text.startswith("Grbl") for _, text in sender.replies[-3:]),
                    timeout_s=10, what="the reset's banner")
        rest = front.device_mm()
        for report in held:
            # At rest a servo may still creep toward its commanded position by the
            # following error the report shows (its integrator against friction): the
            # encoder then rests between the two.
            errors = re.search(r"\|FE:([-\d.,]+)", report.text)
            creep = [abs(float(v)) for v in errors.group(1).split(",")] if errors else [0.0] * 3
            for axis, reported, fe in zip("XYZ", report.mpos, creep, strict=True):
                assert reported == pytest.approx(rest[axis], abs=0.01 + fe), (
                    f"{axis}: every Hold:0 report shows where the encoder rests", report.text,
                    rest)
        assert sender.errors() == []


def test_the_console_shows_the_machine_moving_during_a_cycle_and_a_jog(
        tmp_path: Path) -> None:
    """The console's ``?`` during ``$c`` and during a continuous jog: the machine's
    encoders as they move, and the line it executes."""
    program = tmp_path / "line.ngc"
    program.write_text("G21 G90\nG1 X25 F600\nG1 Y5\nM2\n")
    world = SimWorld(realtime=True)
    said: list[str] = []
    with connect_session(load_config(fast_homing_machine(tmp_path)), world=world) as session:
        console = Console(session, said.append)
        console.operator.on_idle = world.keep_pace
        try:
            for line in ("$r", f"$l {program}", "$c"):
                console.handle(line)
            _until(lambda: session.state is MachineState.RUN, said)
            time.sleep(0.5)
            shown = []
            for _ in range(3):
                console.handle("?")
                shown.append(said[-1])
                time.sleep(0.3)
            assert console.operator.wait_idle(60)
            xs = [float(text.split("machine X ")[1].split()[0]) for text in shown]
            assert xs[0] < xs[1] < xs[2], shown
            assert all("line 2 of 4" in text for text in shown), shown
            console.handle("$j X+ F600")
            _until(lambda: session.state is MachineState.JOG, said)
            time.sleep(0.3)
            console.handle("?")
            first = said[-1]
            time.sleep(0.3)
            console.handle("?")
            second = said[-1]
            console.handle("$jx")
            assert console.operator.wait_idle(30)
            jogged = [float(text.split("machine X ")[1].split()[0]) for text in (first, second)]
            assert jogged[0] < jogged[1] and first.startswith("state: Jog"), (first, second)
        finally:
            console.close()
            session.shutdown()


def _until(condition: Callable[[], bool], said: list[str], timeout_s: float = 30) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, said[-5:]
        time.sleep(0.01)


THIRTY_SIX = [
    "G21 G90 G17 (36 lines: a pocket's outline, a slot, two arcs and the retracts)",
    "G0 Z-2", "G0 X2 Y2", "G1 Z-4 F600", "G1 X12 F1200", "G1 Y4.5", "G1 X2", "G1 Y7",
    "G1 X12", "G1 Y9.5", "G1 X2", "G1 Y12", "G1 X12", "G0 Z-2", "G0 X7 Y2", "G1 Z-4 F600",
    "G1 Y12 F900", "G0 Z-2", "G0 X15 Y7", "G1 Z-4 F600", "G2 X20 Y7 I2.5 J0 F900",
    "G2 X15 Y7 I-2.5 J0", "G0 Z-2", "G0 X23 Y3", "G1 Z-4 F600", "G3 X23 Y10 I0 J3.5 F900",
    "G1 X25", "G1 Y3", "G1 X23", "G0 Z-2", "G0 X3 Y13", "G1 X5 F1200", "G1 X7",
    "G1 X9", "G0 Z0", "M2",
]


def test_a_senders_ok_follows_the_machine_and_its_plan_keeps_time(tmp_path: Path) -> None:
    """A character-counting sender streams a 36-line program: at no moment while it runs
    are the lines acknowledged more than 16 ahead of the line the devices execute (grbl's
    planner holds 16 blocks; before the first motion begins no line executes), and the
    streamed program takes the time of its whole plan within 1 %."""
    assert len(THIRTY_SIX) == 36
    with served_real(tmp_path) as real, _sender(real.server.path) as sender:
        sender.reset_and_home()
        assert sender.command("G21") == "ok"
        feed = real.operator.feed
        assert feed is not None
        base = feed.lines
        here = real.session.live.read().machine_mm(measured=False)
        _, plan = plan_gcode(real.session.config, "\n".join(THIRTY_SIX) + "\n",
                             start_mm=tuple(here[a] for a in "XYZ"))
        with executing_lines(real.session) as executing:
            acks = sender.stream(THIRTY_SIX, timeout_s=120)
            sender.wait(real.idle, timeout_s=120, what="the program's end")
        ahead = most_lines_ahead(executing, enumerate(acks), base + 1)
        assert ahead <= 16, f"acknowledged up to {ahead} lines ahead of the line executing"
        report = real.operator.last_report
        assert report is not None and report.completed, report
        print(f"\nlines acknowledged ahead of the line executing: at most {ahead};"
              f" streamed {report.executed_time_s:.3f} s against the whole plan's"
              f" {plan.duration_s:.3f} s")
        assert report.executed_time_s <= 1.01 * plan.duration_s
        assert sender.errors() == []


@contextmanager
def _both_cores_loaded() -> Iterator[None]:
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        yield
    finally:
        for process in busy:
            process.kill()
            process.wait()


def test_a_streamed_engraving_of_short_moves_runs_its_path_with_both_cores_loaded(
        tmp_path: Path) -> None:
    """Thousands of 0.1-0.5 mm moves streamed by a character-counting sender through the
    grbl front, both cores busy with other work: the program runs to its end, no alarm, no
    error, on the program's own path."""
    lines = engraving(2000, seed=7, feed_mm_min=1200, stroke=1000, turn_rad=0.1)
    with served_real(tmp_path) as real, _sender(real.server.path) as sender:
        sender.reset_and_home()
        start = real.session.live.read().machine_mm(measured=False)
        with _both_cores_loaded():
            sender.stream(lines, timeout_s=240)
            sender.wait(real.idle, timeout_s=120, what="the engraving's end")
        executed = real.executed_mm()
        assert sender.errors() == [], sender.errors()
        report = real.operator.last_report
        assert report is not None and report.completed, report
    problems, deviation_mm = path_deviation(executed, _corners(lines, start))
    step_mm = float(np.abs(np.diff(executed, axis=0)).max())
    print(f"\nengraving: {len(lines)} lines, path deviation {deviation_mm:.4f} mm, largest"
          f" setpoint step {step_mm:.4f} mm a tick")
    assert problems == [], problems[:5]
    assert step_mm <= 20.0 * 0.001 + 1 / 240 + 1e-9, "no jump: at most 20 mm/s and a count"


def _corners(lines: list[str], start: dict[str, float]) -> list[tuple[float, float, float]]:
    """Where each move of a program of G0/G1 lines (absolute, mm) ends, from ``start``."""
    here = [start["X"], start["Y"], start["Z"]]
    points: list[tuple[float, float, float]] = [(here[0], here[1], here[2])]
    for line in lines:
        words = line.split("(")[0].split()
        if not words or words[0] not in ("G0", "G1"):
            continue
        for word in words[1:]:
            if word[0] in "XYZ":
                here["XYZ".index(word[0])] = float(word[1:])
        if (here[0], here[1], here[2]) != points[-1]:
            points.append((here[0], here[1], here[2]))
    return points
