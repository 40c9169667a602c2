"""The checkers of the conformance tests: a transcript replayed against the front on the
fake machine byte for byte, a status report's format, a character-counting sender, and the
path the machine executed against the program's.

Each returns the differences it found, in words (empty: conforms), so a test can also show
that a deliberate mistake is caught.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from tests.grbl.harness import Bench

from usbmotion.grbl.protocol import GrblProtocol


@dataclass(frozen=True, slots=True)
class Send:
    """Bytes from the sender (the front is polled once after)."""

    data: bytes


@dataclass(frozen=True, slots=True)
class Wait:
    """Virtual time passing, the front polled every 5 ms."""

    seconds: float


@dataclass(frozen=True, slots=True)
class Expect:
    """Exactly the bytes the front wrote since the previous Expect (or the start)."""

    data: bytes


@dataclass(frozen=True, slots=True)
class Do:
    """Something done to the machine (a fault armed, a switch pressed)."""

    what: str
    action: Callable[[Bench], None]


Step = Send | Wait | Expect | Do


@dataclass(frozen=True, slots=True)
class Exchange:
    """One recorded exchange: how grbl 1.1 answers, from its documentation."""

    name: str
    steps: tuple[Step, ...]
    homed: bool = True
    """Home first (the fake machine starts in alarm, not homed), output discarded."""
    machine: dict[str, object] = field(default_factory=dict)
    """Options for the fake machine."""


def replay(exchange: Exchange, *,
           front: Callable[[Bench], GrblProtocol] | None = None) -> list[str]:
    """Replay ``exchange``; each step where the bytes differ, in words.

    Parameters:
        front: builds another front for the bench (to show a broken one is caught).
    """
    bench = Bench.make(**exchange.machine)
    if front is not None:
        bench.front = front(bench)
        bench.take()
        bench.front.connect()
    if exchange.homed:
        bench.unlocked()
    problems: list[str] = []
    for index, step in enumerate(exchange.steps):
        if isinstance(step, Send):
            bench.front.receive(step.data)
            bench.run()
        elif isinstance(step, Wait):
            bench.run(step.seconds)
        elif isinstance(step, Do):
            step.action(bench)
        else:
            got = bench.take()
            if got != step.data:
                problems.append(f"step {index}: expected {step.data!r}, got {got!r}")
    return problems


_STATES = ("Idle", "Run", "Hold:0", "Hold:1", "Jog", "Alarm", "Door:0", "Door:1", "Door:2",
           "Door:3", "Check", "Home", "Sleep")
_FIELD = re.compile(r"([A-Za-z]+):(.*)")


def status_report_problems(line: str, *, axes: int, inches: bool = False) -> list[str]:
    """What is wrong with one status report line against interface.md's format, and
    against what cncjs reads (the fields it parses: MPos/WPos, WCO, Bf, Ln, FS, Ov, Pn).
    ``inches``: ``$13=1``, positions with 4 decimals and feeds with 1."""
    places = 4 if inches else 3
    problems: list[str] = []
    if not (line.startswith("<") and line.endswith(">")):
        return [f"{line!r} is not enclosed in < >"]
    fields = line[1:-1].split("|")
    if fields[0] not in _STATES:
        problems.append(f"state {fields[0]!r} is not one of {', '.join(_STATES)}")
    if len(fields) < 2 or not fields[1].startswith(("MPos:", "WPos:")):
        problems.append("the second field is not MPos: or WPos:")
    seen: set[str] = set()
    for text in fields[1:]:
        match = _FIELD.fullmatch(text)
        if match is None:
            problems.append(f"field {text!r} is not type:values")
            continue
        kind, values = match.groups()
        if kind in seen:
            problems.append(f"field {kind} twice")
        seen.add(kind)
        parts = values.split(",")
        if kind in ("MPos", "WPos", "WCO", "FE"):
            if len(parts) != axes:
                problems.append(f"{kind} has {len(parts)} values for {axes} axes")
            if not all(re.fullmatch(rf"-?\d+\.\d{{{places}}}", p) for p in parts):
                problems.append(f"{kind} values {values!r} do not have {places} decimals")
        elif kind == "FS":
            feed = r"\d+\.\d" if inches else r"\d+"
            if len(parts) != 2 or not re.fullmatch(feed, parts[0]) or \
                    not re.fullmatch(r"\d+", parts[1]):
                problems.append(f"FS:{values} is not a feed and a spindle speed")
        elif kind in ("Bf", "Ov"):
            expected = 3 if kind == "Ov" else 2
            if len(parts) != expected or not all(re.fullmatch(r"\d+", p) for p in parts):
                problems.append(f"{kind}:{values} is not {expected} whole numbers")
        elif kind == "Ln":
            if not re.fullmatch(r"\d+", values):
                problems.append(f"Ln:{values} is not a line number")
        elif kind == "Pn":
            if not re.fullmatch(r"[XYZABCPDHRS]+", values):
                problems.append(f"Pn:{values} has letters grbl does not use")
        else:
            problems.append(f"field {kind} is none that grbl 1.1 or this front defines")
    if "FS" not in seen and "F" not in seen:
        problems.append("no FS: field")
    return problems


@dataclass(slots=True)
class StreamResult:
    """What a character-counting sender saw."""

    responses: list[str]
    max_in_flight_bytes: int
    messages: list[str]


def stream_counting(bench: Bench, program: Sequence[str], *, rx_bytes: int = 128,
                    limit_s: float = 120.0, greedy: bool = False) -> StreamResult:
    """Stream ``program`` the way interface.md's character-counting protocol says: send
    while the bytes not yet answered fit in ``rx_bytes``; each ``ok``/``error`` frees its
    line's bytes. ``greedy`` sends everything at once (a sender that does not count)."""
    lines = [f"{text}\n".encode() for text in program]
    in_flight: list[int] = []
    responses: list[str] = []
    messages: list[str] = []
    largest = 0
    pending = b""
    sent = 0
    end = bench.clock.now_s + limit_s
    while len(responses) < len(lines):
        if bench.clock.now_s > end:
            raise AssertionError(f"{len(responses)} answers of {len(lines)} in {limit_s} s")
        while sent < len(lines) and (greedy or sum(in_flight) + len(lines[sent]) <= rx_bytes):
            bench.front.receive(lines[sent])
            in_flight.append(len(lines[sent]))
            sent += 1
        largest = max(largest, sum(in_flight))
        bench.run(0.005)
        pending += bench.take()
        while b"\r\n" in pending:
            raw, pending = pending.split(b"\r\n", 1)
            text = raw.decode()
            if text == "ok" or text.startswith("error:"):
                responses.append(text)
                in_flight.pop(0)
            elif text:
                messages.append(text)
    return StreamResult(responses, largest, messages)


def path_problems(executed: Sequence[tuple[float, ...]],
                  expected: Sequence[tuple[float, ...]], *, tolerance_mm: float = 1e-6
                  ) -> list[str]:
    """Where the executed move end points differ from the program's."""
    problems: list[str] = []
    if len(executed) != len(expected):
        problems.append(f"{len(executed)} moves executed, the program has {len(expected)}")
    for index, (got, want) in enumerate(zip(executed, expected, strict=False)):
        if len(got) != len(want) or any(abs(g - w) > tolerance_mm
                                        for g, w in zip(got, want, strict=False)):
            problems.append(f"move {index}: ended at {got}, the program says {want}")
    return problems
