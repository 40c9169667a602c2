"""The grbl front on the fake machine in virtual time, driven byte by byte."""

from __future__ import annotations

from dataclasses import dataclass, field

from tests.grbl.fake_machine import FakeMachine

from usbmotion.grbl.protocol import GrblProtocol

POLL_S = 0.005
"""The poll cadence the server uses."""


@dataclass(slots=True)
class VirtualClock:
    """Seconds that pass only when the test says."""

    now_s: float = 0.0

    def __call__(self) -> float:
        return self.now_s


@dataclass(slots=True)
class Bench:
    """A front, its fake machine, a virtual clock and everything the front wrote."""

    clock: VirtualClock
    machine: FakeMachine
    front: GrblProtocol
    output: bytearray = field(default_factory=bytearray)

    @classmethod
    def make(cls, **machine_options: object) -> Bench:
        """A bench connected (the banner written), nothing taken yet."""
        clock = VirtualClock()
        machine = FakeMachine(clock, **machine_options)  # type: ignore[arg-type]
        output = bytearray()
        front = GrblProtocol(machine, output.extend)
        bench = cls(clock, machine, front, output)
        front.connect()
        return bench

    def take(self) -> bytes:
        """What was written since the last take."""
        data = bytes(self.output)
        self.output.clear()
        return data

    def run(self, seconds: float = 0.0) -> None:
        """Poll at the server's cadence while ``seconds`` of virtual time pass (at least
        one poll)."""
        end = self.clock.now_s + seconds
        self.front.poll()
        while self.clock.now_s < end - 1e-12:
            self.clock.now_s = min(end, self.clock.now_s + POLL_S)
            self.front.poll()

    def exchange(self, sent: bytes, seconds: float = 0.0) -> bytes:
        """Send bytes, run, and return what came back."""
        self.take()
        self.front.receive(sent)
        self.run(seconds)
        return self.take()

    def run_until_idle(self, limit_s: float = 60.0) -> None:
        """Run until the machine has nothing left to do."""
        end = self.clock.now_s + limit_s
        while self.clock.now_s < end:
            self.run(POLL_S)
            if self.machine.motion_done() and not self.front.rx_bytes_free < 128:
                return
        raise AssertionError(f"the machine still moves after {limit_s} s")

    def unlocked(self) -> Bench:
        """Home (the machine starts in alarm), leaving the output empty."""
        self.front.receive(b"$H\n")
        self.run(1.0)
        self.take()
        return self
