"""A machine session driven while it moves: what a console or a sender front needs.

A :class:`MachineSession` does one thing at a time on the calling thread (home, run, jog).
An :class:`Operator` gives it a worker thread, so a front keeps reading its operator while
the machine moves: G-code lines (MDI, or a program streamed line by line) go into one
:class:`~usbmotion.session.feed.ProgramFeed` whose modal state lasts between lines, as a
controller's does, and the worker runs it whenever it holds moves; a hold, a resume, a
stop, a jog cancel and the overrides are requests the session takes at once. The worker
alone talks to the devices; what a front shows comes from the session's live model
(:attr:`MachineSession.live`), which the runs feed while the machine moves and
:meth:`Operator.keep_alive` refreshes at rest.

A feed hold is latched until a cycle start, as grbl latches it: asked while the machine is
idle (or while a run is finishing), the next motion starts held and waits for the resume.
"""

from __future__ import annotations

import queue
import re
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import TypeVar

from usbmotion.errors import MachineStateError, UsbMotionError
from usbmotion.host.config import MachineConfig
from usbmotion.motion.dialects import Dialect
from usbmotion.motion.gcode import Pause
from usbmotion.session.feed import FRONT_HORIZON_S, FRONT_WINDOW_MOVES, ProgramFeed
from usbmotion.session.live import LiveSnapshot
from usbmotion.session.planning import program_axes
from usbmotion.session.probing import ProbeMode, probing_line
from usbmotion.session.report import RunReport
from usbmotion.session.session import MachineSession
from usbmotion.session.state import MachineState, StopReason

Action = Callable[[], None]
T = TypeVar("T")


_STEP = re.compile(r"\s*([A-Za-z])\s*=?\s*([-+]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+]?\d+)?)")


def parse_steps(words: list[str]) -> dict[str, float]:
    """``["X", "10", "Y-5"]`` -> ``{"X": 10.0, "Y": -5.0}``: each axis once, in mm.

    Raises:
        ValueError: the words are no AXIS DISTANCE pairs (the message shows where).
    """
    text = " ".join(words)
    steps: dict[str, float] = {}
    at = 0
    while text[at:].strip():
        match = _STEP.match(text, at)
        if match is None:
            raise ValueError(f"{text[at:].strip()!r} is no AXIS DISTANCE pair (X 10, Y-2.5)")
        letter = match.group(1).upper()
        if letter in steps:
            raise ValueError(f"axis {letter} is given twice")
        steps[letter] = float(match.group(2)) + 0.0  # -0 is 0
        at = match.end()
    if not steps:
        raise ValueError("give at least one AXIS DISTANCE pair (X 10, Y-2.5)")
    return steps


class Operator:
    """A session with a worker thread (see the module docstring); a context manager.

    Parameters:
        session: the session (its live control is turned on).
        on_message: called (from the worker) with what the operator should hear: a run's
            end, a pause and its message, an error of the worker.
        file: the name errors give the lines written (``<mdi>``).
        window: the most moves the feed holds that the machine has not executed, and
            ``horizon_s`` the most planned seconds of them: a line beyond either waits
            (a sender's ``ok`` follows the machine, as grbl's 15-block planner makes it).
        dialect: the lines are read in it (default: the machine file's).
    """

    def __init__(self, session: MachineSession, *,
                 on_message: Callable[[str], None] | None = None,
                 file: str = "<mdi>", window: int = FRONT_WINDOW_MOVES,
                 horizon_s: float = FRONT_HORIZON_S, dialect: Dialect | None = None) -> None:
        session.live_control = True
        session.on_pause = self._on_pause
        self.session = session
        self.on_message = on_message or (lambda _: None)
        self.file = file
        self.window = window
        self.horizon_s = horizon_s
        self.dialect = dialect
        """The dialect the lines are read in (None: the machine file's)."""
        self.feed: ProgramFeed | None = None
        self.last_report: RunReport | None = None
        self.last_error: str = ""
        self._actions: queue.Queue[tuple[Action, threading.Event | None] | None] = \
            queue.Queue()
        self._pending = 0
        """Actions queued or running: counted up before one is queued and down once it has
        ended, so the operator is never seen idle between taking an action and starting it."""
        self.last_failure: UsbMotionError | None = None
        """The error of the last action that failed, until a front takes it (sets it to
        None): for a front that tells failures apart (a probe that found nothing is grbl's
        alarm 5)."""
        self._pending_lock = threading.Lock()
        self._run_queued = False
        self._unrun = False
        """The feed holds moves no run has taken yet."""
        self._probing = False
        """A probing line waits or runs: the lines after it wait."""
        self._lock = threading.Lock()
        self.lines_waiting: Callable[[], bool] | None = None
        """Asked before a streamed run that played out everything it was given ends: True
        while the front holds lines it is about to write (a sender's lines in a receive
        buffer), so the run waits for them rather than ending and starting again."""
        self.on_idle: Callable[[], None] | None = None
        """Called before each idle read, holding the links (a simulated machine in real
        time keeps its clock in step with the wall clock there)."""
        self.unlocked = False
        """True once the operator unlocked an unhomed machine (grbl's ``$X``): lines then
        run in the devices' own counts, without soft limits, until it is homed."""
        self._links = threading.Lock()
        """Held by whoever talks to the devices: the worker, or an idle keep-alive."""
        session.read_live()
        self._thread = threading.Thread(target=self._serve, name="usbmotion-operator",
                                        daemon=True)
        self._thread.start()

    # --- what the fronts call ---------------------------------------------------------------

    @property
    def busy(self) -> bool:
        """True while the worker homes, runs or jogs, or has something queued."""
        return self._pending > 0

    def status(self) -> LiveSnapshot:
        """The machine now: the session's live model, with a hold asked since it was last
        published (never waits on a device)."""
        snapshot = self.session.live.read()
        pending = self.session.hold_requested
        return snapshot if snapshot.hold_pending == pending else replace(
            snapshot, hold_pending=pending)

    def submit(self, line: str) -> bool:
        """A G-code line for the machine: interpreted at once (an invalid line raises and
        changes nothing) and run as soon as it holds motion, after what is queued; False
        when the planner's window or horizon is full, or the last run is still finishing
        (try again).

        Raises:
            GCodeError, PlanningError: the line is invalid or leaves the travel.
            MachineStateError: the machine is in Alarm, homing, or not homed.
        """
        session = self.session
        with self._lock:
            if session.state is MachineState.ALARM:
                raise MachineStateError("the machine is in Alarm: reset it first",
                                        state=session.state.value)
            if session.state is MachineState.HOMING:
                raise MachineStateError("the machine is homing", state=session.state.value)
            if self._probing:
                return False  # the lines after a probe go on from where it stopped
            probing = probing_line(line)
            if probing is not None:
                return self._submit_probe(*probing)
            feed = self.feed
            if feed is not None and feed.homed != session.is_homed and not self.busy:
                feed = self.feed = None
            if feed is None:
                if self.busy:
                    return False
                feed = self._open_feed()
                self._unrun = False
            elif feed.closed:
                if self.busy:
                    return False
                feed.restart(self._where())
                self._unrun = False
            if not feed.add(line):
                return False
            self._unrun = self._unrun or feed.has_moves
            if not (feed.has_moves or self._run_queued or self.busy
                    or session.hold_requested):
                self._put(self._keep_modes)
            self._queue_run()
            return True

    def _open_feed(self) -> ProgramFeed:
        """A new feed for the lines from where the machine stands (under :attr:`_lock`):
        unhomed only when the operator unlocked a machine that is not homed. Called on a
        front's thread while the machine is idle, it reads where the machine stands from
        the live model (refreshed after every action and by :meth:`keep_alive`): only the
        worker and the keep-alive talk to the devices."""
        session = self.session
        unhomed = self.unlocked and not session.is_homed
        start = self._where() if session.is_homed or unhomed else None
        feed = self.feed = session.open_feed(
            file=self.file, unhomed=unhomed, window=self.window, horizon_s=self.horizon_s,
            dialect=self.dialect, start_mm=start)
        feed.more_coming = self._more_coming
        return feed

    def _submit_probe(self, mode: ProbeMode, move: str) -> bool:
        """A probing line (its G38.n read as G1 in ``move``): run once the motion before it
        has ended, alone (:meth:`MachineSession.probe`); the lines after it wait, and go on
        from where the probe stopped (under :attr:`_lock`). False while anything runs or
        waits to."""
        session = self.session
        if self.busy or self._run_queued or self._unrun:
            if self.feed is not None and not self.feed.closed:
                self.feed.close()  # no line joins the run before the probe: it ends
            return False
        if not session.is_homed:
            raise MachineStateError(f"{mode.code} needs a homed machine (its soft limits):"
                                    " home it first", state=session.state.value)
        feed = self.feed
        if feed is None or feed.homed != session.is_homed:
            feed = self._open_feed()
        elif feed.closed or feed.has_moves:
            feed.restart(self._where())
        try:
            target, feed_mm_min = feed.probe_target(move)
        except BaseException:
            feed.restart(self._where())
            raise
        axes = program_axes(session.config)
        goal = dict(zip(axes, target, strict=True))

        def go() -> None:
            try:
                result = session.probe(goal, feed_mm_min=feed_mm_min, mode=mode)
            finally:
                with self._lock:
                    feed.restart(self._where())
                    self._probing = False
            shown = " ".join(f"{name}{value:.3f}" for name, value in result.position_mm.items())
            self.on_message(f"{mode.code}: {'contact' if result.tripped else 'no contact'}"
                            f" at {shown} (machine)")

        self._probing = True
        self._put(go)
        return True

    def measured_tool(self, line: str = "") -> None:
        """A tool was measured outside the feed (the setter's moves): the lines after go on
        from where the machine stands, reading the tool table as it is now; ``line``, a
        line of modes alone (grbl's ``G43.1 Z...``), is taken first.

        Raises:
            GCodeError: ``line`` is not a line of modes the dialect reads.
        """
        tools = self.session.tool_table()
        with self._lock:
            feed = self.feed
            if feed is None and line:
                feed = self._open_feed()
            if feed is not None:
                feed.restart(self._where())
                feed.use_tools(tools)
                if line:
                    feed.add(line)

    def _keep_modes(self) -> None:
        """A line of modes alone (``G55``, ``G10 L20 P1 X0``, ``G92 Z0``, ``M8``) taken while
        nothing runs: the offsets and coordinate system it leaves kept in the parameter
        file, as a run that ends keeps them, and shown in the live model at once; the
        coolant switched at once."""
        with self._lock:
            feed = self.feed
            if feed is None or feed.has_moves or self._run_queued:
                return
            program = feed.program()
        session = self.session
        try:
            if program.offsets != session.work_offsets():
                session.save_work_offsets(program.offsets)
        except OSError as error:
            self.on_message(f"the work offsets could not be kept: {error}")
        session.coolant_now(program.outputs)

    def _queue_run(self) -> None:
        """The feed's run queued for the worker, unless it is, or a hold latched while idle
        keeps it waiting for the resume (under :attr:`_lock`)."""
        if self._unrun and not self._run_queued and not self.session.hold_requested:
            self._run_queued = True
            self._put(self._run_feed)

    def hold(self) -> None:
        """Feed hold (``!``): a running program decelerates along its path to rest; asked
        while idle, the next motion starts held. Either way until :meth:`resume` (or
        :meth:`stop`, :meth:`drop_held`). During a jog it cancels the jog; ignored in
        Alarm and while homing."""
        self.session.request_hold()

    @property
    def hold_pending(self) -> bool:
        """True from a feed hold until the resume that releases it."""
        return self.session.hold_requested

    def resume(self) -> None:
        """Cycle start (``~``): resume a hold or a pause, or release a hold latched while
        idle (the lines that came meanwhile start running)."""
        self.session.request_resume()
        with self._lock:
            self._queue_run()

    def reset(self) -> None:
        """A controller reset (grbl's Ctrl-X): stop what runs (along its deceleration), drop
        a latched hold and the lines that waited, and reset the lines' modal state as the
        dialect's controller does (grbl: back to power-on, the G92 offset cleared), once
        the machine is at rest."""
        busy = self.busy
        if busy:
            self.stop()
        self.drop_held()
        with self._lock:
            self._unrun = False  # what the feed held, no run takes

        def reset_feed() -> None:
            with self._lock:
                if self.feed is not None:
                    self.feed.reset(self._where())
                    self._unrun = False

        if self.feed is None:
            return
        if busy:
            self._put(reset_feed)  # once the machine is at rest
        else:
            reset_feed()

    def drop_held(self) -> None:
        """Forget a feed hold asked while idle and the lines that came since, which no run
        has taken (a reset while idle); the modal state stays."""
        self.session.drop_hold()
        with self._lock:
            if self._unrun and not self._run_queued and self.feed is not None:
                self.feed.restart(self._where())
                self._unrun = False

    def stop(self) -> None:
        """Stop (Ctrl-X): every axis to rest along its deceleration, what is queued dropped;
        the machine stays homed and Idle. A pending hold is forgotten."""
        self.session.request_stop(StopReason.OPERATOR.value)

    def jog(self, moves: Mapping[str, float], *, feed_mm_min: float, work: bool = False,
            absolute: bool = False, continuous: bool = False) -> None:
        """Queue a jog (:meth:`MachineSession.jog`); its errors reach :attr:`on_message`.

        Raises:
            MachineStateError: a program runs (a jog runs from Idle).
        """
        if self.busy:
            raise MachineStateError("the machine is busy: a jog runs from Idle",
                                    state=self.session.state.value)

        def go() -> None:
            report = self.session.jog(moves, feed_mm_min=feed_mm_min, work=work,
                                      absolute=absolute, continuous=continuous)
            self._ended(report)

        self._put(go)

    def do(self, action: Action) -> None:
        """Queue ``action`` (it may use the session and its devices) for the worker, after
        what it is doing and what is queued."""
        self._put(action)

    def call(self, action: Callable[[], T], *, timeout_s: float) -> T:
        """Run ``action`` on the worker, after what is queued, and return its result once
        the worker has ended it (so the operator is no longer busy on its account).

        Raises:
            UsbMotionError: what ``action`` raised.
            TimeoutError: it did not end within ``timeout_s``.
        """
        ended = threading.Event()
        result: list[T] = []
        failure: list[UsbMotionError] = []

        def go() -> None:
            try:
                result.append(action())
            except UsbMotionError as error:
                failure.append(error)

        self._put(go, ended)
        if not ended.wait(timeout_s):
            raise TimeoutError(f"the machine did not answer within {timeout_s:g} s")
        if failure:
            raise failure[0]
        return result[0]

    def jog_cancel(self) -> None:
        """Cancel a jog (0x85)."""
        self.session.request_jog_cancel()

    def home(self) -> None:
        """Queue homing every axis (from Alarm too: homing resets first, as grbl's ``$H``).

        Raises:
            MachineStateError: the machine is busy.
        """
        if self.busy:
            raise MachineStateError("the machine is busy", state=self.session.state.value)

        def go() -> None:
            seconds = self.session.home()
            self.on_message(f"homed in {seconds:.2f} s")

        self._put(go)

    def reconfigure(self, config: MachineConfig) -> tuple[str, ...]:
        """A changed machine file taken while idle (:meth:`MachineSession.reconfigure`):
        the axes that need homing again. The lines' modal state stays.

        Raises:
            MachineStateError: the machine is busy, or not idle.
            ConfigError: the change needs a restart.
        """
        if self.busy:
            raise MachineStateError("the machine is busy", state=self.session.state.value)
        with self._links, self._lock:
            unhomed = self.session.reconfigure(config)
            if self.feed is not None:
                self.feed.reconfigure(config)
                if unhomed:
                    self.feed = None  # its positions were homed ones
            return unhomed

    def keep_alive(self) -> None:
        """When idle: feed the watchdogs, take the operator's requests and refresh the live
        model from the devices; the worker's own actions keep the watchdogs fed while it
        works. Never waits for the worker."""
        if self.busy or not self._links.acquire(blocking=False):
            return
        try:
            if not self.busy:
                if self.on_idle is not None:
                    self.on_idle()
                self.session.requests.take()
                self.session.read_live()
        finally:
            self._links.release()

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Until nothing is queued or running; False on the timeout."""
        done = threading.Event()
        self._put(done.set)
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        if not done.wait(timeout_s):
            return False
        while self.busy:
            if deadline is not None and time.monotonic() > deadline:
                return False
            time.sleep(0.001)
        return True

    def close(self) -> None:
        """Stop what runs and end the worker."""
        self.session.request_stop("the front closed")
        self._actions.put(None)
        self._thread.join(timeout=10)

    def __enter__(self) -> Operator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- the worker -----------------------------------------------------------------------------

    def _put(self, action: Action, ended: threading.Event | None = None) -> None:
        """Queue ``action`` for the worker, busy from now until it has ended (then
        ``ended`` is set, when given)."""
        with self._pending_lock:
            self._pending += 1
        self._actions.put((action, ended))

    def _serve(self) -> None:
        while True:
            item = self._actions.get()
            if item is None:
                return
            action, ended = item
            with self._links:
                try:
                    self.last_error = ""
                    action()
                except UsbMotionError as error:
                    self.last_error = str(error)
                    self.last_failure = error
                    self.on_message(f"error: {error}")
                finally:
                    self.session.clear_stop_request()
                    try:
                        self.session.read_live()
                    except UsbMotionError as error:
                        self.on_message(f"error: reading the positions: {error}")
                    with self._pending_lock:
                        self._pending -= 1
                    if ended is not None:
                        ended.set()

    def _run_feed(self) -> None:
        with self._lock:
            feed = self.feed
            if self.session.hold_requested or not self._unrun:  # the resume queues it again
                self._run_queued = False
                return
            self._unrun = False
        completed = False
        try:
            if feed is None or not feed.has_moves:
                return
            report, _ = self.session.run_feed(feed)
            completed = report.completed
        finally:
            with self._lock:
                self._run_queued = False
                self._unrun = False  # what came while it ran, it ran (or dropped)
            if feed is not None and not completed and not feed.closed:
                feed.close()
        self._ended(report)
        if not report.completed:
            here = self.session.positions_mm()
            with self._lock:
                feed.restart(tuple(here[name] for name in program_axes(self.session.config)))
                feed.close()

    def _ended(self, report: RunReport) -> None:
        self.last_report = report
        if not report.completed:
            self.on_message(f"stopped: {report.stop_reason}")

    def _more_coming(self) -> bool:
        waiting = self.lines_waiting
        return waiting is not None and waiting()

    def _on_pause(self, pause: Pause) -> None:
        self.on_message(f"paused at line {pause.line} ({pause.code}): {pause.message};"
                        " ~ resumes")

    def _where(self) -> tuple[float, ...]:
        """Where a new program starts: where the machine is commanded to stand."""
        where = self.session.live.read().machine_mm(measured=False)
        return tuple(where[name] for name in program_axes(self.session.config))


IDLE_READ_S = 0.1
"""How often a front's :class:`IdleReader` reads an idle machine."""


class IdleReader:
    """Reads an idle machine for a front, on a thread of its own: every ``period_s`` the
    operator's :meth:`Operator.keep_alive` (its watchdogs fed, its positions and switches
    current in the live model); a read that fails goes to ``on_error``.

    Parameters:
        operator: the session's operator.
        on_error: told of each read that failed.
        name: the thread's name.
        period_s: how often.
    """

    def __init__(self, operator: Operator, *, on_error: Callable[[UsbMotionError], None],
                 name: str, period_s: float = IDLE_READ_S) -> None:
        self.operator = operator
        self.on_error = on_error
        self.period_s = period_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, name=name, daemon=True)

    def start(self) -> None:
        """Begin reading."""
        self._thread.start()

    def close(self) -> None:
        """Stop reading (safe when never started)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)

    def _read(self) -> None:
        while not self._stop.wait(self.period_s):
            try:
                self.operator.keep_alive()
            except UsbMotionError as error:
                self.on_error(error)


__all__ = ["IdleReader", "Operator", "parse_steps"]
