"""What a run tells the live model as it goes: from the device clock of the devices' last
diagnostics lines, the row of the setpoints they execute, so the program line, how far the
program is (by line and by planned time) and what is left."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from usbmotion.motion.gcode import GCodeProgram
from usbmotion.session.feeding import Feeding
from usbmotion.session.legs import Legs
from usbmotion.session.live import LiveModel
from usbmotion.session.state import MachineState
from usbmotion.session.streaming import RunStreams

PROGRESS_S = 0.05
"""With someone following the live model, a run publishes it at least this often in device
time, however fast (virtual) time runs."""


class RunProgress:
    """A run's reports to the live model.

    Parameters:
        live: the model; ``legs``, ``streams``, ``feeding`` the run's parts.
        program: the program run (a fed program's total lines grow as they come).
        fields: what the live model shows of the session besides (offsets, tool).
        hear: brings the lines the devices sent so far into the live model (before a
            publication reads it).
    """

    def __init__(self, live: LiveModel, legs: Legs, streams: RunStreams, feeding: Feeding,
                 program: GCodeProgram, *, fields: Callable[[], dict[str, object]],
                 hear: Callable[[], None]) -> None:
        self.live, self.legs, self.streams, self.feeding = live, legs, streams, feeding
        self.program = program
        self.fields = fields
        self.hear = hear
        self.axes = streams.axes
        self.published_tick = 0
        self.progress_ticks = max(1, round(PROGRESS_S / live.tick_s))

    def row_at_tick(self, tick: int) -> float:
        """The row of the setpoints due at device tick ``tick``: no further than the last
        row the devices were given (at a pause they wait on it while the clock runs on)."""
        row = (tick - self.streams.start_tick) / self.streams.scalar
        released = self.streams.released
        return min(row, released - 1) if released > 0 else row

    def line_at_tick(self, tick: int) -> int:
        """The program line the devices execute at device tick ``tick``."""
        return self.legs.place(self.row_at_tick(tick)).line if self.legs.count else 0

    def segments_at_ticks(self, ticks: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        """The plan segment the devices execute at each device tick of ``ticks`` (the
        last one from the end of the rows on)."""
        if not self.legs.count:
            return np.zeros(ticks.shape, dtype=np.int64)
        rows = (ticks - self.streams.start_tick).astype(np.float64) / self.streams.scalar
        segments = self.legs.segments(rows)
        segments[segments < 0] = max(0, len(self.legs.plan) - 1)
        return segments

    def wanted(self, *, force: bool = False) -> bool:
        """Whether :meth:`publish` may publish now: ``force``, a listener following the
        live model, or :data:`~usbmotion.session.live.PUBLISH_S` passed since the last
        snapshot (a caller skips gathering the fields when not)."""
        live = self.live
        return force or bool(live.on_publish) or live.due()

    def publish(self, state: MachineState, *, force: bool, at_rest: bool, hold_pending: bool,
                pause: str, line: int = 0) -> None:
        """Publish the live model (at most every :data:`~usbmotion.session.live.PUBLISH_S`
        of wall time, and with a listener every :data:`PROGRESS_S` of device time, unless
        ``force``); ``line``: the line executing, when the run knows it better than the rows
        do (a pause's: its zero-second dwell ends where the next line begins)."""
        if not self.wanted(force=force):
            return
        live = self.live
        self.hear()
        ticks = live.ticks(self.axes)
        tick = min(ticks) if ticks else 0
        if not (force or live.due() or tick - self.published_tick >= self.progress_ticks):
            return
        self.published_tick = tick
        legs = self.legs
        row = self.row_at_tick(tick) if ticks and self.streams.sync else 0.0
        place = legs.place(row)
        total_s = legs.plan.duration_s
        lines_total = max(self.program.end_line, self.feeding.lines_total())
        # The lines before the one executing are done; all of them once the devices have
        # executed the plan's last setpoint.
        finished = legs.count > 0 and place.program_time_s >= total_s
        line = line or place.line
        live.publish(
            state=state, at_rest=at_rest, hold_pending=hold_pending, program=self.program.file,
            line=line, lines_done=lines_total if finished else max(0, line - 1),
            lines_total=lines_total,
            done_s=min(place.program_time_s, total_s), total_s=total_s,
            eta_s=0.0 if at_rest else legs.left_s(row),
            feed_override=legs.overrides[0], rapid_override=legs.overrides[1], pause=pause,
            **self.fields())
