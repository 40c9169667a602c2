"""Robots (``usbmotion.robot``): joints in the machine file, trajectories, and plays on three
simulated devices: one start tick for every device, the joints following the trajectory to a
few counts, a hold and a stop that keep to the path; ``usbmotion play``; the examples."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from usbmotion.cli.main import app
from usbmotion.errors import ArgumentError, ConfigError, StopRequestedError
from usbmotion.hermite import sample_keyframes
from usbmotion.host.config import load_config, parse_config
from usbmotion.robot import JointTrajectory, PlayReport, Robot, check_limits
from usbmotion.session import MachineSession
from usbmotion.sim.machine import connect_session

ROOT = Path(__file__).resolve().parents[1]
ARM = ROOT / "examples" / "robot-arm.toml"
FOLLOW_BOUND_COUNTS = 4
"""How far (counts) a joint's measured position may be from the trajectory on any tick."""


@pytest.fixture
def arm() -> Iterator[tuple[MachineSession, Robot]]:
    with connect_session(load_config(ARM)) as session:
        session.home()
        yield session, Robot(session.machine)


def _wave(seconds: float = 2.0) -> JointTrajectory:
    """From where homing leaves the arm, a swing of every joint and back to rest."""
    times = np.linspace(0.0, seconds, 41)
    fade = np.sin(np.pi * times / seconds) ** 2
    shoulder = -150.0 + 60.0 * fade * (1 + 0.3 * np.sin(4 * np.pi * times / seconds))
    elbow = -150.0 + 50.0 * fade
    lift = -8.0 * fade
    return JointTrajectory.from_points(["shoulder", "elbow", "lift"], times,
                                       np.column_stack([shoulder, elbow, lift]))


# --- the machine file ---------------------------------------------------------------------------


def test_joints_are_read_from_the_machine_file() -> None:
    joints = {joint.name: joint for joint in load_config(ARM).joints}
    assert list(joints) == ["shoulder", "elbow", "lift"]
    shoulder = joints["shoulder"]
    assert (shoulder.axis, shoulder.unit) == ("X", "deg")
    assert shoulder.range == pytest.approx((-150.0, 150.0))
    assert shoulder.max_velocity == pytest.approx(180.0)
    assert joints["lift"].unit == "mm" and joints["lift"].range == pytest.approx((-100.0, 0.0))


@pytest.mark.parametrize(("joint", "words"), [
    ('[joints.a]\naxis = "Q"\ncounts_per_unit = 5.0\n', "'Q' is not an axis of this machine"),
    ('[joints.a]\naxis = "X"\ncounts_per_unit = 5.0\n[joints.b]\naxis = "X"\n'
     'counts_per_unit = 5.0\n', "already drives joint a"),
    ('[joints.a]\naxis = "X"\nunit = "rad"\ncounts_per_unit = 5.0\n', "'rad' is not a joint"),
    ('[joints.a]\naxis = "X"\n', "missing required key 'counts_per_unit'"),
    ('[joints.a]\naxis = "X"\ncounts_per_unit = 5.0\nmax_velocity = 1000.0\n', "max_velocity"),
    ('[joints."2arm"]\naxis = "X"\ncounts_per_unit = 5.0\n', "not a joint name"),
    ('[joints.a]\naxis = "X"\ncounts_per_unit = 5.0\nspeed = 3\n', "unknown key 'speed'"),
])
def test_a_bad_joint_is_refused_naming_it(joint: str, words: str) -> None:
    text = ARM.read_text().split("[joints.shoulder]")[0] + joint
    with pytest.raises(ConfigError, match=words):
        parse_config(text, path=ARM)


# --- trajectories -------------------------------------------------------------------------------


def test_trajectories_are_checked_and_read_from_csv_and_json(tmp_path: Path) -> None:
    for args, words in (((["a"], [0.0], [[1.0]]), "two points"),
                        ((["a", "a"], [0.0, 1.0], [[1, 2], [3, 4]]), "each once"),
                        ((["a"], [0.5, 1.0], [[1.0], [2.0]]), "starts at 0"),
                        ((["a"], [0.0, 1.0, 1.0], [[1.0], [2.0], [3.0]]), "point 3"),
                        ((["a"], [0.0, 1.0], [[1.0], [float("nan")]]), "point 2"),
                        ((["a"], [0.0, 1.0], [[1.0, 2.0], [3.0, 4.0]]), "one column")):
        with pytest.raises(ArgumentError, match=words):
            JointTrajectory.from_points(*args)
    csv = tmp_path / "t.csv"
    csv.write_text("time_s,shoulder,elbow\n0,0,0\n0.5,10,5\n1.0,20,10\n")
    loaded = JointTrajectory.load(csv)
    assert loaded.joints == ("shoulder", "elbow") and loaded.duration_s == 1.0
    positions, velocities = loaded.at(np.array([0.0, 0.5, 1.0]))
    assert positions.tolist() == [[0, 0], [10, 5], [20, 10]]
    assert velocities[0].tolist() == [0, 0] and velocities[1].tolist() == [20, 10]
    as_json = tmp_path / "t.json"
    as_json.write_text(json.dumps({"joints": ["shoulder", "elbow"],
                                   "points": [[0, 0, 0], [0.5, 10, 5], [1.0, 20, 10]]}))
    assert np.array_equal(JointTrajectory.load(as_json).positions, loaded.positions)
    for text, words in (("time,a\n0,1\n", "header"), ("time_s,a\n0,1\n1,x\n", "row 3"),
                        ("time_s,a\n0,1,2\n", "row 2")):
        csv.write_text(text)
        with pytest.raises(ArgumentError, match=words):
            JointTrajectory.load(csv)


def test_limits_are_checked_before_anything_moves() -> None:
    joints = {joint.name: joint for joint in load_config(ARM).joints}
    fast = JointTrajectory.from_points(["shoulder"], [0.0, 0.5, 1.0], [[0.0], [150.0], [0.0]])
    with pytest.raises(ArgumentError, match=r"joint shoulder: its speed reaches .* deg/s"):
        check_limits(fast, joints)
    out = JointTrajectory.from_points(["lift"], [0.0, 10.0], [[0.0], [5.0]])
    with pytest.raises(ArgumentError, match=r"joint lift: its position reaches"):
        check_limits(out, joints)
    with pytest.raises(ArgumentError, match="'wrist' is not one of this machine's"):
        check_limits(JointTrajectory.from_points(["wrist"], [0, 1], [[0], [1]]), joints)


# --- plays on simulated devices -----------------------------------------------------------------


def _followed(report: PlayReport, trajectory: JointTrajectory, robot: Robot,
              tick_s: float) -> dict[str, int]:
    """Per joint, the largest distance (counts) of its measured position from the
    trajectory at the same time since the start tick."""
    worst = {}
    for column, name in enumerate(trajectory.joints):
        records = report.records[name]
        clocks = np.array([r.clock for r in records])
        actual = np.array([r.actual_counts for r in records])
        keep = clocks >= report.start_tick
        times = (clocks[keep] - report.start_tick) * tick_s
        wanted, _ = trajectory.at(times)
        scale = robot.joints[name].counts_per_unit
        worst[name] = int(np.max(np.abs(actual[keep] - np.rint(wanted[:, column] * scale))))
    return worst


def test_a_trajectory_on_three_devices_starts_on_one_tick_and_is_followed(
        arm: tuple[MachineSession, Robot]) -> None:
    session, robot = arm
    trajectory = _wave()
    report = robot.play(trajectory, record=True)
    assert report.completed and report.holds == 0
    _played_from_one_tick(report, round(session.config.servo_period_s * 1e6))
    worst = _followed(report, trajectory, robot, session.config.servo_period_s)
    assert max(worst.values()) <= FOLLOW_BOUND_COUNTS, worst
    assert max(report.peak_error_counts.values()) <= FOLLOW_BOUND_COUNTS
    for column, name in enumerate(trajectory.joints):
        scale = robot.joints[name].counts_per_unit
        assert abs(report.end[name] - trajectory.positions[-1, column]) * scale <= 2
    print(f"three joints from tick {report.start_tick}: peak following error"
          f" {report.peak_error_counts} counts; farthest from the trajectory {worst} counts")


def test_a_host_held_up_as_it_starts_a_play_still_starts_every_joint_on_one_tick(
        arm: tuple[MachineSession, Robot], monkeypatch: pytest.MonkeyPatch) -> None:
    """The host held up 0.4 s (more than the start's margin) before it gives the devices
    their first keyframes: every device is held while its curve takes them, then all are
    armed, so the joints still start together and follow the trajectory."""
    from usbmotion import robot as robots  # noqa: PLC0415

    session, robot = arm
    send = robots._Player._send
    calls = [0]

    def held_up(player: robots._Player, count: int, *, target: float = 1.0) -> None:
        calls[0] += 1
        if calls[0] == 1:
            player.machine.clock.sleep(0.4)
        send(player, count, target=target)

    monkeypatch.setattr(robots._Player, "_send", held_up)
    trajectory = _wave()
    report = robot.play(trajectory, record=True)
    assert report.completed
    _played_from_one_tick(report, round(session.config.servo_period_s * 1e6))
    worst = _followed(report, trajectory, robot, session.config.servo_period_s)
    assert max(worst.values()) <= FOLLOW_BOUND_COUNTS, worst


def test_a_hold_decelerates_along_the_path_and_a_resume_goes_on(
        arm: tuple[MachineSession, Robot]) -> None:
    _, robot = arm
    trajectory = _wave(3.0)
    held_at: list[dict[str, float]] = []

    def hold_midway(reached_s: float) -> None:
        if reached_s >= 1.2 and not held_at:
            held_at.append({})
            robot.hold()
            threading.Thread(target=resume, daemon=True).start()

    def resume() -> None:
        assert robot.held.wait(timeout=60)
        held_at[0] = robot.positions()
        robot.resume()

    report = robot.play(trajectory, record=True, on_progress=hold_midway)
    assert report.completed and report.holds == 1
    _assert_on_path(report, trajectory, robot, held_at[0])
    assert report.duration_s > trajectory.duration_s + 0.2


def test_a_stop_comes_to_rest_on_the_path(arm: tuple[MachineSession, Robot]) -> None:
    session, robot = arm
    tick_s = session.config.servo_period_s
    trajectory = _wave(3.0)

    def stop_midway(reached_s: float) -> None:
        if reached_s >= 1.0:
            robot.stop("enough")

    with pytest.raises(StopRequestedError, match="enough") as caught:
        robot.play(trajectory, record=True, on_progress=stop_midway)
    report: PlayReport = caught.value.report  # type: ignore[attr-defined]
    assert not report.completed and 1.0 < report.stopped_at_s < 2.0
    _assert_on_path(report, trajectory, robot, robot.positions())
    # along the deceleration: no jump in any desired position beyond the trajectory's speed
    for name, records in report.records.items():
        desired = np.array([r.desired for r in records])
        limit = robot.joints[name].max_velocity * robot.joints[name].counts_per_unit
        assert np.max(np.abs(np.diff(desired))) <= limit * tick_s + 2


def _played_from_one_tick(report: PlayReport, tick_us: int) -> None:
    """Each device's desired position on every tick is exactly the curve of the keyframes
    it was sent (``hermite.sample_keyframes``, what curve mode plays), counted from the
    common start tick with the same offset for every device; and every device's curve
    has the same length: they start on one tick and arrive on one tick."""
    offsets = set()
    lengths = set()
    for name, records in report.records.items():
        start, keyframes = report.sent[name]
        expected = sample_keyframes(start, keyframes, tick_us=tick_us)
        lengths.add(len(expected))
        played = [r for r in records if report.start_tick + 1 <= r.clock
                  < report.start_tick + len(expected) - 1]
        assert len(played) >= len(expected) - 2, (name, len(played), len(expected))
        fits = [d for d in (-1, 0, 1) if all(
            r.desired == expected[r.clock - report.start_tick + d] for r in played)]
        assert len(fits) == 1, (name, fits)
        offsets.add(fits[0])
    assert len(offsets) == 1 and len(lengths) == 1, (offsets, lengths)


def _assert_on_path(report: PlayReport, trajectory: JointTrajectory, robot: Robot,
                    rest: dict[str, float]) -> None:
    """Where the joints rested is a point of the trajectory's path (within 2 counts per
    joint of some instant of it)."""
    times = np.arange(0.0, trajectory.duration_s, 0.0005)
    path, _ = trajectory.at(times)
    scale = np.array([robot.joints[n].counts_per_unit for n in trajectory.joints])
    here = np.array([rest[n] for n in trajectory.joints])
    distance = np.max(np.abs(path - here) * scale, axis=1)
    assert float(np.min(distance)) <= 2.0, (rest, float(np.min(distance)))


def test_move_to_brings_every_joint_there_together(arm: tuple[MachineSession, Robot]) -> None:
    _, robot = arm
    report = robot.move_to({"shoulder": 30.0, "elbow": -45.0, "lift": -20.0}, record=True)
    assert report.completed
    _played_from_one_tick(report, 1000)
    assert robot.positions()["lift"] == pytest.approx(-20.0, abs=2 / 240)
    with pytest.raises(ArgumentError, match=r"allowed -100\.\.0 mm"):
        robot.move_to({"lift": 5.0})
    with pytest.raises(ArgumentError, match="'wrist': allowed shoulder, elbow, lift"):
        robot.move_to({"wrist": 5.0})


# --- the command and the examples ---------------------------------------------------------------


def test_usbmotion_play(tmp_path: Path) -> None:
    machine = tmp_path / "arm.toml"  # a copy, its files beside it in tmp_path
    machine.write_text(ARM.read_text())
    wave = ROOT / "examples" / "arm-wave.csv"
    done = CliRunner().invoke(app, ["play", str(wave), "--machine", str(machine)])
    assert done.exit_code == 0, done.output
    assert "every device from tick" in done.output and "result         completed" in done.output
    homing = float(done.output.split("homing ", 1)[1].split()[0])
    assert homing > 0, "the copy's robot starts unhomed: its homing time is said, as run says it"
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,shoulder\n0,0\n0.1,100\n")
    for args, words in (([str(bad), "--machine", str(machine)], "its speed reaches"),
                        ([str(wave)], "names no joints"),
                        ([str(tmp_path / "none.csv"), "--machine", str(machine)],
                         "cannot read")):
        done = CliRunner().invoke(app, ["play", *args])
        assert done.exit_code == 2, done.output
        assert words in done.output, done.output


@pytest.mark.parametrize("example", ["pan_tilt.py", "two_link_arm.py"])
def test_the_examples_run(example: str) -> None:
    done = subprocess.run([sys.executable, str(ROOT / "examples" / example)],
                          capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    assert "every device from tick" in done.stdout, done.stdout
