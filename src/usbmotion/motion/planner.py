"""Look-ahead motion planning: moves in, timed trapezoidal segments out.

``plan_moves`` turns the interpreter's moves (``motion.moves``) into a ``Plan``:

1. Arcs are cut into chords whose sagitta is at most ``arc_tolerance_mm``:
   ``theta_per_chord = 2 * acos(1 - tol / r)`` with ``r`` the larger of the start and end
   radii (at most 120 degrees per chord, and no chord shorter than ``min_segment_mm``). The
   sweep follows LinuxCNC: ``rotation`` P > 0 turns counter-clockwise about the
   plane normal (right-hand rule), P < 0 clockwise, ``|P| - 1`` extra full turns, a start and
   end that coincide in the plane (within 1e-8 mm) make a full turn. When the start and end
   radii differ the path is LinuxCNC's slight spiral (radius linear in the angle); a helix
   spreads its travel along the normal evenly over the angle.
2. Every segment gets a nominal speed and an acceleration such that NO axis exceeds its own
   limits: ``v = min(feed, min_k v_k / |u_k|)`` and ``a = min_k a_k / |u_k|`` for the unit
   direction ``u``. Rapids (G0) take the fastest speed the axes allow along their direction,
   feed moves ``min(F / 60, that)``.
3. Junction speeds follow the junction-deviation model of grbl and Klipper:
   ``v^2 = a_j * delta * sin(theta/2) / (1 - sin(theta/2))`` where ``theta`` is the angle
   between the two directions taken at the corner (``pi`` for a straight continuation, 0 for
   a full reversal) and ``a_j`` the smallest of the two moves' accelerations and of the
   acceleration the axis limits allow along the junction vector ``u2 - u1`` (grbl's
   junction acceleration; taking the smallest keeps every axis within its limit both at the
   middle of the turn and along either move), capped by both moves' nominal speeds and by the
   centripetal limit ``a_j * (L_min / 2) * tan(theta/2)`` of the circle tangent to the
   shorter of the two segments at its midpoint (Klipper's guard for arcs cut into chords).
   Dwells and the start and end of the program are junctions at speed 0.
4. A backward pass lets every segment decelerate into the next junction and a forward pass
   limits what it can reach from the previous one. Both passes are vectorised: with squared
   speeds ``w`` and ``d_i = 2 a_i L_i``, ``w_i = min(c_i, w_{i+1} + d_i)`` is a cumulative
   minimum of ``c_j + R_j`` where ``R`` is the prefix sum of ``d`` (and likewise forward).
5. Each segment gets a trapezoidal (or triangular) velocity profile.

Speed: the only per-move Python work is reading the moves (and the arc geometry); chord
generation, junctions, passes and profiles are numpy work over all segments, in blocks that
stay in cache and write straight into the plan's columns (one sweep forward for the geometry,
the junctions and the prefix sums, the backward pass, one sweep forward for the forward pass,
the profiles and the start times). Planning is bounded by the Python loop for line-heavy
programs and by the number of chords for arc-heavy ones, of which writing the columns (about
160 bytes a segment with three axes, all of it fresh memory) is a fair part (see
``benchmarks/planner_speed.py``).

The ``Plan`` holds its segments as columns (numpy arrays, read-only); ``Plan.segments``
materialises ``PlannedSegment`` objects on first use.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum
from functools import cached_property

import numpy as np
import numpy.typing as npt

from usbmotion.errors import PlanningError
from usbmotion.motion.limits import AxisLimits, PlannerConfig
from usbmotion.motion.moves import (
    AXIS_ORDER,
    DEFAULT_AXES,
    Arc,
    Dwell,
    Linear,
    Move,
    Plane,
    Point,
    Rapid,
)

__all__ = [
    "AxisLimits",
    "Plan",
    "PlannedSegment",
    "PlannerConfig",
    "SegmentKind",
    "exact_cumsum",
    "plan_moves",
]

FloatArray = npt.NDArray[np.float64]
_TWO_PI = 2.0 * math.pi
_FULL_CIRCLE_FUZZ_MM = 1e-8
_SPLIT_SCALE = 2.0**20
_SPLIT_SHIFT = 2.0**32
_BLOCK = 32768

_ArcRow = tuple[int, int, float, float, float, float, float, float, float, float]
"""An arc cut into chords: first segment, chords, centre (first, second axis), start radius,
radius change, start angle, sweep, start and travel along the normal."""
_ARC_ROW_SIZE = 10


class SegmentKind(IntEnum):
    """What a planned segment came from."""

    RAPID = 0
    LINEAR = 1
    ARC = 2
    DWELL = 3


@dataclass(frozen=True, slots=True)
class PlannedSegment:
    """One straight, timed segment: accelerate, cruise, decelerate (or a dwell).

    Fields:
        start, end: positions in mm (equal for a dwell).
        length_mm: straight-line length.
        v_entry_mm_s, v_cruise_mm_s, v_exit_mm_s: path speed at entry, cruise, exit.
        accel_mm_s2: path acceleration of the ramps (0 for a dwell).
        t_accel_s, t_cruise_s, t_decel_s: phase durations (a dwell is all cruise, at 0 speed).
        line: G-code line of the move the segment belongs to.
        kind: rapid, linear, arc chord or dwell.
        start_time_s: time of the segment's start from the plan's start.
    """

    start: Point
    end: Point
    length_mm: float
    v_entry_mm_s: float
    v_cruise_mm_s: float
    v_exit_mm_s: float
    accel_mm_s2: float
    t_accel_s: float
    t_cruise_s: float
    t_decel_s: float
    line: int
    kind: SegmentKind
    start_time_s: float

    @property
    def duration_s(self) -> float:
        """Total time of the segment."""
        return self.t_accel_s + self.t_cruise_s + self.t_decel_s

    def distance_at(self, t_s: float) -> float:
        """Distance travelled along the segment ``t_s`` seconds after its start (clamped)."""
        if self.kind is SegmentKind.DWELL or t_s <= 0.0:
            return 0.0
        a = self.accel_mm_s2
        if t_s < self.t_accel_s:
            return self.v_entry_mm_s * t_s + 0.5 * a * t_s * t_s
        cruise_end = self.t_accel_s + self.t_cruise_s
        if t_s < cruise_end:
            s_accel = self.v_entry_mm_s * self.t_accel_s + 0.5 * a * self.t_accel_s**2
            return s_accel + self.v_cruise_mm_s * (t_s - self.t_accel_s)
        remaining = max(0.0, self.duration_s - t_s)
        return self.length_mm - (self.v_exit_mm_s * remaining + 0.5 * a * remaining * remaining)


def exact_cumsum(values: FloatArray) -> tuple[FloatArray, float]:
    """Start offsets (exclusive prefix sums) and the total of non-negative ``values``.

    Each value is split into a multiple of 2**-20 (whose partial sums are exact in float64
    up to 2**33) and a remainder below 2**-21; the sums of the two parts are added once, so
    each offset is within a few ulps of the exact sum, with no drift over millions of terms.
    """
    if values.size and float(values.max()) < _SPLIT_SHIFT:
        high = (values + _SPLIT_SHIFT) - _SPLIT_SHIFT  # rounds to the 2**-20 grid
    else:
        high = np.round(values * _SPLIT_SCALE) / _SPLIT_SCALE
    low = values - high
    sums = np.zeros(values.shape[0] + 1, dtype=np.float64)
    np.cumsum(high, out=sums[1:])
    sums[1:] += np.cumsum(low)
    return sums[:-1], float(sums[-1])


def _readonly(array: npt.NDArray[np.generic]) -> npt.NDArray[np.generic]:
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class Plan:
    """A planned program: segments as read-only columns, in time order.

    Segment ``i`` runs from ``vertices_mm[i]`` to ``vertices_mm[i + 1]``. Times are seconds,
    lengths mm, speeds mm/s, accelerations mm/s^2.

    Fields:
        vertices_mm: (n + 1, k) positions, one column per axis of ``axes``; row 0 is the
            start, the last row the end.
        unit: (n, k) unit directions (zero rows for dwells).
        kind: (n,) ``SegmentKind`` codes.
        line: (n,) G-code lines.
        length_mm, v_entry_mm_s, v_cruise_mm_s, v_exit_mm_s, accel_mm_s2, t_accel_s,
            t_cruise_s, t_decel_s, start_time_s: (n,) per-segment values.
        v_junction_max_mm_s: (n + 1,) the speed limit at each vertex before the passes
            (junction deviation, centripetal and nominal caps; 0 at stops): why a corner is
            as slow as it is.
        feed_mm_s: (n,) the path speed each segment asked for: the feed for feed moves,
            ``inf`` for rapids (the axes' own limits), 0 for dwells (re-planning the rest of
            a program at another speed starts from it: ``motion.replanning``).
        duration_s: total time of the program.
        move_count: how many input moves were planned.
        axes: the letters of the columns (``"XYZ"``, ``"XY"``, ...).
    """

    vertices_mm: FloatArray
    unit: FloatArray
    kind: npt.NDArray[np.int8]
    line: npt.NDArray[np.int64]
    length_mm: FloatArray
    v_entry_mm_s: FloatArray
    v_cruise_mm_s: FloatArray
    v_exit_mm_s: FloatArray
    accel_mm_s2: FloatArray
    t_accel_s: FloatArray
    t_cruise_s: FloatArray
    t_decel_s: FloatArray
    start_time_s: FloatArray
    v_junction_max_mm_s: FloatArray
    duration_s: float
    move_count: int
    feed_mm_s: FloatArray
    axes: str = DEFAULT_AXES

    def __len__(self) -> int:
        return int(self.length_mm.shape[0])

    @property
    def start(self) -> Point:
        """Where the program starts, mm."""
        return tuple(self.vertices_mm[0].tolist())

    @property
    def end(self) -> Point:
        """Where the program ends, mm."""
        return tuple(self.vertices_mm[-1].tolist())

    @property
    def segment_duration_s(self) -> FloatArray:
        """(n,) duration of each segment."""
        return self.t_accel_s + self.t_cruise_s + self.t_decel_s

    @cached_property
    def segments(self) -> tuple[PlannedSegment, ...]:
        """The segments as ``PlannedSegment`` objects (built on first use)."""
        vertices = [tuple(row) for row in self.vertices_mm.tolist()]
        kinds = list(SegmentKind)
        rows = zip(
            vertices[:-1],
            vertices[1:],
            self.length_mm.tolist(),
            self.v_entry_mm_s.tolist(),
            self.v_cruise_mm_s.tolist(),
            self.v_exit_mm_s.tolist(),
            self.accel_mm_s2.tolist(),
            self.t_accel_s.tolist(),
            self.t_cruise_s.tolist(),
            self.t_decel_s.tolist(),
            self.line.tolist(),
            [kinds[kind] for kind in self.kind.tolist()],
            self.start_time_s.tolist(),
            strict=True,
        )
        return tuple(PlannedSegment(*row) for row in rows)


def _check_point(name: str, point: object, axes: str) -> Point:
    if not isinstance(point, tuple) or len(point) != len(axes):
        raise PlanningError(f"{name} {point!r} is not a tuple of {len(axes)} coordinates in"
                            f" mm, one per axis {', '.join(axes)}")
    for value in point:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise PlanningError(f"{name} {point!r} holds {value!r}, which is not a number")
        if not math.isfinite(value):
            raise PlanningError(f"{name} {point!r} holds {value!r}; coordinates must be finite")
    return tuple(float(value) for value in point)


def _check_axes(axes: object) -> str:
    if (not isinstance(axes, str) or not axes or len(set(axes)) != len(axes)
            or axes != "".join(a for a in AXIS_ORDER if a in axes)):
        raise PlanningError(f"axes {axes!r} must be one to nine of {AXIS_ORDER!r}, in that"
                            " order, each once")
    return axes


def _check_limits(limits: Sequence[AxisLimits], axes: str) -> tuple[AxisLimits, ...]:
    if isinstance(limits, (str, bytes)) or len(limits) != len(axes):
        raise PlanningError(
            f"limits {limits!r} must be {len(axes)} AxisLimits, one per axis {', '.join(axes)}"
        )
    for name, axis in zip(axes, limits, strict=True):
        if not isinstance(axis, AxisLimits):
            raise PlanningError(f"limits for axis {name} {axis!r} is not an AxisLimits")
    return tuple(limits)


def _as_float(value: object) -> float:
    """A feed as a float, or NaN when it is not a number (reported with its line)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return math.nan
    return float(value)


def _check_join(move: Move, where: Point, expected: Point, tolerance: float) -> None:
    """Refuse a move starting at ``where`` farther than ``tolerance`` from ``expected``."""
    if len(where) != len(expected):
        raise PlanningError(f"line {move.line}: position {where!r} has {len(where)}"
                            f" coordinates; the program's axes have {len(expected)}")
    if all(abs(a - b) <= tolerance for a, b in zip(where, expected, strict=True)):
        return
    if not all(math.isfinite(value) for value in (*where, *expected)):
        raise PlanningError(
            f"line {move.line}: position {where!r} (after {expected!r}) is not finite"
        )
    raise PlanningError(
        f"line {move.line}: move starts at {where!r} but the previous move ended at "
        f"{expected!r}; moves must join within {tolerance!r} mm"
    )


def _arc_sweep(move: Arc, theta0: float, theta1: float, chord_mm: float) -> float:
    rotation = move.rotation
    if isinstance(rotation, bool) or not isinstance(rotation, int) or rotation == 0:
        raise PlanningError(
            f"line {move.line}: arc rotation {rotation!r} must be a non-zero integer "
            "(-P for G2, +P for G3)"
        )
    full = chord_mm < _FULL_CIRCLE_FUZZ_MM
    if rotation > 0:
        sweep = _TWO_PI if full else (theta1 - theta0) % _TWO_PI
        return sweep + _TWO_PI * (rotation - 1)
    sweep = _TWO_PI if full else (theta0 - theta1) % _TWO_PI
    return -(sweep + _TWO_PI * (-rotation - 1))


def _squared_gap(end: Point, kept: Point) -> float:
    """The squared distance from ``kept`` to ``end``, added axis by axis (a move whose end is
    less than ``min_segment_mm`` from the last end kept is dropped)."""
    return sum([(a - b) * (a - b) for a, b in zip(end, kept, strict=True)])


def _wrong_end(move: Move, end: Point, axes: str) -> PlanningError:
    return PlanningError(f"line {move.line}: end {end!r} has {len(end)} coordinates; the"
                         f" program's axes have {len(axes)}")


def plan_moves(
    moves: Sequence[Move],
    limits: Sequence[AxisLimits],
    config: PlannerConfig,
    *,
    start: Point | None = None,
    axes: str = DEFAULT_AXES,
) -> Plan:
    """Plan ``moves`` into timed segments within every axis's limits.

    Parameters:
        moves: the program's moves in order; each must start where the previous one ended
            (the first at ``start``), within ``config.continuity_tolerance_mm``.
        limits: ``AxisLimits`` for each axis of ``axes``.
        config: arc tolerance, junction deviation, minimum segment.
        start: the machine's position before the first move, mm (zeros when not given).
        axes: the letters of the moves' coordinates (X, Y, Z by default; one to nine of
            X Y Z A B C U V W, A B C in degrees).

    Returns a ``Plan`` that starts and ends at rest.

    Raises:
        PlanningError: bad limits, a non-finite coordinate, a feed that is not positive and
            finite, a negative or non-finite dwell, a zero-radius arc, a zero rotation, a gap
            between moves, an end with the wrong number of coordinates, or an object that is
            not a move; the message names the G-code line and the value.
    """
    axes = _check_axes(axes)
    axis_limits = _check_limits(limits, axes)
    if not isinstance(config, PlannerConfig):
        raise PlanningError(f"config {config!r} is not a PlannerConfig")
    origin = _check_point("start", (0.0,) * len(axes) if start is None else start, axes)

    tolerance = config.continuity_tolerance_mm
    min_segment = config.min_segment_mm
    min_segment_sq = min_segment * min_segment
    arc_tolerance = config.arc_tolerance_mm
    axis_count = len(axes)
    # A move longer than near_mm (math.dist) moves along some axis by more than
    # near_mm / sqrt(axis_count) >= 2 * min_segment, so its squared length added axis by axis
    # is more than min_segment_sq however either rounds: only nearer ends need that sum.
    near_mm = 2.0 * axis_count * min_segment

    # One entry per kept move (``dwell_s``: per dwell); ``end_coords`` holds the ends'
    # coordinates one after another, ``arc_values`` an ``_ArcRow`` per arc cut into chords.
    item_kind: list[int] = []
    item_line: list[int] = []
    item_feed: list[object] = []
    item_count: list[int] = []
    dwell_s: list[float] = []
    end_coords: list[float] = []
    arc_values: list[float] = []
    arc_planes: list[tuple[int, int, int]] = []
    add_kind = item_kind.append
    add_line = item_line.append
    add_feed = item_feed.append
    add_count = item_count.append
    add_end = end_coords.extend

    kept = origin
    expected = origin
    total = 0
    inf = math.inf
    dist = math.dist
    isfinite = math.isfinite
    hypot = math.hypot
    atan2 = math.atan2
    acos = math.acos
    ceil = math.ceil
    plane_axes: dict[object, tuple[int, int, int]] = {}
    for plane in Plane:
        if plane.letters[0] in axes and plane.letters[1] in axes:
            plane_axes[plane] = plane.indices(axes)
    # Planes are looked up by identity first: an Enum member hashes in Python.
    plane_axes_by_id = {id(plane): indices for plane, indices in plane_axes.items()}

    for move in moves:
        cls = type(move)
        if cls is Linear or cls is Rapid:
            line_move: Linear | Rapid = move  # type: ignore[assignment]
            s = line_move.start
            if s != expected:
                _check_join(move, s, expected, tolerance)
            e = line_move.end
            expected = e
            try:
                near = dist(e, kept) <= near_mm
            except ValueError:
                raise _wrong_end(move, e, axes) from None
            if near and _squared_gap(e, kept) < min_segment_sq:
                continue
            if cls is Linear:
                add_kind(1)
                add_feed(line_move.feed_mm_min)  # type: ignore[union-attr]
            else:
                add_kind(0)
                add_feed(inf)
            count = 1
        elif cls is Arc:
            arc: Arc = move  # type: ignore[assignment]
            s = arc.start
            if s != expected:
                _check_join(move, s, expected, tolerance)
            e = arc.end
            expected = e
            indices = plane_axes_by_id.get(id(arc.plane)) or plane_axes.get(arc.plane)
            if indices is None:
                raise PlanningError(f"line {arc.line}: arc plane {arc.plane!r} is not a Plane"
                                    f" of two of the axes {', '.join(axes)}")
            a1, a2, an = indices
            c = arc.centre
            cu = c[a1]
            cv = c[a2]
            su = s[a1] - cu
            sv = s[a2] - cv
            eu = e[a1] - cu
            ev = e[a2] - cv
            r0 = hypot(su, sv)
            r1 = hypot(eu, ev)
            if not (r0 > min_segment and r1 > min_segment and isfinite(r0 + r1)):
                raise PlanningError(
                    f"line {arc.line}: arc from {s!r} to {e!r} about centre {c!r} has "
                    f"radius {r0!r} at the start and {r1!r} at the end; both must be "
                    f"finite and larger than {min_segment!r} mm"
                )
            theta0 = atan2(sv, su)
            sweep = _arc_sweep(arc, theta0, atan2(ev, eu), hypot(eu - su, ev - sv))
            normal_travel = e[an] - s[an] if an >= 0 else 0.0
            turn = sweep if sweep > 0.0 else -sweep
            r_min = r0 if r0 < r1 else r1
            r_max = r1 if r0 < r1 else r0
            planar = turn * 0.5 * (r0 + r1)
            if planar * planar + normal_travel * normal_travel < min_segment_sq:
                continue
            if len(e) != axis_count:
                raise _wrong_end(move, e, axes)
            cosine = 1.0 - arc_tolerance / r_max
            chords = ceil(turn / (2.0 * acos(cosine if cosine > 0.5 else 0.5)))
            shortest = int(0.8 * hypot(turn * r_min, normal_travel) / min_segment)
            count = chords if chords <= shortest else shortest
            if count > 1:
                arc_values.extend(
                    (
                        total,
                        count,
                        cu,
                        cv,
                        r0,
                        r1 - r0,
                        theta0,
                        sweep,
                        s[an] if an >= 0 else 0.0,
                        normal_travel,
                    )
                )
                arc_planes.append(indices)
            else:
                count = 1
            add_kind(2)
            add_feed(arc.feed_mm_min)
        elif cls is Dwell:
            dwell: Dwell = move  # type: ignore[assignment]
            p = dwell.position
            if p != expected:
                _check_join(move, p, expected, tolerance)
            seconds = dwell.seconds
            if isinstance(seconds, bool) or not isinstance(seconds, (int, float)):
                raise PlanningError(f"line {dwell.line}: dwell {seconds!r} s is not a number")
            if not (math.isfinite(seconds) and seconds >= 0.0):
                raise PlanningError(
                    f"line {dwell.line}: dwell {seconds!r} s must be finite and >= 0"
                )
            add_kind(3)
            add_feed(0.0)
            dwell_s.append(float(seconds))
            count = 1
            e = kept
        else:
            raise PlanningError(f"moves holds {move!r}, which is not a Rapid, Linear, Arc or Dwell")
        add_line(move.line)
        add_count(count)
        add_end(e)
        kept = e
        total += count

    items = _Items(
        kind=np.array(item_kind, dtype=np.int8),
        line=np.array(item_line, dtype=np.int64),
        feed=item_feed,
        count=np.array(item_count, dtype=np.int64),
        ends=np.fromiter(end_coords, np.float64, len(end_coords)).reshape(-1, axis_count),
        dwell_s=np.array(dwell_s, dtype=np.float64),
        arc_rows=np.fromiter(arc_values, np.float64, len(arc_values)).reshape(-1, _ARC_ROW_SIZE),
        arc_planes=arc_planes,
    )
    return _plan_items(
        items, origin=origin, limits=axis_limits, config=config, move_count=len(moves), axes=axes
    )


@dataclass(frozen=True, eq=False)
class _Items:
    """The moves a plan keeps (``m`` of them, zero-length ones dropped) as columns.

    Fields:
        kind: (m,) ``SegmentKind`` codes.
        line: (m,) G-code lines.
        feed: the feeds as given, mm/min (``inf`` for rapids, 0 for dwells): checked, and
            quoted in the message when bad.
        count: (m,) segments of each (an arc's chords, 1 otherwise).
        ends: (m, k) where each ends, mm (a dwell: where it holds).
        dwell_s: (d,) the dwells' seconds, in order.
        arc_rows: (a, 10) an ``_ArcRow`` per arc cut into more than one chord.
        arc_planes: the (first, second, normal) axis indices of each arc row.
    """

    kind: npt.NDArray[np.int8]
    line: npt.NDArray[np.int64]
    feed: Sequence[object]
    count: npt.NDArray[np.int64]
    ends: FloatArray
    dwell_s: FloatArray
    arc_rows: FloatArray
    arc_planes: Sequence[tuple[int, int, int]]


def _plan_columns(
    *,
    origin: Point,
    limits: tuple[AxisLimits, ...],
    config: PlannerConfig,
    move_count: int,
    total: int,
    item_kind: list[int],
    item_line: list[int],
    item_feed: list[float],
    item_dwell: list[float],
    item_count: list[int],
    ends: list[Point],
    arc_rows: list[_ArcRow],
    arc_planes: list[tuple[int, int, int]],
    axes: str,
    entry_speed_mm_s: float = 0.0,
) -> Plan:
    """``_plan_items`` of moves given as lists, one entry per move, ``item_dwell`` 0 but
    for dwells (``motion.replanning``'s way in); ``total``, the sum of ``item_count``, is
    not needed."""
    kind = np.array(item_kind, dtype=np.int8)
    items = _Items(
        kind=kind,
        line=np.array(item_line, dtype=np.int64),
        feed=item_feed,
        count=np.array(item_count, dtype=np.int64),
        ends=np.array(ends, dtype=np.float64).reshape(-1, len(axes)),
        dwell_s=np.array(item_dwell, dtype=np.float64)[kind == SegmentKind.DWELL],
        arc_rows=np.array(arc_rows, dtype=np.float64).reshape(-1, _ARC_ROW_SIZE),
        arc_planes=arc_planes,
    )
    return _plan_items(items, origin=origin, limits=limits, config=config,
                       move_count=move_count, axes=axes, entry_speed_mm_s=entry_speed_mm_s)


def _feeds(feed: Sequence[object]) -> FloatArray:
    """The feeds as floats (NaN for one that is not a number)."""
    try:
        return np.fromiter(feed, np.float64, len(feed))
    except (TypeError, ValueError):
        return np.array([_as_float(value) for value in feed], dtype=np.float64)


def _plan_items(
    items: _Items,
    *,
    origin: Point,
    limits: tuple[AxisLimits, ...],
    config: PlannerConfig,
    move_count: int,
    axes: str,
    entry_speed_mm_s: float = 0.0,
) -> Plan:
    """Plan the kept moves ``items``: steps 1 to 5 of the module docstring, vectorised.

    Elementwise work runs in blocks of ``_BLOCK`` segments that stay in cache, written
    straight into the plan's columns, in three sweeps: geometry, junction limits and the
    prefix sums of ``2 a L`` going forward (``_segments``), the backward pass from the end
    (``_backward_pass``), then the forward pass with the profiles and the start times
    (``_forward_pass``).
    """
    kinds_item = items.kind
    lines_item = items.line
    counts = items.count
    feed_item = _feeds(items.feed)
    feed_moves = (kinds_item == SegmentKind.LINEAR) | (kinds_item == SegmentKind.ARC)
    bad_feed = feed_moves & ~(np.isfinite(feed_item) & (feed_item > 0.0))
    if bad_feed.any():
        index = int(np.flatnonzero(bad_feed)[0])
        raise PlanningError(
            f"line {int(lines_item[index])}: feed {items.feed[index]!r} mm/min must "
            "be positive and finite"
        )
    speed_item = feed_item / 60.0

    # Columns: vertices[axis, i]; the Plan exposes the (n + 1, k) transpose.
    last_vertex = np.cumsum(counts)
    total = int(last_vertex[-1]) if last_vertex.size else 0
    vertices = np.empty((len(axes), total + 1), dtype=np.float64)
    vertices[:, 0] = origin
    for row, ends in zip(vertices, items.ends.T, strict=True):
        row[last_vertex] = ends  # a row's own index is the quicker scatter
    if items.arc_rows.size:
        _fill_arc_vertices(vertices, items.arc_rows, items.arc_planes)

    kind = np.repeat(kinds_item, counts)
    line = np.repeat(lines_item, counts)
    speed = np.repeat(speed_item, counts)
    dwells = last_vertex[kinds_item == SegmentKind.DWELL] - 1
    segments = _segments(vertices, speed, dwells, limits, config)
    if not np.isfinite(segments.length).all():  # so is every vertex when all lengths are
        _check_finite(vertices, last_vertex, lines_item)
    junction_sq = segments.junction_sq
    junction_sq[0] = entry_speed_mm_s * entry_speed_mm_s
    junction_sq[dwells] = 0.0
    junction_sq[dwells + 1] = 0.0
    v_junction_max = np.sqrt(junction_sq)
    _backward_pass(junction_sq, segments.prefix)
    profile = _forward_pass(segments, dwells, items.dwell_s)
    return Plan(
        vertices_mm=_readonly(vertices.T),  # type: ignore[arg-type]
        unit=_readonly(segments.unit.T),  # type: ignore[arg-type]
        kind=_readonly(kind),  # type: ignore[arg-type]
        line=_readonly(line),  # type: ignore[arg-type]
        length_mm=_readonly(segments.length),  # type: ignore[arg-type]
        v_entry_mm_s=_readonly(profile.v_at_vertex[:-1]),  # type: ignore[arg-type]
        v_cruise_mm_s=_readonly(profile.v_cruise),  # type: ignore[arg-type]
        v_exit_mm_s=_readonly(profile.v_at_vertex[1:]),  # type: ignore[arg-type]
        accel_mm_s2=_readonly(segments.accel),  # type: ignore[arg-type]
        t_accel_s=_readonly(profile.t_accel),  # type: ignore[arg-type]
        t_cruise_s=_readonly(profile.t_cruise),  # type: ignore[arg-type]
        t_decel_s=_readonly(profile.t_decel),  # type: ignore[arg-type]
        start_time_s=_readonly(profile.start_time),  # type: ignore[arg-type]
        v_junction_max_mm_s=_readonly(v_junction_max),  # type: ignore[arg-type]
        duration_s=profile.duration_s,
        move_count=move_count,
        feed_mm_s=_readonly(speed),  # type: ignore[arg-type]
        axes=axes,
    )


def _check_finite(
    vertices: FloatArray, last_vertex: npt.NDArray[np.int64], lines_item: npt.NDArray[np.int64]
) -> None:
    """Refuse the first vertex that is not finite, naming the line of its move."""
    if not np.isfinite(vertices).all():
        bad_vertex = int(np.flatnonzero(~np.isfinite(vertices).all(axis=0))[0])
        index = int(np.searchsorted(last_vertex, bad_vertex, side="left"))
        raise PlanningError(
            f"line {int(lines_item[index])}: position "
            f"{tuple(vertices[:, bad_vertex].tolist())!r} is not finite"
        )


@dataclass(frozen=True, eq=False)
class _Segments:
    """What the forward sweep finds for n segments (``_segments``).

    Fields:
        unit: (k, n) unit directions (zero for dwells).
        length: (n,) lengths, mm.
        v_nominal_sq: (n,) squared nominal speeds (0 for dwells).
        accel: (n,) accelerations (0 for dwells).
        junction_sq: (n + 1,) squared speed limits at the vertices (0 at both ends).
        prefix: (n + 1,) sums of ``2 a L`` over the segments before each vertex.
    """

    unit: FloatArray
    length: FloatArray
    v_nominal_sq: FloatArray
    accel: FloatArray
    junction_sq: FloatArray
    prefix: FloatArray


def _segments(
    vertices: FloatArray,
    speed: FloatArray,
    dwells: npt.NDArray[np.int64],
    limits: tuple[AxisLimits, ...],
    config: PlannerConfig,
) -> _Segments:
    """Geometry, junction limits and prefix sums of the segments between ``vertices``,
    block by block; ``speed`` is each segment's feed, ``dwells`` the dwells' segments."""
    k, total = vertices.shape[0], vertices.shape[1] - 1
    inv_v = [1.0 / axis.velocity_mm_s for axis in limits]
    inv_a = [1.0 / axis.accel_mm_s2 for axis in limits]
    unit = np.empty((k, total), dtype=np.float64)
    length = np.empty(total, dtype=np.float64)
    v_nominal_sq = np.empty(total, dtype=np.float64)
    accel = np.empty(total, dtype=np.float64)
    junction_sq = np.zeros(total + 1, dtype=np.float64)
    prefix = np.empty(total + 1, dtype=np.float64)
    prefix[0] = 0.0
    # Dwells (zero length) divide by zero and are set right afterwards.
    with np.errstate(divide="ignore", invalid="ignore"):
        for lo in range(0, total, _BLOCK):
            hi = min(total, lo + _BLOCK)
            _geometry(vertices[:, lo : hi + 1], speed[lo:hi], inv_v, inv_a, unit=unit[:, lo:hi],
                      length=length[lo:hi], v_nominal_sq=v_nominal_sq[lo:hi],
                      accel=accel[lo:hi])
            if dwells.size:
                held = dwells[np.searchsorted(dwells, lo) : np.searchsorted(dwells, hi)]
                unit[:, held] = 0.0
                v_nominal_sq[held] = 0.0
                accel[held] = 0.0
            reach = _reach(accel[lo:hi], length[lo:hi])
            if lo:
                reach[0] += prefix[lo]  # one running sum over the program, as np.cumsum
            np.cumsum(reach, out=prefix[lo + 1 : hi + 1])
            first = max(lo, 1)  # junction j joins segments j - 1 and j
            _junction_limits(
                unit[:, first - 1 : hi],
                length[first - 1 : hi],
                v_nominal_sq[first - 1 : hi],
                accel[first - 1 : hi],
                inv_a,
                config.junction_deviation_mm,
                out=junction_sq[first:hi],
            )
    return _Segments(unit, length, v_nominal_sq, accel, junction_sq, prefix)


def _reach(accel: FloatArray, length: FloatArray) -> FloatArray:
    """``2 a L``: how much a segment can change the squared speed."""
    reach = np.multiply(accel, 2.0)
    reach *= length
    return reach


def _backward_pass(limit_sq: FloatArray, prefix: FloatArray) -> None:
    """Lower each vertex's squared speed limit ``limit_sq`` in place to what the rest of
    the program lets it decelerate from (``min_j (limit_j + prefix_j) - prefix_i`` over
    ``j >= i``), block by block from the end."""
    carry = math.inf
    for hi in range(limit_sq.shape[0], 0, -_BLOCK):
        lo = max(0, hi - _BLOCK)
        limit = limit_sq[lo:hi]
        reachable = np.add(limit, prefix[lo:hi])
        np.minimum.accumulate(reachable[::-1], out=reachable[::-1])
        np.minimum(reachable, carry, out=reachable)
        carry = float(reachable[0])
        reachable -= prefix[lo:hi]
        # The j == i term is taken exactly, so rounding in the prefix sums never nudges a
        # speed that no pass had to lower.
        np.minimum(limit, reachable, out=limit)


@dataclass(frozen=True, eq=False)
class _Profile:
    """The speeds and times of n segments (``_forward_pass``).

    Fields:
        v_at_vertex: (n + 1,) speed at each vertex (entry of segment i, exit of i - 1).
        v_cruise, t_accel, t_cruise, t_decel: (n,) cruise speed and phase durations.
        start_time: (n,) when each segment starts (``exact_cumsum`` of the durations).
        duration_s: the total.
    """

    v_at_vertex: FloatArray
    v_cruise: FloatArray
    t_accel: FloatArray
    t_cruise: FloatArray
    t_decel: FloatArray
    start_time: FloatArray
    duration_s: float


def _forward_pass(
    segments: _Segments, dwells: npt.NDArray[np.int64], dwell_s: FloatArray
) -> _Profile:
    """The forward pass over the backward pass's limits (``segments.junction_sq`` by now),
    the trapezoids and the start times, block by block; the ``dwells`` segments hold for
    ``dwell_s``."""
    limit_sq, prefix = segments.junction_sq, segments.prefix
    total = limit_sq.shape[0] - 1
    v_at_vertex = np.empty(total + 1, dtype=np.float64)
    v_cruise = np.empty(total, dtype=np.float64)
    t_accel = np.empty(total, dtype=np.float64)
    t_cruise = np.empty(total, dtype=np.float64)
    t_decel = np.empty(total, dtype=np.float64)
    sums = np.zeros(total + 1, dtype=np.float64)
    carry = math.inf
    high_sum = low_sum = 0.0
    splits = True
    with np.errstate(divide="ignore", invalid="ignore"):
        for lo in range(0, total, _BLOCK):
            hi = min(total, lo + _BLOCK)
            # The block's vertices lo..hi: the next block redoes hi, from the same carry.
            speed_sq = np.subtract(limit_sq[lo : hi + 1], prefix[lo : hi + 1])
            np.minimum.accumulate(speed_sq, out=speed_sq)
            np.minimum(speed_sq, carry, out=speed_sq)
            carry = float(speed_sq[-1])
            speed_sq += prefix[lo : hi + 1]
            np.minimum(limit_sq[lo : hi + 1], speed_sq, out=speed_sq)
            np.maximum(speed_sq, 0.0, out=speed_sq)
            np.sqrt(speed_sq, out=v_at_vertex[lo : hi + 1])
            _trapezoids(
                speed_sq[:-1],
                speed_sq[1:],
                v_at_vertex[lo:hi],
                v_at_vertex[lo + 1 : hi + 1],
                _reach(segments.accel[lo:hi], segments.length[lo:hi]),
                segments.v_nominal_sq[lo:hi],
                segments.accel[lo:hi],
                segments.length[lo:hi],
                v_cruise=v_cruise[lo:hi],
                t_accel=t_accel[lo:hi],
                t_cruise=t_cruise[lo:hi],
                t_decel=t_decel[lo:hi],
            )
            if dwells.size:
                begin, end = np.searchsorted(dwells, (lo, hi))
                held = dwells[begin:end]
                v_cruise[held] = 0.0
                t_accel[held] = 0.0
                t_decel[held] = 0.0
                t_cruise[held] = dwell_s[begin:end]
            # exact_cumsum of the durations, its two running sums carried across blocks.
            duration = t_accel[lo:hi] + t_cruise[lo:hi]
            duration += t_decel[lo:hi]
            splits = splits and bool(duration.max() < _SPLIT_SHIFT)
            high = duration + _SPLIT_SHIFT
            high -= _SPLIT_SHIFT
            low = np.subtract(duration, high, out=duration)
            if lo:
                high[0] += high_sum
                low[0] += low_sum
            np.cumsum(high, out=high)
            np.cumsum(low, out=low)
            high_sum = float(high[-1])
            low_sum = float(low[-1])
            np.add(high, low, out=sums[lo + 1 : hi + 1])
    if splits:
        start_time, duration_s = sums[:-1], float(sums[-1])
    else:  # a segment of 2**32 s or more: exact_cumsum splits on a coarser grid
        start_time, duration_s = exact_cumsum(t_accel + t_cruise + t_decel)
    return _Profile(v_at_vertex, v_cruise, t_accel, t_cruise, t_decel, start_time, duration_s)


def _geometry(
    vertices: FloatArray,
    speed: FloatArray,
    inv_v: list[float],
    inv_a: list[float],
    *,
    unit: FloatArray,
    length: FloatArray,
    v_nominal_sq: FloatArray,
    accel: FloatArray,
) -> None:
    """Unit directions (k, m), lengths, squared nominal speeds and accelerations of a block
    of m segments, written into the arrays given."""
    np.subtract(vertices[:, 1:], vertices[:, :-1], out=unit)
    np.sqrt(_sum_of_squares(unit, out=length), out=length)
    unit /= length
    share = np.abs(unit)
    v_nominal = _largest_share(share, inv_v)
    np.divide(1.0, v_nominal, out=v_nominal)
    np.minimum(speed, v_nominal, out=v_nominal)
    np.multiply(v_nominal, v_nominal, out=v_nominal_sq)
    np.divide(1.0, _largest_share(share, inv_a), out=accel)


def _sum_of_squares(rows: FloatArray, *, out: FloatArray | None = None) -> FloatArray:
    """Per column, the sum of the squares of the rows (added in row order)."""
    total: FloatArray = np.multiply(rows[0], rows[0], out=out)
    for row in rows[1:]:
        total += row * row
    return total


def _largest_share(shares: FloatArray, inverse: list[float]) -> FloatArray:
    """Per column, the largest ``shares[k] * inverse[k]`` over the axes ``k``."""
    largest: FloatArray = shares[0] * inverse[0]
    for row, factor in zip(shares[1:], inverse[1:], strict=True):
        np.maximum(largest, row * factor, out=largest)
    return largest


def _trapezoids(
    entry_sq: FloatArray,
    exit_sq: FloatArray,
    v_entry: FloatArray,
    v_exit: FloatArray,
    reach: FloatArray,
    v_nominal_sq: FloatArray,
    accel: FloatArray,
    length: FloatArray,
    *,
    v_cruise: FloatArray,
    t_accel: FloatArray,
    t_cruise: FloatArray,
    t_decel: FloatArray,
) -> None:
    """The cruise speeds and phase durations of a block, written into the arrays given."""
    peak_sq = 0.5 * (entry_sq + exit_sq + reach)
    cruise_sq = np.maximum(np.minimum(v_nominal_sq, peak_sq), np.maximum(entry_sq, exit_sq))
    np.sqrt(cruise_sq, out=v_cruise)
    half_inv_accel = 0.5 / accel
    s_accel = (cruise_sq - entry_sq) * half_inv_accel
    s_decel = (cruise_sq - exit_sq) * half_inv_accel
    np.divide(2.0 * s_accel, v_cruise + v_entry, out=t_accel)
    np.divide(2.0 * s_decel, v_cruise + v_exit, out=t_decel)
    remaining = length - s_accel
    remaining -= s_decel
    np.maximum(remaining, 0.0, out=remaining)
    np.divide(remaining, v_cruise, out=t_cruise)


def _fill_arc_vertices(
    vertices: FloatArray,
    arc_rows: FloatArray,
    arc_planes: Sequence[tuple[int, int, int]],
) -> None:
    """Write the inner chord vertices of every arc: per plane, in blocks of about
    ``_BLOCK`` vertices."""
    plane_of = np.array([axes[0] for axes in arc_planes], dtype=np.int64)
    axes_by_first = {axes[0]: axes for axes in arc_planes}
    for first_axis in sorted(axes_by_first):
        selected = arc_rows[plane_of == first_axis]
        inner = selected[:, 1].astype(np.int64) - 1
        ends = np.cumsum(inner)
        begin = 0
        while begin < len(selected):
            stop = max(begin + 1, int(np.searchsorted(ends, ends[begin] + _BLOCK, side="left")))
            _arc_block(vertices, selected[begin:stop], axes_by_first[first_axis])
            begin = stop


def _arc_block(vertices: FloatArray, rows: FloatArray, axes: tuple[int, int, int]) -> None:
    axis1, axis2, normal = axes
    first = rows[:, 0].astype(np.int64)
    chords = rows[:, 1].astype(np.int64)
    inner = chords - 1
    offsets = np.cumsum(inner) - inner
    step = np.arange(int(inner.sum()), dtype=np.int64) - np.repeat(offsets, inner) + 1
    fraction = step / np.repeat(chords, inner)
    angle = np.repeat(rows[:, 6], inner) + np.repeat(rows[:, 7], inner) * fraction
    radius = np.repeat(rows[:, 4], inner) + np.repeat(rows[:, 5], inner) * fraction
    index = np.repeat(first, inner) + step
    vertices[axis1][index] = np.repeat(rows[:, 2], inner) + radius * np.cos(angle)
    vertices[axis2][index] = np.repeat(rows[:, 3], inner) + radius * np.sin(angle)
    if normal >= 0:
        vertices[normal][index] = (np.repeat(rows[:, 8], inner)
                                   + np.repeat(rows[:, 9], inner) * fraction)
    others = [axis for axis in range(vertices.shape[0]) if axis not in (axis1, axis2, normal)]
    if others:
        # Axes outside the plane and its normal (U V W with an XY arc) move linearly
        # along the arc, as its normal does in a helix.
        start = np.repeat(first, inner)
        end = np.repeat(first + chords, inner)
        for axis in others:
            begin = vertices[axis][start]
            vertices[axis][index] = begin + (vertices[axis][end] - begin) * fraction


def _junction_limits(
    unit: FloatArray,
    length: FloatArray,
    v_nominal_sq: FloatArray,
    accel: FloatArray,
    inv_a: list[float],
    deviation_mm: float,
    *,
    out: FloatArray,
) -> None:
    """Squared speed limits at the m - 1 junctions of a block of m segments, into ``out``.

    A straight continuation (``cos_half == 0``) divides by zero to an infinite limit, and its
    undefined junction direction (0 / 0) is skipped by ``fmin``: the nominal speeds rule.
    """
    turn = unit[:, 1:] - unit[:, :-1]
    straight = unit[:, 1:] + unit[:, :-1]
    # theta is the angle at the corner: cos(theta/2) = |u2 - u1| / 2, sin(theta/2) = |u2 + u1| / 2.
    w_length = np.sqrt(_sum_of_squares(turn))
    cos_half = 0.5 * w_length
    sin_half = np.minimum(0.5 * np.sqrt(_sum_of_squares(straight)), 1.0)
    a_share = _largest_share(np.abs(turn), inv_a)
    a_junction = np.fmin(w_length / a_share, np.minimum(accel[1:], accel[:-1]))
    deviation_sq = a_junction * deviation_mm * sin_half * (1.0 + sin_half) / (cos_half * cos_half)
    centripetal_sq = a_junction * 0.5 * np.minimum(length[1:], length[:-1]) * sin_half / cos_half
    np.minimum(v_nominal_sq[1:], v_nominal_sq[:-1], out=out)
    np.minimum(out, deviation_sq, out=out)
    np.minimum(out, centripetal_sq, out=out)
