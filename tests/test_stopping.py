"""Stopping along a planned path: the planned deceleration's distance, every axis within its
acceleration limit, on the path, at rest at the end."""

from __future__ import annotations

import math

import numpy as np
import pytest

from usbmotion.errors import PlanningError
from usbmotion.motion.stopping import QUANTUM_COUNTS, stop_setpoints

PERIOD_S = 0.001


def _line(speed_counts_s: tuple[float, ...], rows: int = 3000) -> np.ndarray:
    steps = np.arange(rows, dtype=np.float64)[:, None] * np.array(speed_counts_s) * PERIOD_S
    return np.rint(steps).astype(np.int64)


@pytest.mark.parametrize("speed", [1000.0, 4800.0, 9600.0])
def test_a_straight_line_stops_in_its_planned_v2_over_2a(speed: float) -> None:
    accel = 120_000.0
    path = _line((speed,))
    stop = stop_setpoints(path, 1000, period_s=PERIOD_S, accel_counts_s2=[accel])
    rows = stop.setpoints[:, 0]
    travelled = rows[-1] - path[999, 0]
    planned = speed * speed / (2 * accel)
    sample = speed * PERIOD_S
    assert planned - sample - 0.02 * planned - 2 <= travelled <= planned + 2, (
        "within v^2/2a, short of it by at most the half period a sampled ramp saves (and the"
        " measured speed's rounding)", travelled, planned)
    assert rows[-1] == rows[-2], "ends at rest"
    assert np.all(np.diff(rows) >= 0), "never goes back along the path"
    duration_s = speed / accel
    assert abs(len(rows) * PERIOD_S - duration_s) <= 2 * PERIOD_S


def test_every_axis_keeps_within_its_own_limit() -> None:
    path = _line((4800.0, 4800.0, 1200.0))
    limits = [120_000.0, 40_000.0, 120_000.0]
    stop = stop_setpoints(path, 700, period_s=PERIOD_S, accel_counts_s2=limits)
    trail = np.vstack((path[698:700], stop.setpoints)).astype(np.float64)
    second = np.abs(np.diff(trail, n=2, axis=0))
    bounds = np.array(limits) * PERIOD_S**2 + QUANTUM_COUNTS
    assert np.all(second <= bounds)
    y_time = 4800.0 / 40_000.0
    assert len(stop.setpoints) * PERIOD_S == pytest.approx(y_time, abs=3 * PERIOD_S), (
        "the slowest axis sets the stop; the others follow the path, not their own ramps")


def test_a_stop_on_an_arc_stays_on_the_circle_and_within_the_limits() -> None:
    radius, speed = 24_000.0, 4800.0
    angles = np.arange(5000) * speed * PERIOD_S / radius
    path = np.rint(np.stack((radius * np.cos(angles), radius * np.sin(angles)), axis=1))
    limits = [100_000.0, 100_000.0]
    stop = stop_setpoints(path.astype(np.int64), 2000, period_s=PERIOD_S,
                          accel_counts_s2=limits)
    radii = np.hypot(stop.setpoints[:, 0], stop.setpoints[:, 1])
    assert np.all(np.abs(radii - radius) <= 2.0), "on the path"
    trail = np.vstack((path[1998:2000], stop.setpoints))
    assert np.all(np.abs(np.diff(trail, n=2, axis=0)) <= 100_000.0 * PERIOD_S**2 + QUANTUM_COUNTS)
    assert 2000 < stop.end_index < 2000 + speed / 100_000.0 / PERIOD_S


def test_a_path_at_rest_needs_no_stop() -> None:
    path = np.zeros((100, 2), dtype=np.int64)
    still = stop_setpoints(path, 50, period_s=PERIOD_S, accel_counts_s2=[1.0, 1.0])
    assert still.setpoints.size == 0
    moving = _line((1000.0, 0.0))
    assert stop_setpoints(moving, 0, period_s=PERIOD_S,
                          accel_counts_s2=[1.0, 1.0]).setpoints.size == 0, "not started yet"


def test_a_stop_near_the_program_end_does_not_run_past_it() -> None:
    path = _line((4800.0,), rows=1010)
    stop = stop_setpoints(path, 1000, period_s=PERIOD_S, accel_counts_s2=[10_000.0])
    assert stop.setpoints[-1, 0] <= path[-1, 0]
    assert stop.end_index <= 1009


@pytest.mark.parametrize(("start", "limits"), [(5000, [1.0]), (10, [0.0]), (10, [1.0, 2.0])])
def test_bad_arguments_are_refused(start: int, limits: list[float]) -> None:
    with pytest.raises(PlanningError):
        stop_setpoints(_line((100.0,), rows=100), start, period_s=PERIOD_S,
                       accel_counts_s2=limits)


def test_the_distance_check_would_catch_an_abrupt_stop() -> None:
    """The checks above can fail: a queue cut dead (the old stop) moves nowhere, and a stop
    at twice the acceleration takes half the distance."""
    speed, accel = 4800.0, 120_000.0
    path = _line((speed,))
    stop = stop_setpoints(path, 1000, period_s=PERIOD_S, accel_counts_s2=[2 * accel])
    travelled = stop.setpoints[-1, 0] - path[999, 0]
    planned = speed * speed / (2 * accel)
    assert travelled < planned - speed * PERIOD_S - 0.02 * planned - 2, "caught as too short"
    assert not math.isclose(travelled, planned, rel_tol=0.02, abs_tol=2)
