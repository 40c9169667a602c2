"""Diagnostics lines taken in blocks: what the live model, the trace and the client keep is
what taking them one by one keeps."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from usbmotion.device import Device
from usbmotion.errors import ArgumentError
from usbmotion.host.device import DeviceClient, Diagnostics, DiagnosticsBlock
from usbmotion.host.transport import LineTransport
from usbmotion.protocol import codec, parse_diagnostics
from usbmotion.protocol.table import DIAGNOSTICS
from usbmotion.session.live import PEAK_LINES, AxisScale, LiveModel
from usbmotion.session.report import Trace
from usbmotion.session.watch import Watch
from usbmotion.sim import SimWorld, drop_world, set_world

INT64 = st.integers(-(2**63), 2**63 - 1)
SMALL = st.integers(-(10**6), 10**6)

Line = tuple[int, int, int, int, int, int, int]
"""A diagnostics line's values: clock, desired, actual, velocity, output_mv, queued, peak."""


def _block(lines: list[Line]) -> DiagnosticsBlock:
    return DiagnosticsBlock(np.array(lines, dtype=np.int64).reshape(len(lines), 7))


def _split(items: list[Line], cuts: list[int]) -> Iterator[list[Line]]:
    """``items`` in consecutive pieces cut at ``cuts``."""
    last = 0
    for cut in [*sorted({min(cut, len(items)) for cut in cuts}), len(items)]:
        if cut > last:
            yield items[last:cut]
            last = cut


# --- the codec -----------------------------------------------------------------------------


@given(st.lists(st.tuples(*[INT64] * 7), max_size=20))
@settings(max_examples=200, deadline=None)
def test_lines_as_printed_convert_in_bulk_as_one_by_one(rows: list[Line]) -> None:
    lines = [DIAGNOSTICS.format(*row).encode("ascii") for row in rows]
    bulk = codec.parse_diagnostics_lines(lines)
    if all(len(str(abs(value))) <= codec.HUGE_DIGITS for row in rows for value in row):
        assert bulk is not None
        assert bulk.tolist() == [list(parse_diagnostics(line) or ()) for line in lines]
    else:
        assert bulk is None


LINE_BYTES = st.sampled_from([b"D", b" ", b"-", b"+", b"0", b"7", b"9", b"\r", b"\t", b"x"])


@given(st.lists(st.one_of(
    st.tuples(*[SMALL] * 7).map(lambda row: DIAGNOSTICS.format(*row).encode("ascii")),
    st.lists(LINE_BYTES, max_size=30).map(b"".join)), max_size=8))
@settings(max_examples=300, deadline=None)
def test_a_block_converts_only_when_every_line_would(lines: list[bytes]) -> None:
    bulk = codec.parse_diagnostics_lines(lines)
    one_by_one = [parse_diagnostics(line) for line in lines]
    if bulk is None:
        assert None in one_by_one
    else:
        assert bulk.tolist() == [list(values or ()) for values in one_by_one]


# --- the live model ------------------------------------------------------------------------

LIVE_LINES = st.lists(st.tuples(st.integers(-5, 10**6), SMALL, SMALL, SMALL), max_size=40)


def _axis_state(model: LiveModel) -> tuple[Any, ...]:
    axis = model._axes["X"]
    return (axis.clock, axis.desired, axis.actual, axis.peak, axis.v_desired, axis.v_actual,
            axis.run_peak, axis.run_peak_clock, axis.peaks.tolist(), model._counts["X"])


@given(LIVE_LINES, st.lists(st.integers(0, 40), max_size=6), st.integers(0, 2 * PEAK_LINES))
@settings(max_examples=200, deadline=None)
def test_the_live_model_takes_a_block_as_its_lines_one_by_one(
        lines: list[tuple[int, int, int, int]], cuts: list[int], before: int) -> None:
    one, blocks = (LiveModel({"X": AxisScale(100.0)}, tick_s=1e-4) for _ in range(2))
    for model in (one, blocks):  # lines before, some of them wrapping the peaks' ring
        for index in range(before % 7):
            model.take_line("X", index, index, 0, index - 3)
        model._counts["X"] = before
    for clock, desired, actual, peak in lines:
        one.take_line("X", clock, desired, actual, peak)
    rows = [(clock, desired, actual, 0, 0, 0, peak) for clock, desired, actual, peak in lines]
    for piece in _split(rows, cuts):
        block = _block(piece)
        blocks.take_lines("X", block.clock, block.desired, block.actual_counts,
                          block.peak_error_counts)
    assert _axis_state(blocks) == _axis_state(one)


# --- the watch's trace ---------------------------------------------------------------------


def _trace_one_by_one(lines: list[Line], keep: int) -> list[list[int]]:
    """The trace's columns (clock, desired, actual, queued, peak) as a line-by-line watch
    keeps them: every ``keep``-th line, with the largest peak magnitude since the one before."""
    kept: list[list[int]] = [[], [], [], [], []]
    peak = 0
    for count, (clock, desired, actual, _, _, queued, line_peak) in enumerate(lines, start=1):
        peak = max(peak, abs(line_peak))
        if count % keep == 0:
            for column, value in zip(kept, (clock, desired, actual, queued, peak), strict=True):
                column.append(value)
            peak = 0
    return kept


@given(st.lists(st.tuples(*[SMALL] * 7), max_size=60), st.lists(st.integers(0, 60), max_size=8),
       st.integers(1, 7))
@settings(max_examples=200, deadline=None)
def test_the_watch_keeps_every_so_many_lines_of_blocks_as_of_lines(
        lines: list[Line], cuts: list[int], keep: int) -> None:
    trace = Trace(tick_s=1e-4, start_tick=0)
    live = LiveModel({"X": AxisScale(100.0)}, tick_s=1e-4)
    watch = Watch(None, trace, live, line_at_tick=lambda tick: 0)  # type: ignore[arg-type]
    watch.keep = keep
    on_lines = watch._on_lines("X")
    for piece in _split(lines, cuts):
        on_lines(_block(piece))
    columns = [trace.column(store, "X").tolist()
               for store in (trace.clock, trace.desired, trace.actual, trace.queued, trace.peak)]
    assert columns == _trace_one_by_one(lines, keep)


# --- the client ----------------------------------------------------------------------------


def test_held_lines_come_in_one_block_in_order_and_stray_ones_are_counted() -> None:
    transport = LineTransport.open("loop://")
    client = DeviceClient(transport, name="loop")
    blocks: list[DiagnosticsBlock] = []
    with client.listening(diagnostics_block=blocks.append):
        transport.write(b"D 1 2 3 4 5 6 7\nD 2 x\n D 3 2 3 4 5 6 -7 \nD 4 2 3 4 5 6 7\n")
        client.read_pending()
        assert blocks == []
        client.deliver_diagnostics()
        assert [block.rows.tolist() for block in blocks] == [
            [[1, 2, 3, 4, 5, 6, 7], [3, 2, 3, 4, 5, 6, -7], [4, 2, 3, 4, 5, 6, 7]]]
        assert client.stray_lines == 1
        transport.write(b"D 5 2 3 4 5 6 7\n")
        client.read_pending()
    assert blocks[-1].lines() == [Diagnostics(5, 2, 3, 4, 5, 6, 7)]  # handed over on leaving
    assert client.on_diagnostics_block is None
    with (pytest.raises(ArgumentError),
          client.listening(diagnostics=print, diagnostics_block=blocks.append)):
        pass
    client.close()


def test_a_block_listener_hears_what_a_line_listener_hears() -> None:
    heard: dict[str, list[list[int]]] = {}
    for how in ("lines", "blocks"):
        world = SimWorld()
        world.add(Device(), key="X")
        set_world("blocks-test", world)
        try:
            with DeviceClient.open("sim://X?world=blocks-test", name="X") as client:
                lines: list[Diagnostics] = []
                blocks: list[DiagnosticsBlock] = []
                listener = ({"diagnostics": lines.append} if how == "lines"
                            else {"diagnostics_block": blocks.append})
                with client.listening(**listener):  # type: ignore[arg-type]
                    client.set_servo_enable(True)
                    client.set_diagnostics_interval(7)
                    client.add_setpoints(list(range(0, 500, 5)))
                    for _ in range(20):
                        world.advance(30_000)
                        client.read_pending()
                    client.status()  # lines read on the way to an answer too
                heard[how] = ([[line.clock, line.desired, line.actual_counts, line.queued,
                                line.peak_error_counts] for line in lines]
                              or [row for block in blocks
                                  for row in block.rows[:, [0, 1, 2, 5, 6]].tolist()])
        finally:
            drop_world("blocks-test")
    assert len(heard["lines"]) > 50
    assert heard["blocks"] == heard["lines"]
