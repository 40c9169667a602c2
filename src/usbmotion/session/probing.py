"""Probing: G38.2 to G38.5 as LinuxCNC and grbl run them, one line at a time.

A probing line is a straight move toward its target at its feed that stops, along its
deceleration, once the probe input changes: G38.2 and G38.3 on contact, G38.4 and G38.5 on
the loss of it; G38.2 and G38.4 are an error when the move ends without the change, G38.3
and G38.5 end quietly. Every device latches its encoder count on the tick its probe input
changes (call 41), so the contact position is exact to the count however late the host sees
it: an axis whose device latched gives its latched count; an axis whose device did not (no
probe wired to it) is placed on the move's straight line at the latched axis's share of the
way, within its following error.

A program does not probe: the lines after a G38 depend on where it stopped, and a run plans
its program ahead. The console, a grbl sender and the dashboard's MDI send probing lines
one by one (:meth:`usbmotion.session.operator.Operator.submit`), as cncjs's probe widget
and a tool-length setter do.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

from usbmotion.errors import MachineStateError
from usbmotion.host.device import ProbeState
from usbmotion.host.machine import Machine

_PROBE_WORD = re.compile(r"G\s*0*38\s*\.\s*([2-5])(?![0-9])", re.IGNORECASE)
_COMMENT = re.compile(r"\([^)]*\)|;.*$")


@dataclass(frozen=True, slots=True)
class ProbeMode:
    """One of G38.2 to G38.5.

    Fields:
        code: ``"G38.2"`` ...
        toward: the move stops when the probe closes (G38.2, G38.3), else when it opens.
        required: the move ending without that change is an error (G38.2, G38.4).
    """

    code: str
    toward: bool
    required: bool


MODES: Mapping[str, ProbeMode] = {
    "2": ProbeMode("G38.2", toward=True, required=True),
    "3": ProbeMode("G38.3", toward=True, required=False),
    "4": ProbeMode("G38.4", toward=False, required=True),
    "5": ProbeMode("G38.5", toward=False, required=False),
}


def probing_line(line: str) -> tuple[ProbeMode, str] | None:
    """The probing mode of a G-code line and the line with its G38.n read as G1 (the move
    it makes, with the line's other words: distance mode, units, feed), or None for a line
    that does not probe. Comments are not searched."""
    code = _COMMENT.sub(lambda m: " " * len(m.group(0)), line)
    found = _PROBE_WORD.search(code)
    if found is None:
        return None
    return MODES[found.group(1)], line[:found.start()] + "G1" + line[found.end():]


class ProbeFailedError(MachineStateError):
    """A G38.2 or G38.4 ended without the probe changing, or a probing move started with
    the probe already as the move was to make it (grbl's alarms 5 and 4)."""

    def __init__(self, message: str, *, at_start: bool) -> None:
        super().__init__(message, state="Alarm")
        self.at_start = at_start
        """True when the probe was already in the state the move was to reach."""


@dataclass(frozen=True, slots=True)
class ProbeResult:
    """What a probing move found.

    Fields:
        code: the G38 code run.
        tripped: the probe changed during the move.
        position_mm: machine position of every axis at the change (the latched counts), or
            where the move ended when it did not change.
        latched: the axes whose device latched the change.
    """

    code: str
    tripped: bool
    position_mm: Mapping[str, float]
    latched: tuple[str, ...] = ()


def probe_states(machine: Machine) -> dict[str, ProbeState]:
    """Every axis's probe input and its last edge (call 41)."""
    return {name: axis.client.probe() for name, axis in machine.axes.items()}


def probe_touching(states: Mapping[str, ProbeState]) -> bool:
    """Whether the probe touches: any device's probe input closed (the probe line is one)."""
    return any(state.closed for state in states.values())


def changed(before: Mapping[str, ProbeState], after: Mapping[str, ProbeState],
            mode: ProbeMode) -> tuple[str, ...]:
    """The axes whose device latched the change ``mode`` stops on since ``before``."""
    return tuple(name for name, now in after.items()
                 if now.edges != before[name].edges and now.edge_closed == mode.toward)


def contact_position(machine: Machine, latched: tuple[str, ...],
                     after: Mapping[str, ProbeState], start_mm: Mapping[str, float],
                     target_mm: Mapping[str, float]) -> dict[str, float]:
    """Every axis's machine position at the change: latched axes from their counts, the
    others on the move's straight line at the share of the way the latched axis that moves
    the most had gone (an axis that does not move: where it stood)."""
    position = {name: machine.axis(name).scale.to_mm(after[name].position_counts)
                for name in latched}
    leading = max(latched, key=lambda n: abs(target_mm.get(n, start_mm[n]) - start_mm[n]))
    span = target_mm.get(leading, start_mm[leading]) - start_mm[leading]
    share = (position[leading] - start_mm[leading]) / span if abs(span) > 1e-9 else 0.0
    share = min(max(share, 0.0), 1.0)
    for name in machine.axes:
        if name not in position:
            start = start_mm[name]
            position[name] = start + share * (target_mm.get(name, start) - start)
    return position


__all__ = ["MODES", "ProbeFailedError", "ProbeMode", "ProbeResult", "changed",
           "contact_position", "probe_states", "probe_touching", "probing_line"]
