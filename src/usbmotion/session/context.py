"""What a run needs of the session that starts it (:class:`RunContext`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from usbmotion.host.config import MachineConfig
from usbmotion.host.machine import Machine
from usbmotion.motion.gcode import Pause
from usbmotion.session.live import LiveModel
from usbmotion.session.requests import RequestQueue
from usbmotion.session.state import StateMachine


@dataclass(slots=True)
class RunContext:
    """What a run needs of the session that starts it.

    Fields:
        machine, config: the machine; ``states`` its state; ``requests`` the operator's
            requests; ``live`` the live model.
        live_control: a front may ask for holds, resumes and overrides while it runs
            (requests are looked at every :data:`~usbmotion.session.run.REQUEST_CHECK_S`, else every
            :data:`~usbmotion.session.watch.FAULT_CHECK_S`; the live model is fed 50 times
            a second or more).
        keep_alive_s: how often the devices need a command while the run waits at rest
            (0: no watchdog); ``keep_alive`` sends one to each.
        on_pause: called when the run comes to rest at a program pause (None: left it).
        live_fields: what the live model shows of the session (offsets, tool, ...).
    """

    machine: Machine
    config: MachineConfig
    states: StateMachine
    requests: RequestQueue
    live: LiveModel
    live_control: bool = False
    keep_alive_s: float = 0.0
    keep_alive: Callable[[], None] = lambda: None
    on_pause: Callable[[Pause | None], None] = lambda _: None
    live_fields: Callable[[], dict[str, object]] = dict
