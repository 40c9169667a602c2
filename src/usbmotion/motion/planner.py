"""Look-ahead motion planning: moves in, timed trapezoidal segments out.

``plan_moves`` turns the interpreter's moves (``motion.moves``) into a ``Plan``:

1. Arcs are cut into chords whose sagitta is at most ``arc_tolerance_mm``:
   ``theta_per_chord = 2 * acos(1 - tol / r)`` with ``r`` the larger of the start and end
   radii. The sweep follows LinuxCNC: ``rotation`` P > 0 turns counter-clockwise about the
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
generation, junctions, passes and profiles are numpy passes over all segments, so planning is
bounded by the Python loop for line-heavy programs and by the number of chords for arc-heavy
ones (see ``benchmarks/planner_speed.py``).

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
from usbmotion.motion.limits import AXIS_NAMES, AxisLimits, PlannerConfig
from usbmotion.motion.moves import Arc, Dwell, Linear, Move, Plane, Rapid, Vec3

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
_MAX_THETA_PER_CHORD = 2.0 * math.pi / 3.0
_SPLIT_SCALE = 2.0**20

_ArcRow = tuple[int, int, float, float, float, float, float, float, float, float]
_AXES_BY_FIRST = {plane.axes[0]: plane.axes for plane in Plane}


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

    start: Vec3
    end: Vec3
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
    high = np.round(values * _SPLIT_SCALE) / _SPLIT_SCALE
    low = values - high
    high_sum = np.concatenate(([0.0], np.cumsum(high)))
    low_sum = np.concatenate(([0.0], np.cumsum(low)))
    sums = high_sum + low_sum
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
        vertices_mm: (n + 1, 3) positions; row 0 is the start, the last row the end.
        unit: (n, 3) unit directions (zero rows for dwells).
        kind: (n,) ``SegmentKind`` codes.
        line: (n,) G-code lines.
        length_mm, v_entry_mm_s, v_cruise_mm_s, v_exit_mm_s, accel_mm_s2, t_accel_s,
            t_cruise_s, t_decel_s, start_time_s: (n,) per-segment values.
        v_junction_max_mm_s: (n + 1,) the speed limit at each vertex before the passes
            (junction deviation, centripetal and nominal caps; 0 at stops): why a corner is
            as slow as it is.
        duration_s: total time of the program.
        move_count: how many input moves were planned.
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

    def __len__(self) -> int:
        return int(self.length_mm.shape[0])

    @property
    def start(self) -> Vec3:
        """Where the program starts, mm."""
        x, y, z = self.vertices_mm[0].tolist()
        return (x, y, z)

    @property
    def end(self) -> Vec3:
        """Where the program ends, mm."""
        x, y, z = self.vertices_mm[-1].tolist()
        return (x, y, z)

    @property
    def segment_duration_s(self) -> FloatArray:
        """(n,) duration of each segment."""
        return self.t_accel_s + self.t_cruise_s + self.t_decel_s

    @cached_property
    def segments(self) -> tuple[PlannedSegment, ...]:
        """The segments as ``PlannedSegment`` objects (built on first use)."""
        vertices = [tuple(row) for row in self.vertices_mm.tolist()]
        columns = zip(
            self.length_mm.tolist(),
            self.v_entry_mm_s.tolist(),
            self.v_cruise_mm_s.tolist(),
            self.v_exit_mm_s.tolist(),
            self.accel_mm_s2.tolist(),
            self.t_accel_s.tolist(),
            self.t_cruise_s.tolist(),
            self.t_decel_s.tolist(),
            self.line.tolist(),
            self.kind.tolist(),
            self.start_time_s.tolist(),
            strict=True,
        )
        kinds = list(SegmentKind)
        return tuple(
            PlannedSegment(
                vertices[i],
                vertices[i + 1],
                length,
                v_entry,
                v_cruise,
                v_exit,
                accel,
                t_accel,
                t_cruise,
                t_decel,
                line,
                kinds[kind],
                start_time,
            )
            for i, (
                length,
                v_entry,
                v_cruise,
                v_exit,
                accel,
                t_accel,
                t_cruise,
                t_decel,
                line,
                kind,
                start_time,
            ) in enumerate(columns)
        )


def _check_point(name: str, point: object) -> Vec3:
    if not isinstance(point, tuple) or len(point) != 3:
        raise PlanningError(f"{name} {point!r} is not an (x, y, z) tuple in mm")
    for value in point:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise PlanningError(f"{name} {point!r} holds {value!r}, which is not a number")
        if not math.isfinite(value):
            raise PlanningError(f"{name} {point!r} holds {value!r}; coordinates must be finite")
    return (float(point[0]), float(point[1]), float(point[2]))


def _check_limits(limits: Sequence[AxisLimits]) -> tuple[AxisLimits, AxisLimits, AxisLimits]:
    if isinstance(limits, (str, bytes)) or len(limits) != 3:
        raise PlanningError(
            f"limits {limits!r} must be three AxisLimits, one per axis {', '.join(AXIS_NAMES)}"
        )
    for name, axis in zip(AXIS_NAMES, limits, strict=True):
        if not isinstance(axis, AxisLimits):
            raise PlanningError(f"limits for axis {name} {axis!r} is not an AxisLimits")
    return (limits[0], limits[1], limits[2])


def _as_float(value: object) -> float:
    """A feed as a float, or NaN when it is not a number (reported with its line)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return math.nan
    return float(value)


def _gap_error(move: Move, where: Vec3, expected: Vec3, tolerance: float) -> PlanningError:
    if not all(math.isfinite(value) for value in (*where, *expected)):
        return PlanningError(
            f"line {move.line}: position {where!r} (after {expected!r}) is not finite"
        )
    return PlanningError(
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


def plan_moves(
    moves: Sequence[Move],
    limits: Sequence[AxisLimits],
    config: PlannerConfig,
    *,
    start: Vec3 = (0.0, 0.0, 0.0),
) -> Plan:
    """Plan ``moves`` into timed segments within every axis's limits.

    Parameters:
        moves: the program's moves in order; each must start where the previous one ended
            (the first at ``start``), within ``config.continuity_tolerance_mm``.
        limits: ``AxisLimits`` for X, Y and Z.
        config: arc tolerance, junction deviation, minimum segment.
        start: the machine's position before the first move, mm.

    Returns a ``Plan`` that starts and ends at rest.

    Raises:
        PlanningError: bad limits, a non-finite coordinate, a feed that is not positive and
            finite, a negative or non-finite dwell, a zero-radius arc, a zero rotation, a gap
            between moves, or an object that is not a move; the message names the G-code line
            and the value.
    """
    axis_limits = _check_limits(limits)
    if not isinstance(config, PlannerConfig):
        raise PlanningError(f"config {config!r} is not a PlannerConfig")
    origin = _check_point("start", start)

    tolerance = config.continuity_tolerance_mm
    min_segment = config.min_segment_mm
    min_segment_sq = min_segment * min_segment
    arc_tolerance = config.arc_tolerance_mm

    item_kind: list[int] = []
    item_line: list[int] = []
    item_feed: list[float] = []
    item_dwell: list[float] = []
    item_count: list[int] = []
    end_x: list[float] = []
    end_y: list[float] = []
    end_z: list[float] = []
    arc_rows: list[_ArcRow] = []
    arc_planes: list[tuple[int, int, int]] = []

    kx, ky, kz = origin
    expected = origin
    total = 0
    inf = math.inf
    hypot = math.hypot
    atan2 = math.atan2

    for move in moves:
        cls = type(move)
        if cls is Linear or cls is Rapid:
            line_move: Linear | Rapid = move  # type: ignore[assignment]
            s = line_move.start
            if s != expected and not (
                abs(s[0] - expected[0]) <= tolerance
                and abs(s[1] - expected[1]) <= tolerance
                and abs(s[2] - expected[2]) <= tolerance
            ):
                raise _gap_error(move, s, expected, tolerance)
            e = line_move.end
            expected = e
            ex, ey, ez = e
            dx = ex - kx
            dy = ey - ky
            dz = ez - kz
            if dx * dx + dy * dy + dz * dz < min_segment_sq:
                continue
            if cls is Linear:
                item_kind.append(1)
                item_feed.append(line_move.feed_mm_min)  # type: ignore[union-attr]
            else:
                item_kind.append(0)
                item_feed.append(inf)
            item_line.append(move.line)
            item_dwell.append(0.0)
            item_count.append(1)
            end_x.append(ex)
            end_y.append(ey)
            end_z.append(ez)
            kx, ky, kz = ex, ey, ez
            total += 1
        elif cls is Arc:
            arc: Arc = move  # type: ignore[assignment]
            s = arc.start
            if s != expected and not (
                abs(s[0] - expected[0]) <= tolerance
                and abs(s[1] - expected[1]) <= tolerance
                and abs(s[2] - expected[2]) <= tolerance
            ):
                raise _gap_error(move, s, expected, tolerance)
            e = arc.end
            expected = e
            if not isinstance(arc.plane, Plane):
                raise PlanningError(f"line {arc.line}: arc plane {arc.plane!r} is not a Plane")
            a1, a2, an = arc.plane.axes
            c = arc.centre
            sx = s[a1] - c[a1]
            sy = s[a2] - c[a2]
            ex = e[a1] - c[a1]
            ey = e[a2] - c[a2]
            r0 = hypot(sx, sy)
            r1 = hypot(ex, ey)
            if not (r0 > min_segment and r1 > min_segment and math.isfinite(r0 + r1)):
                raise PlanningError(
                    f"line {arc.line}: arc from {s!r} to {e!r} about centre {c!r} has "
                    f"radius {r0!r} at the start and {r1!r} at the end; both must be "
                    f"finite and larger than {min_segment!r} mm"
                )
            theta0 = atan2(sy, sx)
            sweep = _arc_sweep(arc, theta0, atan2(ey, ex), hypot(ex - sx, ey - sy))
            normal_travel = e[an] - s[an]
            r_min = min(r0, r1)
            r_max = max(r0, r1)
            planar = abs(sweep) * 0.5 * (r0 + r1)
            if planar * planar + normal_travel * normal_travel < min_segment_sq:
                continue
            theta_chord = 2.0 * math.acos(max(0.5, 1.0 - arc_tolerance / r_max))
            chords = max(1, math.ceil(abs(sweep) / theta_chord))
            shortest = 0.8 * math.hypot(abs(sweep) * r_min, normal_travel)
            chords = max(1, min(chords, int(shortest / min_segment)))
            item_kind.append(2)
            item_feed.append(arc.feed_mm_min)
            item_line.append(arc.line)
            item_dwell.append(0.0)
            item_count.append(chords)
            end_x.append(e[0])
            end_y.append(e[1])
            end_z.append(e[2])
            if chords > 1:
                arc_rows.append(
                    (
                        total,
                        chords,
                        c[a1],
                        c[a2],
                        r0,
                        r1 - r0,
                        theta0,
                        sweep,
                        s[an],
                        normal_travel,
                    )
                )
                arc_planes.append((a1, a2, an))
            kx, ky, kz = e
            total += chords
        elif cls is Dwell:
            dwell: Dwell = move  # type: ignore[assignment]
            p = dwell.position
            if p != expected and not (
                abs(p[0] - expected[0]) <= tolerance
                and abs(p[1] - expected[1]) <= tolerance
                and abs(p[2] - expected[2]) <= tolerance
            ):
                raise _gap_error(move, p, expected, tolerance)
            seconds = dwell.seconds
            if isinstance(seconds, bool) or not isinstance(seconds, (int, float)):
                raise PlanningError(f"line {dwell.line}: dwell {seconds!r} s is not a number")
            if not (math.isfinite(seconds) and seconds >= 0.0):
                raise PlanningError(
                    f"line {dwell.line}: dwell {seconds!r} s must be finite and >= 0"
                )
            item_kind.append(3)
            item_feed.append(0.0)
            item_line.append(dwell.line)
            item_dwell.append(float(seconds))
            item_count.append(1)
            end_x.append(kx)
            end_y.append(ky)
            end_z.append(kz)
            total += 1
        else:
            raise PlanningError(f"moves holds {move!r}, which is not a Rapid, Linear, Arc or Dwell")

    return _plan_columns(
        origin=origin,
        limits=axis_limits,
        config=config,
        move_count=len(moves),
        total=total,
        item_kind=item_kind,
        item_line=item_line,
        item_feed=item_feed,
        item_dwell=item_dwell,
        item_count=item_count,
        ends=(end_x, end_y, end_z),
        arc_rows=arc_rows,
        arc_planes=arc_planes,
    )


def _plan_columns(
    *,
    origin: Vec3,
    limits: tuple[AxisLimits, AxisLimits, AxisLimits],
    config: PlannerConfig,
    move_count: int,
    total: int,
    item_kind: list[int],
    item_line: list[int],
    item_feed: list[float],
    item_dwell: list[float],
    item_count: list[int],
    ends: tuple[list[float], list[float], list[float]],
    arc_rows: list[_ArcRow],
    arc_planes: list[tuple[int, int, int]],
) -> Plan:
    counts = np.array(item_count, dtype=np.int64)
    kinds_item = np.array(item_kind, dtype=np.int8)
    lines_item = np.array(item_line, dtype=np.int64)
    try:
        feed_item = np.array(item_feed, dtype=np.float64)
    except (TypeError, ValueError):
        feed_item = np.array([_as_float(feed) for feed in item_feed], dtype=np.float64)
    feed_moves = (kinds_item == SegmentKind.LINEAR) | (kinds_item == SegmentKind.ARC)
    bad_feed = feed_moves & ~(np.isfinite(feed_item) & (feed_item > 0.0))
    if bad_feed.any():
        index = int(np.flatnonzero(bad_feed)[0])
        raise PlanningError(
            f"line {int(lines_item[index])}: feed {item_feed[index]!r} mm/min must "
            "be positive and finite"
        )
    speed_item = feed_item / 60.0

    vertices = np.empty((total + 1, 3), dtype=np.float64)
    vertices[0] = origin
    last_vertex = np.cumsum(counts)
    vertices[last_vertex, 0] = ends[0]
    vertices[last_vertex, 1] = ends[1]
    vertices[last_vertex, 2] = ends[2]
    if arc_rows:
        _fill_arc_vertices(vertices, arc_rows, arc_planes)

    if not np.isfinite(vertices).all():
        bad_vertex = int(np.flatnonzero(~np.isfinite(vertices).all(axis=1))[0])
        index = int(np.searchsorted(last_vertex, bad_vertex, side="left"))
        raise PlanningError(
            f"line {int(lines_item[index])}: position {tuple(vertices[bad_vertex].tolist())!r} "
            "is not finite"
        )

    kind = np.repeat(kinds_item, counts)
    line = np.repeat(lines_item, counts)
    speed = np.repeat(speed_item, counts)
    dwell_s = np.repeat(np.array(item_dwell, dtype=np.float64), counts)
    moving = kind != SegmentKind.DWELL

    delta = np.diff(vertices, axis=0)
    dx = np.ascontiguousarray(delta[:, 0])
    dy = np.ascontiguousarray(delta[:, 1])
    dz = np.ascontiguousarray(delta[:, 2])
    length = np.sqrt(dx * dx + dy * dy + dz * dz)
    safe_length = np.where(moving, length, 1.0)
    ux = np.where(moving, dx / safe_length, 0.0)
    uy = np.where(moving, dy / safe_length, 0.0)
    uz = np.where(moving, dz / safe_length, 0.0)

    inv_v = [1.0 / axis.velocity_mm_s for axis in limits]
    inv_a = [1.0 / axis.accel_mm_s2 for axis in limits]
    ax, ay, az = np.abs(ux), np.abs(uy), np.abs(uz)
    v_share = np.maximum(np.maximum(ax * inv_v[0], ay * inv_v[1]), az * inv_v[2])
    a_share = np.maximum(np.maximum(ax * inv_a[0], ay * inv_a[1]), az * inv_a[2])
    v_nominal = np.where(moving, np.minimum(speed, 1.0 / np.where(moving, v_share, 1.0)), 0.0)
    accel = np.where(moving, 1.0 / np.where(moving, a_share, 1.0), 0.0)
    v_nominal_sq = v_nominal * v_nominal

    junction_sq = _junction_limits(
        ux, uy, uz, length, moving, v_nominal_sq, accel, inv_a, config.junction_deviation_mm
    )

    reach = 2.0 * accel * length
    prefix = np.concatenate(([0.0], np.cumsum(reach)))
    # The j == i term of each minimum is taken exactly (``np.minimum`` with the limit itself),
    # so rounding in the prefix sums never nudges a speed that no pass had to lower.
    backward = np.minimum(
        junction_sq, np.minimum.accumulate((junction_sq + prefix)[::-1])[::-1] - prefix
    )
    forward = prefix + np.minimum.accumulate(backward - prefix)
    speed_sq = np.maximum(np.minimum(backward, forward), 0.0)

    entry_sq = speed_sq[:-1]
    exit_sq = speed_sq[1:]
    peak_sq = 0.5 * (entry_sq + exit_sq + reach)
    cruise_sq = np.maximum(np.minimum(v_nominal_sq, peak_sq), np.maximum(entry_sq, exit_sq))
    v_entry = np.sqrt(entry_sq)
    v_exit = np.sqrt(exit_sq)
    v_cruise = np.sqrt(cruise_sq)
    safe_accel = np.where(moving, accel, 1.0)
    s_accel = (cruise_sq - entry_sq) / (2.0 * safe_accel)
    s_decel = (cruise_sq - exit_sq) / (2.0 * safe_accel)
    safe_cruise = np.where(moving, v_cruise, 1.0)
    t_accel = np.where(moving, 2.0 * s_accel / np.where(moving, v_cruise + v_entry, 1.0), 0.0)
    t_decel = np.where(moving, 2.0 * s_decel / np.where(moving, v_cruise + v_exit, 1.0), 0.0)
    s_cruise = np.maximum(length - s_accel - s_decel, 0.0)
    t_cruise = np.where(moving, s_cruise / safe_cruise, dwell_s)

    start_time, duration = exact_cumsum(t_accel + t_cruise + t_decel)
    unit = np.stack((ux, uy, uz), axis=1)
    return Plan(
        vertices_mm=_readonly(vertices),  # type: ignore[arg-type]
        unit=_readonly(unit),  # type: ignore[arg-type]
        kind=_readonly(kind),  # type: ignore[arg-type]
        line=_readonly(line),  # type: ignore[arg-type]
        length_mm=_readonly(np.where(moving, length, 0.0)),  # type: ignore[arg-type]
        v_entry_mm_s=_readonly(v_entry),  # type: ignore[arg-type]
        v_cruise_mm_s=_readonly(np.where(moving, v_cruise, 0.0)),  # type: ignore[arg-type]
        v_exit_mm_s=_readonly(v_exit),  # type: ignore[arg-type]
        accel_mm_s2=_readonly(accel),  # type: ignore[arg-type]
        t_accel_s=_readonly(t_accel),  # type: ignore[arg-type]
        t_cruise_s=_readonly(t_cruise),  # type: ignore[arg-type]
        t_decel_s=_readonly(t_decel),  # type: ignore[arg-type]
        start_time_s=_readonly(start_time),  # type: ignore[arg-type]
        v_junction_max_mm_s=_readonly(np.sqrt(junction_sq)),  # type: ignore[arg-type]
        duration_s=duration,
        move_count=move_count,
    )


def _fill_arc_vertices(
    vertices: FloatArray,
    arc_rows: list[_ArcRow],
    arc_planes: list[tuple[int, int, int]],
) -> None:
    """Write the inner chord vertices of every arc, one numpy pass per plane."""
    rows = np.array(arc_rows, dtype=np.float64)
    plane_of = np.array([axes[0] for axes in arc_planes], dtype=np.int64)
    for first_axis in np.unique(plane_of).tolist():
        selected = rows[plane_of == first_axis]
        axis1, axis2, normal = _AXES_BY_FIRST[first_axis]
        first = selected[:, 0].astype(np.int64)
        chords = selected[:, 1].astype(np.int64)
        inner = chords - 1
        offsets = np.cumsum(inner) - inner
        step = np.arange(int(inner.sum()), dtype=np.int64) - np.repeat(offsets, inner) + 1
        fraction = step / np.repeat(chords, inner)
        angle = np.repeat(selected[:, 6], inner) + np.repeat(selected[:, 7], inner) * fraction
        radius = np.repeat(selected[:, 4], inner) + np.repeat(selected[:, 5], inner) * fraction
        index = np.repeat(first, inner) + step
        vertices[index, axis1] = np.repeat(selected[:, 2], inner) + radius * np.cos(angle)
        vertices[index, axis2] = np.repeat(selected[:, 3], inner) + radius * np.sin(angle)
        vertices[index, normal] = (
            np.repeat(selected[:, 8], inner) + np.repeat(selected[:, 9], inner) * fraction
        )


def _junction_limits(
    ux: FloatArray,
    uy: FloatArray,
    uz: FloatArray,
    length: FloatArray,
    moving: npt.NDArray[np.bool_],
    v_nominal_sq: FloatArray,
    accel: FloatArray,
    inv_a: list[float],
    deviation_mm: float,
) -> FloatArray:
    """Squared speed limits at every vertex: 0 at both ends and around dwells."""
    wx = ux[1:] - ux[:-1]
    wy = uy[1:] - uy[:-1]
    wz = uz[1:] - uz[:-1]
    sx = ux[1:] + ux[:-1]
    sy = uy[1:] + uy[:-1]
    sz = uz[1:] + uz[:-1]
    # theta is the angle at the corner: cos(theta/2) = |u2 - u1| / 2, sin(theta/2) = |u2 + u1| / 2.
    cos_half = 0.5 * np.sqrt(wx * wx + wy * wy + wz * wz)
    sin_half = np.minimum(0.5 * np.sqrt(sx * sx + sy * sy + sz * sz), 1.0)
    turning = cos_half > 1e-12
    safe_w = np.where(turning, 2.0 * cos_half, 1.0)
    a_share = np.maximum(
        np.maximum(np.abs(wx) * inv_a[0], np.abs(wy) * inv_a[1]), np.abs(wz) * inv_a[2]
    )
    a_junction = np.minimum(
        safe_w / np.where(a_share > 0.0, a_share, 1.0), np.minimum(accel[1:], accel[:-1])
    )
    safe_cos = np.where(turning, cos_half, 1.0)
    deviation_sq = a_junction * deviation_mm * sin_half * (1.0 + sin_half) / (safe_cos * safe_cos)
    shorter = np.minimum(length[1:], length[:-1])
    centripetal_sq = a_junction * 0.5 * shorter * sin_half / safe_cos
    nominal_sq = np.minimum(v_nominal_sq[1:], v_nominal_sq[:-1])
    limit = np.where(
        turning, np.minimum(np.minimum(deviation_sq, centripetal_sq), nominal_sq), nominal_sq
    )
    limit = np.where(moving[1:] & moving[:-1], limit, 0.0)
    return np.concatenate(([0.0], limit, [0.0]))
