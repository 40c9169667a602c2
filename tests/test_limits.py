"""Soft limits (``motion.limits.check_travel``): a path inside the travel passes, one that
leaves it is refused naming the line, the axis and the limit; a machine standing just
outside a travel end (within the settled band) is at that end, and from anywhere outside a
path may come back but never go farther out."""

from __future__ import annotations

import numpy as np
import pytest

from usbmotion.errors import PlanningError, SoftLimitError
from usbmotion.motion.limits import SETTLED_BAND_COUNTS, check_travel, settled_band_mm
from usbmotion.session.report import SETTLE_COUNTS

TRAVEL = [(0.0, 200.0), (-100.0, 0.0)]
"""X 0..200 homing down, Z -100..0 homing up (the default machine's)."""
AXES = ("X", "Z")
BAND = settled_band_mm([240.0, 240.0])
COUNT = 1 / 240


def check(*points: tuple[float, float], band: tuple[float, ...] | None = BAND) -> None:
    """Soft limits on the path through ``points`` (X, Z), segment k on line k + 2."""
    lines = np.arange(2, len(points) + 1)
    check_travel(np.array(points), lines, TRAVEL, axes=AXES, band_mm=band)


def refused(*points: tuple[float, float]) -> SoftLimitError:
    with pytest.raises(SoftLimitError) as caught:
        check(*points)
    return caught.value


def test_the_band_is_twice_the_settle_band_in_counts() -> None:
    assert SETTLED_BAND_COUNTS == 2 * SETTLE_COUNTS == 4
    assert settled_band_mm([240.0, 100.0]) == (4 / 240, 0.04)


def test_a_path_inside_passes_and_one_that_leaves_is_refused_naming_the_limit() -> None:
    check((0.0, 0.0), (200.0, -100.0), (0.0, 0.0))
    error = refused((0.0, 0.0), (10.0, -5.0), (10.0, 0.5))
    assert (error.line, error.axis, error.limit_mm) == (3, "Z", 0.0)
    assert error.coordinate_mm == pytest.approx(0.5)
    assert str(error) == ("line 3: Z would reach 0.500 mm, beyond the upper end 0 mm of axis"
                          " Z's travel_mm [-100, 0]; nothing was moved")
    error = refused((0.0, 0.0), (-0.001, 0.0))
    assert (error.line, error.axis, error.limit_mm) == (2, "X", 0.0)
    assert "beyond the lower end 0 mm" in str(error)


def test_a_start_settled_within_the_band_outside_an_end_counts_as_at_that_end() -> None:
    out = 2 * COUNT  # where a servo settles, then disabled, after G53 G0 Z0
    check((10.0, out), (50.0, out), (50.0, -20.0))  # X moves first, Z where it stands
    check((10.0, out), (10.0, 0.0), (50.0, 0.0))  # back onto the end, then along it
    check((-out, out), (5.0, -5.0))  # outside both ends at once
    error = refused((10.0, out), (10.0, out + COUNT))
    assert (error.line, error.axis, error.limit_mm) == (2, "Z", 0.0)
    assert "farther out than the 0.008 mm it started from" in str(error)
    error = refused((10.0, out), (10.0, 0.0), (20.0, out))
    assert (error.line, error.axis) == (3, "Z"), "once back on the end, the end is the limit"
    strict = pytest.raises(SoftLimitError, match="line 2: the machine stands outside")
    with strict:
        check((10.0, out), (50.0, out), band=None)


def test_from_beyond_the_band_only_a_path_that_comes_back_first_is_taken() -> None:
    out = 0.5  # a limit fault, a hand push, a shorter travel
    check((10.0, out), (10.0, -5.0), (50.0, -5.0))
    check((10.0, out), (20.0, 0.2), (30.0, 0.1), (30.0, -10.0))  # back step by step
    error = refused((10.0, out), (50.0, out), (50.0, -5.0))
    assert (error.line, error.axis, error.limit_mm) == (2, "Z", 0.0)
    assert error.coordinate_mm == pytest.approx(out)
    assert str(error) == (
        "line 2: the machine stands outside its travel (Z 0.500 mm, 0.500 mm above the upper"
        " end 0 mm of axis Z's travel_mm [-100, 0], more than the 0.0167 mm a settled servo"
        " may stand beyond it): from there a program's first move must bring an axis that"
        " stands outside back toward its travel (jog it back, or home the machine); nothing"
        " was moved")
    error = refused((10.0, out), (10.0, out + 0.1))
    assert (error.line, error.axis) == (2, "Z")
    error = refused((10.0, out), (10.0, 0.2), (10.0, 0.3))
    assert (error.line, error.axis, error.limit_mm) == (3, "Z", 0.0), "back, then out again"


def test_with_two_axes_outside_either_may_come_back_first() -> None:
    check((-0.5, 0.5), (-0.5, -10.0), (10.0, -10.0))
    check((-0.5, 0.5), (5.0, 0.5), (5.0, -1.0))
    error = refused((-0.5, 0.5), (-0.6, -10.0))
    assert (error.line, error.axis, error.limit_mm) == (2, "X", 0.0)


def test_a_plan_with_no_segment_moves_nothing_and_passes() -> None:
    check((10.0, 0.5))


@pytest.mark.parametrize("band", [(0.01,), (0.01, -1.0), (0.01, float("nan"))])
def test_a_band_that_does_not_fit_the_axes_is_refused(band: tuple[float, ...]) -> None:
    with pytest.raises(PlanningError, match="band_mm"):
        check((0.0, 0.0), (1.0, -1.0), band=band)
