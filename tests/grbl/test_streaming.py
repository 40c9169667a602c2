"""Character-counting streaming, every status report's format, and the path executed: each
checked on the fake machine, and each checker shown to catch a deliberate mistake."""

from __future__ import annotations

import dataclasses

import pytest
from tests.grbl.conformance import (
    Exchange,
    Expect,
    path_problems,
    replay,
    status_report_problems,
    stream_counting,
)
from tests.grbl.harness import Bench
from tests.grbl.recorded import EXCHANGES

from usbmotion.grbl.interface import Admission
from usbmotion.grbl.protocol import GrblProtocol

PROGRAM = (
    "G21 G90 G54 (a square, twice, in short segments)",
    "G0 X0 Y0",
    *(f"G1 X{x / 2:.1f} Y0 F3000" for x in range(1, 41)),
    *(f"G1 X20.0 Y{y / 2:.1f}" for y in range(1, 41)),
    *(f"G1 X{20 - x / 2:.1f} Y20.0" for x in range(1, 41)),
    *(f"G1 X0.0 Y{20 - y / 2:.1f}" for y in range(1, 41)),
    "G4 P0.01",
    "M2",
)
"""160 short moves: the planner (15 blocks) and the 128-byte buffer both fill."""


def expected_path() -> list[tuple[float, ...]]:
    """The program's move end points, worked out from its text."""
    points: list[tuple[float, ...]] = [(0.0, 0.0, 0.0)]
    points += [(x / 2, 0.0, 0.0) for x in range(1, 41)]
    points += [(20.0, y / 2, 0.0) for y in range(1, 41)]
    points += [(20 - x / 2, 20.0, 0.0) for x in range(1, 41)]
    points += [(0.0, 20 - y / 2, 0.0) for y in range(1, 41)]
    return points


def test_character_counting_stream_keeps_the_buffer_and_the_path() -> None:
    bench = Bench.make().unlocked()
    result = stream_counting(bench, PROGRAM)
    assert result.responses == ["ok"] * len(PROGRAM)
    assert result.messages == ["[MSG:Pgm End]"]
    assert result.max_in_flight_bytes <= 128
    statistics = bench.front.statistics
    assert statistics.dropped_rx_bytes == 0
    assert 100 < statistics.max_rx_bytes <= 128  # the buffer was used, never overflowed
    assert path_problems([d.target_mm for d in bench.machine.done], expected_path()) == []


def test_ok_is_sent_when_a_line_leaves_for_the_planner_not_when_it_runs() -> None:
    bench = Bench.make().unlocked()
    bench.front.receive(b"G1F600\n" + b"".join(b"X%d\n" % x for x in range(1, 21)))
    bench.run()
    assert bench.front.statistics.dropped_rx_bytes == 0
    assert bench.take() == b"ok\r\n" * 16  # G1F600 moves nothing; the planner holds 15
    assert bench.machine.done == []
    bench.front.receive(b"?")
    report = bench.take().decode()
    assert "|Bf:0," in report
    bench.run(0.12)  # the first move (1 mm at 10 mm/s) is done: one more line fits
    assert bench.take() == b"ok\r\n"


def test_a_greedy_sender_overflows_and_the_statistics_say_so() -> None:
    bench = Bench.make().unlocked()
    with pytest.raises(AssertionError):  # lines lost: some never get an answer
        stream_counting(bench, PROGRAM, greedy=True, limit_s=5.0)
    assert bench.front.statistics.dropped_rx_bytes > 0
    assert bench.front.statistics.max_rx_bytes == 128


def test_the_path_checker_catches_a_lost_and_a_moved_point() -> None:
    path = expected_path()
    assert path_problems(path[:-1], path) == [
        f"{len(path) - 1} moves executed, the program has {len(path)}"]
    moved = [*path[:5], (99.0, 0.0, 0.0), *path[6:]]
    assert path_problems(moved, path) == [
        f"move 5: ended at (99.0, 0.0, 0.0), the program says {path[5]}"]


def _reports(exchange: Exchange) -> list[str]:
    return [line for step in exchange.steps if isinstance(step, Expect)
            for line in step.data.decode().split("\r\n") if line.startswith("<")]


@pytest.mark.parametrize("exchange", [e for e in EXCHANGES if _reports(e)],
                         ids=lambda e: e.name)
def test_every_recorded_status_report_has_grbls_format(exchange: Exchange) -> None:
    axes = len(exchange.machine.get("axes", "XYZ"))  # type: ignore[arg-type]
    inches = any(b"$13=1" in getattr(step, "data", b"") for step in exchange.steps)
    for line in _reports(exchange):
        assert status_report_problems(line, axes=axes, inches=inches) == []


@pytest.mark.parametrize(("line", "problem"), [
    ("Idle|MPos:0.000,0.000,0.000|FS:0,0", "is not enclosed"),
    ("<Running|MPos:0.000,0.000,0.000|FS:0,0>", "state 'Running'"),
    ("<Idle|FS:0,0|MPos:0.000,0.000,0.000>", "second field"),
    ("<Idle|MPos:0.000,0.000|FS:0,0>", "2 values for 3 axes"),
    ("<Idle|MPos:0.0,0.0,0.0|FS:0,0>", "do not have 3 decimals"),
    ("<Idle|MPos:0.000,0.000,0.000|Bf:15|FS:0,0>", "Bf:15 is not 2 whole numbers"),
    ("<Idle|MPos:0.000,0.000,0.000>", "no FS"),
    ("<Idle|MPos:0.000,0.000,0.000|FS:0,0|Pn:Q>", "Pn:Q"),
    ("<Idle|MPos:0.000,0.000,0.000|FS:0,0|Xyz:1>", "field Xyz"),
    ("<Idle|MPos:0.000,0.000,0.000|FS:0,0|FS:0,0>", "FS twice"),
])
def test_the_status_report_checker_catches_each_mistake(line: str, problem: str) -> None:
    assert any(problem in found for found in status_report_problems(line, axes=3))


@pytest.mark.parametrize("exchange", [e for e in EXCHANGES
                                      if any(isinstance(s, Expect) and s.data
                                             for s in e.steps)],
                         ids=lambda e: e.name)
def test_the_replay_checker_catches_one_wrong_byte(exchange: Exchange) -> None:
    index = next(i for i, s in enumerate(exchange.steps) if isinstance(s, Expect) and s.data)
    step = exchange.steps[index]
    assert isinstance(step, Expect)
    wrong = bytes([step.data[0] ^ 0x20]) + step.data[1:]
    mutated = dataclasses.replace(exchange, steps=(
        *exchange.steps[:index], Expect(wrong), *exchange.steps[index + 1:]))
    assert replay(mutated)


class _OkOnReceipt(GrblProtocol):
    """A broken front: answers G4 at once instead of after the motion before it."""

    def _submit(self, line: str, number: int | None, effects: object) -> None:
        if self.machine.submit(line, number) is Admission.ACCEPTED:
            self._ok()


class _EchoingFront(GrblProtocol):
    """A broken front: puts real-time bytes in the buffer too."""

    def receive(self, data: bytes) -> None:
        for byte in data:
            if byte in b"?!~":
                self._rx.append(byte)
            super().receive(bytes([byte]))


@pytest.mark.parametrize(("broken", "name"), [
    (_OkOnReceipt, "G4: its ok only once the motion before it has finished"),
    (_EchoingFront, "real-time bytes are never echoed, counted or kept in the buffer"),
])
def test_a_broken_front_fails_its_exchange(broken: type[GrblProtocol], name: str) -> None:
    exchange = next(e for e in EXCHANGES if e.name == name)
    assert replay(exchange) == []
    assert replay(exchange, front=lambda bench: broken(bench.machine, bench.output.extend))


def test_the_front_says_when_lines_are_on_their_way_to_the_machine() -> None:
    """What the machine asks before a streamed run that played out its lines ends: a whole
    line in the buffer, or one waiting for the planner, is on its way; half a line, or a
    line that waits for the motion to end (G4), is not."""
    bench = Bench.make().unlocked()
    waiting = bench.machine.lines_waiting
    assert waiting == bench.front.lines_waiting and not waiting()
    bench.front.receive(b"G1X1F600")
    assert not waiting(), "half a line"
    bench.front.receive(b"\n")
    assert waiting()
    bench.run()
    assert not waiting(), "taken by the planner"
    bench.front.receive(b"G4P1\nG1X2\n")
    bench.run()
    assert not waiting(), "G4 waits for the motion: the run must end for it"
    bench.run_until_idle()
    bench.front.receive(b"".join(b"X%d\n" % x for x in range(3, 40)))
    bench.run()
    assert waiting(), "lines wait for room in the planner"
    bench.run_until_idle()
    assert not waiting()
