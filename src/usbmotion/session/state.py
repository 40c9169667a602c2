"""The machine's states, each a small unit that decides the next state, and the one door
through which the state changes.

::

               home                    homed / stopped
      +------> HOMING ----------------------------------+
      |          | fault                                 v
    ALARM <------+---------- fault (from any) ------- IDLE ---- start ---> RUN
      |  \\                                              ^  \\--- jog ----> JOG
      |   +--- home -----> HOMING                        |
      +------ reset ------------------------------------>+
                                                          |
    RUN  --hold--> HOLD --resume--> RUN         RUN --pause--> PAUSED --resume--> RUN
    RUN  --done--> IDLE          JOG --done--> IDLE
    RUN, HOLD, PAUSED, JOG --stop--> STOPPING --at rest--> IDLE

- ``IDLE``: connected, nothing moving; homed or not.
- ``HOMING``: grbl's homing cycle runs; a stop brings every axis to rest along its
  deceleration and leaves the machine idle and not homed.
- ``RUN``: a program (or MDI lines) streams to the devices.
- ``HOLD``: a feed hold: every axis decelerates along the program's path to rest and stays
  there, servos enabled, keeping the program's place, until a resume continues the path
  (``at_rest`` tells grbl's ``Hold:1`` from ``Hold:0``).
- ``PAUSED``: at rest at a program pause (M0, M1, M6) until a resume.
- ``JOG``: a jog runs; a jog cancel, a hold or a stop brings it to rest (``STOPPING``).
- ``STOPPING``: every axis decelerates along the path to rest; the rest of the program is
  dropped, and the machine is then idle (still homed).
- ``ALARM``: a device latched a fault, a link was lost, homing failed: nothing moves until
  a reset (or a homing, which resets first, as grbl's ``$H`` does).

:class:`StateMachine` holds the state; :meth:`StateMachine.fire` asks the current state's
unit what an event leads to and changes the state through :meth:`StateMachine._enter`, the
only place the state is assigned, which checks the transition against
:data:`TRANSITIONS` (every unit's possible next states).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from enum import Enum

from usbmotion.errors import MachineStateError


class MachineState(Enum):
    """What the machine is doing."""

    IDLE = "Idle"
    HOMING = "Homing"
    RUN = "Run"
    HOLD = "Hold"
    PAUSED = "Paused"
    JOG = "Jog"
    STOPPING = "Stopping"
    ALARM = "Alarm"


class Event(Enum):
    """What happens to the machine: an operator's request or what the devices did."""

    HOME = "home"
    """Homing starts (from Alarm it resets the devices first)."""
    HOMED = "homed"
    START = "start"
    """A program (or a feed of lines) starts streaming."""
    JOG = "jog"
    HOLD = "hold"
    PAUSE = "pause"
    """The program came to rest at a pause (M0, M1, M6)."""
    RESUME = "resume"
    STOP = "stop"
    """Stop along the deceleration, the rest dropped (a stop request, a jog cancel, a hold
    during a jog, a homing stopped)."""
    AT_REST = "at rest"
    """A stop's deceleration ended: every axis at rest."""
    DONE = "done"
    """The program or jog played out and settled."""
    FAULT = "fault"
    """A device fault, a lost link, a failed homing."""
    RESET = "reset"


class StateUnit:
    """One state: what it means (its docstring) and which event leads where.

    ``next_state`` answers the state an event leads to from here, or None when the event
    does not apply (a caller that needs it raises, one that asked in passing ignores it).
    """

    state: MachineState
    moving: bool = False
    """Whether motion can be under way in this state (a run's, a jog's, homing's)."""
    targets: frozenset[MachineState] = frozenset()
    """Every state this one may lead to."""

    def next_state(self, event: Event, *, at_rest: bool) -> MachineState | None:
        """The state ``event`` leads to (``at_rest``: every axis is at rest now)."""
        raise NotImplementedError


class Idle(StateUnit):
    """Connected, nothing moving: a program, a jog or homing may start."""

    state = MachineState.IDLE
    targets = frozenset({MachineState.HOMING, MachineState.RUN, MachineState.JOG,
                         MachineState.ALARM})

    def next_state(self, event: Event, *, at_rest: bool) -> MachineState | None:
        return {Event.HOME: MachineState.HOMING, Event.START: MachineState.RUN,
                Event.JOG: MachineState.JOG, Event.FAULT: MachineState.ALARM}.get(event)


class Homing(StateUnit):
    """The homing cycle runs; it ends homed (Idle), stopped (Idle, not homed) or failed."""

    state = MachineState.HOMING
    moving = True
    targets = frozenset({MachineState.IDLE, MachineState.ALARM})

    def next_state(self, event: Event, *, at_rest: bool) -> MachineState | None:
        if event in (Event.HOMED, Event.AT_REST):
            return MachineState.IDLE
        return MachineState.ALARM if event is Event.FAULT else None


class Run(StateUnit):
    """A program streams: a hold, a pause, a stop or a fault interrupts it."""

    state = MachineState.RUN
    moving = True
    targets = frozenset({MachineState.HOLD, MachineState.PAUSED, MachineState.STOPPING,
                         MachineState.IDLE, MachineState.ALARM})

    def next_state(self, event: Event, *, at_rest: bool) -> MachineState | None:
        return {Event.HOLD: MachineState.HOLD, Event.PAUSE: MachineState.PAUSED,
                Event.STOP: MachineState.STOPPING, Event.DONE: MachineState.IDLE,
                Event.FAULT: MachineState.ALARM}.get(event)


class Hold(StateUnit):
    """Decelerating to rest along the path, then at rest keeping the program's place: a
    resume continues it once at rest; a stop at rest leaves it (Idle), while still
    decelerating it becomes a stop (Stopping)."""

    state = MachineState.HOLD
    moving = True
    targets = frozenset({MachineState.RUN, MachineState.STOPPING, MachineState.IDLE,
                         MachineState.ALARM})

    def next_state(self, event: Event, *, at_rest: bool) -> MachineState | None:
        if event is Event.RESUME:
            return MachineState.RUN if at_rest else None
        if event is Event.STOP:
            return MachineState.IDLE if at_rest else MachineState.STOPPING
        return MachineState.ALARM if event is Event.FAULT else None


class Paused(StateUnit):
    """At rest at a program pause (M0, M1, M6): a resume continues, a stop leaves it."""

    state = MachineState.PAUSED
    targets = frozenset({MachineState.RUN, MachineState.IDLE, MachineState.ALARM})

    def next_state(self, event: Event, *, at_rest: bool) -> MachineState | None:
        return {Event.RESUME: MachineState.RUN, Event.STOP: MachineState.IDLE,
                Event.FAULT: MachineState.ALARM}.get(event)


class Jog(StateUnit):
    """A jog runs: it ends played out, or a cancel (a stop, or a hold: grbl's feed hold
    cancels a jog) brings it to rest."""

    state = MachineState.JOG
    moving = True
    targets = frozenset({MachineState.IDLE, MachineState.STOPPING, MachineState.ALARM})

    def next_state(self, event: Event, *, at_rest: bool) -> MachineState | None:
        if event in (Event.STOP, Event.HOLD):
            return MachineState.STOPPING
        return {Event.DONE: MachineState.IDLE, Event.FAULT: MachineState.ALARM}.get(event)


class Stopping(StateUnit):
    """Every axis decelerates along the path to rest; then Idle (the rest dropped)."""

    state = MachineState.STOPPING
    moving = True
    targets = frozenset({MachineState.IDLE, MachineState.ALARM})

    def next_state(self, event: Event, *, at_rest: bool) -> MachineState | None:
        if event in (Event.AT_REST, Event.DONE):
            return MachineState.IDLE
        return MachineState.ALARM if event is Event.FAULT else None


class Alarm(StateUnit):
    """A fault latched, a link lost or homing failed: nothing moves until a reset, or a
    homing (which resets first)."""

    state = MachineState.ALARM
    targets = frozenset({MachineState.IDLE, MachineState.HOMING})

    def next_state(self, event: Event, *, at_rest: bool) -> MachineState | None:
        return {Event.RESET: MachineState.IDLE, Event.HOME: MachineState.HOMING}.get(event)


UNITS: Mapping[MachineState, StateUnit] = {unit.state: unit for unit in (
    Idle(), Homing(), Run(), Hold(), Paused(), Jog(), Stopping(), Alarm())}
"""Every state's unit."""

TRANSITIONS: Mapping[MachineState, frozenset[MachineState]] = {
    state: unit.targets for state, unit in UNITS.items()}
"""Every state a state may change to (the units' targets)."""


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


class StateMachine:
    """The machine's state, changed only by :meth:`fire` (safe to read from any thread).

    Parameters:
        on_change: called with (old, new) after every change, on the thread that fired.
    """

    def __init__(self, on_change: Callable[[MachineState, MachineState], None] | None = None
                 ) -> None:
        self._state = MachineState.IDLE
        self._lock = threading.Lock()
        self.on_change = on_change

    @property
    def state(self) -> MachineState:
        """The state now."""
        return self._state

    @property
    def moving(self) -> bool:
        """Whether motion can be under way (Homing, Run, Hold, Jog, Stopping)."""
        return UNITS[self._state].moving

    def allows(self, event: Event, *, at_rest: bool = True) -> bool:
        """Whether ``event`` leads anywhere from the state now."""
        return UNITS[self._state].next_state(event, at_rest=at_rest) is not None

    def fire(self, event: Event, *, at_rest: bool = True) -> MachineState:
        """Take ``event``: the current state's unit decides the next state, entered through
        the one door. Returns the new state.

        Raises:
            MachineStateError: the event does not apply in this state (names both).
        """
        with self._lock:
            current = self._state
            wanted = UNITS[current].next_state(event, at_rest=at_rest)
            if wanted is None:
                raise MachineStateError(
                    f"the machine is in {current.value}: {event.value} does not apply",
                    state=current.value)
            self._enter(wanted)
        if self.on_change is not None and wanted is not current:
            self.on_change(current, wanted)
        return wanted

    def _enter(self, wanted: MachineState) -> None:
        """The one door: the state becomes ``wanted`` (checked against TRANSITIONS)."""
        check_transition(self._state, wanted)
        self._state = wanted


class StopReason(Enum):
    """Why a run or a homing ended: the report says it in these words."""

    COMPLETED = "completed"
    USER = "interrupted by the user"
    TERMINATED = "terminated (SIGTERM)"
    FAULT = "fault"
    JOG_CANCELLED = "jog cancelled"
    LINK = "link lost"
    OPERATOR = "stopped by the operator"
    TOOL_MEASURE = "stopped at the tool change to measure the new tool"
