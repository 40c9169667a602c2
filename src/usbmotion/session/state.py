"""The machine's states and the transitions between them.

::

                 home()                 done
      +-------> HOMING ---------------------------+
      |            | fault                        |
      |            v                              v
    IDLE <----- ALARM <------- fault -------- (any)       IDLE --run()--> RUN
      ^   reset()                                          RUN --completed--> IDLE
      |                                                    RUN --stop asked--> HOLD
      +------------- at rest (program abandoned) --------- HOLD
                                                           HOLD --resume--> RUN
                                                           RUN --fault / link lost--> ALARM

- ``IDLE``: connected, nothing moving; homed or not (:attr:`MachineSession.homed`).
- ``HOMING``: the homing cycle runs; a stop request brings every axis to rest along its
  deceleration and leaves the machine ``IDLE`` and not homed.
- ``RUN``: a program is streaming.
- ``HOLD``: the machine decelerates along the program's path to rest. After a stop
  request it becomes ``IDLE`` once every axis is at rest, the rest of the program dropped;
  after a feed hold it stays at rest, servos enabled, keeping the program's place, until a
  resume (back to ``RUN``, the path continued from there) or a stop (``IDLE``).
- ``ALARM``: a device latched a fault, a link was lost or an axis could not be stopped:
  nothing moves until :meth:`MachineSession.reset`, which clears the faults and, when a
  fault disabled a servo (position may be lost), requires homing again.
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import Enum

from usbmotion.errors import MachineStateError


class MachineState(Enum):
    """What the machine is doing."""

    IDLE = "Idle"
    HOMING = "Homing"
    RUN = "Run"
    HOLD = "Hold"
    ALARM = "Alarm"


TRANSITIONS: Mapping[MachineState, frozenset[MachineState]] = {
    MachineState.IDLE: frozenset({MachineState.HOMING, MachineState.RUN, MachineState.ALARM}),
    MachineState.HOMING: frozenset({MachineState.IDLE, MachineState.ALARM}),
    MachineState.RUN: frozenset({MachineState.IDLE, MachineState.HOLD, MachineState.ALARM}),
    MachineState.HOLD: frozenset({MachineState.IDLE, MachineState.RUN, MachineState.ALARM}),
    MachineState.ALARM: frozenset({MachineState.IDLE}),
}
"""Every state a state may change to (documented in the module docstring)."""


def check_transition(current: MachineState, wanted: MachineState) -> None:
    """Raise unless ``current`` may change to ``wanted``.

    Raises:
        MachineStateError: the transition is not one of :data:`TRANSITIONS` (names both
            states and what is allowed).
    """
    if wanted not in TRANSITIONS[current]:
        allowed = ", ".join(sorted(s.value for s in TRANSITIONS[current]))
        raise MachineStateError(
            f"the machine is in {current.value}: it cannot go to {wanted.value}"
            f" (from {current.value}: {allowed})", state=current.value)


class StopReason(Enum):
    """Why a run or a homing ended: the report says it in these words."""

    COMPLETED = "completed"
    USER = "interrupted by the user"
    TERMINATED = "terminated (SIGTERM)"
    FAULT = "fault"
    JOG_CANCELLED = "jog cancelled"
    LINK = "link lost"
