"""The sampler: sample counts, exact ends, no drift over ten hours, chunking, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from usbmotion.errors import PlanningError
from usbmotion.motion.moves import Arc, Dwell, Linear, Move, Plane, Rapid
from usbmotion.motion.planner import AxisLimits, Plan, PlannerConfig, plan_moves
from usbmotion.motion.profiles import trapezoid_profile
from usbmotion.motion.sampler import (
    iter_sample_chunks,
    positions_at_mm,
    sample_axis,
    sample_count,
    sample_plan,
    sample_positions_mm,
    sample_times,
)

LIMITS = (AxisLimits(200.0, 1000.0), AxisLimits(200.0, 1000.0), AxisLimits(50.0, 500.0))
CONFIG = PlannerConfig()
COUNTS = (1000.0, 1000.0, 2000.0)


def program() -> list[Move]:
    return [
        Rapid(1, (0, 0, 0), (5, 5, 1)),
        Linear(2, (5, 5, 1), (30, 5, 1), 3000),
        Arc(3, (30, 5, 1), (30, 25, 1), (30, 15, 1), Plane.XY, 1, 1200),
        Dwell(4, (30, 25, 1), 0.1),
        Linear(5, (30, 25, 1), (-12.3456, 7.891, -2.5), 6000),
    ]


def plan_of(moves: list[Move]) -> Plan:
    return plan_moves(moves, LIMITS, CONFIG)


def test_sample_count_and_exact_end() -> None:
    plan = plan_of(program())
    for period in (0.001, 0.0001, 0.0037, 0.25):
        setpoints = sample_plan(plan, period_s=period, counts_per_mm=COUNTS)
        assert setpoints.dtype == np.int32
        assert setpoints.shape == (math.ceil(plan.duration_s / period) + 1, 3)
        assert setpoints[0].tolist() == [0, 0, 0]
        assert setpoints[-1].tolist() == [-12346, 7891, -5000]
        assert len(sample_times(plan, period)) == len(setpoints)


def test_a_whole_number_of_periods_adds_no_sample() -> None:
    plan = plan_of([Linear(1, (0, 0, 0), (100, 0, 0), 6000)])  # 1.1 s
    assert sample_count(plan, 0.001) == 1101
    assert sample_count(plan, 0.1) == 12
    times = sample_times(plan, 0.001)
    assert times[-1] == pytest.approx(1.1)
    assert times[1234 % 1101] == (1234 % 1101) * 0.001


def test_samples_follow_the_trapezoid() -> None:
    plan = plan_of([Linear(1, (0, 0, 0), (100, 0, 0), 6000)])
    profile = trapezoid_profile(100.0, 100.0, 1000.0)
    period = 0.001
    expected = np.rint(profile.sample(period) * 1000.0)
    assert sample_axis(plan, 0, period_s=period, counts_per_mm=1000.0).tolist() == (
        expected.astype(int).tolist()
    )


def test_ten_hours_of_one_slow_move_end_on_the_count() -> None:
    # 600 mm at 1 mm/min: 36000 s plus the (tiny) ramps.
    plan = plan_of([Linear(1, (0, 0, 0), (600.0, -300.0, 0), 1.0)])
    assert plan.duration_s == pytest.approx(36000 * math.hypot(600, 300) / 600, rel=1e-6)
    period = 0.01
    setpoints = sample_plan(plan, period_s=period, counts_per_mm=COUNTS)
    assert len(setpoints) == math.ceil(plan.duration_s / period) + 1
    assert setpoints[-1].tolist() == [600_000, -300_000, 0]
    # Mid-way the position is where constant speed puts it (no drift).
    k = len(setpoints) // 2
    speed = 1.0 / 60.0
    ramp = plan.t_accel_s[0]
    distance = speed * (k * period - ramp) + 0.5 * speed * ramp
    direction = np.array([600.0, -300.0]) / math.hypot(600, 300)
    assert np.abs(setpoints[k, :2] - distance * direction * 1000.0).max() <= 0.5 + 1e-6


def test_ten_hours_of_many_short_moves_do_not_drift() -> None:
    # 36,600 collinear 1 mm moves at 61 mm/min: one ten-hour cruise made of 36,600 segments
    # whose start times are sums of 36,600 durations. The samples must match the single
    # trapezoid of the whole path: to the nanometre in mm, and to the count once rounded
    # (except where a value falls within float noise of a half count).
    moves: list[Move] = [
        Linear(i + 1, (float(i), 0.0, 0.0), (float(i + 1), 0.0, 0.0), 61.0) for i in range(36_600)
    ]
    plan = plan_of(moves)
    assert len(plan) == 36_600
    whole = trapezoid_profile(36_600.0, 61.0 / 60.0, 1000.0)
    assert plan.duration_s == pytest.approx(36_000.0, abs=0.01)  # plus one ramp time
    assert plan.duration_s == pytest.approx(whole.duration_s, abs=1e-9)
    period = 0.01
    x = sample_axis(plan, 0, period_s=period, counts_per_mm=1000.0)
    assert len(x) == math.ceil(plan.duration_s / period) + 1
    assert x[-1] == 36_600_000
    expected = np.rint(whole.sample(period) * 1000.0).astype(np.int64)
    assert len(expected) == len(x)
    assert np.abs(x - expected).max() <= 1
    assert (x == expected).mean() > 0.9999
    probe = sample_times(plan, period)[::97]
    assert np.abs(positions_at_mm(plan, probe)[:, 0] - whole.position_at(probe)).max() < 1e-6


def test_every_setpoint_at_a_segment_start_is_its_vertex() -> None:
    plan = plan_of(program())
    positions = positions_at_mm(plan, plan.start_time_s)
    assert np.allclose(positions, plan.vertices_mm[:-1], atol=1e-9)
    outside = positions_at_mm(plan, [-5.0, plan.duration_s + 5.0])
    assert outside[0].tolist() == [0.0, 0.0, 0.0]
    assert outside[1].tolist() == list(plan.end)
    with pytest.raises(PlanningError, match="NaN"):
        positions_at_mm(plan, [math.nan])


def test_single_axis_and_chunks_agree_with_the_whole() -> None:
    plan = plan_of(program())
    period = 0.0005
    whole = sample_plan(plan, period_s=period, counts_per_mm=COUNTS)
    for axis in range(3):
        column = sample_axis(plan, axis, period_s=period, counts_per_mm=COUNTS[axis])
        assert np.array_equal(column, whole[:, axis])
    small = sample_plan(plan, period_s=period, counts_per_mm=COUNTS, chunk_samples=7)
    assert np.array_equal(small, whole)
    streamed = np.concatenate(
        list(iter_sample_chunks(plan, period_s=period, counts_per_mm=COUNTS, chunk_samples=100))
    )
    assert np.array_equal(streamed, whole)
    mm = sample_positions_mm(plan, period_s=period, chunk_samples=333)
    assert np.array_equal(np.rint(mm * np.array(COUNTS)).astype(np.int32), whole)


def test_dwell_holds_every_axis() -> None:
    plan = plan_of(program())
    dwell = int(np.flatnonzero(plan.kind == 3)[0])
    times = sample_times(plan, 0.001)
    setpoints = sample_plan(plan, period_s=0.001, counts_per_mm=COUNTS)
    start = plan.start_time_s[dwell]
    held = setpoints[(times >= start) & (times <= start + 0.1)]
    assert len(held) >= 99
    assert (held == [30_000, 25_000, 2_000]).all()


def test_empty_plan_gives_one_setpoint() -> None:
    plan = plan_moves([], LIMITS, CONFIG, start=(1.0, -2.0, 0.5))
    assert sample_plan(plan, period_s=0.001, counts_per_mm=COUNTS).tolist() == [[1000, -2000, 1000]]


def test_negative_counts_per_mm_flip_the_axis() -> None:
    plan = plan_of(program())
    flipped = sample_plan(plan, period_s=0.01, counts_per_mm=(-1000.0, 1000.0, 2000.0))
    normal = sample_plan(plan, period_s=0.01, counts_per_mm=COUNTS)
    assert np.array_equal(flipped[:, 0], -normal[:, 0])


@pytest.mark.parametrize(
    ("kwargs", "text"),
    [
        ({"period_s": 0.0, "counts_per_mm": COUNTS}, "period_s 0.0"),
        ({"period_s": math.nan, "counts_per_mm": COUNTS}, "period_s nan"),
        ({"period_s": 0.001, "counts_per_mm": (1.0, 2.0)}, "counts_per_mm"),
        ({"period_s": 0.001, "counts_per_mm": (1.0, 0.0, 1.0)}, "0.0"),
        ({"period_s": 0.001, "counts_per_mm": (1.0, math.inf, 1.0)}, "inf"),
        ({"period_s": 0.001, "counts_per_mm": (1e9, 1.0, 1.0)}, "int32"),
        ({"period_s": 0.001, "counts_per_mm": COUNTS, "chunk_samples": 0}, "chunk_samples"),
    ],
)
def test_bad_arguments_are_rejected(kwargs: dict[str, object], text: str) -> None:
    plan = plan_of(program())
    with pytest.raises(PlanningError, match=text):
        sample_plan(plan, **kwargs)  # type: ignore[arg-type]


def test_bad_axis_is_rejected() -> None:
    plan = plan_of(program())
    with pytest.raises(PlanningError, match="axis 3"):
        sample_axis(plan, 3, period_s=0.001, counts_per_mm=1.0)


@given(st.lists(st.integers(0, 40), min_size=1, max_size=30),
       st.lists(st.integers(-5, 50), min_size=0, max_size=200))
@settings(max_examples=400, deadline=None)
def test_ascending_times_find_the_segments_a_search_finds(starts: list[int],
                                                          times: list[int]) -> None:
    """A chunk of samples is placed by searching the segment starts among its times: the
    same segment for every time as searching each time among the starts, equal starts
    (segments of no length) and times before the first start or after the last included."""
    from usbmotion.motion.sampler import _segments  # noqa: PLC0415

    begun = np.asarray(sorted(starts), dtype=np.float64) / 4
    ascending = np.asarray(sorted(times), dtype=np.float64) / 4
    assert np.array_equal(_segments(begun, ascending, ascending=True),
                          _segments(begun, ascending, ascending=False))
