"""What the devices executed, checked: velocity and acceleration within the limits, no
jump, the same path as another run (see :mod:`tests.test_live_control` for the tolerances).
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import tomlkit

from usbmotion.host.config import MachineConfig
from usbmotion.session import MachineSession
from usbmotion.session.report import RunReport
from usbmotion.sim.machine import connect_session
from usbmotion.sim.recording import ExecutedRecorder

AXES = ["X", "Y", "Z"]
VELOCITY_WINDOW = 10
ACCEL_WINDOW = 20
PATH_TOLERANCE_COUNTS = 1.5
Positions = npt.NDArray[np.int64]
TickAction = Callable[[MachineSession, int], None]


def near_the_switches(config: MachineConfig, mm: float = 5.0) -> MachineConfig:
    """``config`` with every simulated carriage powering up ``mm`` inside the end of its
    travel that it homes to (as examples/served-machine.toml's do), not at mid-travel:
    homing then takes a third of the time, for tests whose subject comes after it."""
    axes = []
    for axis in config.axes:
        low, high = axis.travel_mm
        start_mm = low + mm if axis.homing.direction < 0 else high - mm
        axes.append(axis if axis.sim is None else dataclasses.replace(
            axis, sim=dataclasses.replace(axis.sim, start_mm=start_mm)))
    return dataclasses.replace(config, axes=tuple(axes))


def near_the_switches_text(text: str, mm: float = 5.0) -> str:
    """A machine file's ``text`` with its simulated carriages powering up as
    :func:`near_the_switches` has them (for tests that hand the command a file)."""
    document = tomlkit.parse(text)
    for table in document["axes"].values():  # type: ignore[union-attr]
        sim = table.get("sim")
        if sim is None or "start_mm" not in sim:
            continue
        low, high = table["travel_mm"]
        sim["start_mm"] = low + mm if table["homing"]["direction"] < 0 else high - mm
    return tomlkit.dumps(document)


def record(config: MachineConfig, go: Callable[[MachineSession], RunReport],
           act: TickAction | None = None, *, live: bool = True,
           ) -> tuple[MachineSession, Positions, RunReport]:
    """Home a simulated machine, then ``go(session)`` with ``act(session, tick)`` called on
    every servo tick: the session (closed; ``final_state`` is its state after ``go``), what
    the devices executed meanwhile, and the report. ``live``: the session's live control
    (requests looked at every 10 ms, else 50 ms)."""
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
            report = go(session)
        session.final_state = session.state  # type: ignore[attr-defined]
        session.shutdown()
        return session, recorder.positions(), report


def peaks(positions: Positions) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Per-axis peak velocity (counts/tick, over VELOCITY_WINDOW) and acceleration
    (counts/tick^2, over ACCEL_WINDOW)."""
    w = VELOCITY_WINDOW
    velocity = np.abs(positions[w:] - positions[:-w]).max(axis=0) / w
    a = ACCEL_WINDOW
    second = positions[2 * a:] - 2 * positions[a:-a] + positions[:-2 * a]
    return velocity, np.abs(second).max(axis=0) / (a * a)


def check_limits(config: MachineConfig, positions: Positions, reference: Positions) -> None:
    tick_s = config.servo_period_s
    velocity, accel = peaks(positions)
    _, reference_accel = peaks(reference)
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


PAIRS_AT_ONCE = 1 << 21
"""How many (point, segment) pairs :func:`distance_to_path` measures in one go (memory)."""
_NEIGHBOURS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])


def distance_to_path(points: Positions, path: Positions) -> float:
    """The largest distance (counts) from any of ``points`` to the polyline ``path``.

    Each point is measured against the segments starting in its 16-count cell or in one of
    the 26 around it (a point with none is infinitely far); the points in bulk."""
    path_f = path.astype(np.float64)
    keep = np.concatenate(([True], np.any(np.diff(path_f, axis=0) != 0, axis=1)))
    path_f = path_f[keep]
    start = path_f[:-1]
    d = path_f[1:] - start
    dd = np.einsum("ij,ij->i", d, d)
    unique = np.unique(points, axis=0).astype(np.float64)
    if len(unique) == 0:
        return 0.0
    if len(start) == 0:
        return float("inf")
    cell = 16.0
    segment_cells = np.floor(start / cell).astype(np.int64)
    point_cells = np.floor(unique / cell).astype(np.int64)
    low = np.minimum(segment_cells.min(axis=0), point_cells.min(axis=0)) - 1
    span = np.maximum(segment_cells.max(axis=0), point_cells.max(axis=0)) - low + 2

    def key(cells: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        """One integer per cell (every neighbour of every cell included)."""
        shifted = cells - low
        return (shifted[:, 0] * span[1] + shifted[:, 1]) * span[2] + shifted[:, 2]

    segment_keys = key(segment_cells)
    order = np.argsort(segment_keys, kind="stable")
    sorted_keys = segment_keys[order]
    first = np.empty((len(_NEIGHBOURS), len(unique)), dtype=np.int64)
    count = np.empty_like(first)
    for row, offset in enumerate(_NEIGHBOURS):
        neighbour = key(point_cells + offset)
        first[row] = np.searchsorted(sorted_keys, neighbour, side="left")
        count[row] = np.searchsorted(sorted_keys, neighbour, side="right") - first[row]
    pairs = np.cumsum(count.sum(axis=0))
    if pairs[0] == 0 or np.any(np.diff(pairs) == 0):
        return float("inf")
    cuts = np.searchsorted(pairs, np.arange(PAIRS_AT_ONCE, pairs[-1], PAIRS_AT_ONCE), "right")
    edges = np.unique(np.concatenate(([0], cuts, [len(unique)])))
    worst = 0.0
    for lo, hi in itertools.pairwise(edges.tolist()):
        nearest = np.full(hi - lo, np.inf)
        for row in range(len(_NEIGHBOURS)):
            n = count[row, lo:hi]
            some = np.flatnonzero(n)
            if len(some) == 0:
                continue
            n = n[some]
            ends = np.cumsum(n)
            segment = order[np.repeat(first[row, lo:hi][some] - (ends - n), n)
                            + np.arange(ends[-1])]
            point = unique[lo:hi][np.repeat(some, n)]
            a, step = start[segment], d[segment]
            t = np.clip(np.einsum("ij,ij->i", point - a, step) / dd[segment], 0, 1)
            distance = np.linalg.norm(a + step * t[:, None] - point, axis=1)
            nearest[some] = np.minimum(nearest[some], np.minimum.reduceat(distance, ends - n))
        worst = max(worst, float(nearest.max()))
    return worst


def check_same_path(positions: Positions, reference: Positions) -> None:
    assert distance_to_path(positions, reference) <= PATH_TOLERANCE_COUNTS, "left the path"
    assert distance_to_path(reference, positions) <= PATH_TOLERANCE_COUNTS, "skipped a part"
    assert np.array_equal(positions[-1], reference[-1]), "the same end position"


def at_rest_spans(positions: Positions, least: int) -> list[tuple[int, int]]:
    """Stretches of at least ``least`` ticks where no axis moved."""
    still = np.concatenate(([False], np.all(np.diff(positions, axis=0) == 0, axis=1), [False]))
    edges = np.flatnonzero(np.diff(still.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)
            if b - a >= least]
