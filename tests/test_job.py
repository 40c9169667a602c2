"""The main job end to end: homing the simulated machine, usbmotion run, the console, tune."""

from __future__ import annotations

import json
import os
import pty
import re
import select
import subprocess
import sys
import time
from pathlib import Path

import pytest
from tests.commands import invoke
from typer.testing import CliRunner

from usbmotion.cli.main import app
from usbmotion.cli.run import default_machine
from usbmotion.demos import demo_path
from usbmotion.host.config import load_config
from usbmotion.motion import gcode
from usbmotion.session import home_position_mm, planning
from usbmotion.sim.machine import SimulatedMachine, connect_session
from usbmotion.tuning import step_response

ROOT = Path(__file__).resolve().parents[1]
FOLLOWING_ERROR_BOUND_MM = 0.1
"""The stated bound on each axis's following error for the demo programs."""
ENDPOINT_TOLERANCE_MM = 0.05
"""The stated tolerance: the executed path passes this close to every programmed end point."""


def _usbmotion(*args: str, timeout: float = 240,
               cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "usbmotion", *args], capture_output=True,
                          text=True, timeout=timeout, check=False, cwd=cwd)


def test_full_home_zeroes_every_axis_on_its_latched_switch_edge() -> None:
    config = load_config(default_machine())
    with connect_session(config) as session:
        starts = session.positions_mm()
        assert all(v == 0 for v in starts.values()), "positions start at 0 before homing"
        assert not session.is_homed
        seconds = session.home()
        assert 0 < seconds < 60
        assert session.is_homed
        for name, status in session.machine.status().items():
            axis = config.axis(name)
            client = session.machine.axis(name).client
            edge = client.switch_edge(1 if axis.homing.direction < 0 else 2)  # Z's is above
            assert (edge.edges, edge.closed) == (4, False), "seek, back off, locate, pull off"
            zero = session.zeroes[name]
            assert zero.edge_counts + zero.shift_counts == axis.scale.to_counts(
                axis.homing.position_mm), f"{name}: the locate edge is the switch's position"
            assert not status.lower_limit and not status.upper_limit, "pulled off the switch"
            assert status.desired_counts == axis.scale.to_counts(home_position_mm(axis))
            assert abs(status.actual_counts - status.desired_counts) <= 2
            assert status.fault == 0
            assert status.enabled


def test_homing_uses_each_axis_velocity_gains(monkeypatch: pytest.MonkeyPatch) -> None:
    """The velocity loop of homing runs on the gains the machine file gives each axis."""
    from dataclasses import replace  # noqa: PLC0415

    from usbmotion.host.config import PidGains  # noqa: PLC0415
    from usbmotion.host.device import DeviceClient  # noqa: PLC0415

    config = load_config(default_machine())
    wanted = {"X": PidGains(0.0011, 0.51, 0.0), "Y": PidGains(0.0009, 0.49, 0.0)}
    axes = tuple(replace(axis, velocity_gains=wanted[axis.name]) if axis.name in wanted
                 else axis for axis in config.axes)
    config = replace(config, axes=axes)
    seen: dict[str, list[tuple[float, float, float]]] = {}
    original = DeviceClient.set_gains

    def spy(self: DeviceClient, *, kp: float, ki: float, kd: float) -> None:
        seen.setdefault(self.name, []).append((kp, ki, kd))
        original(self, kp=kp, ki=ki, kd=kd)

    with connect_session(config) as session:
        machine = session.machine
        monkeypatch.setattr(DeviceClient, "set_gains", spy)
        session.home()
        for name, axis in machine.axes.items():
            gains = axis.config.velocity_gains
            assert seen[axis.client.name][0] == (gains.kp, gains.ki, gains.kd), name
            position = axis.config.gains
            assert seen[axis.client.name][-1] == (position.kp, position.ki, position.kd)


def test_usbmotion_run_a_demo_as_a_user_does(tmp_path: Path) -> None:
    program = tmp_path / "square.ngc"
    program.write_text(demo_path(1).read_text())
    report_path = tmp_path / "report.json"
    work = tmp_path / "work"
    work.mkdir()
    done = _usbmotion("run", str(program), "--report", str(report_path), "-q", cwd=work)
    assert done.returncode == 0, done.stderr
    assert "following error" in done.stdout
    report = json.loads(report_path.read_text())
    assert report["completed"] is True
    assert report["faults"] == []
    assert report["endpoints_checked"] == 14
    assert report["max_endpoint_miss_mm"] < ENDPOINT_TOLERANCE_MM
    for axis in report["axes"]:
        assert axis["max_error_mm"] < FOLLOWING_ERROR_BOUND_MM, axis
        assert axis["samples"] > 1000
    assert abs(report["executed_time_s"] - report["planned_time_s"]) < 0.01
    assert report["ignored_words"] == []  # G94 is acted on (G93 is inverse time)
    assert report["stop_reason"] == "completed"
    plot = work / "square.png"
    assert plot.stat().st_size > 20_000, "a real plot was written in the working directory"
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_run_interprets_its_program_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                           ) -> None:
    """Checked, homed and run: the program is interpreted (and planned) once, from where
    homing leaves the machine."""
    calls: list[str] = []
    original = gcode.parse_gcode

    def counted(*args: object, **kwargs: object) -> object:
        calls.append(str(kwargs.get("file")))
        return original(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(gcode, "parse_gcode", counted)
    monkeypatch.setattr(planning, "parse_gcode", counted)
    program = tmp_path / "square.ngc"
    program.write_text(demo_path(1).read_text())
    machine = tmp_path / "machine.toml"  # its parameter file beside it, in tmp_path
    machine.write_text(default_machine().read_text())
    done = CliRunner().invoke(app, ["run", str(program), "-q", "--no-plot", "--machine",
                                    str(machine)])
    assert done.exit_code == 0, done.output
    assert calls == [str(program)]


def test_a_program_that_does_not_parse_stops_before_anything_moves(tmp_path: Path) -> None:
    program = tmp_path / "bad.ngc"
    program.write_text("G21 G90\nG0 X10\nG2 X20 Y0 F100\nM2\n")
    done = _usbmotion("run", str(program), "-q", "--no-plot")
    assert done.returncode == 2
    assert f"{program}:3:" in done.stderr
    assert "Traceback" not in done.stderr
    assert "homing" not in done.stdout


def test_a_fault_during_the_run_stops_every_axis_and_says_where(tmp_path: Path) -> None:
    text = default_machine().read_text()
    tight = text.replace("following_error_limit_mm = 1.0", "following_error_limit_mm = 0.005",
                         1)
    assert tight != text, "X trips on its first ramp: a following-error limit of one count"
    machine_file = tmp_path / "tight.toml"
    machine_file.write_text(tight)
    program = tmp_path / "move.ngc"
    program.write_text("G21 G90\nG1 X50 F600\nG1 Y50\nM2\n")
    done = _usbmotion("run", str(program), "--machine", str(machine_file), "--no-home",
                      "--report", str(tmp_path / "r.json"), "-q", "--no-plot")
    assert done.returncode == 1, done.stdout + done.stderr
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["completed"] is False
    fault = report["faults"][0]
    assert fault["axis"] == "X"
    assert fault["fault"] == "following error"
    assert fault["line"] == 2
    assert fault["time_s"] > 0
    assert report["stop_reason"] == "fault: axis X following error"
    assert "STOPPED (fault: axis X following error) at program line 2" in done.stdout
    assert f"resume         from line 2: usbmotion run {program} --from-line 2" in done.stdout


def test_console_through_a_pseudo_terminal() -> None:
    leader, follower = pty.openpty()
    process = subprocess.Popen([sys.executable, "-m", "usbmotion", "console"],
                               stdin=follower, stdout=follower, stderr=follower, close_fds=True)
    os.close(follower)
    output = bytearray()

    def read_until(marker: bytes, timeout: float = 180.0) -> str:
        deadline = time.monotonic() + timeout
        while marker not in output:
            left = deadline - time.monotonic()
            assert left > 0, f"no {marker!r} in {bytes(output)!r}"
            ready, _, _ = select.select([leader], [], [], left)
            if ready:
                try:
                    output.extend(os.read(leader, 65536))
                except OSError:
                    break
        end = output.find(marker)
        end = len(output) if end < 0 else end + len(marker)
        text = output[:end].decode(errors="replace")
        del output[:end]  # what came after the marker is read next
        return text

    def send(line: str) -> None:
        os.write(leader, line.encode() + b"\n")

    try:
        assert "$h for help" in read_until(b"> ")
        send("$d 1")
        assert "loaded 1-rounded-square.ngc: 14 moves" in read_until(b"> ")
        send("$c")
        text = read_until(b"\ndone")
        assert "cycle start" in text and "faults         none" in text
        for _ in range(100):  # the live line while the run's last reading ends, then idle
            send("?")
            text = read_until(b"state: ") + read_until(b"\r\n")
            if "program:" in text:
                break
            assert "state: Idle; line 17 of 18; machine X 5.000" in text, text
            time.sleep(0.1)
        text += read_until(b"\r\nZ:") + read_until(b"\r\n")
        assert "state: Idle; program: 1-rounded-square.ngc; homed: yes; last run: completed" in text
        assert re.search(r"X:\s+(4\.99|5\.00)\d mm", text), text
        send("$r")
        text = read_until(b"homed in")
        assert "reset: stopping every axis" in text
        send("$y 5")
        assert "error: unknown command '$y 5'" in read_until(b"'$y 5'")
        send("$d 9")
        assert "demo 9 does not exist" in read_until(b"does not exist")
        send("$q")
        assert "bye" in read_until(b"bye")
        assert process.wait(timeout=30) == 0
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        os.close(leader)


def test_console_with_piped_input() -> None:
    done = subprocess.run([sys.executable, "-m", "usbmotion", "console"], input="$h\n?\n$c\n",
                          capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert "$d N      load demo program N" in done.stdout
    assert "state: Idle; program: none; homed: no" in done.stdout
    assert "error: no program loaded" in done.stdout


def test_step_response_figures() -> None:
    config = load_config(default_machine())
    with SimulatedMachine.connect(config) as machine:
        machine.configure()
        response = step_response(machine, "X", step_mm=1000 / 240, duration_s=0.4)
    metrics = response.metrics
    assert metrics.step_counts == 1000
    assert 0.02 < metrics.rise_time_s < 0.12
    assert metrics.overshoot_pct <= 10.0
    assert metrics.settling_time_s <= 0.15
    assert abs(metrics.steady_state_error_counts) <= 2


def test_tune_command_prints_the_figures_and_writes_a_plot(tmp_path: Path) -> None:
    plot = tmp_path / "step.png"
    done = _usbmotion("tune", "--axis", "Y", "--step-mm", "2", "--kp", "0.5", "--plot", str(plot))
    assert done.returncode == 0, done.stderr
    for word in ("rise time", "overshoot", "settling time", "steady-state error", "kp 0.5"):
        assert word in done.stdout
    assert plot.read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize(("args", "message"), [
    (("tune", "--axis", "Q"), "no axis 'Q'"),
    (("run", "missing.ngc", "-q"), "cannot read"),
])
def test_bad_command_lines_are_clear(args: tuple[str, ...], message: str) -> None:
    code, _, err = invoke(*args)
    assert code == 2
    assert message in err
    assert "Traceback" not in err


@pytest.mark.parametrize("spread_mm", [0.3, 0.02])
def test_end_points_are_measured_against_the_whole_path(spread_mm: float) -> None:
    """The pruned search equals a brute-force distance to every segment of the path, for
    end points well off it and close to it."""
    from array import array  # noqa: PLC0415

    import numpy as np  # noqa: PLC0415

    from usbmotion.motion.gcode import parse_gcode  # noqa: PLC0415
    from usbmotion.session.report import Trace, _endpoint_misses  # noqa: PLC0415

    rng = np.random.default_rng(7)
    steps = rng.normal(0.0, 0.4, size=(3000, 3))
    steps[::250] *= 40  # a few long jumps, as rapids leave between samples
    path = np.cumsum(steps, axis=0) + 100.0
    trace = Trace(tick_s=0.001, start_tick=0, counts_per_mm=dict.fromkeys("XYZ", 1000.0))
    for index, name in enumerate("XYZ"):
        trace.clock[name] = array("q", range(len(path)))
        trace.actual[name] = array("q", np.round(path[:, index] * 1000).astype(np.int64))
    ends = path[rng.integers(0, len(path), 40)] + rng.normal(0.0, spread_mm, size=(40, 3))
    program = parse_gcode("G21 G90\n" + "".join(
        f"G1 X{x:.3f} Y{y:.3f} Z{z:.3f} F600\n" for x, y, z in ends) + "M2\n")
    checked, worst = _endpoint_misses(program, trace, "XYZ")

    points = np.stack([np.asarray(trace.actual[n], dtype=float) / 1000 for n in "XYZ"], axis=1)
    starts, spans = points[:-1], np.diff(points, axis=0)
    brute = 0.0
    for end in np.array([move.end for move in program.moves]):
        along = np.clip(np.einsum("ij,ij->i", end - starts, spans)
                        / np.einsum("ij,ij->i", spans, spans), 0.0, 1.0)
        gaps = starts + along[:, None] * spans - end
        brute = max(brute, float(np.sqrt(np.einsum("ij,ij->i", gaps, gaps).min())))
    assert checked == 40
    assert worst == pytest.approx(brute, abs=1e-9)


def test_the_worst_end_point_is_found_when_its_nearest_sample_is_not_the_farthest() -> None:
    """An end point halfway along a long segment is far from every sample but close to the
    path; one beside a sample is closer to the samples and farther from the path: the
    second is the worst miss, though the search measures the first one first."""
    from array import array  # noqa: PLC0415

    from usbmotion.motion.gcode import parse_gcode  # noqa: PLC0415
    from usbmotion.session.report import Trace, _endpoint_misses  # noqa: PLC0415

    trace = Trace(tick_s=0.001, start_tick=0, counts_per_mm=dict.fromkeys("XYZ", 1000.0))
    for name, values in (("X", [0, 10_000, 20_000]), ("Y", [0, 0, 0]), ("Z", [0, 0, 0])):
        trace.clock[name] = array("q", range(3))
        trace.actual[name] = array("q", values)
    program = parse_gcode("G21 G90\nG1 X5 Y0.3 F600\nG1 X0 Y0.5\nM2\n")
    assert _endpoint_misses(program, trace, "XYZ") == (2, pytest.approx(0.5, abs=1e-12))


TOOL_CHANGES = "G21 G90\nT1 M6\nG0 X10 Y10 Z-5\nT2 M6\nG0 X20\nM2\n"


def test_the_report_names_every_tool_change(tmp_path: Path) -> None:
    program = tmp_path / "tools.ngc"
    program.write_text(TOOL_CHANGES)
    report_path = tmp_path / "r.json"
    done = _usbmotion("run", str(program), "--no-plot", "-q", "--report", str(report_path))
    assert done.returncode == 0, done.stderr
    changes = json.loads(report_path.read_text())["tool_changes"]
    assert [(c["line"], c["tool"], c["manual"]) for c in changes] == [(2, 1, True),
                                                                     (4, 2, True)]
    said = [line for line in done.stdout.splitlines() if line.startswith("tool change")]
    assert said == ["tool change    line 2: tool 1 put in the spindle (M6)",
                    "tool change    line 4: tool 2 put in the spindle (M6)"]


@pytest.mark.parametrize("enters", [2, 1])
def test_pause_on_m6_waits_for_enter_at_each_tool_change(tmp_path: Path, enters: int) -> None:
    """With someone at the machine each tool change pauses the run until Enter; standard
    input ending at a pause stops the run there (along its deceleration: it is at rest)."""
    program = tmp_path / "tools.ngc"
    program.write_text(TOOL_CHANGES)
    done = subprocess.run([sys.executable, "-m", "usbmotion", "run", str(program), "--no-plot",
                           "-q", "--pause-on-m6"], input="\n" * enters, capture_output=True,
                          text=True, timeout=240, check=False)
    paused = [line for line in done.stderr.splitlines() if line.startswith("paused")]
    assert paused[0].startswith("paused         line 2 (M6): tool change: put tool 1 in the"
                                " spindle"), done.stderr
    if enters == 2:
        assert done.returncode == 0 and len(paused) == 2 and "tool 2" in paused[1]
        assert "result         completed" in done.stdout
    else:
        assert done.returncode == 130 and len(paused) == 2, done.stderr
        assert "standard input ended at a pause" in done.stdout
