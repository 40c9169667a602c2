"""Curve mode (control mode 3): the device's keyframe buffer and Hermite player.

The buffer holds up to 8 keyframes not yet reached (every slot can be appended; a full
buffer refuses the keyframe and keeps what it holds). While the servo runs in curve mode
the player gives one desired position per tick, with the semantics of
:func:`usbmotion.hermite.sample_keyframes`:

- a curve starts on the first running tick that finds keyframes while none is playing:
  that tick is tick 0 of the curve at the current desired position, leaving it with a zero
  tangent;
- tick ``k`` of a curve is at ``k * tick_us`` after its start; a tick exactly on a segment
  boundary belongs to the end of the earlier segment (the keyframe's own position), and a
  keyframe leaves the buffer on that tick (its slot is free again);
- keyframes appended while a curve plays extend it seamlessly (the next segment leaves the
  last keyframe with its out-tangent, on the same time line);
- when the time passes the end of the last keyframe the curve has run dry: the position
  holds at the last keyframe at zero velocity, and the next keyframe starts a new curve.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from usbmotion.hermite import Keyframe, hermite_position
from usbmotion.protocol.table import CURVE_BUFFER_CAPACITY


@dataclass(frozen=True, slots=True)
class _Snapshot:
    buffer: tuple[Keyframe, ...]
    playing: bool
    elapsed_us: int
    start_position: int
    start_tangent: int
    hold: int


class CurvePlayer:
    """The keyframe buffer and the tick-by-tick Hermite evaluation of curve mode."""

    def __init__(self) -> None:
        self._buffer: deque[Keyframe] = deque()
        self._playing = False
        self._elapsed_us = 0
        self._start_position = 0
        self._start_tangent = 0
        self._hold = 0

    @property
    def queued(self) -> int:
        """Keyframes in the buffer (not yet reached)."""
        return len(self._buffer)

    @property
    def free(self) -> int:
        """Free slots in the buffer."""
        return CURVE_BUFFER_CAPACITY - len(self._buffer)

    @property
    def playing(self) -> bool:
        """True while a curve plays (it has not run dry)."""
        return self._playing

    def append(self, keyframe: Keyframe) -> bool:
        """Append a keyframe; False (nothing changed) when the buffer is full."""
        if len(self._buffer) >= CURVE_BUFFER_CAPACITY:
            return False
        self._buffer.append(keyframe)
        return True

    def clear(self, hold_position: int) -> None:
        """Empty the buffer and stop any curve; the position holds at ``hold_position``."""
        self._buffer.clear()
        self._playing = False
        self._elapsed_us = 0
        self._hold = hold_position

    def next_position(self, current_desired: int, tick_us: int) -> int:
        """The desired position of the next running tick, in counts (may exceed int32)."""
        if self._playing:
            self._elapsed_us += tick_us
        elif self._buffer:
            self._playing = True
            self._elapsed_us = 0
            self._start_position = current_desired
            self._start_tangent = 0
        else:
            self._hold = current_desired
            return current_desired
        buffer = self._buffer
        while buffer and self._elapsed_us > buffer[0].duration_ms * 1000:
            done = buffer.popleft()
            self._elapsed_us -= done.duration_ms * 1000
            self._start_position = done.position_counts
            self._start_tangent = done.tangent_out
        if not buffer:
            self._playing = False
            self._hold = self._start_position
            return self._hold
        target = buffer[0]
        position = hermite_position(
            self._start_position,
            target.position_counts,
            self._start_tangent,
            target.tangent_in,
            target.duration_ms,
            self._elapsed_us,
        )
        if self._elapsed_us == target.duration_ms * 1000:
            buffer.popleft()
            self._elapsed_us = 0
            self._start_position = target.position_counts
            self._start_tangent = target.tangent_out
        self._hold = position
        return position

    def ticks_until_reached(self, tick_us: int) -> int | None:
        """Running ticks until the tick that reaches the first buffered keyframe.

        That tick frees its slot. None when the buffer is empty. A curve that has not
        started yet starts on the first running tick.
        """
        if not self._buffer:
            return None
        first_us = self._buffer[0].duration_ms * 1000
        if self._playing:
            return max(1, -(-(first_us - self._elapsed_us) // tick_us))
        return -(-first_us // tick_us) + 1

    def interrupt(self, hold_position: int) -> None:
        """Stop the playing curve but keep the buffer: the next running tick starts a new
        curve from the desired position then (used when the servo is enabled again)."""
        self._playing = False
        self._elapsed_us = 0
        self._hold = hold_position

    def snapshot(self) -> _Snapshot:
        """The player's state, to undo ticks that were computed but not run."""
        return _Snapshot(
            tuple(self._buffer),
            self._playing,
            self._elapsed_us,
            self._start_position,
            self._start_tangent,
            self._hold,
        )

    def restore(self, snapshot: _Snapshot) -> None:
        """Return to a state taken with :meth:`snapshot`."""
        self._buffer = deque(snapshot.buffer)
        self._playing = snapshot.playing
        self._elapsed_us = snapshot.elapsed_us
        self._start_position = snapshot.start_position
        self._start_tangent = snapshot.start_tangent
        self._hold = snapshot.hold
