"""The look-ahead planner: corner speeds, limits on sampled setpoints, times, arcs, dwells."""

from __future__ import annotations

import hashlib
import math
import platform

import numpy as np
import pytest

from usbmotion.errors import PlanningError
from usbmotion.motion.moves import Arc, Dwell, Linear, Move, Plane, Point, Rapid
from usbmotion.motion.planner import (
    AxisLimits,
    Plan,
    PlannerConfig,
    SegmentKind,
    exact_cumsum,
    plan_moves,
)
from usbmotion.motion.sampler import sample_plan, sample_positions_mm, sample_times

LIMITS = (AxisLimits(200.0, 1000.0), AxisLimits(200.0, 1000.0), AxisLimits(200.0, 1000.0))
UNEVEN = (AxisLimits(100.0, 500.0), AxisLimits(250.0, 2000.0), AxisLimits(40.0, 300.0))
CONFIG = PlannerConfig()


def chain(points: list[Point], feed_mm_min: float, *, first_line: int = 1) -> list[Move]:
    return [
        Linear(first_line + i, points[i], points[i + 1], feed_mm_min)
        for i in range(len(points) - 1)
    ]


def junction_speed(a: float, deviation: float, angle_between_rad: float) -> float:
    """grbl's formula; ``angle_between_rad`` is the angle at the corner (pi when straight)."""
    sin_half = math.sin(angle_between_rad / 2.0)
    return math.sqrt(a * deviation * sin_half / (1.0 - sin_half))


# --- times and speeds ----------------------------------------------------------------------


def test_single_move_takes_the_hand_computed_time() -> None:
    plan = plan_moves([Linear(1, (0, 0, 0), (100, 0, 0), 6000)], LIMITS, CONFIG)
    # 100 mm/s cruise, 1000 mm/s^2: 0.1 s and 5 mm at each end, 90 mm at cruise.
    assert plan.duration_s == pytest.approx(100 / 100 + 100 / 1000, abs=1e-12)
    (segment,) = plan.segments
    assert segment.v_cruise_mm_s == pytest.approx(100.0)
    assert segment.t_accel_s == pytest.approx(0.1)
    assert segment.t_cruise_s == pytest.approx(0.9)
    assert segment.v_entry_mm_s == 0.0
    assert segment.v_exit_mm_s == 0.0
    assert segment.line == 1
    assert segment.kind is SegmentKind.LINEAR


def test_long_move_reaches_cruise_and_short_move_is_a_triangle() -> None:
    long_plan = plan_moves([Linear(1, (0, 0, 0), (0, 300, 0), 9000)], LIMITS, CONFIG)
    assert long_plan.v_cruise_mm_s[0] == pytest.approx(150.0)
    assert long_plan.t_cruise_s[0] > 1.0
    short = plan_moves([Linear(1, (0, 0, 0), (2, 0, 0), 9000)], LIMITS, CONFIG)
    assert short.t_cruise_s[0] == pytest.approx(0.0, abs=1e-12)
    assert short.v_cruise_mm_s[0] == pytest.approx(math.sqrt(1000.0 * 2.0))
    assert short.duration_s == pytest.approx(2 * math.sqrt(2.0 / 1000.0))


@pytest.mark.parametrize("deviation", [0.01, 0.05, 0.2])
def test_square_corners_take_the_junction_deviation_speed(deviation: float) -> None:
    square = chain([(0, 0, 0), (100, 0, 0), (100, 100, 0), (0, 100, 0), (0, 0, 0)], 6000)
    plan = plan_moves(square, LIMITS, PlannerConfig(junction_deviation_mm=deviation))
    expected = junction_speed(1000.0, deviation, math.pi / 2)
    assert plan.v_entry_mm_s[1:].tolist() == pytest.approx([expected] * 3, rel=1e-12)
    assert plan.v_exit_mm_s[:-1].tolist() == pytest.approx([expected] * 3, rel=1e-12)
    assert plan.v_entry_mm_s[0] == 0.0
    assert plan.v_exit_mm_s[-1] == 0.0


def test_corner_speed_follows_the_angle() -> None:
    # A 135 degree corner (45 degree deflection) is faster than a right angle.
    moves = chain([(0, 0, 0), (100, 0, 0), (200, 100, 0)], 12_000)
    plan = plan_moves(moves, LIMITS, CONFIG)
    # Junction acceleration: the smaller of the two moves' and the one along u2 - u1.
    u1 = np.array([1.0, 0.0])
    u2 = np.array([1.0, 1.0]) / math.sqrt(2)
    w = (u2 - u1) / np.linalg.norm(u2 - u1)
    a_moves = min(1000.0, 1000.0 / np.abs(u2).max())
    a_junction = min(a_moves, 1000.0 / np.abs(w).max())
    expected = junction_speed(a_junction, 0.01, 3 * math.pi / 4)
    assert plan.v_entry_mm_s[1] == pytest.approx(expected, rel=1e-12)


def test_reversal_stops_and_straight_continuation_keeps_speed() -> None:
    back = chain([(0, 0, 0), (50, 0, 0), (0, 0, 0)], 6000)
    assert plan_moves(back, LIMITS, CONFIG).v_entry_mm_s[1] == 0.0
    straight = chain([(0, 0, 0), (50, 0, 0), (100, 0, 0)], 6000)
    assert plan_moves(straight, LIMITS, CONFIG).v_entry_mm_s[1] == pytest.approx(100.0)


def test_rapids_run_at_the_axes_limits() -> None:
    along_x = plan_moves([Rapid(1, (0, 0, 0), (500, 0, 0))], UNEVEN, CONFIG)
    assert along_x.v_cruise_mm_s[0] == pytest.approx(100.0)
    assert along_x.accel_mm_s2[0] == pytest.approx(500.0)
    diagonal = plan_moves([Rapid(1, (0, 0, 0), (500, 500, 0))], LIMITS, CONFIG)
    assert diagonal.v_cruise_mm_s[0] == pytest.approx(200.0 * math.sqrt(2))
    assert diagonal.accel_mm_s2[0] == pytest.approx(1000.0 * math.sqrt(2))
    # Z is the slow axis: a move mostly along X still may not push Z past 40 mm/s.
    steep = plan_moves([Rapid(1, (0, 0, 0), (300, 0, 400))], UNEVEN, CONFIG)
    assert steep.v_cruise_mm_s[0] == pytest.approx(40.0 / 0.8)


def test_feed_is_capped_by_the_axes() -> None:
    plan = plan_moves([Linear(1, (0, 0, 0), (0, 0, 100), 60_000)], UNEVEN, CONFIG)
    assert plan.v_cruise_mm_s[0] == pytest.approx(40.0)
    slow = plan_moves([Linear(1, (0, 0, 0), (0, 0, 100), 600)], UNEVEN, CONFIG)
    assert slow.v_cruise_mm_s[0] == pytest.approx(10.0)


# --- limits on sampled setpoints -----------------------------------------------------------


def mixed_program() -> list[Move]:
    moves: list[Move] = [
        Rapid(1, (0, 0, 0), (10, 5, 2)),
        Linear(2, (10, 5, 2), (40, 5, 2), 3000),
        Linear(3, (40, 5, 2), (40, 35, -3), 2400),
        Arc(4, (40, 35, -3), (20, 35, -3), (30, 35, -3), Plane.XY, 1, 1800),
        Arc(5, (20, 35, -3), (20, 35, -3), (20, 35, 2), Plane.XZ, -1, 1500),
        Dwell(6, (20, 35, -3), 0.05),
        Arc(7, (20, 35, -3), (20, 35, 7), (20, 30, -3), Plane.YZ, 2, 1200),
        Linear(8, (20, 35, 7), (0, 0, 0), 6000),
        Rapid(9, (0, 0, 0), (-30, 20, 10)),
    ]
    return moves


@pytest.mark.parametrize("limits", [LIMITS, UNEVEN])
def test_sampled_setpoints_respect_every_axis_limit(limits: tuple[AxisLimits, ...]) -> None:
    plan = plan_moves(mixed_program(), limits, CONFIG)
    period = 0.0005
    positions = sample_positions_mm(plan, period_s=period)
    times = sample_times(plan, period)
    v_max = np.array([axis.velocity_mm_s for axis in limits])
    a_max = np.array([axis.accel_mm_s2 for axis in limits])

    # Velocity: each step is the mean velocity over one period, so it obeys the limit
    # everywhere (corners included). Float noise only: 1e-9 relative.
    velocity = np.diff(positions, axis=0) / period
    assert (np.abs(velocity) <= v_max * (1 + 1e-9)).all()
    assert np.abs(velocity).max(axis=0).max() > 0.5 * v_max.min()
    # The same on the integer setpoints, where rounding adds up to one count per step.
    counts_per_mm = (800.0, 1000.0, 2000.0)
    counts = sample_plan(plan, period_s=period, counts_per_mm=counts_per_mm).astype(np.int64)
    step_limit = v_max * np.array(counts_per_mm) * period * (1 + 1e-9) + 1.0
    assert (np.abs(np.diff(counts, axis=0)) <= step_limit).all()

    # Acceleration: a second difference averages the acceleration over two periods. Inside
    # one segment it obeys the limit; across a corner the junction-deviation model allows a
    # velocity step (checked separately below), so stencils that straddle a junction where
    # the direction changes are left out. Tolerance: float noise in a difference of three
    # positions, 1e-6 relative plus 1e-3 mm/s^2.
    starts = plan.start_time_s
    ends = starts + plan.segment_duration_s
    segment = np.searchsorted(starts, times, side="right") - 1
    inner = np.arange(1, len(times) - 1)
    same = (times[inner - 1] >= starts[segment[inner]]) & (times[inner + 1] <= ends[segment[inner]])
    accel = (positions[2:] - 2 * positions[1:-1] + positions[:-2]) / period**2
    checked = accel[same]
    assert len(checked) > 0.5 * len(inner)
    assert (np.abs(checked) <= a_max * (1 + 1e-6) + 1e-3).all()
    assert np.abs(checked).max() > 0.5 * a_max.min()


def test_junction_speeds_never_exceed_the_model() -> None:
    plan = plan_moves(mixed_program(), UNEVEN, CONFIG)
    inv_a = 1.0 / np.array([axis.accel_mm_s2 for axis in UNEVEN])
    unit = plan.unit
    for i in range(1, len(plan)):
        if plan.kind[i] == SegmentKind.DWELL or plan.kind[i - 1] == SegmentKind.DWELL:
            assert plan.v_entry_mm_s[i] == 0.0
            continue
        speed = plan.v_entry_mm_s[i]
        assert speed == plan.v_exit_mm_s[i - 1]
        assert speed <= min(plan.v_cruise_mm_s[i], plan.v_cruise_mm_s[i - 1]) * (1 + 1e-12)
        w = unit[i] - unit[i - 1]
        if np.linalg.norm(w) < 1e-12:
            continue
        a_j = min(
            plan.accel_mm_s2[i],
            plan.accel_mm_s2[i - 1],
            1.0 / (np.abs(w / np.linalg.norm(w)) * inv_a).max(),
        )
        angle = math.acos(float(np.clip(-unit[i] @ unit[i - 1], -1.0, 1.0)))
        assert speed <= junction_speed(a_j, 0.01, angle) * (1 + 1e-9)


def reference_passes(plan: Plan) -> np.ndarray:
    """The backward and forward passes written as plain loops over the junction limits."""
    reach = 2.0 * plan.accel_mm_s2 * plan.length_mm
    speed_sq = (plan.v_junction_max_mm_s**2).tolist()
    for i in range(len(plan) - 1, -1, -1):
        speed_sq[i] = min(speed_sq[i], speed_sq[i + 1] + reach[i])
    for i in range(len(plan)):
        speed_sq[i + 1] = min(speed_sq[i + 1], speed_sq[i] + reach[i])
    return np.sqrt(np.array(speed_sq, dtype=np.float64))


def test_vectorised_passes_equal_the_loops() -> None:
    rng = np.random.default_rng(7)
    points: list[Point] = [(0.0, 0.0, 0.0)]
    for _ in range(400):
        step = rng.normal(size=3) * rng.choice([0.05, 1.0, 30.0])
        x, y, z = (np.array(points[-1]) + step).tolist()
        points.append((x, y, z))
    plan = plan_moves(chain(points, 4000), UNEVEN, CONFIG)
    speeds = np.concatenate((plan.v_entry_mm_s, [0.0]))
    assert np.allclose(reference_passes(plan), speeds, rtol=1e-9, atol=1e-9)
    assert np.array_equal(plan.v_entry_mm_s[1:], plan.v_exit_mm_s[:-1])
    assert (speeds <= plan.v_junction_max_mm_s).all()
    assert (speeds == plan.v_junction_max_mm_s).mean() > 0.3  # most corners bind
    # Every segment can reach its exit from its entry within its acceleration.
    change = np.abs(plan.v_exit_mm_s**2 - plan.v_entry_mm_s**2)
    assert (change <= 2 * plan.accel_mm_s2 * plan.length_mm * (1 + 1e-9) + 1e-9).all()
    # Lengths of the phases add up.
    s_accel = (plan.v_cruise_mm_s**2 - plan.v_entry_mm_s**2) / (2 * plan.accel_mm_s2)
    s_decel = (plan.v_cruise_mm_s**2 - plan.v_exit_mm_s**2) / (2 * plan.accel_mm_s2)
    total = s_accel + s_decel + plan.v_cruise_mm_s * plan.t_cruise_s
    assert np.allclose(total, plan.length_mm, rtol=1e-9, atol=1e-9)


# --- arcs ----------------------------------------------------------------------------------


@pytest.mark.parametrize("plane", [Plane.XY, Plane.XZ, Plane.YZ])
@pytest.mark.parametrize("rotation", [1, -1])
def test_full_circle_chords_lie_within_the_tolerance(plane: Plane, rotation: int) -> None:
    first, second, normal = plane.axes
    radius = 12.5
    start = [5.0, -3.0, 2.0]
    centre = list(start)
    centre[first] -= radius
    moves = [Arc(1, tuple(start), tuple(start), tuple(centre), plane, rotation, 1200)]  # type: ignore[arg-type]
    tolerance = 0.002
    plan = plan_moves(moves, LIMITS, PlannerConfig(arc_tolerance_mm=tolerance), start=tuple(start))  # type: ignore[arg-type]

    vertices = plan.vertices_mm
    radial = np.hypot(vertices[:, first] - centre[first], vertices[:, second] - centre[second])
    assert np.abs(radial - radius).max() < 1e-9
    assert np.all(vertices[:, normal] == start[normal])
    # Sagitta of every chord: the circle bulges from the chord's middle by at most tol.
    middle = 0.5 * (vertices[1:] + vertices[:-1])
    mid_radius = np.hypot(middle[:, first] - centre[first], middle[:, second] - centre[second])
    assert (radius - mid_radius).max() <= tolerance + 1e-12
    assert (radius - mid_radius).max() > 0.5 * tolerance  # not needlessly fine
    expected_chords = math.ceil(2 * math.pi / (2 * math.acos(1 - tolerance / radius)))
    assert len(plan) == expected_chords

    # The direction: right-hand rule about the normal, counter-clockwise for +1.
    angle = np.unwrap(
        np.arctan2(vertices[:, second] - centre[second], vertices[:, first] - centre[first])
    )
    assert angle[-1] - angle[0] == pytest.approx(rotation * 2 * math.pi)

    positions = sample_positions_mm(plan, period_s=0.001)
    sampled = np.hypot(positions[:, first] - centre[first], positions[:, second] - centre[second])
    assert sampled.min() >= radius - tolerance - 1e-9
    assert sampled.max() <= radius + 1e-9


def test_helix_with_extra_turns() -> None:
    # G19 G2 with P2 and travel along X (the YZ plane's normal): two clockwise turns.
    start = (0.0, 2.0, 0.0)
    end = (5.0, -2.0, 0.0)
    centre = (0.0, 0.0, -10.0)
    plan = plan_moves([Arc(6, start, end, centre, Plane.YZ, -2, 1000)], LIMITS, CONFIG, start=start)
    vertices = plan.vertices_mm
    assert tuple(vertices[-1]) == end
    r_start = math.hypot(2.0, 10.0)
    angle = np.unwrap(np.arctan2(vertices[:, 2] - centre[2], vertices[:, 1] - centre[1]))
    sweep = angle[-1] - angle[0]
    end_angle = math.atan2(10.0, -2.0)  # (Y, Z) relative to the centre
    start_angle = math.atan2(10.0, 2.0)
    one_pass = -((start_angle - end_angle) % (2 * math.pi))
    assert sweep == pytest.approx(one_pass - 2 * math.pi)
    # Travel along the normal is linear in the angle.
    fraction = (angle - angle[0]) / sweep
    assert np.allclose(vertices[:, 0], 5.0 * fraction, atol=1e-9)
    radius = np.hypot(vertices[:, 1] - centre[1], vertices[:, 2] - centre[2])
    assert np.allclose(radius, r_start, atol=1e-9)
    assert (np.diff(vertices[:, 0]) > 0).all()
    assert set(plan.line.tolist()) == {6}
    assert set(plan.kind.tolist()) == {SegmentKind.ARC}
    # A chord's 3D sagitta equals its in-plane sagitta: the helix rises linearly.
    middle = 0.5 * (vertices[1:] + vertices[:-1])
    mid_radius = np.hypot(middle[:, 1] - centre[1], middle[:, 2] - centre[2])
    assert (r_start - mid_radius).max() <= CONFIG.arc_tolerance_mm + 1e-12
    path = math.hypot(abs(sweep) * r_start, 5.0)
    assert plan.length_mm.sum() == pytest.approx(path, rel=2e-4)  # chords are a bit shorter


def test_spiral_radius_is_linear_in_the_angle() -> None:
    # LinuxCNC accepts a centre slightly off the perpendicular bisector: start radius 10,
    # end radius 10.01; the path spirals between them.
    start = (10.0, 0.0, 0.0)
    end = (-10.01, 0.0, 0.0)
    plan = plan_moves(
        [Arc(1, start, end, (0, 0, 0), Plane.XY, 1, 600)], LIMITS, CONFIG, start=start
    )
    vertices = plan.vertices_mm
    angle = np.unwrap(np.arctan2(vertices[:, 1], vertices[:, 0]))
    assert angle[-1] == pytest.approx(math.pi)
    radius = np.hypot(vertices[:, 0], vertices[:, 1])
    assert np.allclose(radius, 10.0 + 0.01 * angle / math.pi, atol=1e-9)


def test_arc_quarter_turn_directions() -> None:
    # G2 from (10, 0) about the origin to (0, -10) is a quarter turn; G3 the long way.
    cw = plan_moves(
        [Arc(1, (10, 0, 0), (0, -10, 0), (0, 0, 0), Plane.XY, -1, 600)],
        LIMITS,
        CONFIG,
        start=(10, 0, 0),
    )
    ccw = plan_moves(
        [Arc(1, (10, 0, 0), (0, -10, 0), (0, 0, 0), Plane.XY, 1, 600)],
        LIMITS,
        CONFIG,
        start=(10, 0, 0),
    )
    assert cw.length_mm.sum() == pytest.approx(0.5 * math.pi * 10, rel=1e-4)
    assert ccw.length_mm.sum() == pytest.approx(1.5 * math.pi * 10, rel=1e-4)
    assert cw.vertices_mm[1, 1] < 0 < ccw.vertices_mm[1, 1]


def test_arc_speed_is_capped_by_centripetal_acceleration() -> None:
    # At 6000 mm/min on a 5 mm radius the centripetal acceleration would be 2000 mm/s^2.
    plan = plan_moves(
        [Arc(1, (5, 0, 0), (5, 0, 0), (0, 0, 0), Plane.XY, 1, 6000)],
        LIMITS,
        CONFIG,
        start=(5, 0, 0),
    )
    # Per axis, the centripetal acceleration v^2 / r * |n_k| (n the radial direction) stays
    # within 1000 mm/s^2, up to 1% for the chords' approximation of the circle.
    radial = plan.vertices_mm[1:-1, :2] / 5.0
    speed_sq = plan.v_entry_mm_s[1:] ** 2
    per_axis = speed_sq / 5.0 * np.abs(radial).max(axis=1)
    assert per_axis.max() <= 1000.0 * 1.01
    assert per_axis.max() > 0.9 * 1000.0
    assert plan.v_cruise_mm_s.max() < 100.0


# --- dwells, edges, errors -----------------------------------------------------------------


def test_dwell_stops_and_holds() -> None:
    moves: list[Move] = [
        Linear(1, (0, 0, 0), (10, 0, 0), 6000),
        Dwell(2, (10, 0, 0), 0.75),
        Linear(3, (10, 0, 0), (20, 0, 0), 6000),
    ]
    plan = plan_moves(moves, LIMITS, CONFIG)
    single = plan_moves(moves[:1], LIMITS, CONFIG).duration_s
    assert plan.duration_s == pytest.approx(2 * single + 0.75)
    assert plan.v_exit_mm_s[0] == 0.0
    assert plan.v_entry_mm_s[2] == 0.0
    dwell = plan.segments[1]
    assert dwell.kind is SegmentKind.DWELL
    assert dwell.t_cruise_s == 0.75
    assert dwell.start == dwell.end == (10.0, 0.0, 0.0)
    positions = sample_positions_mm(plan, period_s=0.01)
    times = sample_times(plan, 0.01)
    during = (times >= single) & (times <= single + 0.75)
    assert during.sum() >= 74
    assert (positions[during] == [10.0, 0.0, 0.0]).all()


def test_zero_length_moves_are_dropped_and_empty_plans_work() -> None:
    plan = plan_moves(
        [Rapid(1, (0, 0, 0), (0, 0, 0)), Linear(2, (0, 0, 0), (1, 0, 0), 600)], LIMITS, CONFIG
    )
    assert len(plan) == 1
    assert plan.line.tolist() == [2]
    empty = plan_moves([], LIMITS, CONFIG, start=(1.0, 2.0, 3.0))
    assert len(empty) == 0
    assert empty.duration_s == 0.0
    assert empty.start == empty.end == (1.0, 2.0, 3.0)
    assert empty.move_count == 0


def test_plan_columns_are_read_only_and_segments_match() -> None:
    plan = plan_moves(mixed_program(), LIMITS, CONFIG)
    with pytest.raises(ValueError, match="read-only"):
        plan.length_mm[0] = 1.0
    segments = plan.segments
    assert len(segments) == len(plan)
    assert segments[3].start_time_s == plan.start_time_s[3]
    assert segments[-1].end == plan.end
    assert sum(s.duration_s for s in segments) == pytest.approx(plan.duration_s)
    assert (np.diff(plan.start_time_s) >= 0).all()
    probe = segments[1]
    assert probe.distance_at(probe.duration_s) == pytest.approx(probe.length_mm)
    assert probe.distance_at(0.0) == 0.0


def test_exact_cumsum_does_not_drift() -> None:
    values = np.full(1_000_000, 0.1)
    starts, total = exact_cumsum(values)
    assert total == 100_000.0
    assert starts[-1] == pytest.approx(99_999.9, abs=1e-9)
    assert np.cumsum(values)[-1] != 100_000.0  # what a plain running sum does


@pytest.mark.parametrize(
    ("build", "text"),
    [
        (lambda: AxisLimits(0.0, 100.0), "velocity_mm_s 0.0"),
        (lambda: AxisLimits(100.0, -5.0), "accel_mm_s2 -5.0"),
        (lambda: AxisLimits(math.nan, 100.0), "velocity_mm_s nan"),
        (lambda: AxisLimits(100.0, math.inf), "accel_mm_s2 inf"),
        (lambda: PlannerConfig(junction_deviation_mm=0.0), "junction_deviation_mm 0.0"),
        (lambda: PlannerConfig(arc_tolerance_mm=-1.0), "arc_tolerance_mm -1.0"),
    ],
)
def test_bad_limits_and_config_are_rejected(build: object, text: str) -> None:
    with pytest.raises(PlanningError, match=text):
        build()  # type: ignore[operator]


@pytest.mark.parametrize(
    ("moves", "text"),
    [
        ([Linear(7, (0, 0, 0), (1, 0, 0), 0.0)], "line 7: feed 0.0"),
        ([Linear(7, (0, 0, 0), (1, 0, 0), math.nan)], "line 7: feed nan"),
        ([Linear(3, (0, 0, 0), (math.nan, 0, 0), 100.0)], "line 3: position"),
        ([Linear(4, (1, 0, 0), (2, 0, 0), 100.0)], "line 4: move starts at"),
        (
            [Linear(3, (0, 0, 0), (math.nan, 0, 0), 100.0), Rapid(4, (math.nan, 0, 0), (0, 0, 0))],
            r"line 3: position \(nan, 0.0, 0.0\) is not finite",
        ),
        (
            [
                Linear(3, (0, 0, 0), (float("nan"), 0, 0), 100.0),
                Rapid(4, (float("nan"), 0, 0), (0, 0, 0)),
            ],
            "line 4: position .* not finite",
        ),
        ([Dwell(5, (0, 0, 0), -1.0)], "line 5: dwell -1.0"),
        ([Arc(6, (0, 0, 0), (0, 0, 0), (0, 0, 0), Plane.XY, 1, 100.0)], "line 6: arc"),
        ([Arc(8, (0, 0, 0), (2, 0, 0), (1, 0, 0), Plane.XY, 0, 100.0)], "rotation 0"),
        (["G1 X1"], "'G1 X1'"),
    ],
)
def test_bad_moves_are_rejected_with_their_line(moves: list[Move], text: str) -> None:
    with pytest.raises(PlanningError, match=text):
        plan_moves(moves, LIMITS, CONFIG)


def test_bad_call_arguments_are_rejected() -> None:
    with pytest.raises(PlanningError, match="limits"):
        plan_moves([], LIMITS[:2], CONFIG)
    with pytest.raises(PlanningError, match="start"):
        plan_moves([], LIMITS, CONFIG, start=(0.0, math.inf, 0.0))
    with pytest.raises(PlanningError, match="config"):
        plan_moves([], LIMITS, None)  # type: ignore[arg-type]


def test_arc_smaller_than_the_tolerance_still_turns() -> None:
    # r = 1 um is below the 2 um tolerance: at most 120 degrees per chord, so a full circle
    # is a triangle whose sagitta (r / 2) is within the tolerance.
    start = (0.001, 0.0, 0.0)
    plan = plan_moves(
        [Arc(1, start, start, (0, 0, 0), Plane.XY, 1, 60)], LIMITS, CONFIG, start=start
    )
    assert len(plan) == 3
    radius = np.hypot(plan.vertices_mm[:, 0], plan.vertices_mm[:, 1])
    assert np.allclose(radius, 0.001, atol=1e-12)


# --- the plan itself, pinned -----------------------------------------------------------------

PLAN_COLUMNS = (
    "vertices_mm", "unit", "kind", "line", "length_mm", "v_entry_mm_s", "v_cruise_mm_s",
    "v_exit_mm_s", "accel_mm_s2", "t_accel_s", "t_cruise_s", "t_decel_s", "start_time_s",
    "v_junction_max_mm_s", "feed_mm_s",
)


def seeded_program(count: int, *, seed: int, arcs: bool) -> list[Move]:
    """``count`` connected moves from the origin on a 1 um grid, drawn without trigonometry:
    rapids, lines (a few of zero length), dwells and, with ``arcs``, arcs in all three planes
    ending a quarter, half or three quarters of a turn on, or where they start (full
    circles), some helical, some turning twice."""
    rng = np.random.default_rng(seed)
    moves: list[Move] = []
    position: Point = (0.0, 0.0, 0.0)
    for line in range(1, count + 1):
        roll = rng.random()
        step = tuple(int(value) / 1000 for value in rng.integers(-20_000, 20_000, 3))
        if roll < 0.1:
            end: Point = tuple(c + 5.0 * d for c, d in zip(position, step, strict=True))
            moves.append(Rapid(line, position, end))
        elif roll < 0.15:
            moves.append(Dwell(line, position, float(rng.integers(0, 500)) / 1000))
            continue
        elif roll < 0.6 or not arcs:
            if roll < 0.17:
                step = (0.0, 0.0, 0.0)
            end = tuple(c + d for c, d in zip(position, step, strict=True))
            moves.append(Linear(line, position, end, float(rng.integers(60, 12_000))))
        else:
            plane = (Plane.XY, Plane.XZ, Plane.YZ)[int(rng.integers(0, 3))]
            first, second, normal = plane.axes
            u, v = step[0] / 2, step[1] / 2  # from the centre to the start
            quarters = int(rng.integers(0, 4))
            for _ in range(quarters):
                u, v = -v, u
            centre = list(position)
            centre[first] -= step[0] / 2
            centre[second] -= step[1] / 2
            end_list = list(position)
            end_list[first] = centre[first] + u
            end_list[second] = centre[second] + v
            if rng.random() < 0.3:
                end_list[normal] += step[2] / 4
            rotation = int(rng.choice([-2, -1, -1, 1, 1, 2]))
            end = (end_list[0], end_list[1], end_list[2])
            moves.append(Arc(line, position, end, (centre[0], centre[1], centre[2]), plane,
                             rotation, float(rng.integers(60, 6_000))))
        position = end
    return moves


def plan_digest(plan: Plan) -> str:
    """SHA-256 of every column's bytes (little-endian) and the duration."""
    digest = hashlib.sha256()
    for name in PLAN_COLUMNS:
        column = getattr(plan, name)
        digest.update(np.ascontiguousarray(column, dtype=column.dtype.newbyteorder("<")))
    digest.update(repr(plan.duration_s).encode())
    return digest.hexdigest()


PINNED_LINES = (2951, "0dc81c086f2f1b38f7f77180359b6bb2781ecab8b4077eb47fcefbe289daefa5")
PINNED_ARCS = (106591, "09806d2f0bf1b6215257c1e2d1a7eb12ecf24190bbb63f47ed64d8245500560b")


def test_plan_of_lines_is_pinned() -> None:
    # Square roots and the four operations only: the same bits on every IEEE machine. A
    # change to how the planner computes must leave these unchanged (or say why not).
    plan = plan_moves(seeded_program(3000, seed=20260101, arcs=False), UNEVEN, CONFIG)
    assert len(plan) == PINNED_LINES[0]
    assert plan_digest(plan) == PINNED_LINES[1]


@pytest.mark.skipif(
    platform.system() != "Linux" or platform.machine() != "x86_64"
    or platform.libc_ver()[0] != "glibc",
    reason="arcs go through the C library's trigonometry: pinned on Linux x86_64 glibc",
)
def test_plan_with_arcs_is_pinned() -> None:
    plan = plan_moves(seeded_program(2000, seed=20260102, arcs=True), UNEVEN, CONFIG)
    assert len(plan) == PINNED_ARCS[0]
    assert plan_digest(plan) == PINNED_ARCS[1]
