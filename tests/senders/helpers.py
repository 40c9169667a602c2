"""What the sender tests share: skipping (or, in CI, failing) when a sender is not
installed, the fake machine or a real machine session (the simulated machine in real time)
served on a pseudo-terminal, the programs they stream, and the check of what the simulated
devices executed against the program."""

from __future__ import annotations

import json
import math
import os
import shutil
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from tests.grbl.fake_machine import FakeMachine

from usbmotion.cli.run import default_machine
from usbmotion.grbl.protocol import GrblProtocol, Statistics
from usbmotion.grbl.server import GrblServer
from usbmotion.grbl.session_machine import SessionMachine
from usbmotion.host.config import load_config
from usbmotion.session import MachineSession
from usbmotion.session.operator import Operator
from usbmotion.sim.machine import connect_session
from usbmotion.sim.recording import ExecutedRecorder
from usbmotion.sim.world import SimWorld

HERE = Path(__file__).resolve().parent
MEASUREMENTS = HERE.parents[1] / "build" / "senders"
"""Where each sender test records what it measured (build/ is not committed)."""
NODE_MODULES = HERE / "node_modules"
INSTALL = "bash tests/senders/install.sh"


def need(available: bool, what: str) -> None:
    """Skip the test when ``what`` is missing; in CI (``CI=true``) fail instead."""
    if available:
        return
    text = f"{what} is not installed: run `{INSTALL}`"
    if os.environ.get("CI") == "true":
        pytest.fail(text, pytrace=False)
    pytest.skip(text)


def node_package(name: str) -> bool:
    """True when the npm package ``name`` is installed under tests/senders/node_modules."""
    return (NODE_MODULES / name / "package.json").is_file() and shutil.which("node") is not None


SEGMENTS = 72
"""The circle's segments: short moves, so the planner and the receive buffer both fill."""


def _circle(size_mm: float) -> list[tuple[float, float]]:
    half = size_mm / 2
    points = []
    for index in range(1, SEGMENTS + 1):
        angle = 2 * math.pi * index / SEGMENTS
        points.append((round(half + half * math.cos(angle), 3),
                       round(half + half * math.sin(angle), 3)))
    return points


def square_and_circle(size_mm: float) -> tuple[str, list[tuple[float, float, float]]]:
    """A program (a square of ``size_mm`` with its diagonal, then the inscribed circle in
    :data:`SEGMENTS` segments, at a feed above any axis's limit, cut at Z-2 from Z-1, below
    the top of Z's travel where homing leaves it, so that it ends away from where it began)
    and where each of its moves ends, machine coordinates (no work offset)."""
    s, h = size_mm, size_mm / 2
    circle = _circle(size_mm)
    text = "\n".join([
        f"G21 G90 G54 (a {s:g} mm square with its diagonal, then a circle in {SEGMENTS}"
        " segments)",
        "G0 X0 Y0 Z-1",
        "G1 Z-2 F600",
        f"G1 X{s:g} F3000",
        f"G1 Y{s:g}",
        f"G1 X{h:g} Y{s:g}",
        f"G1 X0 Y{s:g}",
        "G1 Y0",
        f"G1 X{s:g} Y{s:g}",
        *(f"G1 X{x:.3f} Y{y:.3f}" for x, y in circle),
        "G0 Z-1",
        "G0 X0 Y0",
        "M2",
    ]) + "\n"
    path = [
        (0.0, 0.0, -1.0), (0.0, 0.0, -2.0), (s, 0.0, -2.0), (s, s, -2.0), (h, s, -2.0),
        (0.0, s, -2.0), (0.0, 0.0, -2.0), (s, s, -2.0), *((x, y, -2.0) for x, y in circle),
        (s, h, -1.0), (0.0, 0.0, -1.0),
    ]
    return text, path


PROGRAM, PROGRAM_PATH = square_and_circle(20.0)
"""The program the senders stream to the fake machine, and where each of its moves ends."""
PROGRAM_LINES = PROGRAM.count("\n")
SHORT_PROGRAM, SHORT_PROGRAM_PATH = square_and_circle(10.0)
"""The program for the simulated machine, which moves in real time at up to 20 mm/s."""


AXES = ["X", "Y", "Z"]
PATH_TOLERANCE_MM = 0.05
"""How far an executed point may be from the programmed polyline, and a programmed end
point from the nearest executed point (the recorded positions are the devices' setpoints,
exact to a count's rounding: 1 / 240 mm)."""
START_MM = 3.0
"""How far inside the travel end it homes to each simulated axis starts (X and Y above
their lower switches, Z below its upper one), with a quicker slow approach (4 mm/s from
0.5 mm; the edge is latched by the device either way): homing (Z, then X and Y) takes
about 2 s instead of 22 s."""
WATCHDOG_MS = 1250
"""The devices' watchdog, on as on a real machine. It counts the world's time, which
follows the wall clock while the host waits on a device or idles, and stands still while
the host computes (:data:`usbmotion.sim.world.REALTIME_SLACK_S`): a host slowed by a
loaded machine is not taken for a silent one."""


def fast_homing_machine(folder: Path) -> Path:
    """The default machine file, its axes starting :data:`START_MM` inside the travel end
    they home to and their watchdogs on, written into ``folder``; its path."""
    text = Path(default_machine()).read_text()
    for start, near in (("start_mm = 100.0", START_MM), ("start_mm = -50.0", -START_MM)):
        assert start in text, f"the default machine file no longer says {start!r}"
        text = text.replace(start, f"start_mm = {near}")
    assert "watchdog_ms = 0 " in text
    text = text.replace("watchdog_ms = 0 ", f"watchdog_ms = {WATCHDOG_MS} ")
    slow = "slow_speed_mm_s = 1.0, backoff_mm = 1.0"
    assert text.count(slow) == 3, f"the default machine file no longer homes with {slow!r}"
    text = text.replace(slow, "slow_speed_mm_s = 4.0, backoff_mm = 0.5")
    path = folder / "machine.toml"
    path.write_text(text)
    return path


@dataclass
class RealMachine:
    """A machine session on the simulated machine in real time, served as a grbl
    controller; what its devices executed is recorded from the end of the first homing."""

    server: GrblServer
    front: SessionMachine
    operator: Operator
    session: MachineSession
    messages: list[str] = field(default_factory=list)
    """What the operator said (runs' ends, pauses, errors)."""
    recorder: ExecutedRecorder | None = None
    homed_at: int | None = None
    """The recorder's tick at which the first homing ended."""

    @property
    def counts_per_mm(self) -> float:
        return self.session.config.axis("X").counts_per_mm

    def idle(self) -> bool:
        """True when homed and nothing runs or is queued."""
        return self.session.is_homed and not self.operator.busy

    def executed_mm(self) -> npt.NDArray[np.float64]:
        """The devices' setpoints at every servo tick since the homing ended, mm."""
        assert self.recorder is not None and self.homed_at is not None, \
            "the machine was never homed"
        since = self.recorder.positions()[self.homed_at:]
        positions: npt.NDArray[np.float64] = since / self.counts_per_mm
        return positions


@contextmanager
def served_real(folder: Path, *, plate_mm: float | None = None,
                **server_options: object) -> Iterator[RealMachine]:
    """The default simulated machine (homing fast: :func:`fast_homing_machine` in
    ``folder``; with ``plate_mm``, a probe plate under Z at that height) in real time through
    an operator and the grbl front, served on a pseudo-terminal (or as asked), as
    ``usbmotion grbl`` serves it. Leaving it stops the machine and closes everything it
    opened."""
    path = fast_homing_machine(folder)
    if plate_mm is not None:
        text = path.read_text()
        z_sim = f"sim = {{ start_mm = {-START_MM}"
        assert text.count(z_sim) == 1, f"Z's sim table no longer starts {z_sim!r}"
        path.write_text(text.replace(z_sim, f"sim = {{ probe_below_mm = {plate_mm},"
                                             f" start_mm = {-START_MM}"))
    config = load_config(path)
    world = SimWorld(realtime=True)
    with connect_session(config, world=world) as session:
        messages: list[str] = []
        operator = Operator(session, on_message=messages.append, file="<grbl>")
        operator.on_idle = world.keep_pace
        front = SessionMachine(operator)
        machine: RealMachine | None = None
        recorder = ExecutedRecorder(world, AXES)
        home = session.home

        def home_and_mark(*args: Any, **kwargs: Any) -> float:
            # On the operator's worker, before the world runs on: the mark is exact.
            seconds = home(*args, **kwargs)
            if machine is not None and machine.homed_at is None:
                machine.homed_at = min(len(values) for values in recorder.desired.values())
            return seconds

        session.home = home_and_mark  # type: ignore[method-assign]
        try:
            front.start()
            with GrblServer(front, **server_options) as server:  # type: ignore[arg-type]
                machine = RealMachine(server, front, operator, session, messages, recorder)
                server.start()
                yield machine
                assert server.error is None
        finally:
            front.close()
            operator.close()
            recorder.close()
            session.shutdown()


REALTIME_NAMES = {ord("!"): "! (feed hold)", ord("~"): "~ (cycle start)",
                  0x18: "Ctrl-X (soft reset)", 0x85: "0x85 (jog cancel)"}


def tap_received(server: GrblServer) -> list[tuple[float, str]]:
    """From now on, what the sender writes to ``server``'s front: (wall time, each line or
    real-time byte in words), ``?`` left out; the list is filled as bytes arrive."""
    received: list[tuple[float, str]] = []
    line = bytearray()
    protocol = server.protocol
    receive = protocol.receive

    def tapped(data: bytes) -> None:
        for byte in data:
            if byte == ord("?"):
                continue
            if byte in REALTIME_NAMES or byte >= 0x80:
                received.append((time.time(), REALTIME_NAMES.get(byte, f"0x{byte:02x}")))
            elif byte in b"\r\n":
                if line:
                    received.append((time.time(), line.decode(errors="replace")))
                    line.clear()
            else:
                line.append(byte)
        receive(data)

    protocol.receive = tapped  # type: ignore[method-assign]
    return received


def path_deviation(executed_mm: npt.NDArray[np.float64],
                   path_mm: list[tuple[float, float, float]], *,
                   tolerance_mm: float = PATH_TOLERANCE_MM) -> tuple[list[str], float]:
    """Whether the executed positions (one row per servo tick) follow the polyline
    ``path_mm`` (its first point where they start): every point of the polyline's ends
    passed in order within ``tolerance_mm``, no executed point farther than that from the
    polyline, and the last one at its end. The problems in words, and the largest distance
    of an executed point from the polyline, mm."""
    problems: list[str] = []
    if len(executed_mm) == 0:
        return ["nothing executed"], math.inf
    corners = np.array(path_mm, dtype=np.float64)
    start, end = corners[:-1], corners[1:]
    along = end - start
    length2 = np.maximum(np.einsum("ij,ij->i", along, along), 1e-18)
    points = np.unique(executed_mm, axis=0)
    worst = 0.0
    worst_point = points[0]
    for chunk in np.array_split(points, max(1, len(points) // 2000)):
        offset = chunk[:, None, :] - start[None, :, :]
        t = np.clip(np.einsum("pij,ij->pi", offset, along) / length2, 0.0, 1.0)
        closest = start[None, :, :] + t[:, :, None] * along[None, :, :]
        distance = np.linalg.norm(chunk[:, None, :] - closest, axis=2).min(axis=1)
        if len(distance) and distance.max() > worst:
            worst = float(distance.max())
            worst_point = chunk[int(distance.argmax())]
    if worst > tolerance_mm:
        problems.append(f"the executed point {tuple(np.round(worst_point, 4))} is {worst:.4f}"
                        f" mm from the program's path (at most {tolerance_mm} mm)")
    at = 0
    for index, corner in enumerate(corners):
        distance = np.linalg.norm(executed_mm[at:] - corner, axis=1)
        near = np.flatnonzero(distance <= tolerance_mm)
        if len(near) == 0:
            problems.append(f"point {index} of the path, {tuple(corner)}, was never reached"
                            f" after tick {at} (nearest {distance.min():.4f} mm)")
            break
        at += int(near[0])
    if np.linalg.norm(executed_mm[-1] - corners[-1]) > tolerance_mm:
        problems.append(f"it ended at {tuple(np.round(executed_mm[-1], 4))}, the program at"
                        f" {tuple(corners[-1])}")
    return problems, worst


@contextmanager
def served_fake(**server_options: object) -> Iterator[tuple[GrblServer, FakeMachine]]:
    """The fake machine in real time, served on a pseudo-terminal (or as asked). Only the
    server's thread may call the machine; a test reads its plain attributes."""
    machine = FakeMachine(time.monotonic, homing_s=1.0)  # long enough to be seen in reports
    with GrblServer(machine, **server_options) as server:  # type: ignore[arg-type]
        server.start()
        yield server, machine
        assert server.error is None


@contextmanager
def executing_lines(session: MachineSession) -> Iterator[list[tuple[float, int]]]:
    """While inside: when (monotonic s) and which line the live model shows executing, in
    the list given: every 2 ms, and as the grbl front writes each ``ok`` (the line the
    front knew then; a watcher thread starved on a loaded machine would report an older
    one, and count an acknowledgement as further ahead than it was)."""
    executing: list[tuple[float, int]] = []
    done = threading.Event()

    def sample() -> None:
        executing.append((time.monotonic(), session.live.read().line))

    def watch() -> None:
        while not done.wait(0.002):
            sample()

    write_ok = GrblProtocol._ok

    def sampled_ok(protocol: GrblProtocol) -> None:
        sample()
        write_ok(protocol)

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    GrblProtocol._ok = sampled_ok  # type: ignore[method-assign]
    try:
        yield executing
    finally:
        GrblProtocol._ok = write_ok  # type: ignore[method-assign]
        done.set()
        watcher.join(timeout=5)


def most_lines_ahead(executing: list[tuple[float, int]], acked: Iterable[tuple[int, float]],
                     first_line: int) -> int:
    """The most lines acknowledged ahead of the line executing: ``acked`` holds each
    program line's index (0: ``first_line``) and when its ``ok`` came; before the program's
    first line executes (its motion not begun), none counts."""
    ahead = 0
    for index, when in acked:
        now = max((line for at, line in executing if at <= when), default=0)
        if now >= first_line:
            ahead = max(ahead, first_line + index - now)
    return ahead


def wait_for(condition: object, *, timeout_s: float, what: str,
             seen: Callable[[], object] | None = None) -> None:
    """Poll ``condition()`` until true; fail saying ``what`` did not happen (and what
    ``seen()`` returns then)."""
    deadline = time.monotonic() + timeout_s
    while not condition():  # type: ignore[operator]
        if time.monotonic() > deadline:
            instead = f"; instead: {seen()!r}" if seen is not None else ""
            raise AssertionError(f"{what} did not happen within {timeout_s} s{instead}")
        time.sleep(0.01)


def record(sender: str, statistics: Statistics, *, path_problems: list[str],
           machine: str = "fake", path_deviation_mm: float | None = None,
           run_s: float | None = None, run_from: str = "",
           most_lines_acknowledged_ahead: int | None = None) -> None:
    """Record what the front measured while ``sender`` streamed to ``machine`` (``fake`` or
    ``simulated in real time``), in ``build/senders/SENDER.json``, and print it (seen with
    ``pytest -s``): the receive buffer's peak, the bytes dropped, the lines, whether the
    path equals the program's, and for the simulated machine the largest distance of an
    executed point from the program's path and how long the run took (``run_from``
    says from what to what), and the most lines acknowledged ahead of the one executing."""
    measured: dict[str, object] = {
        "sender": sender, "machine": machine, "max_rx_bytes": statistics.max_rx_bytes,
        "rx_buffer_bytes": 128, "dropped_rx_bytes": statistics.dropped_rx_bytes,
        "lines": statistics.lines, "path_equals_program": not path_problems,
        "path_problems": path_problems}
    if path_deviation_mm is not None:
        measured["path_max_deviation_mm"] = round(path_deviation_mm, 5)
    if run_s is not None:
        measured["run_s"] = round(run_s, 2)
        measured["run_from"] = run_from
    if most_lines_acknowledged_ahead is not None:
        measured["most_lines_acknowledged_ahead"] = most_lines_acknowledged_ahead
    MEASUREMENTS.mkdir(parents=True, exist_ok=True)
    (MEASUREMENTS / f"{sender}.json").write_text(json.dumps(measured, indent=2) + "\n")
    extra = ""
    if path_deviation_mm is not None:
        extra += f" (at most {path_deviation_mm:.4f} mm off)"
    if run_s is not None:
        extra += f", run {run_s:.1f} s"
    print(f"{sender} ({machine} machine): receive buffer at most {statistics.max_rx_bytes}"
          f" of 128 bytes, {statistics.dropped_rx_bytes} dropped, {statistics.lines} lines,"
          f" path {'equals the program' if not path_problems else 'differs'}{extra}")
