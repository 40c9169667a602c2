"""Robots: named joints in degrees or millimetres, moved together and played along joint
trajectories through the devices' curve mode (OpenServo-style Hermite keyframes).

A joint (:class:`usbmotion.host.config.JointConfig`, the machine file's ``[joints.<name>]``)
is one axis's device seen in the joint's unit: joint 0 is the axis's machine zero, and
``counts_per_unit`` encoder counts make one degree (or mm).

A :class:`JointTrajectory` is a joint position per time: cubic Hermite through the points,
with the velocities given or Catmull-Rom ones, at rest at both ends. :meth:`Robot.play`
plays it on every joint's device at once: the devices' clocks are synchronised and every
device armed to start on the same tick (call 31), then each is given keyframes
(:data:`KEYFRAME_MS` apart, the same instants for every joint) a few at a time, so they
move on one time line and arrive on the same tick. :meth:`Robot.move_to` is a play of the
time-optimal jerk-limited move (ruckig) from where the joints stand.

Hold and stop keep to the path: the keyframes are the trajectory sampled along a time
scale ``tau(t)`` whose rate ``r = dtau/dt`` is 1 while playing; a hold ramps ``r`` to 0 over
:func:`ramp_time_s` (the joints decelerate along the very path they followed) and a resume
ramps it back, after a common start tick again. The keyframes already in the devices'
buffers (at most :data:`KEYFRAMES_AHEAD`) play out first: a hold begins within
``KEYFRAMES_AHEAD * KEYFRAME_MS`` of being asked.
"""

from __future__ import annotations

import csv
import json
import math
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from usbmotion.errors import (
    ArgumentError,
    DeviceError,
    DeviceFaultError,
    StartMissedError,
    StopRequestedError,
)
from usbmotion.hermite import Keyframe, tangent_to_fixed
from usbmotion.host.config import JointConfig
from usbmotion.host.device import ControlMode, DeviceClient, Diagnostics
from usbmotion.host.machine import Machine
from usbmotion.host.timesync import held_up, start_filled
from usbmotion.motion.profiles import jerk_limited_profile
from usbmotion.session.report import SETTLE_COUNTS
from usbmotion.session.rest import wait_until_settled

FloatArray = npt.NDArray[np.float64]

KEYFRAME_MS = 10
"""The time between two keyframes, ms."""
KEYFRAMES_AHEAD = 5
"""The most keyframes a device holds beyond the one it plays (of its 8 slots)."""
START_MARGIN_S = 0.15
"""How far beyond the round trips that arm it the common start tick is."""
AT_START_TOLERANCE = 0.5
"""How far (in counts, per joint) the joints may stand from a trajectory's first point."""
CHECK_STEP_S = 0.001
"""The time step a trajectory's limits are checked at."""


# --- trajectories -----------------------------------------------------------------------------


@dataclass(frozen=True)
class JointTrajectory:
    """Joint positions at times, a cubic Hermite curve through them.

    Fields:
        joints: the joints' names, one column each.
        times_s: strictly increasing, from 0.
        positions: (n, joints) positions, each joint in its own unit.
        velocities: (n, joints) velocities at the points (unit/s): the ones given, or
            Catmull-Rom ones (zero at both ends: the trajectory starts and ends at rest).
    """

    joints: tuple[str, ...]
    times_s: FloatArray
    positions: FloatArray
    velocities: FloatArray

    @classmethod
    def from_points(cls, joints: Sequence[str], times_s: Sequence[float] | FloatArray,
                    positions: Sequence[Sequence[float]] | FloatArray,
                    velocities: Sequence[Sequence[float]] | FloatArray | None = None,
                    ) -> JointTrajectory:
        """A trajectory of ``positions[i]`` at ``times_s[i]`` (see the class).

        Raises:
            ArgumentError: no joint, a repeated name, fewer than two points, times that do
                not start at 0 or do not increase, a shape that does not match, or a value
                that is not finite (each named).
        """
        names = tuple(joints)
        if not names or len(set(names)) != len(names):
            raise ArgumentError(f"joints {list(names)!r}: one name or more, each once",
                                reason="joints")
        times = np.asarray(times_s, dtype=np.float64)
        values = np.asarray(positions, dtype=np.float64)
        if times.ndim != 1 or times.shape[0] < 2:
            raise ArgumentError(f"a trajectory needs two points or more; it has {times.size}",
                                reason="times")
        if values.shape != (times.shape[0], len(names)):
            raise ArgumentError(f"positions of shape {values.shape}: one row per time"
                                f" ({times.shape[0]}), one column per joint ({len(names)})",
                                reason="positions")
        for label, array in (("time", times), ("position", values)):
            if not np.isfinite(array).all():
                row = int(np.flatnonzero(~np.isfinite(array.reshape(times.shape[0], -1))
                                         .all(axis=1))[0])
                raise ArgumentError(f"point {row + 1}: a {label} that is not a finite number",
                                    reason=label)
        if times[0] != 0.0:
            raise ArgumentError(f"the first point is at {times[0]:g} s; a trajectory starts"
                                " at 0 s", reason="times")
        steps = np.diff(times)
        if (steps <= 0).any():
            row = int(np.flatnonzero(steps <= 0)[0]) + 2
            raise ArgumentError(f"point {row}: its time {times[row - 1]:g} s is not after the"
                                f" one before ({times[row - 2]:g} s)", reason="times")
        if velocities is None:
            rates = np.zeros_like(values)
            if times.shape[0] > 2:
                rates[1:-1] = (values[2:] - values[:-2]) / (times[2:] - times[:-2])[:, None]
        else:
            rates = np.asarray(velocities, dtype=np.float64)
            if rates.shape != values.shape or not np.isfinite(rates).all():
                raise ArgumentError(f"velocities of shape {rates.shape}: finite, as the"
                                    f" positions' {values.shape}", reason="velocities")
        return cls(names, times, values, rates)

    @classmethod
    def load(cls, path: str | Path) -> JointTrajectory:
        """A trajectory file: CSV with a header ``time_s,<joint>,<joint>...`` and one row a
        point, or JSON ``{"joints": [...], "points": [[time_s, value, ...], ...]}``.

        Raises:
            ArgumentError: the file is not such a trajectory (names the file and the row).
            OSError: it cannot be read.
        """
        path = Path(path)
        text = path.read_text(encoding="utf-8")
        try:
            if path.suffix.lower() == ".json":
                data = json.loads(text)
                if not isinstance(data, dict) or not isinstance(data.get("joints"), list) \
                        or not isinstance(data.get("points"), list):
                    raise ArgumentError('a JSON trajectory is {"joints": [names],'
                                        ' "points": [[time_s, value, ...], ...]}',
                                        reason="file")
                names = [str(name) for name in data["joints"]]
                rows = [_row(point, len(names), index) for index, point in
                        enumerate(data["points"], 1)]
            else:
                lines = [line for line in csv.reader(text.splitlines()) if line]
                if not lines or lines[0][0].strip() != "time_s":
                    raise ArgumentError("a CSV trajectory starts with the header"
                                        " time_s,<joint>,<joint>...", reason="file")
                names = [name.strip() for name in lines[0][1:]]
                rows = [_row([cell.strip() for cell in line], len(names), index)
                        for index, line in enumerate(lines[1:], 2)]
            table = np.array(rows, dtype=np.float64).reshape(len(rows), len(names) + 1)
            return cls.from_points(names, table[:, 0], table[:, 1:])
        except (ArgumentError, ValueError) as error:
            raise ArgumentError(f"{path}: {error}", reason="file") from None

    @property
    def duration_s(self) -> float:
        """The time of the last point."""
        return float(self.times_s[-1])

    def at(self, times_s: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Positions and velocities (each ``(len(times_s), joints)``) at ``times_s``,
        held at the ends beyond them."""
        t = np.clip(np.asarray(times_s, dtype=np.float64), 0.0, self.duration_s)
        index = np.clip(np.searchsorted(self.times_s, t, side="right") - 1, 0,
                        self.times_s.shape[0] - 2)
        t0 = self.times_s[index]
        h = (self.times_s[index + 1] - t0)[:, None]
        s = ((t - t0)[:, None]) / h
        p0, p1 = self.positions[index], self.positions[index + 1]
        m0, m1 = self.velocities[index] * h, self.velocities[index + 1] * h
        s2, s3 = s * s, s * s * s
        position = ((2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * m0
                    + (-2 * s3 + 3 * s2) * p1 + (s3 - s2) * m1)
        velocity = ((6 * s2 - 6 * s) * p0 + (3 * s2 - 4 * s + 1) * m0
                    + (-6 * s2 + 6 * s) * p1 + (3 * s2 - 2 * s) * m1) / h
        return position, velocity


def _row(point: object, joints: int, index: int) -> list[float]:
    if not isinstance(point, list | tuple) or len(point) != joints + 1:
        raise ArgumentError(f"row {index}: {point!r} is not a time and {joints} joint"
                            " value(s)", reason="file")
    try:
        return [float(value) for value in point]
    except (TypeError, ValueError):
        raise ArgumentError(f"row {index}: {point!r} holds something that is not a number",
                            reason="file") from None


def check_limits(trajectory: JointTrajectory, joints: Mapping[str, JointConfig]) -> None:
    """Refuse a trajectory that leaves a joint's range or exceeds its velocity or
    acceleration (checked every :data:`CHECK_STEP_S`).

    Raises:
        ArgumentError: names the joint, the time, the value and the limit.
    """
    for name in trajectory.joints:
        if name not in joints:
            raise ArgumentError(f"joint {name!r} is not one of this machine's: allowed"
                                f" {', '.join(joints) or 'none (the file has no [joints])'}",
                                reason="joints")
    times = np.arange(0.0, trajectory.duration_s + CHECK_STEP_S, CHECK_STEP_S)
    positions, velocities = trajectory.at(times)
    accelerations = np.diff(velocities, axis=0) / CHECK_STEP_S
    for column, name in enumerate(trajectory.joints):
        joint = joints[name]
        low, high = joint.range
        unit = joint.unit
        position = positions[:, column]
        speed = np.abs(velocities[:, column])
        accel = np.abs(accelerations[:, column])
        checks = (
            ("position", position, (position < low - 1e-9) | (position > high + 1e-9),
             f"its range {low:g}..{high:g} {unit}", unit),
            ("speed", speed, speed > joint.max_velocity * (1 + 1e-9),
             f"its max_velocity {joint.max_velocity:g} {unit}/s", f"{unit}/s"),
            ("acceleration", accel, accel > joint.max_accel * (1 + 1e-6),
             f"its max_accel {joint.max_accel:g} {unit}/s^2", f"{unit}/s^2"),
        )
        for what, values, beyond, limit, shown in checks:
            bad = np.flatnonzero(beyond)
            if bad.size:
                at = int(bad[0])
                raise ArgumentError(
                    f"joint {name}: its {what} reaches {values[at]:.4g} {shown} at"
                    f" {times[at]:.3f} s, beyond {limit}: slow the trajectory down (spread"
                    " its times) or keep it inside", reason="trajectory")


def ramp_time_s(trajectory: JointTrajectory, joints: Mapping[str, JointConfig]) -> float:
    """How long a hold takes to bring the time scale from 1 to 0 (and a resume back): long
    enough that slowing down adds at most each joint's ``max_accel`` to the trajectory's
    own acceleration (at least 50 ms)."""
    times = np.arange(0.0, trajectory.duration_s + CHECK_STEP_S, CHECK_STEP_S)
    _, velocities = trajectory.at(times)
    peaks = [float(np.max(np.abs(velocities[:, column]), initial=0.0)) / joints[name].max_accel
             for column, name in enumerate(trajectory.joints)]
    return max(0.05, *peaks)


# --- what a play says -------------------------------------------------------------------------


@dataclass
class PlayReport:
    """How a play went.

    Fields:
        joints: the joints played.
        start_tick: the device tick every device started on.
        completed: the trajectory was played to its end (not stopped).
        stopped_at_s: where along the trajectory a stop brought the joints to rest (its
            time, s), or its duration.
        duration_s: the time the play took on the devices (holds included), s.
        holds: how many holds it came to rest in.
        peak_error_counts: per joint, the largest |desired - actual| of any servo tick
            (the device's statistics, call 35).
        end: per joint, where it came to rest, in its unit.
        keyframes: keyframes sent to each device.
        records: per joint, the devices' diagnostics lines, when recorded.
        sent: per joint, the keyframes sent and the desired position its curve started
            from, when recorded (what the device plays: ``hermite.sample_keyframes``).
    """

    joints: tuple[str, ...]
    start_tick: int
    completed: bool
    stopped_at_s: float
    duration_s: float
    holds: int
    peak_error_counts: dict[str, int]
    end: dict[str, float]
    keyframes: int
    records: dict[str, list[Diagnostics]] = field(default_factory=dict)
    sent: dict[str, tuple[int, list[Keyframe]]] = field(default_factory=dict)


# --- the robot --------------------------------------------------------------------------------


class Robot:
    """A machine's joints (its file's ``[joints]``), moved and played together.

    The machine's axes must be homed (joint positions are machine positions); a play puts
    the joints' devices in curve mode and leaves them enabled, holding the end.
    ``hold``, ``resume`` and ``stop`` may be called from any thread while a play runs.

    Raises:
        ArgumentError: the machine file has no joints.
    """

    def __init__(self, machine: Machine) -> None:
        self.machine = machine
        joints = machine.config.joints
        if not joints:
            raise ArgumentError(f"{machine.config.path} names no joints: add [joints.<name>]"
                                " tables (axis, unit, counts_per_unit)", reason="joints")
        self.joints: dict[str, JointConfig] = {joint.name: joint for joint in joints}
        self._lock = threading.Lock()
        self._hold = False
        self._stop = ""
        self.held = threading.Event()
        """Set while a play is held at rest (waiting for :meth:`resume`)."""

    # --- reading ------------------------------------------------------------------------------

    def _client(self, name: str) -> DeviceClient:
        return self.machine.axis(self.joints[name].axis).client

    def positions(self) -> dict[str, float]:
        """Where every joint stands (its encoder), in its unit."""
        return {name: self._client(name).status().actual_counts / joint.counts_per_unit
                for name, joint in self.joints.items()}

    def read(self) -> dict[str, tuple[float, float, float]]:
        """Per joint: (measured, commanded, following error = commanded - measured), in its
        unit, from its device now."""
        out: dict[str, tuple[float, float, float]] = {}
        for name, joint in self.joints.items():
            status = self._client(name).status()
            scale = joint.counts_per_unit
            out[name] = (status.actual_counts / scale, status.desired_counts / scale,
                         (status.desired_counts - status.actual_counts) / scale)
        return out

    # --- operator requests --------------------------------------------------------------------

    def hold(self) -> None:
        """Decelerate along the path to rest, until :meth:`resume`."""
        with self._lock:
            self._hold = True

    def resume(self) -> None:
        """Go on after a hold."""
        with self._lock:
            self._hold = False

    def stop(self, reason: str = "stopped") -> None:
        """Decelerate along the path to rest and end the play there."""
        with self._lock:
            self._stop = reason or "stopped"

    # --- moving -------------------------------------------------------------------------------

    def move_to(self, targets: Mapping[str, float], *, record: bool = False,
                on_progress: Callable[[float], None] | None = None) -> PlayReport:
        """Move the named joints (the others stay) to ``targets`` together: the time-optimal
        jerk-limited move within every joint's limits, all arriving on the same tick.

        Raises:
            ArgumentError: an unknown joint or a target out of its range.
            StopRequestedError, DeviceError: as :meth:`play`.
        """
        for name, value in targets.items():
            if name not in self.joints:
                raise ArgumentError(f"joint {name!r}: allowed {', '.join(self.joints)}",
                                    reason="joints")
            low, high = self.joints[name].range
            if not (math.isfinite(value) and low <= value <= high):
                raise ArgumentError(f"joint {name} target {value!r}: allowed {low:g}..{high:g}"
                                    f" {self.joints[name].unit}", reason="targets")
        names = list(targets)
        here = self.positions()
        start = [here[name] for name in names]
        goal = [float(targets[name]) for name in names]
        if all(abs(a - b) * self.joints[n].counts_per_unit < AT_START_TOLERANCE
               for a, b, n in zip(start, goal, names, strict=True)):
            return self.play(JointTrajectory.from_points(names, [0.0, KEYFRAME_MS / 1000],
                                                         [start, start]), record=record)
        profile = jerk_limited_profile(
            start, goal, [self.joints[n].max_velocity for n in names],
            [self.joints[n].max_accel for n in names], [self.joints[n].max_jerk for n in names])
        step = KEYFRAME_MS / 1000
        count = max(2, math.ceil(profile.duration_s / step) + 1)
        times = np.linspace(0.0, profile.duration_s, count)
        samples = [profile.at(float(t)) for t in times]
        trajectory = JointTrajectory.from_points(
            names, times, [s[0] for s in samples], [s[1] for s in samples])
        return self.play(trajectory, record=record, on_progress=on_progress,
                         check=False)

    def play(self, trajectory: JointTrajectory, *, record: bool = False,
             on_progress: Callable[[float], None] | None = None,
             check: bool = True) -> PlayReport:
        """Play ``trajectory`` on its joints' devices from one start tick (see the module).
        The joints must stand at its first point (:meth:`move_to` it first). Returns once
        every joint has come to rest at its end, or where a stop brought it.

        ``on_progress`` is told the trajectory time reached after every batch of
        keyframes; ``record`` keeps every device's diagnostics lines (one a tick).

        Raises:
            ArgumentError: a joint unknown, out of its limits (``check``), or not at the
                first point.
            StopRequestedError: a stop came (the report is on the error's ``report``).
            DeviceFaultError: a device faulted (every joint is stopped at once).
            DeviceError: a device refused, or the host fell behind the devices.
        """
        if check:
            check_limits(trajectory, self.joints)
        else:
            for name in trajectory.joints:
                if name not in self.joints:
                    raise ArgumentError(f"joint {name!r}: allowed {', '.join(self.joints)}",
                                        reason="joints")
        names = trajectory.joints
        joints = [self.joints[name] for name in names]
        here = self.positions()
        first = trajectory.positions[0]
        for name, joint, value in zip(names, joints, first, strict=True):
            if abs(here[name] - value) * joint.counts_per_unit > max(AT_START_TOLERANCE,
                                                                     SETTLE_COUNTS):
                raise ArgumentError(
                    f"joint {name} stands at {here[name]:.4f} {joint.unit}, the trajectory"
                    f" starts at {value:.4f}: move_to its first point first", reason="start")
        with self._lock:
            self._hold, self._stop = False, ""
        player = _Player(self, trajectory, joints, record=record)
        return player.run(on_progress)


class _Player:
    """One play of a trajectory (:meth:`Robot.play`)."""

    def __init__(self, robot: Robot, trajectory: JointTrajectory,
                 joints: list[JointConfig], *, record: bool) -> None:
        self.robot = robot
        self.machine = robot.machine
        self.trajectory = trajectory
        self.joints = joints
        self.clients = [self.machine.axis(joint.axis).client for joint in joints]
        self.scale = np.array([joint.counts_per_unit for joint in joints])
        self.ramp_s = ramp_time_s(trajectory, robot.joints)
        self.step_s = KEYFRAME_MS / 1000
        self.tau = 0.0
        self.rate = 1.0
        self.sent = 0
        self.holds = 0
        self.record = record
        self.records: dict[str, list[Diagnostics]] = {j.name: [] for j in joints}
        self.kept: dict[str, tuple[int, list[Keyframe]]] = {}

    def run(self, on_progress: Callable[[float], None] | None) -> PlayReport:
        machine = self.machine
        axes = [joint.axis for joint in self.joints]
        machine.set_mode(ControlMode.CURVE, axes=axes)
        for client in self.clients:
            client.clear_keyframes()
            client.reset_motion_stats()
            client.set_servo_enable(True)
        try:
            if self.record:
                for client, joint in zip(self.clients, self.joints, strict=True):
                    client.on_diagnostics = self.records[joint.name].append
                    client.set_diagnostics_interval(1)
            if self.record:
                self.kept = {joint.name: (client.status().desired_counts, [])
                             for joint, client in zip(self.joints, self.clients, strict=True)}
            start_tick, started_s = self._start(zero=True)
            stopped = self._play(on_progress)
            wait_until_settled(lambda: [client.status() for client in self.clients],
                               machine.clock)
            finished_s = machine.clock.now()
        except DeviceFaultError:
            machine.stop()
            raise
        finally:
            if self.record:
                for client in self.clients:
                    client.set_diagnostics_interval(0)
                    client.sync()
                    client.on_diagnostics = None
        end = {joint.name: client.status().actual_counts / joint.counts_per_unit
               for joint, client in zip(self.joints, self.clients, strict=True)}
        peak = {joint.name: client.motion_stats().max_error_counts
                for joint, client in zip(self.joints, self.clients, strict=True)}
        report = PlayReport(
            joints=self.trajectory.joints, start_tick=start_tick, completed=not stopped,
            stopped_at_s=min(self.tau, self.trajectory.duration_s),
            duration_s=finished_s - started_s, holds=self.holds, peak_error_counts=peak,
            end=end, keyframes=self.sent,
            records=self.records if self.record else {}, sent=self.kept)
        if stopped:
            error = StopRequestedError(f"stopped: {stopped}", reason=stopped)
            error.report = report  # type: ignore[attr-defined]
            raise error
        return report

    def _start(self, *, zero: bool) -> tuple[int, float]:
        """Give every device its first keyframes, each held meanwhile, then arm them all to
        start on one tick (:func:`usbmotion.host.timesync.start_filled`).

        Raises:
            StartMissedError: a device confirmed the start only after its tick (the host was
                held up): every curve is emptied at once, each servo holding its joint.
        """
        try:
            sync = start_filled(self.clients, lambda: self._send(KEYFRAMES_AHEAD + 1),
                                margin_s=START_MARGIN_S, zero=zero)
        except StartMissedError as error:
            for client in self.clients:
                client.clear_keyframes()
            raise held_up(error, what="joints", again="play it again") from error
        return sync.devices[0].start_tick, sync.start_s

    def _play(self, on_progress: Callable[[float], None] | None) -> str:
        """Keep the devices' buffers topped up until the end or a stop; the stop's reason."""
        clock = self.machine.clock
        robot = self.robot
        while True:
            with robot._lock:
                holding, stopping = robot._hold, robot._stop
            target = 0.0 if holding or stopping else 1.0
            ended = self.tau >= self.trajectory.duration_s and self.rate == 1.0
            if ended or (self.rate == 0.0 and target == 0.0):
                self._drain()
                if ended:
                    return ""
                if stopping:
                    return stopping
                self.holds += 1
                robot.held.set()
                try:
                    if not self._wait_for_resume():
                        return robot._stop
                finally:
                    robot.held.clear()
                self._start(zero=False)
                continue
            free = min(self._free())
            room = free - (8 - KEYFRAMES_AHEAD - 1)
            if room > 0:
                self._send(room, target=target)
                if on_progress is not None:
                    on_progress(min(self.tau, self.trajectory.duration_s))
            clock.sleep(self.step_s / 2)

    def _free(self) -> list[int]:
        free = []
        for client, joint in zip(self.clients, self.joints, strict=True):
            status = client.status()
            if status.fault:
                raise DeviceFaultError(f"joint {joint.name}: its device faulted (fault"
                                       f" {status.fault})", device=client.name)
            left = client.curve_free()
            if left == 8 and self.sent and self.tau < self.trajectory.duration_s:
                raise DeviceError(f"joint {joint.name}: its keyframes ran out before the"
                                  " next ones came (the host fell behind the devices)",
                                  device=client.name)
            free.append(left)
        return free

    def _send(self, count: int, *, target: float = 1.0) -> None:
        """The next ``count`` keyframes of every joint, the time scale's rate moving toward
        ``target`` by 1 / ramp a second."""
        slope = self.step_s / self.ramp_s
        taus: list[float] = []
        rates: list[float] = []
        tau, rate = self.tau, self.rate
        for _ in range(count):
            if tau >= self.trajectory.duration_s and rate == 1.0:
                break
            if rate == 0.0 and target == 0.0:
                break
            new_rate = min(target, rate + slope) if target > rate else max(target, rate - slope)
            tau += self.step_s * 0.5 * (rate + new_rate)
            rate = new_rate
            if tau >= self.trajectory.duration_s and rate > 0.0:
                tau, rate = self.trajectory.duration_s, 1.0  # the end, at rest
            taus.append(tau)
            rates.append(rate)
        if not taus:
            return
        positions, velocities = self.trajectory.at(np.array(taus))
        counts = np.rint(positions * self.scale).astype(np.int64)
        slopes = velocities * np.array(rates)[:, None] * self.scale / 1000.0  # counts/ms
        ended = np.array(taus) >= self.trajectory.duration_s
        for row in range(len(taus)):
            for column, client in enumerate(self.clients):
                tangent = 0 if ended[row] else tangent_to_fixed(float(slopes[row, column]))
                keyframe = Keyframe(KEYFRAME_MS, int(counts[row, column]), tangent, tangent)
                client.append_keyframe(keyframe)
                if self.kept:
                    self.kept[self.joints[column].name][1].append(keyframe)
        self.tau, self.rate = tau, rate
        self.sent += len(taus)

    def _drain(self) -> None:
        """Until every device has played all its keyframes."""
        clock = self.machine.clock
        while min(client.curve_free() for client in self.clients) < 8:
            clock.sleep(self.step_s)

    def _wait_for_resume(self) -> bool:
        """At rest in a hold: until a resume (True) or a stop (False)."""
        clock = self.machine.clock
        robot = self.robot
        while True:
            with robot._lock:
                if robot._stop:
                    return False
                if not robot._hold:
                    return True
            for client in self.clients:
                client.status()  # keeps the watchdogs fed
            clock.sleep(0.02)

__all__ = ["KEYFRAME_MS", "JointTrajectory", "PlayReport", "Robot", "check_limits",
           "ramp_time_s"]
