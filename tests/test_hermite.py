"""Hermite keyframe maths: exact against Fractions, endpoints, symmetry, tick semantics."""

from __future__ import annotations

import itertools
import math
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from usbmotion.errors import ProfileError
from usbmotion.hermite import (
    TANGENT_MAX,
    TANGENT_MIN,
    TANGENT_ONE,
    Keyframe,
    fixed_to_tangent,
    hermite_position,
    hermite_velocity,
    keyframe_tick_count,
    sample_keyframes,
    tangent_to_fixed,
)

positions = st.integers(-(2**31), 2**31 - 1)
tangents = st.integers(TANGENT_MIN, TANGENT_MAX)
durations = st.integers(1, 65535)


def exact_value(p0: int, p1: int, m0: int, m1: int, duration_ms: int, elapsed_us: int) -> Fraction:
    s = Fraction(elapsed_us, duration_ms * 1000)
    m0_scaled = Fraction(m0 * duration_ms, TANGENT_ONE)
    m1_scaled = Fraction(m1 * duration_ms, TANGENT_ONE)
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    return h00 * p0 + h10 * m0_scaled + h01 * p1 + h11 * m1_scaled


def round_half_away(value: Fraction) -> int:
    magnitude = math.floor(abs(value) + Fraction(1, 2))
    return magnitude if value >= 0 else -magnitude


@st.composite
def segments(draw: st.DrawFn) -> tuple[int, int, int, int, int, int]:
    duration = draw(durations)
    elapsed = draw(st.integers(0, duration * 1000))
    return (draw(positions), draw(positions), draw(tangents), draw(tangents), duration, elapsed)


@settings(max_examples=400, deadline=None)
@given(segments())
def test_position_is_the_exact_cubic_rounded_to_nearest(
    segment: tuple[int, int, int, int, int, int],
) -> None:
    exact = exact_value(*segment)
    result = hermite_position(*segment)
    assert result == round_half_away(exact)
    assert abs(result - exact) <= Fraction(1, 2)


@settings(max_examples=200, deadline=None)
@given(positions, positions, tangents, tangents, durations)
def test_endpoints_are_exact(p0: int, p1: int, m0: int, m1: int, duration: int) -> None:
    assert hermite_position(p0, p1, m0, m1, duration, 0) == p0
    assert hermite_position(p0, p1, m0, m1, duration, duration * 1000) == p1


@settings(max_examples=300, deadline=None)
@given(segments())
def test_negating_every_input_negates_the_result(
    segment: tuple[int, int, int, int, int, int],
) -> None:
    p0, p1, m0, m1, duration, elapsed = segment
    if -(2**31) in (p0, p1) or TANGENT_MIN in (m0, m1):
        return
    mirrored = hermite_position(-p0, -p1, -m0, -m1, duration, elapsed)
    assert mirrored == -hermite_position(p0, p1, m0, m1, duration, elapsed)


def test_ties_round_away_from_zero_for_both_signs() -> None:
    # s = 1/2 with zero tangents gives exactly half the step.
    assert hermite_position(0, 1, 0, 0, 1, 500) == 1
    assert hermite_position(0, -1, 0, 0, 1, 500) == -1
    assert hermite_position(-5, -4, 0, 0, 10, 5000) == -5  # -4.5
    assert hermite_position(4, 5, 0, 0, 10, 5000) == 5  # 4.5
    assert hermite_position(-5, 5, 0, 0, 10, 5000) == 0


def test_tangents_are_scaled_by_the_duration() -> None:
    # A straight line: p1 - p0 equals the scaled tangent m * duration / 1024.
    for elapsed in range(0, 2_000_001, 250_000):
        expected = Fraction(2000 * elapsed, 2_000_000)
        assert hermite_position(0, 2000, 1024, 1024, 2000, elapsed) == round_half_away(expected)


@settings(max_examples=100, deadline=None)
@given(segments())
def test_velocity_matches_the_exact_derivative(
    segment: tuple[int, int, int, int, int, int],
) -> None:
    p0, p1, m0, m1, duration, elapsed = segment
    s = Fraction(elapsed, duration * 1000)
    d = p1 - p0
    ds = (
        d * (6 * s - 6 * s**2)
        + Fraction(m0 * duration, TANGENT_ONE) * (3 * s**2 - 4 * s + 1)
        + Fraction(m1 * duration, TANGENT_ONE) * (3 * s**2 - 2 * s)
    )
    expected = float(ds / Fraction(duration, 1000))
    assert hermite_velocity(*segment) == pytest.approx(expected, rel=1e-9, abs=1e-6)


def test_velocity_at_the_ends_equals_the_tangents() -> None:
    assert hermite_velocity(0, 500, 2048, -512, 100, 0) == pytest.approx(2048 * 1000 / 1024)
    assert hermite_velocity(0, 500, 2048, -512, 100, 100_000) == pytest.approx(-512 * 1000 / 1024)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("duration_ms", 0),
        ("duration_ms", 65536),
        ("position_counts", 2**31),
        ("position_counts", -(2**31) - 1),
        ("tangent_in", 32768),
        ("tangent_out", -32769),
        ("duration_ms", 1.5),
        ("tangent_in", True),
    ],
)
def test_keyframe_rejects_bad_fields(field: str, value: object) -> None:
    fields: dict[str, object] = {
        "duration_ms": 10,
        "position_counts": 0,
        "tangent_in": 0,
        "tangent_out": 0,
    }
    fields[field] = value
    with pytest.raises(ValueError, match=field) as raised:
        Keyframe(**fields)  # type: ignore[arg-type]
    assert repr(value) in str(raised.value)
    assert isinstance(raised.value, ProfileError)


def test_keyframe_accepts_the_extremes() -> None:
    Keyframe(1, -(2**31), TANGENT_MIN, TANGENT_MAX)
    Keyframe(65535, 2**31 - 1, TANGENT_MAX, TANGENT_MIN)


@pytest.mark.parametrize(
    ("args", "name"),
    [
        ((0, 0, 0, 0, 10, 10_001), "elapsed_us"),
        ((0, 0, 0, 0, 10, -1), "elapsed_us"),
        ((0, 0, 0, 0, 0, 0), "duration_ms"),
        ((0, 2**31, 0, 0, 10, 0), "p1"),
        ((0, 0, 40_000, 0, 10, 0), "m0_fixed"),
        ((0.5, 0, 0, 0, 10, 0), "p0"),
    ],
)
def test_segment_inputs_are_validated(args: tuple[int, ...], name: str) -> None:
    with pytest.raises(ProfileError, match=name):
        hermite_position(*args)
    with pytest.raises(ProfileError, match=name):
        hermite_velocity(*args)


def test_tangent_fixed_point_conversion() -> None:
    assert TANGENT_ONE == 1024
    assert tangent_to_fixed(1.0) == 1024
    assert tangent_to_fixed(-2.5) == -2560
    assert tangent_to_fixed(0.5 / 1024) == 1  # a tie rounds away from zero
    assert tangent_to_fixed(-0.5 / 1024) == -1
    assert tangent_to_fixed(0.4 / 1024) == 0
    assert tangent_to_fixed(100.0) == TANGENT_MAX
    assert tangent_to_fixed(-100.0) == TANGENT_MIN
    assert fixed_to_tangent(TANGENT_MAX) == pytest.approx(31.999, abs=1e-3)
    assert fixed_to_tangent(-1024) == -1.0
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(ProfileError, match="tangent"):
            tangent_to_fixed(bad)
    with pytest.raises(ProfileError, match="tangent"):
        fixed_to_tangent(40_000)


@settings(max_examples=200, deadline=None)
@given(st.integers(TANGENT_MIN, TANGENT_MAX))
def test_fixed_round_trips(fixed: int) -> None:
    assert tangent_to_fixed(fixed_to_tangent(fixed)) == fixed


def reference_ticks(start: int, keyframes: list[Keyframe], tick_us: int) -> list[int]:
    """The tick semantics written out literally, one ``hermite_position`` call per tick."""
    ends = list(itertools.accumulate(k.duration_ms * 1000 for k in keyframes))
    count = -(-ends[-1] // tick_us) + 1 if keyframes else 1
    values = []
    for k in range(count):
        t = k * tick_us
        for i, end in enumerate(ends):
            if t <= end:  # a tick on a boundary belongs to the earlier segment
                p0 = start if i == 0 else keyframes[i - 1].position_counts
                m0 = 0 if i == 0 else keyframes[i - 1].tangent_out
                keyframe = keyframes[i]
                values.append(
                    hermite_position(
                        p0,
                        keyframe.position_counts,
                        m0,
                        keyframe.tangent_in,
                        keyframe.duration_ms,
                        t - (end - keyframe.duration_ms * 1000),
                    )
                )
                break
        else:
            values.append(keyframes[-1].position_counts if keyframes else start)
    return values


def keyframe_lists(longest_ms: int) -> st.SearchStrategy[list[Keyframe]]:
    keyframe = st.builds(
        Keyframe,
        duration_ms=st.integers(1, longest_ms),
        position_counts=positions,
        tangent_in=tangents,
        tangent_out=tangents,
    )
    return st.lists(keyframe, min_size=0, max_size=8)


def assert_sampled_like_the_reference(start: int, keyframes: list[Keyframe], tick_us: int) -> None:
    """``sample_keyframes`` gives int64 values, as many as counted, equal to the reference."""
    sampled = sample_keyframes(start, keyframes, tick_us=tick_us)
    assert sampled.dtype == np.int64
    assert len(sampled) == keyframe_tick_count(keyframes, tick_us=tick_us)
    assert sampled.tolist() == reference_ticks(start, keyframes, tick_us)


@settings(max_examples=100, deadline=None)
@given(positions, keyframe_lists(200), st.sampled_from([250, 500, 1000, 1250, 4096]))
def test_sample_keyframes_equals_the_per_tick_reference(
    start: int, keyframes: list[Keyframe], tick_us: int
) -> None:
    assert_sampled_like_the_reference(start, keyframes, tick_us)


@settings(max_examples=40, deadline=None)
@given(positions, keyframe_lists(3), st.sampled_from([1, 7, 333]))
def test_sample_keyframes_fine_ticks_equal_the_reference(
    start: int, keyframes: list[Keyframe], tick_us: int
) -> None:
    assert_sampled_like_the_reference(start, keyframes, tick_us)


def test_sample_keyframes_ties_are_exact() -> None:
    # Half-count values at many ticks, with both signs: the float fast path must defer
    # to the exact evaluation.
    keyframes = [Keyframe(1, 1, 0, 0), Keyframe(1, -2, 0, 0), Keyframe(2, -(2**31), 0, 0)]
    sampled = sample_keyframes(0, keyframes, tick_us=125)
    assert sampled.tolist() == reference_ticks(0, keyframes, 125)
    assert sampled[4] == 1  # 0.5 -> 1
    assert sampled[12] == -1  # from 1 to -2 at s = 1/2: -0.5 -> -1


def test_boundary_ticks_take_the_keyframe_position() -> None:
    keyframes = [
        Keyframe(10, 1000, 5000, -3000),
        Keyframe(10, -500, 2000, 7000),
        Keyframe(5, 200, 0, 0),
    ]
    sampled = sample_keyframes(-100, keyframes, tick_us=1000)
    assert len(sampled) == 26
    assert sampled[0] == -100
    assert sampled[10] == 1000
    assert sampled[20] == -500
    assert sampled[25] == 200


def test_final_position_holds_and_no_spike_at_segment_ends() -> None:
    keyframes = [Keyframe(20, 2000, 100 * TANGENT_ONE // 10, 100 * TANGENT_ONE // 10)] * 1
    keyframes += [Keyframe(20, 4000, 100 * TANGENT_ONE // 10, 0)]
    sampled = sample_keyframes(0, keyframes, tick_us=100)
    steps = np.diff(sampled)
    # A smooth curve at about 100 counts/ms moves about 10 counts per 100 us tick, never a jump.
    assert np.abs(steps).max() <= 16
    assert sampled[-1] == 4000
    held = sample_keyframes(0, keyframes, tick_us=30_000)
    assert held.tolist()[-1] == 4000


def test_empty_keyframes_give_the_start() -> None:
    assert sample_keyframes(42, [], tick_us=1000).tolist() == [42]


@pytest.mark.parametrize(
    ("start", "keyframes", "tick_us", "name"),
    [
        (2**31, [], 1000, "start_position"),
        (0, [], 0, "tick_us"),
        (0, [(10, 0, 0, 0)], 1000, "keyframes"),
    ],
)
def test_sample_keyframes_rejects_bad_input(
    start: int, keyframes: list[object], tick_us: int, name: str
) -> None:
    with pytest.raises(ProfileError, match=name):
        sample_keyframes(start, keyframes, tick_us=tick_us)  # type: ignore[arg-type]
