"""grbl-streamer (PyPI) against the grbl server on a pseudo-terminal, with the fake machine
and with a real machine session (the simulated machine in real time, as ``usbmotion grbl``
serves it): it connects, unlocks, homes, streams a program with character counting and
reports it done; the receive buffer never overflows and the machine's path is the
program's (on the simulated machine: what its devices executed). A device fault
mid-program reaches it as an alarm."""

from __future__ import annotations

import importlib.util
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from tests.grbl.conformance import path_problems
from tests.grbl.fake_machine import FakeMachine
from tests.senders.helpers import (
    PROGRAM,
    PROGRAM_PATH,
    SHORT_PROGRAM,
    SHORT_PROGRAM_PATH,
    executing_lines,
    most_lines_ahead,
    need,
    path_deviation,
    record,
    served_fake,
    served_real,
    wait_for,
)

from usbmotion.grbl.interface import Fault
from usbmotion.grbl.server import GrblServer

pytestmark = pytest.mark.realtime

AT_REST_MM = 0.02
"""How far the simulated machine's encoders may stand from where it was sent, at rest."""


class _Sender:
    """grbl-streamer connected to the server, its events recorded."""

    def __init__(self, server: GrblServer, homed: Callable[[], bool]) -> None:
        from grbl_streamer import GrblStreamer  # type: ignore[import-untyped]  # noqa: PLC0415

        self.server, self.homed = server, homed
        self.events: list[tuple[str, tuple[Any, ...]]] = []
        self.times: list[float] = []
        """When each event came (monotonic s)."""
        self._lock = threading.Lock()
        self._start_job = threading.Event()
        self._all_answered = threading.Event()
        self.streamer = GrblStreamer(self._callback)
        self.streamer.setup_logging()

    def _callback(self, event: str, *data: Any) -> None:
        with self._lock:
            self.events.append((event, data))
            self.times.append(time.monotonic())
        # grbl-streamer streams from the caller of job_run and from its reader thread on
        # each ok, unguarded: started from another thread, a line can go out twice. So the
        # job starts here, on its reader thread, on the ok of the $N sent last.
        if not self._start_job.is_set():
            return
        if event == "on_read" and str(data[0]).startswith("$N0="):
            self._all_answered.set()
        elif event == "on_rx_buffer_percent" and self._all_answered.is_set():
            self._start_job.clear()
            self._all_answered.clear()
            self.streamer.job_run()
            # Requests of its own queued before the job are dropped (see run); from here
            # on, streaming, it makes none.
            self.streamer.gcode_parser_state_requested = False
            self.streamer.hash_state_requested = False
            self.streamer.poll_start()

    def seen(self, event: str, *data: Any) -> bool:
        with self._lock:
            return any(e == event and d[:len(data)] == data for e, d in self.events)

    def events_since(self, index: int) -> list[tuple[str, tuple[Any, ...]]]:
        with self._lock:
            return self.events[index:]

    def data(self, *events: str) -> list[tuple[str, tuple[Any, ...]]]:
        with self._lock:
            return [(e, d) for e, d in self.events if e in events]

    def connect_unlock_and_home(self) -> None:
        self.streamer.cnect(self.server.path, 115200)
        wait_for(lambda: self.seen("on_boot"), timeout_s=5, what="grbl-streamer's on_boot")
        self.streamer.poll_start()
        self.streamer.killalarm()
        self.streamer.homing()
        wait_for(self.homed, timeout_s=15, what="homing")

    def run(self, program: str) -> None:
        """Stream ``program`` counting characters. grbl-streamer sends ``$G`` of its own
        (uncounted) whenever an idle machine's report changes, as a closed-loop machine's
        measured position may at rest; it takes every ok for the oldest counted line's, so
        an ok of such a line arriving after the job started would free a line still in the
        buffer and overrun it. Its polling stops first, and the job starts on the ok of a
        ``$N`` sent after everything else: by then every earlier line is answered."""
        self.streamer.poll_stop()
        self.streamer.incremental_streaming = False  # character counting
        self.streamer.write(program)
        self._start_job.set()
        self.streamer.send_immediately("$N")  # its ok starts the job


@contextmanager
def _connected(server: GrblServer, homed: Callable[[], bool]) -> Iterator[_Sender]:
    sender = _Sender(server, homed)
    try:
        yield sender
    finally:
        sender.streamer.disconnect()


@contextmanager
def _grbl_streamer() -> Iterator[tuple[_Sender, FakeMachine]]:
    need(importlib.util.find_spec("grbl_streamer") is not None, "grbl-streamer (PyPI)")
    with served_fake() as (server, machine), _connected(
            server, lambda: machine.homings == 1) as sender:
        yield sender, machine


def test_grbl_streamer_homes_and_streams_a_program() -> None:
    with _grbl_streamer() as (sender, machine):
        sender.connect_unlock_and_home()
        sender.run(PROGRAM)
        streamer = sender.streamer
        wait_for(lambda: sender.seen("on_job_completed") and streamer.job_finished
                 and streamer.streaming_complete, timeout_s=20, what="the job's end")
        wait_for(lambda: sender.seen("on_stateupdate", "Idle", (0.0, 0.0, -1.0)), timeout_s=10,
                 what="the report of the machine at rest at the program's end")
    assert sender.data("on_error", "on_alarm") == []
    statistics = sender.server.protocol.statistics
    problems = path_problems([done.target_mm for done in machine.done], PROGRAM_PATH)
    record("grbl-streamer", statistics, path_problems=problems)
    assert statistics.dropped_rx_bytes == 0
    assert 0 < statistics.max_rx_bytes <= 128
    assert problems == [], machine.done


def _at_rest_at(sender: _Sender, where: tuple[float, ...], *, after: int) -> bool:
    """Whether a report since event ``after`` shows the machine Idle at ``where`` (its
    encoders, within a few counts of where it was sent)."""
    return any(event == "on_stateupdate" and data[0] == "Idle" and len(data[1]) == len(where)
               and all(abs(a - b) <= AT_REST_MM for a, b in zip(data[1], where, strict=True))
               for event, data in sender.events_since(after))


def test_grbl_streamer_homes_and_streams_a_program_on_the_simulated_machine(
        tmp_path: Path) -> None:
    need(importlib.util.find_spec("grbl_streamer") is not None, "grbl-streamer (PyPI)")
    with served_real(tmp_path) as real, _connected(real.server, real.idle) as sender:
        sender.connect_unlock_and_home()
        started = time.monotonic()
        before = len(sender.events)
        feed = real.operator.feed
        first_line = (feed.lines if feed is not None else 0) + 1
        with executing_lines(real.session) as executing:
            sender.run(SHORT_PROGRAM)
            wait_for(lambda: any(e == "on_job_completed" for e, _ in sender.events_since(before))
                     and sender.streamer.job_finished and sender.streamer.streaming_complete,
                     timeout_s=40, what="the job's end",
                     seen=lambda: sender.events_since(before)[-3:])
        acked: dict[int, float] = {}  # the job's line index -> when its ok was processed
        for (event, data), when in zip(sender.events[before:], sender.times[before:],
                                       strict=True):
            if event == "on_processed_command" and data[0] >= 0:
                acked.setdefault(int(data[0]), when)
        ahead = most_lines_ahead(executing, acked.items(), first_line)
        wait_for(lambda: _at_rest_at(sender, (0.0, 0.0, -1.0), after=before) and real.idle(),
                 timeout_s=10, what="the report of the machine at rest at the program's end",
                 seen=lambda: sender.data("on_stateupdate")[-3:])
        run_s = time.monotonic() - started
    executed = real.executed_mm()
    assert sender.data("on_error", "on_alarm") == []
    statistics = sender.server.protocol.statistics
    problems, deviation_mm = path_deviation(executed, [(0.0, 0.0, 0.0), *SHORT_PROGRAM_PATH])
    record("grbl-streamer-simulated", statistics, path_problems=problems,
           machine="simulated", path_deviation_mm=deviation_mm, run_s=run_s,
           run_from="the job's start to the report of the machine at rest at its end",
           most_lines_acknowledged_ahead=ahead)
    # grbl-streamer writes the first line's three G codes as three lines: its commands
    assert sorted(acked) == list(range(len(acked))) and len(acked) >= SHORT_PROGRAM.count("\n")
    assert ahead <= 16, f"grbl-streamer had {ahead} lines acknowledged ahead of the line" \
        " the devices executed (grbl's planner holds 16)"
    assert statistics.dropped_rx_bytes == 0
    assert 0 < statistics.max_rx_bytes <= 128
    assert problems == [], real.messages
    assert not [m for m in real.messages if m.startswith(("error", "stopped"))]


def test_grbl_streamer_sees_a_device_fault_as_an_alarm() -> None:
    with _grbl_streamer() as (sender, machine):
        sender.connect_unlock_and_home()
        machine.fault_after_moves = (2, Fault(1, "following error 2.000 mm over"
                                              " 1.000 mm", axis="X"))
        sender.run("G1 X5 F3000\nG1 Y5\nG1 X0\nG1 Y0\n")
        wait_for(lambda: sender.seen("on_alarm"), timeout_s=10, what="the alarm")
        wait_for(lambda: sender.streamer.cmode == "Alarm", timeout_s=5, what="the Alarm state")
    assert sender.data("on_alarm") == [("on_alarm", ("ALARM:1",))]
    assert sender.data("on_error") == []
    assert [d.target_mm for d in machine.done] == [(5.0, 0.0, 0.0), (5.0, 5.0, 0.0)]
