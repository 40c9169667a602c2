"""Motion profiles: trapezoid, jerk-limited through ruckig, Hermite keyframe builders."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from usbmotion.errors import ProfileError
from usbmotion.hermite import TANGENT_ONE, Keyframe, sample_keyframes
from usbmotion.motion.profiles import (
    jerk_limited_profile,
    keyframes_through_points,
    line_tangent_fixed,
    polyline_keyframes,
    straight_line_keyframe,
    trapezoid_keyframes,
    trapezoid_profile,
)

# --- trapezoid -----------------------------------------------------------------------------


def test_trapezoid_times_and_shape() -> None:
    profile = trapezoid_profile(100.0, 100.0, 1000.0)
    assert profile.duration_s == pytest.approx(1.1)
    assert profile.t_accel_s == pytest.approx(0.1)
    assert profile.v_peak == 100.0
    assert profile.position_at(0.1) == pytest.approx(5.0)
    assert profile.position_at(1.0) == pytest.approx(95.0)
    assert profile.velocity_at(0.5) == pytest.approx(100.0)
    assert profile.position_at(5.0) == 100.0
    triangle = trapezoid_profile(4.0, 100.0, 1000.0)
    assert triangle.t_cruise_s == 0.0
    assert triangle.v_peak == pytest.approx(math.sqrt(4000.0))


def test_trapezoid_with_end_speeds() -> None:
    profile = trapezoid_profile(10.0, 50.0, 200.0, v0=20.0, v1=5.0)
    assert profile.velocity_at(0.0) == pytest.approx(20.0)
    assert profile.velocity_at(profile.duration_s) == pytest.approx(5.0)
    assert profile.position_at(profile.duration_s) == pytest.approx(10.0)
    braking = trapezoid_profile(1.0, 50.0, 200.0, v0=20.0)  # exactly 2*a*d = v0^2 - 0
    assert braking.t_accel_s == pytest.approx(0.0)
    assert braking.duration_s == pytest.approx(0.1)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-500.0, 500.0).filter(lambda d: d == 0.0 or abs(d) > 1e-6),
    st.floats(1.0, 300.0),
    st.floats(10.0, 5000.0),
    st.sampled_from([0.0005, 0.001, 0.01]),
)
def test_trapezoid_samples_respect_the_limits(
    distance: float, v_max: float, a_max: float, period: float
) -> None:
    profile = trapezoid_profile(distance, v_max, a_max)
    positions = profile.sample(period)
    ratio = profile.duration_s / period
    assert len(positions) in (math.ceil(ratio) + 1, round(ratio) + 1)
    assert positions[0] == 0.0
    assert positions[-1] == distance
    velocity = np.diff(positions) / period
    assert (np.abs(velocity) <= v_max * (1 + 1e-9) + 1e-9).all()
    accel = np.diff(positions, 2) / period**2
    assert (np.abs(accel) <= a_max * (1 + 1e-6) + 1e-6).all()
    steps = np.diff(positions) * np.sign(distance)
    assert (steps >= -1e-9).all()


def test_negative_distance_mirrors() -> None:
    forward = trapezoid_profile(30.0, 20.0, 100.0)
    backward = trapezoid_profile(-30.0, 20.0, 100.0)
    times = np.linspace(0, forward.duration_s, 50)
    assert np.allclose(backward.position_at(times), -forward.position_at(times))
    assert np.allclose(backward.velocity_at(times), -forward.velocity_at(times))


@pytest.mark.parametrize(
    ("args", "kwargs", "text"),
    [
        ((10.0, 0.0, 100.0), {}, "v_max 0.0"),
        ((10.0, 10.0, -1.0), {}, "a_max -1.0"),
        ((math.nan, 10.0, 100.0), {}, "distance nan"),
        ((10.0, 10.0, 100.0), {"v0": 11.0}, "v0 11.0"),
        ((10.0, 10.0, 100.0), {"v1": -1.0}, "v1 -1.0"),
        ((0.1, 10.0, 100.0), {"v0": 10.0}, "cannot go from v0 10.0"),
    ],
)
def test_trapezoid_rejects_bad_input(
    args: tuple[float, ...], kwargs: dict[str, float], text: str
) -> None:
    with pytest.raises(ProfileError, match=text):
        trapezoid_profile(*args, **kwargs)


# --- jerk-limited --------------------------------------------------------------------------


def test_jerk_limited_profile_respects_its_limits() -> None:
    profile = jerk_limited_profile(0.0, 10.0, 5.0, 10.0, 100.0)
    assert profile.dofs == 1
    # Cruise at 5 for most of the way: at least 10/5 s, plus ramps of a/j and v/a.
    assert 2.0 < profile.duration_s < 2.0 + 5.0 / 10.0 + 10.0 / 100.0 + 1e-9
    period = 0.001
    positions = profile.sample(period)[:, 0]
    assert positions[0] == 0.0
    assert positions[-1] == 10.0
    velocity = np.diff(positions) / period
    accel = np.diff(positions, 2) / period**2
    jerk = np.diff(positions, 3) / period**3
    assert np.abs(velocity).max() <= 5.0 * (1 + 1e-6)
    assert np.abs(accel).max() <= 10.0 * (1 + 1e-3)
    assert np.abs(jerk).max() <= 100.0 * (1 + 1e-2)
    _, velocity_at, accel_at = profile.at(profile.duration_s / 2)
    assert velocity_at[0] == pytest.approx(5.0)
    assert accel_at[0] == pytest.approx(0.0, abs=1e-9)
    assert profile.at(-1.0)[0] == (0.0,)
    assert profile.at(99.0)[0][0] == pytest.approx(10.0)


def test_jerk_limited_axes_finish_together_and_sample_counts() -> None:
    profile = jerk_limited_profile([0.0, 100.0], [10.0, 97.0], [5.0, 5.0], 10.0, 100.0)
    assert profile.dofs == 2
    samples = profile.sample(0.01)
    assert samples.shape[1] == 2
    assert samples[-1].tolist() == [10.0, 97.0]
    counts = profile.sample_counts(0.01, 1000.0)
    assert counts[-1].tolist() == [10_000, 97_000]
    assert counts.dtype == np.int64
    # The short axis is stretched to the long one's time: it is still moving mid-way.
    middle = samples[len(samples) // 2]
    assert 97.0 < middle[1] < 100.0


@pytest.mark.parametrize(
    ("kwargs", "text"),
    [
        ({"v1": 50.0}, "ruckig rejected the move.*v1=50.0.*target velocity"),
        ({"a1": 100.0}, "ruckig rejected the move.*acceleration"),
    ],
)
def test_ruckig_errors_become_profile_errors(kwargs: dict[str, float], text: str) -> None:
    with pytest.raises(ProfileError, match=text):
        jerk_limited_profile(0.0, 10.0, 5.0, 10.0, 100.0, **kwargs)


def test_jerk_limited_rejects_bad_input() -> None:
    with pytest.raises(ProfileError, match="j_max"):
        jerk_limited_profile(0.0, 1.0, 1.0, 1.0, 0.0)
    with pytest.raises(ProfileError, match="target"):
        jerk_limited_profile([0.0, 1.0], [1.0, 2.0, 3.0], 1.0, 1.0, 1.0)
    with pytest.raises(ProfileError, match="start"):
        jerk_limited_profile(math.nan, 1.0, 1.0, 1.0, 1.0)
    with pytest.raises(ProfileError, match="counts_per_unit"):
        jerk_limited_profile(0.0, 1.0, 1.0, 1.0, 1.0).sample_counts(0.01, 0.0)


# --- Hermite keyframes ---------------------------------------------------------------------


def ticks_ms(keyframes: tuple[Keyframe, ...], tick_us: int) -> np.ndarray:
    return np.arange(len(sample_keyframes(0, keyframes, tick_us=tick_us))) * tick_us / 1000.0


@settings(max_examples=80, deadline=None)
@given(
    st.integers(-1_000_000, 1_000_000),
    st.integers(-300_000, 300_000),
    st.integers(1, 10_000),
    st.sampled_from([250, 1000, 3000]),
)
def test_straight_line_pair_is_a_linear_ramp_within_one_count(
    start: int, delta: int, duration_ms: int, tick_us: int
) -> None:
    if abs(delta) > 31 * duration_ms:
        delta = int(math.copysign(31 * duration_ms, delta))
    end = start + delta
    keyframes = polyline_keyframes([start, end], [duration_ms], lead_ms=1)
    assert len(keyframes) == 2
    lead, line = keyframes
    assert lead.position_counts == start
    assert lead.tangent_in == 0
    assert lead.tangent_out == line.tangent_in == line_tangent_fixed(start, end, duration_ms)
    sampled = sample_keyframes(start, keyframes, tick_us=tick_us)
    t_ms = np.arange(len(sampled)) * tick_us / 1000.0
    exact = start + delta * np.clip((t_ms - 1.0) / duration_ms, 0.0, 1.0)
    assert np.abs(sampled - exact).max() <= 1.0
    assert sampled[-1] == end


def test_trapezoid_keyframes_rise_hold_and_fall() -> None:
    keyframes = trapezoid_keyframes(-200, 4800, rise_ms=500, hold_ms=300, fall_ms=1000)
    assert [k.duration_ms for k in keyframes] == [1, 500, 300, 1000]
    rise, hold, fall = keyframes[1:]
    assert rise.tangent_in == 10 * TANGENT_ONE
    assert rise.tangent_out == 0  # a corner: in and out tangents differ
    assert hold.tangent_in == 0
    assert hold.tangent_out == fall.tangent_in == -5 * TANGENT_ONE
    sampled = sample_keyframes(-200, keyframes, tick_us=1000)
    assert (sampled[501:802] == 4800).all()  # the wait moves not one count
    t_ms = np.arange(len(sampled), dtype=np.float64)
    rising = -200 + 10.0 * (t_ms[1:502] - 1.0)
    falling = 4800 - 5.0 * (t_ms[801:] - 801.0)
    assert np.abs(sampled[1:502] - rising).max() <= 1.0
    assert np.abs(sampled[801:] - falling).max() <= 1.0
    triangle = trapezoid_keyframes(0, 100, rise_ms=10, hold_ms=0, fall_ms=10, lead_ms=0)
    assert [k.position_counts for k in triangle] == [100, 0]


def test_straight_line_keyframe_and_steep_lines() -> None:
    keyframe = straight_line_keyframe(0, 1000, 100)
    assert keyframe == Keyframe(100, 1000, 10 * TANGENT_ONE, 10 * TANGENT_ONE)
    assert straight_line_keyframe(0, 1000, 100, tangent_out=0).tangent_out == 0
    assert line_tangent_fixed(0, 1, 3) == 341  # 1024 / 3 rounded
    assert line_tangent_fixed(0, -1, 2048) == -1  # -0.5 rounds away from zero
    with pytest.raises(ProfileError, match="at least 313 ms"):
        line_tangent_fixed(0, 10_000, 100)
    with pytest.raises(ProfileError, match="duration_ms 0"):
        line_tangent_fixed(0, 10, 0)


def test_keyframes_through_points_are_smooth_and_exact_at_the_points() -> None:
    points = [0, 1000, 1500, 1200, -300]
    durations = [100, 200, 100, 400]
    keyframes = keyframes_through_points(points, durations)
    assert [k.position_counts for k in keyframes] == points[1:]
    assert all(k.tangent_in == k.tangent_out for k in keyframes)
    assert keyframes[0].tangent_in == round((1500 - 0) / 300 * TANGENT_ONE)
    assert keyframes[-1].tangent_in == 0
    sampled = sample_keyframes(points[0], keyframes, tick_us=1000)
    assert [int(sampled[t]) for t in (0, 100, 300, 400, 800)] == points
    # Smooth: no step larger than the steepest tangent allows (about 12 counts per ms here).
    assert np.abs(np.diff(sampled)).max() <= 14


def test_steep_smooth_tangents_are_clipped_not_rejected() -> None:
    keyframes = keyframes_through_points([0, 100_000, 0], [100, 100])
    assert keyframes[0].tangent_in == 0  # (0 - 0) / 200 ms
    steep = keyframes_through_points([0, 0, 100_000, 100_000], [10, 100, 10])
    assert steep[1].tangent_in == 32767
    assert sample_keyframes(0, steep, tick_us=1000)[110] == 100_000


@pytest.mark.parametrize(
    ("points", "durations", "text"),
    [
        ([0], [], "needs the start"),
        ([0, 10], [10, 10], "one per segment"),
        ([0, 2**31], [10], r"points_counts\[1\]"),
        ([0, 10], [70_000], r"durations_ms\[0\]"),
        ([0, 10.5], [10], r"points_counts\[1\] 10.5"),
    ],
)
def test_keyframe_builders_reject_bad_input(
    points: list[int], durations: list[int], text: str
) -> None:
    with pytest.raises(ProfileError, match=text):
        keyframes_through_points(points, durations)
    with pytest.raises(ProfileError, match=text):
        polyline_keyframes(points, durations)


def test_lead_must_fit_a_keyframe() -> None:
    with pytest.raises(ProfileError, match="lead_ms -1"):
        polyline_keyframes([0, 10], [10], lead_ms=-1)
