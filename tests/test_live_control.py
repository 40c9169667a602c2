"""Feed hold, resume, stop and overrides in virtual time, checked on what the devices
executed (their desired position at every servo tick, :mod:`usbmotion.sim.recording`).

Tolerances, from integer setpoints: velocity is measured over 10 ticks (a count of
rounding at each end: 1 count / 10 ms, 0.42 mm/s at 240 counts/mm) and acceleration as
the second difference over 20-tick windows (2 counts / (20 ms)^2, 20.8 mm/s^2). The
planner's corners (junction deviation) change an axis's velocity within a tick, which the
windowed acceleration sees; a hold, a resume or an override may add nothing beyond the
uninterrupted program's own peak (or the axis's limit, when higher). A path is the same
when every executed point of one run is within 1.5 counts (rounding of both, on three
axes) of the polyline the other executed, both ways round.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

import usbmotion
from usbmotion.cli.run import default_machine
from usbmotion.errors import ArgumentError
from usbmotion.host.config import MachineConfig, load_config
from usbmotion.protocol import FaultCode
from usbmotion.session import MachineSession, MachineState, StopReason
from usbmotion.sim.machine import connect_session
from usbmotion.sim.recording import ExecutedRecorder

DEMO = Path(usbmotion.__file__).parent / "data" / "demos" / "1-rounded-square.ngc"
AXES = ["X", "Y", "Z"]
VELOCITY_WINDOW = 10
ACCEL_WINDOW = 20
PATH_TOLERANCE_COUNTS = 1.5
Positions = npt.NDArray[np.int64]


@pytest.fixture(scope="module")
def config() -> MachineConfig:
    return load_config(default_machine())


def _run(config: MachineConfig,
         act: Callable[[MachineSession, int], None] | None = None, *,
         live: bool = True) -> tuple[MachineSession, Positions, object]:
    """Home, run the demo with ``act(session, tick)`` called on every servo tick, and
    return the session (closed), what the devices executed during the run, and the report.
    ``live``: the session's live control (requests looked at every 10 ms, else 50 ms)."""
    with connect_session(config) as session:
        session.live_control = live
        session.home()
        world = session.machine.world
        assert world is not None
        count = [0]

        def on_tick(_: int) -> None:
            count[0] += 1
            if act is not None:
                act(session, count[0])

        with ExecutedRecorder(world, AXES, on_tick=on_tick) as recorder:
            report, _ = session.run(session.prepare(DEMO))
        session.final_state = session.state  # type: ignore[attr-defined]
        session.report = report  # type: ignore[attr-defined]
        session.shutdown()
        return session, recorder.positions(), report


@pytest.fixture(scope="module")
def reference(config: MachineConfig) -> Positions:
    _, positions, report = _run(config)
    assert report.completed  # type: ignore[attr-defined]
    return positions


def _peaks(positions: Positions) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Per-axis peak velocity (counts/tick, over VELOCITY_WINDOW) and acceleration
    (counts/tick^2, over ACCEL_WINDOW)."""
    w = VELOCITY_WINDOW
    velocity = np.abs(positions[w:] - positions[:-w]).max(axis=0) / w
    a = ACCEL_WINDOW
    second = positions[2 * a:] - 2 * positions[a:-a] + positions[:-2 * a]
    return velocity, np.abs(second).max(axis=0) / (a * a)


def _check_limits(config: MachineConfig, positions: Positions, reference: Positions) -> None:
    tick_s = config.servo_period_s
    velocity, accel = _peaks(positions)
    _, reference_accel = _peaks(reference)
    for column, name in enumerate(AXES):
        axis = config.axis(name)
        v_limit = axis.max_velocity_mm_s * axis.counts_per_mm * tick_s + 1 / VELOCITY_WINDOW
        assert velocity[column] <= v_limit, f"{name}: velocity {velocity[column]} > {v_limit}"
        a_limit = max(axis.max_accel_mm_s2 * axis.counts_per_mm * tick_s**2,
                      reference_accel[column]) + 2 / ACCEL_WINDOW**2
        assert accel[column] <= a_limit + 1e-12, (
            f"{name}: acceleration {accel[column] / tick_s**2 / axis.counts_per_mm} mm/s^2"
            f" beyond {a_limit / tick_s**2 / axis.counts_per_mm}")
        step = np.abs(np.diff(positions[:, column])).max()
        assert step <= axis.max_velocity_mm_s * axis.counts_per_mm * tick_s + 1, f"{name}: a jump"


def _distance_to_path(points: Positions, path: Positions) -> float:
    """The largest distance (counts) from any of ``points`` to the polyline ``path``."""
    path_f = path.astype(np.float64)
    keep = np.concatenate(([True], np.any(np.diff(path_f, axis=0) != 0, axis=1)))
    path_f = path_f[keep]
    start, end = path_f[:-1], path_f[1:]
    cell = 16.0
    cells: dict[tuple[int, int, int], list[int]] = {}
    for index, key in enumerate(map(tuple, np.floor(start / cell).astype(np.int64).tolist())):
        cells.setdefault(key, []).append(index)  # type: ignore[arg-type]
    offsets = [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)]
    worst = 0.0
    for point in np.unique(points, axis=0).astype(np.float64):
        x, y, z = np.floor(point / cell).astype(np.int64).tolist()
        near = [n for i, j, k in offsets for n in cells.get((x + i, y + j, z + k), ())]
        if not near:
            return float("inf")
        a, b = start[near], end[near]
        d = b - a
        t = np.clip(np.einsum("ij,ij->i", point - a, d) / np.einsum("ij,ij->i", d, d), 0, 1)
        closest = a + d * t[:, None]
        worst = max(worst, float(np.min(np.linalg.norm(closest - point, axis=1))))
    return worst


def _check_same_path(positions: Positions, reference: Positions) -> None:
    assert _distance_to_path(positions, reference) <= PATH_TOLERANCE_COUNTS, "left the path"
    assert _distance_to_path(reference, positions) <= PATH_TOLERANCE_COUNTS, "skipped a part"
    assert np.array_equal(positions[-1], reference[-1]), "the same end position"


def _at_rest_spans(positions: Positions, least: int) -> list[tuple[int, int]]:
    """Stretches of at least ``least`` ticks where no axis moved."""
    still = np.concatenate(([False], np.all(np.diff(positions, axis=0) == 0, axis=1), [False]))
    edges = np.flatnonzero(np.diff(still.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)
            if b - a >= least]


@pytest.mark.parametrize("live", [True, False], ids=["live", "batch"])
def test_hold_then_resume_keeps_the_path_within_the_limits(
        config: MachineConfig, reference: Positions, live: bool) -> None:
    states: list[MachineState] = []

    def act(session: MachineSession, tick: int) -> None:
        if tick == 4000:
            session.request_hold()
        if tick == 4600:
            states.append(session.state)
            session.request_resume()

    session, positions, report = _run(config, act, live=live)
    assert states == [MachineState.HOLD]
    assert report.completed and session.final_state is MachineState.IDLE  # type: ignore[attr-defined]
    assert _at_rest_spans(positions, 300), "it came to rest and stayed there"
    _check_limits(config, positions, reference)
    _check_same_path(positions, reference)
    assert session.last_run is not None
    ((_, _, planned_mm, distance_mm),) = session.last_run.holds
    assert distance_mm <= planned_mm + 0.05 and distance_mm > 0.5 * planned_mm


def test_two_holds_and_resumes_one_on_an_arc(config: MachineConfig,
                                             reference: Positions) -> None:
    def act(session: MachineSession, tick: int) -> None:
        if tick in (2500, 9000):
            session.request_hold()
        if tick in (3200, 9700):
            session.request_resume()

    session, positions, report = _run(config, act)
    assert report.completed  # type: ignore[attr-defined]
    assert session.last_run is not None and len(session.last_run.holds) == 2
    _check_limits(config, positions, reference)
    _check_same_path(positions, reference)


def test_stop_while_held_leaves_the_machine_homed_and_idle(config: MachineConfig,
                                                         reference: Positions) -> None:
    def act(session: MachineSession, tick: int) -> None:
        if tick == 5000:
            session.request_hold()
        if tick == 5600:
            session.request_stop()

    session, positions, report = _run(config, act)
    assert not report.completed and report.stop_reason == StopReason.USER.value  # type: ignore[attr-defined]
    assert session.final_state is MachineState.IDLE and session.is_homed  # type: ignore[attr-defined]
    _check_limits(config, positions, reference)
    assert _distance_to_path(positions, reference) <= PATH_TOLERANCE_COUNTS


def test_stop_while_running_decelerates_along_the_path(config: MachineConfig,
                                                      reference: Positions) -> None:
    def act(session: MachineSession, tick: int) -> None:
        if tick == 6000:
            session.request_stop()

    session, positions, report = _run(config, act)
    assert not report.completed and session.final_state is MachineState.IDLE  # type: ignore[attr-defined]
    assert session.is_homed
    _check_limits(config, positions, reference)
    assert _distance_to_path(positions, reference) <= PATH_TOLERANCE_COUNTS
    with connect_session(config) as again:
        assert all(s.fault == FaultCode.NONE for s in again.machine.status().values())


@pytest.mark.parametrize(("feed", "rapid"), [(50, 100), (200, 100), (10, 100), (100, 25)])
def test_an_override_keeps_the_path_and_the_limits(config: MachineConfig, reference: Positions,
                                                  feed: int, rapid: int) -> None:
    def act(session: MachineSession, tick: int) -> None:
        if tick == 3000:
            session.set_feed_override(feed)
            session.set_rapid_override(rapid)
        if tick == 12000 and feed == 10:
            session.set_feed_override(150)

    session, positions, report = _run(config, act)
    assert report.completed  # type: ignore[attr-defined]
    assert session.last_run is not None and session.last_run.seams
    _check_limits(config, positions, reference)
    _check_same_path(positions, reference)
    longer = positions.shape[0] > reference.shape[0]
    assert longer == (feed < 100 or rapid < 100 or feed == 10)


def test_override_values_outside_their_range_are_refused(config: MachineConfig) -> None:
    with connect_session(config) as session:
        session.live_control = True
        for bad in (9, 201, 0, 50.5, True):
            with pytest.raises(ArgumentError, match=r"feed override .* 10 \.\. 200"):
                session.set_feed_override(bad)  # type: ignore[arg-type]
        for bad in (75, 0, 200):
            with pytest.raises(ArgumentError, match=r"rapid override 75|rapid override 0|"
                               r"rapid override 200"):
                session.set_rapid_override(bad)
        assert session.feed_override_percent == 100 and session.rapid_override_percent == 100
