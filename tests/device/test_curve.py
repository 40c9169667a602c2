"""Curve mode: the device plays Hermite keyframes tick by tick, exactly as the maths says."""

from __future__ import annotations

from fractions import Fraction

import pytest

from usbmotion.device import Device
from usbmotion.hermite import Keyframe, keyframe_tick_count, sample_keyframes

from .helpers import desired_positions, send

KEYFRAMES = (
    Keyframe(100, 500, 0, 1024),
    Keyframe(50, 800, 2048, -512),
    Keyframe(200, -300, 0, 0),
    Keyframe(33, -301, 31000, -32768),
    Keyframe(7, 2000, -5000, 100),
    Keyframe(1, 1999, 0, 0),
    Keyframe(120, -12345, 700, 700),
    Keyframe(65, -12000, -32768, 32767),
)


def _exact(p0: int, p1: int, m0: int, m1: int, duration_ms: int, elapsed_us: int) -> Fraction:
    """The cubic Hermite in exact arithmetic, tangents scaled by the duration."""
    s = Fraction(elapsed_us, duration_ms * 1000)
    scale = Fraction(duration_ms, 1024)
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    return h00 * p0 + h10 * m0 * scale + h01 * p1 + h11 * m1 * scale


def _exact_samples(start: int, keyframes: tuple[Keyframe, ...], tick_us: int, n: int) -> list[
    Fraction
]:
    values = []
    for k in range(n):
        t = k * tick_us
        p0, m0, begin = start, 0, 0
        for frame in keyframes:
            end = begin + frame.duration_ms * 1000
            if t <= end:
                values.append(
                    _exact(p0, frame.position_counts, m0, frame.tangent_in,
                           frame.duration_ms, t - begin)
                )
                break
            p0, m0, begin = frame.position_counts, frame.tangent_out, end
        else:
            values.append(Fraction(keyframes[-1].position_counts))
    return values


def _append(device: Device, keyframes: tuple[Keyframe, ...]) -> list[str]:
    return send(device, *(
        f"25 {k.duration_ms} {k.position_counts} {k.tangent_in} {k.tangent_out}"
        for k in keyframes
    ))


@pytest.mark.parametrize(("interval_dms", "start"), [(10, 0), (3, -12345), (1, 77)])
def test_every_tick_matches_the_exact_cubic_and_sample_keyframes(
    interval_dms: int, start: int
) -> None:
    device = Device()
    send(device, f"5 {interval_dms}", "7 3", f"23 {start}")
    assert _append(device, KEYFRAMES) == []
    send(device, "3 1")
    tick_us = interval_dms * 100
    n = keyframe_tick_count(KEYFRAMES, tick_us=tick_us) + 20
    played = desired_positions(device, n)
    sampled = list(sample_keyframes(start, KEYFRAMES, tick_us=tick_us))
    sampled += [KEYFRAMES[-1].position_counts] * (n - len(sampled))
    assert played == sampled
    for got, exact in zip(played, _exact_samples(start, KEYFRAMES, tick_us, n), strict=True):
        assert abs(got - exact) <= Fraction(1, 2)
    assert send(device, "27 -1") == ["CURVE_BUFFER 8"]


def test_keyframes_appended_while_playing_continue_the_same_curve() -> None:
    whole, parts = Device(), Device()
    for device in (whole, parts):
        send(device, "7 3")
    _append(whole, KEYFRAMES)
    _append(parts, KEYFRAMES[:3])
    for device in (whole, parts):
        send(device, "3 1")
    first = desired_positions(whole, 300)
    assert desired_positions(parts, 300) == first
    assert send(parts, "27 -1") == ["CURVE_BUFFER 7"], "two of three reached by tick 299"
    _append(parts, KEYFRAMES[3:])
    assert desired_positions(parts, 400) == desired_positions(whole, 400)


def test_a_full_buffer_refuses_and_loses_nothing() -> None:
    device = Device()
    send(device, "7 3")
    assert _append(device, KEYFRAMES) == []
    assert send(device, "27 -1") == ["CURVE_BUFFER 0"]
    assert _append(device, (Keyframe(10, 5, 0, 0),)) == ["E25"]
    assert device.keyframes() == KEYFRAMES
    send(device, "3 1")
    n = keyframe_tick_count(KEYFRAMES, tick_us=1000)
    assert desired_positions(device, n) == list(sample_keyframes(0, KEYFRAMES, tick_us=1000))
    assert device.keyframes() == ()


def test_running_dry_holds_and_the_next_keyframe_starts_a_new_curve() -> None:
    device = Device()
    send(device, "7 3", "3 1")
    _append(device, KEYFRAMES[:2])
    desired_positions(device, 200)
    assert device.state.desired == 800
    assert desired_positions(device, 50) == [800] * 50
    later = (Keyframe(40, 100, -1024, 0),)
    _append(device, later)
    expected = list(sample_keyframes(800, later, tick_us=1000)) + [100] * 4
    assert desired_positions(device, 45) == expected


def test_the_first_keyframe_is_reached_and_its_slot_freed_on_its_tick() -> None:
    device = Device()
    send(device, "7 3")
    _append(device, KEYFRAMES[:2])
    send(device, "3 1")
    desired_positions(device, 100)  # ticks 0..99: 0 to 99 ms
    assert send(device, "27 -1") == ["CURVE_BUFFER 6"]
    desired_positions(device, 1)  # tick 100: the keyframe at 100 ms
    assert device.state.desired == 500
    assert send(device, "27 -1") == ["CURVE_BUFFER 7"]


def test_clearing_keyframes_holds_the_position() -> None:
    device = Device()
    send(device, "7 3")
    _append(device, KEYFRAMES[:1])
    send(device, "3 1")
    desired_positions(device, 50)
    held = device.state.desired
    send(device, "26 0")
    assert desired_positions(device, 20) == [held] * 20
    assert send(device, "27 -1") == ["CURVE_BUFFER 8"]


def test_keyframes_need_curve_mode_and_curve_mode_plays_only_when_enabled() -> None:
    device = Device()
    assert send(device, "25 10 5 0 0")[0].startswith("ERR 25 ")
    send(device, "7 3")
    _append(device, KEYFRAMES[:1])
    device.run(500)
    assert device.state.desired == 0
    assert device.keyframes() == KEYFRAMES[:1]


def test_curve_mode_follows_the_curve_physically() -> None:
    device = Device()
    send(device, "7 3", "25 500 1500 0 0", "3 1")
    worst = 0
    for expected in sample_keyframes(0, (Keyframe(500, 1500, 0, 0),), tick_us=1000)[1:]:
        device.run(1)
        worst = max(worst, abs(int(expected) - device.state.actual))
    device.run(100)
    assert abs(device.state.actual - 1500) <= 2
    assert worst < 60
