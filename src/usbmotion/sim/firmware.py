"""Run the device firmware (``firmware/``) in the RP2040 emulator (``firmware/emulator``).

Two ways, each a Node.js process on rp2040js per device:

- :class:`EmulatedDevice`, deterministic: power up, give bytes at a servo tick boundary, run a
  number of ticks, and read back every output byte with the tick it arrived at and the cycles
  each core was busy. The differential tests and the budget benchmark drive the firmware so.
- :class:`FirmwareServer`, real time: N emulated devices, each on a TCP port and optionally a
  pseudo-terminal, for the host, ``usbmotion run``, miniterm or any serial client, as real
  devices are.

The emulator needs Node.js 20 (``node`` on the PATH, or ``node=``) and ``npm ci`` run in
``firmware/emulator`` (``make firmware`` does both and builds the UF2).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import selectors
import signal
import socket
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from usbmotion.errors import ArgumentError, DeviceError, DeviceTimeoutError
from usbmotion.protocol import CallNumber, device_name_problem, encode_call, encode_device_name
from usbmotion.protocol.table import INT32_MAX, INT32_MIN
from usbmotion.serving import EventKind, Outbox, PtyEndpoint, Serving

if TYPE_CHECKING:
    from usbmotion.device.motor import MotorParams

_PROJECT_ROOT = Path(__file__).resolve().parents[3]
_QUEUE_QUERY = encode_call(CallNumber.MOTION_QUEUE, -1)
_EMULATOR_ENV = "USBMOTION_EMULATOR_DIR"
_BOOTROM_ENV = "USBMOTION_BOOTROM"
BOOTROM_BYTES = 16384
"""The size of the RP2040's boot ROM (B1)."""
_READ_CHUNK = 65536
_EXIT_WAIT_S = 5.0


def emulator_dir() -> Path:
    """The emulator harness's folder: ``$USBMOTION_EMULATOR_DIR``, else ``firmware/emulator``."""
    override = os.environ.get(_EMULATOR_ENV)
    return Path(override) if override else _PROJECT_ROOT / "firmware" / "emulator"


def default_uf2() -> Path:
    """Where ``make firmware`` writes the firmware: ``build/firmware/usbmotion.uf2``."""
    return _PROJECT_ROOT / "build" / "firmware" / "usbmotion.uf2"


def default_bootrom() -> Path:
    """Where the emulator looks for the RP2040 boot ROM when given none: ``$USBMOTION_BOOTROM``,
    else ``shared/rp2040/bootrom/b1.bin`` beside the project (as ``lib/bootrom.js`` does)."""
    override = os.environ.get(_BOOTROM_ENV)
    if override:
        return Path(override)
    return emulator_dir().resolve().parents[2] / "shared" / "rp2040" / "bootrom" / "b1.bin"


def check_bootrom(bootrom: Path | str | None) -> Path:
    """The boot ROM the emulator is to run: ``bootrom``, else :func:`default_bootrom`.

    Raises:
        FileNotFoundError: there is none, or not 16384 bytes (the message says where it was
            looked for, why, and how to get one).
    """
    given = bootrom is not None
    path = Path(bootrom) if bootrom is not None else default_bootrom()
    where = ("given" if given else f"from ${_BOOTROM_ENV}" if os.environ.get(_BOOTROM_ENV)
             else "beside the project, where the emulator looks by default")
    try:
        size = path.stat().st_size if path.is_file() else -1
    except OSError:
        size = -1
    if size == BOOTROM_BYTES:
        return path
    why = ("no such file" if not path.exists() else "not a file" if size < 0
           else f"{size} bytes, not {BOOTROM_BYTES}")
    raise FileNotFoundError(
        f"no RP2040 boot ROM at {path} ({where}: {why}); the emulator runs the chip's boot"
        f" ROM B1 ({BOOTROM_BYTES} bytes): give --bootrom PATH (or set {_BOOTROM_ENV}); it"
        " is built from github.com/raspberrypi/pico-bootrom (version B1), and wokwi/rp2040js"
        " embeds a copy in demo/bootrom.ts")


def _check_image(uf2: Path, elf: Path | None) -> tuple[Path, Path]:
    elf_path = elf if elf is not None else uf2.with_suffix(".elf")
    for path, what in ((uf2, "UF2 image"), (elf_path, "ELF file (for its symbols)")):
        if not path.is_file():
            raise FileNotFoundError(
                f"firmware {what} {str(path)!r} not found; `make firmware` builds it"
            )
    return uf2, elf_path


def _script(name: str) -> Path:
    script = emulator_dir() / name
    if not (emulator_dir() / "node_modules" / "rp2040js").is_dir():
        raise FileNotFoundError(
            f"the emulator's packages are not installed in {str(emulator_dir())!r}; "
            "run `make firmware` (or `npm ci` there)"
        )
    return script


def _stop_process(process: subprocess.Popen[bytes]) -> None:
    """Ends a child: its stdin closed first (the harness exits on that), then SIGTERM, SIGKILL."""
    if process.stdin is not None:
        with contextlib.suppress(OSError):
            process.stdin.close()
    try:
        process.wait(timeout=_EXIT_WAIT_S)
    except subprocess.TimeoutExpired:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(timeout=_EXIT_WAIT_S)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    for stream in (process.stdout, process.stderr):
        if stream is not None:
            with contextlib.suppress(OSError):
                stream.close()


class _LineReader:
    """Lines from a child's pipe, each within a deadline."""

    def __init__(self, stream: IO[bytes]) -> None:
        self._fd = stream.fileno()
        self._buffer = bytearray()
        self._selector = selectors.DefaultSelector()
        self._selector.register(self._fd, selectors.EVENT_READ)

    def readline(self, timeout_s: float) -> bytes:
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self._buffer:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not self._selector.select(remaining):
                raise TimeoutError
            chunk = os.read(self._fd, _READ_CHUNK)
            if not chunk:
                raise EOFError
            self._buffer += chunk
        end = self._buffer.index(b"\n") + 1
        line = bytes(self._buffer[:end])
        del self._buffer[:end]
        return line

    def close(self) -> None:
        self._selector.close()


# --- deterministic ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class OutputChunk:
    """Bytes the device sent, and the servo tick (ticks done since power-up) they arrived at."""

    tick: int
    data: bytes


@dataclass(frozen=True, slots=True)
class Span:
    """What one request did: the tick it ended at, the output and the cost.

    Fields:
        tick: servo ticks done since power-up when the request ended.
        output: device output during the request, in order, one chunk per tick.
        busy_cycles: cycles core0 and core1 executed (not asleep) during the request.
        emulated_ns: emulated time the request took (the servo timer stands still while
            input is handled, so feeding costs no ticks).
    """

    tick: int
    output: tuple[OutputChunk, ...]
    busy_cycles: tuple[int, int]
    emulated_ns: int

    @property
    def data(self) -> bytes:
        """All the output bytes of the span."""
        return b"".join(chunk.data for chunk in self.output)


@dataclass(frozen=True, slots=True)
class DeviceStatus:
    """Totals since power-up: ticks, busy cycles per core, emulated time."""

    tick: int
    busy_cycles: tuple[int, int]
    emulated_ns: int


@dataclass(frozen=True, slots=True)
class BootTimes:
    """A power-up, emulated nanoseconds from reset: the firmware enabled USB (its pull-up),
    the host had configured the port (after its 10 ms bus reset and enumeration), the first
    byte of the answer to the first line came back; each core's busy cycles by then."""

    usb_enabled_ns: int
    configured_ns: int
    reply_ns: int
    busy_cycles: tuple[int, int]


@dataclass(frozen=True, slots=True)
class StackUsage:
    """One core's stack: the most of it used since power-up and its size, bytes."""

    used: int
    size: int


@dataclass(frozen=True, slots=True)
class PinsMotor:
    """A brushed DC motor on an H-bridge, its quadrature encoder, two limit switches and a
    probe, outside the emulated chip and wired to the firmware's pins
    (``firmware/src/rp2040/pins.h``; the harness's ``lib/pins.js`` MotorWorld): the bridge's
    voltage read from the PWM levels, the motor integrated exactly in binary64 with the
    on-chip simulated motor's model (PROTOCOL.md, "The model"), an encoder edge at each count
    crossed, the switches driven low while the shaft is at or beyond them, the probe's pin low
    while the shaft is at or beyond its surface. The defaults are the on-chip motor's at
    power-up; :meth:`like` copies an on-chip motor's parameters.

    Fields:
        supply_v: the bridge's supply, V.
        torque_constant_nm_per_a: torque (and back-EMF) constant at the output shaft, N m/A.
        resistance_ohm: winding resistance, ohm.
        inertia_kg_m2: inertia at the output shaft, kg m^2.
        viscous_nm_per_rad_s: viscous friction, N m per rad/s.
        load_nm: constant torque opposing motion, N m.
        counts_per_revolution: encoder counts per output revolution (quadrature x4).
        lower_counts, upper_counts: where each switch closes, counts from the first power-up
            (the shaft's position then is count 0); ``None``: no switch.
        overtravel_counts: from each switch to the hard stop beyond it, counts.
        bounces: each switch edge is followed by this many bounces ...
        bounce_interval_us: ... each this long, microseconds: half way through one the pin
            goes back to its level before the edge, at its end it returns.
        probe_side: the probe's surface as call 40 gives it: 0 none (the probe pin is left
            to its pull-up: open), 1 the probe touches at or below ``probe_counts``, 2 at or
            above it.
        probe_counts: the surface, counts from the first power-up.
    """

    supply_v: float = 12.0
    torque_constant_nm_per_a: float = 0.3346
    resistance_ohm: float = 2.182
    inertia_kg_m2: float = 1.1e-3
    viscous_nm_per_rad_s: float = 500e-6
    load_nm: float = 0.05
    counts_per_revolution: int = 1920
    lower_counts: int | None = None
    upper_counts: int | None = None
    overtravel_counts: int = 200
    bounces: int = 0
    bounce_interval_us: float = 50.0
    probe_side: int = 0
    probe_counts: int = 0

    def __post_init__(self) -> None:
        for label in ("supply_v", "torque_constant_nm_per_a", "resistance_ohm",
                      "inertia_kg_m2", "counts_per_revolution", "bounce_interval_us"):
            value = getattr(self, label)
            if not value > 0:
                raise ArgumentError(f"motor {label} {value!r} must be above 0", reason=label)
        for label in ("viscous_nm_per_rad_s", "load_nm", "overtravel_counts", "bounces"):
            value = getattr(self, label)
            if not value >= 0:
                raise ArgumentError(f"motor {label} {value!r} must be 0 or more", reason=label)
        if (self.lower_counts is not None and self.upper_counts is not None
                and self.lower_counts >= self.upper_counts):
            raise ArgumentError(f"motor lower_counts {self.lower_counts!r} must be below "
                                f"upper_counts {self.upper_counts!r}", reason="lower_counts")
        if self.probe_side not in (0, 1, 2):
            raise ArgumentError(f"motor probe_side {self.probe_side!r} must be 0 (none), 1 "
                                f"(at or below probe_counts) or 2 (at or above)",
                                reason="probe_side")

    @classmethod
    def like(cls, params: MotorParams, *, bounces: int = 0,
             bounce_interval_us: float = 50.0) -> PinsMotor:
        """The motor the on-chip simulated motor of ``params`` models (each value as the
        device holds it, its significant digits), its switches at the travel's ends (none
        where the travel is the whole counter)."""
        def value(pair: tuple[int, int]) -> float:
            return float(pair[0] * 10.0 ** pair[1])

        return cls(
            supply_v=value(params.source_voltage_v),
            torque_constant_nm_per_a=value(params.torque_constant_mnm_per_a) / 1e3,
            resistance_ohm=value(params.winding_resistance_ohm),
            inertia_kg_m2=value(params.inertia_kg_m2),
            viscous_nm_per_rad_s=value(params.viscous_friction_unm_per_rad_s) / 1e6,
            load_nm=value(params.load_torque_mnm) / 1e3,
            counts_per_revolution=params.counts_per_revolution,
            lower_counts=(None if params.travel_lower_counts == INT32_MIN
                          else params.travel_lower_counts),
            upper_counts=(None if params.travel_upper_counts == INT32_MAX
                          else params.travel_upper_counts),
            overtravel_counts=params.overtravel_counts,
            bounces=bounces,
            bounce_interval_us=bounce_interval_us,
        )

    def options(self) -> dict[str, Any]:
        """The harness's ``motor`` request options (``lib/pins.js`` MotorWorld's keys)."""
        options: dict[str, Any] = {
            "supplyV": self.supply_v,
            "torqueConstantNmPerA": self.torque_constant_nm_per_a,
            "resistanceOhm": self.resistance_ohm,
            "inertiaKgM2": self.inertia_kg_m2,
            "viscousNmPerRadS": self.viscous_nm_per_rad_s,
            "loadNm": self.load_nm,
            "countsPerRevolution": self.counts_per_revolution,
            "overtravel": self.overtravel_counts,
            "bounce": self.bounces,
            "bounceNanos": self.bounce_interval_us * 1e3,
        }
        if self.lower_counts is not None:
            options["lower"] = self.lower_counts
        if self.upper_counts is not None:
            options["upper"] = self.upper_counts
        if self.probe_side != 0:
            options["probeSide"] = self.probe_side
            options["probePosition"] = self.probe_counts
        return options


@dataclass(frozen=True, slots=True)
class MotorState:
    """The motor outside the chip as it is (:meth:`EmulatedDevice.world`).

    Fields:
        count: the encoder's count (from the first power-up, not wrapped).
        position_counts: the shaft's exact position, counts.
        velocity_counts_s: its velocity, counts/s.
        voltage_v: the bridge's output, V (the supply times the difference of the duties).
        enabled: the enable output is high.
        lower_closed, upper_closed: each switch is closed (the shaft at or beyond it).
        encoder_edges: encoder edges sent to the chip since the motor was attached.
        switch_edges: switch changes since then (bounces not counted).
        switch_pin_changes: the switch pins' changes since then, each bounce's two included.
        probe_closed: the probe touches its surface.
        probe_edges: the probe's changes since the motor was attached.
    """

    count: int
    position_counts: float
    velocity_counts_s: float
    voltage_v: float
    enabled: bool
    lower_closed: bool
    upper_closed: bool
    encoder_edges: int
    switch_edges: int
    switch_pin_changes: int
    probe_closed: bool
    probe_edges: int

    @classmethod
    def from_reply(cls, world: dict[str, Any]) -> MotorState:
        """From the harness's ``world`` field."""
        lower, upper = world["closed"]
        return cls(int(world["count"]), float(world["theta"]), float(world["omega"]),
                   float(world["voltage"]), bool(world["enabled"]), bool(lower), bool(upper),
                   int(world["edges"]), int(world["switchEdges"]),
                   int(world["switchPinChanges"]), bool(world["probeClosed"]),
                   int(world["probeEdges"]))


class EmulatedDevice:
    """One emulated device in deterministic mode (``firmware/emulator/control.js``).

    Input is taken at servo tick boundaries: :meth:`feed` gives bytes after the ticks done so
    far and before the next, and returns once core0 has handled them and sleeps;
    :meth:`run` runs ticks. One process serves many sessions: :meth:`power_cycle` gives a fresh
    chip on the same flash (``erase_flash=True`` resets the flash to the bare program).

    Parameters:
        uf2: the firmware image.
        elf: the same firmware's ELF (default: ``uf2`` with ``.elf``).
        flash: a file keeping the flash contents across power cycles and processes; ``None``
            keeps them in the process only.
        node: the Node.js executable.
        timeout_s: longest wait for one request (a run of 60,000 ticks takes about 2 s).

    Raises:
        FileNotFoundError: the image, its ELF or the emulator's packages are missing.
        DeviceError: the emulator refused a request or stopped.
        DeviceTimeoutError: a request took longer than ``timeout_s``.
    """

    def __init__(
        self,
        uf2: Path | str,
        *,
        elf: Path | str | None = None,
        flash: Path | str | None = None,
        node: str = "node",
        timeout_s: float = 120.0,
    ) -> None:
        self.uf2, self.elf = _check_image(Path(uf2), Path(elf) if elf is not None else None)
        self.flash = Path(flash) if flash is not None else None
        self.timeout_s = timeout_s
        self._stderr = tempfile.TemporaryFile()  # noqa: SIM115 - closed by close()
        self._process: subprocess.Popen[bytes] | None = subprocess.Popen(
            [node, str(_script("control.js"))],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._stderr,
        )
        assert self._process.stdout is not None
        self._reader = _LineReader(self._process.stdout)
        self._powered = False
        try:
            reply = self._request(
                {
                    "cmd": "load",
                    "uf2": str(self.uf2),
                    "elf": str(self.elf),
                    "flash": str(self.flash) if self.flash is not None else None,
                }
            )
        except BaseException:
            self.close()
            raise
        self.symbols: dict[str, int | None] = reply.get("symbols", {})

    @property
    def name(self) -> str:
        """The image this device runs, for messages."""
        return f"emulated {self.uf2.name}"

    def _request(self, request: dict[str, Any]) -> dict[str, Any]:
        process = self._process
        if process is None or process.stdin is None:
            raise DeviceError("the emulated device is closed", device=self.name)
        try:
            process.stdin.write(json.dumps(request).encode("ascii") + b"\n")
            process.stdin.flush()
            line = self._reader.readline(self.timeout_s)
        except TimeoutError:
            raise DeviceTimeoutError(
                f"emulator gave no answer to {request['cmd']!r} in {self.timeout_s} s",
                device=self.name,
            ) from None
        except (EOFError, BrokenPipeError) as error:
            raise DeviceError(
                f"emulator exited during {request['cmd']!r}: {self._stderr_text()}",
                device=self.name,
            ) from error
        reply: dict[str, Any] = json.loads(line)
        if not reply.get("ok"):
            raise DeviceError(
                f"emulator refused {request['cmd']!r}: {reply.get('error')}", device=self.name
            )
        return reply

    def _stderr_text(self) -> str:
        self._stderr.seek(0)
        return self._stderr.read().decode("utf-8", "replace").strip() or "(no message)"

    @staticmethod
    def _span(reply: dict[str, Any]) -> Span:
        cycles = reply["cycles"]
        return Span(
            tick=int(reply["tick"]),
            output=tuple(
                OutputChunk(int(tick), text.encode("latin-1")) for tick, text in reply["output"]
            ),
            busy_cycles=(int(cycles[0]), int(cycles[1])),
            emulated_ns=int(reply["emulated_ns"]),
        )

    def power_up(self, *, erase_flash: bool = False) -> Span:
        """Power on a fresh chip (tick 0: USB configured, core0 asleep); the span is the boot."""
        span = self._span(self._request({"cmd": "power_up", "erase_flash": erase_flash}))
        self._powered = True
        return span

    def power_cycle(self, *, erase_flash: bool = False) -> Span:
        """Power off and on: output not read and input not taken are lost; flash is kept."""
        return self.power_up(erase_flash=erase_flash)

    def flash_reset(self) -> None:
        """Erase the flash but for the program (as freshly loaded); applies at the next power-up."""
        self._request({"cmd": "flash_reset"})

    def feed(self, data: bytes) -> Span:
        """Give the device ``data`` at the current tick boundary; returns once it is handled."""
        return self._span(self._request({"cmd": "feed", "data": data.decode("latin-1")}))

    def run(self, ticks: int) -> Span:
        """Run ``ticks`` servo ticks (and let core0 print what they recorded)."""
        if ticks < 0:
            raise ValueError(f"ticks {ticks!r} is negative; run takes 0 or more")
        return self._span(self._request({"cmd": "run", "ticks": ticks}))

    def status(self) -> DeviceStatus:
        """Totals since power-up."""
        reply = self._request({"cmd": "status"})
        cycles = reply["busy_cycles"]
        return DeviceStatus(
            tick=int(reply["tick"]),
            busy_cycles=(int(cycles[0]), int(cycles[1])),
            emulated_ns=int(reply["emulated_ns"]),
        )

    def stack_usage(self) -> tuple[StackUsage | None, StackUsage | None]:
        """Each core's stack since power-up: its high-water mark and size (None: not named).

        The harness paints both stacks at power-up; the bytes no longer holding the paint
        were used.
        """
        stacks = self._request({"cmd": "stacks"})["stacks"]
        usage = tuple(None if stack is None else StackUsage(int(stack["used"]),
                                                            int(stack["size"]))
                      for stack in stacks)
        return usage[0], usage[1]

    def boot_to_first_reply(self, data: bytes = _QUEUE_QUERY) -> BootTimes:
        """Power on a fresh chip free running, as one plugged in, and send ``data`` the moment
        its port is configured: when the firmware enabled USB, was configured and answered.

        The chip is left running free: :meth:`power_up` before a deterministic session.
        """
        reply = self._request({"cmd": "boot_reply", "data": data.decode("latin-1")})
        self._powered = True
        cycles = reply["cycles"]
        return BootTimes(int(reply["usb_enabled_ns"]), int(reply["configured_ns"]),
                         int(reply["reply_ns"]), (int(cycles[0]), int(cycles[1])))


    def attach_motor(self, motor: PinsMotor | None = None) -> MotorState:
        """Wire ``motor`` (default: :class:`PinsMotor`'s) to the chip's pins, from now on and
        at every later power-up, where the shaft then is. The firmware drives it once call 39
        selected the motor on the pins and a power cycle followed (:meth:`use_pins_motor`).
        """
        motor = motor if motor is not None else PinsMotor()
        return MotorState.from_reply(
            self._request({"cmd": "motor", "options": motor.options()})["world"])

    def use_pins_motor(self, motor: PinsMotor | None = None) -> MotorState:
        """Select the motor on the pins (call 39 1, kept in flash), power cycle, and wire
        ``motor`` to the pins: the firmware then drives it instead of its simulated motor.

        Raises:
            DeviceError: the firmware did not answer call 39 so (it runs the simulated motor).
        """
        answer = self.feed(encode_call(CallNumber.SET_MOTOR, 1) + encode_call(
            CallNumber.SET_MOTOR, -1)).data
        lines = answer.splitlines()
        if not lines or not lines[-1].startswith(b"MOTOR 1 "):
            raise DeviceError(f"the firmware answered {answer!r} to selecting the motor on "
                              "the pins", device=self.name, call=int(CallNumber.SET_MOTOR))
        self.power_cycle()
        return self.attach_motor(motor)

    def world(self) -> MotorState:
        """The motor outside the chip now.

        Raises:
            DeviceError: no motor is attached.
        """
        return MotorState.from_reply(self._request({"cmd": "world"})["world"])

    def output_levels(self) -> tuple[float, ...]:
        """The outputs of call 42 as the chip's pins show them now, per mille: outputs 0 and
        1 the levels of GP13 and GP14 (1000 driven high, else 0), outputs 2 and 3 the PWM
        duties of GP16 and GP17 (0 while their slice is off or the pin is not the PWM's)."""
        return tuple(float(level) for level in self._request({"cmd": "outputs"})["levels"])

    def start_profile(self) -> None:
        """Count the cycles of every instruction from now on, per core (emulation slows)."""
        self._request({"cmd": "profile", "on": True})

    def stop_profile(self) -> tuple[dict[str, int], dict[str, int]]:
        """Stop counting: the cycles each core spent in each function since
        :meth:`start_profile` (by the ELF's function symbols; ``bootrom`` for the ROM)."""
        reply = self._request({"cmd": "profile", "on": False})["functions"]
        core0, core1 = ({row["name"]: int(row["cycles"]) for row in rows} for rows in reply)
        return core0, core1

    def read_symbol(self, symbol: str, size: int | None = None) -> bytes:
        """The bytes of a firmware variable, by its ELF symbol (``size`` default: the symbol's)."""
        request: dict[str, Any] = {"cmd": "read", "symbol": symbol}
        if size is not None:
            request["size"] = size
        return bytes.fromhex(self._request(request)["hex"])

    def close(self) -> None:
        """Stop the emulator process. Safe to call twice."""
        process, self._process = self._process, None
        if process is not None:
            self._reader.close()
            _stop_process(process)
            self._stderr.close()

    def __enter__(self) -> EmulatedDevice:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --- in a virtual-time world ---------------------------------------------------------------


def _lines(runs: Sequence[tuple[int, bytes]]) -> list[tuple[int, bytes]]:
    """Output as (tick, line) pairs, each line with its newline."""
    out: list[tuple[int, bytes]] = []
    for tick, data in runs:
        out.extend((tick, line) for line in data.splitlines(keepends=True))
    return out


class FirmwareSimDevice:
    """The firmware on an emulated chip as a device of a virtual-time world
    (``usbmotion.sim.world.SimWorld``): a host drives it as it drives a Python device.

    The world runs each device in blocks up to its next event (a diagnostics line, the
    watchdog, the queue running dry...), which it asks :meth:`ticks_until_event`. An emulated
    chip cannot say; a Python device given the same bytes at the same ticks (the
    specification) can, so one runs beside the chip as its shadow. What the host reads is
    the chip's output; with ``check`` every line of it is compared with the shadow's and a
    difference raises :class:`~usbmotion.errors.DeviceError` (the firmware no longer answers
    as the Python device, and the shadow's events cannot be trusted).

    With ``motor`` the firmware drives that motor outside the chip through its pins (call 39
    1 and a power cycle before the name is written). The shadow still simulates its motor on
    the chip, so the lines part (diagnostics, statistics, where the switches close) and are
    not compared; the shadow's events stay those of a like motor, so the world still runs the
    chip in blocks to about the right ticks, and what the host reads is the chip's.

    Parameters:
        uf2: the firmware image (the ELF beside it).
        name: the device name written to its flash at power-up (call 18), if any.
        check: compare every line with the shadow's (default: unless ``motor`` is given;
            with ``motor`` it cannot be).
        motor: the motor outside the chip, on the firmware's pins; ``None``: the firmware's
            on-chip simulated motor.
        node: the Node.js executable.

    Raises:
        ArgumentError: ``check`` asked for with ``motor``.
    """

    def __init__(self, uf2: Path | str, *, name: str = "", check: bool | None = None,
                 motor: PinsMotor | None = None, node: str = "node") -> None:
        from usbmotion.device import Device, MemoryFlash  # noqa: PLC0415 - optional part

        if check and motor is not None:
            raise ArgumentError("check compares the chip's lines with a Python device that "
                                "simulates its motor on the chip; with a motor on the pins "
                                "they part: give check=False or no motor", reason="check")
        self.chip = EmulatedDevice(uf2, node=node)
        self.shadow = Device(flash=MemoryFlash())
        self.motor = motor
        """The motor outside the chip, or ``None`` (the on-chip simulated motor)."""
        self.check = motor is None if check is None else check
        self._ticks = 0
        self._output: list[tuple[int, bytes]] = []
        self.lines_compared = 0
        """Lines of output compared with the shadow's so far."""
        try:
            self.chip.power_up(erase_flash=True)
            if motor is not None:
                self.chip.use_pins_motor(motor)
            if name:
                self.feed(encode_device_name(name))
                self.take_timed_output()
        except BaseException:
            self.chip.close()
            raise

    @property
    def name(self) -> str:
        """The device name (as the shadow holds it: the same, or check has failed)."""
        return self.shadow.name

    @property
    def tick_us(self) -> int:
        """The servo period, microseconds."""
        return self.shadow.tick_us

    @property
    def ticks(self) -> int:
        """Servo ticks the chip has run since power-up."""
        return self._ticks

    def _took(self, span: Span) -> None:
        self._ticks = span.tick
        self._output.extend((chunk.tick, chunk.data) for chunk in span.output)

    def feed(self, data: bytes) -> None:
        """Bytes from USB at the present tick boundary."""
        self._took(self.chip.feed(data))
        self.shadow.feed(data)

    def run(self, ticks: int) -> None:
        """Run ``ticks`` servo ticks."""
        self._took(self.chip.run(ticks))
        self.shadow.run(ticks)

    def take_timed_output(self) -> list[tuple[int, bytes]]:
        """What the chip printed since the last call, in runs of one tick each with how many
        ticks ago it printed (as ``Device.take_timed_output``)."""
        output, self._output = self._output, []
        shadow = [(self._ticks - ago, data) for ago, data in self.shadow.take_timed_output()]
        if self.check:
            mine, theirs = _lines(output), _lines(shadow)
            if mine != theirs:
                where = next((i for i, (a, b) in enumerate(zip(mine, theirs, strict=False))
                              if a != b), min(len(mine), len(theirs)))
                raise DeviceError(
                    f"the firmware parted from the Python device at tick "
                    f"{(mine[where:] or theirs[where:])[0][0]}: firmware "
                    f"{mine[where : where + 1]!r}, Python {theirs[where : where + 1]!r}",
                    device=self.chip.name)
            self.lines_compared += len(mine)
        return [(self._ticks - tick, data) for tick, data in output]

    def ticks_until_event(self, *, diagnostics: bool = True) -> int | None:
        """Ticks until the device next prints or changes state on its own (the shadow's)."""
        return self.shadow.ticks_until_event(diagnostics=diagnostics)

    def close(self) -> None:
        """Stop the emulator."""
        self.chip.close()


# --- real time -------------------------------------------------------------------------------


def read_recording(path: Path | str) -> list[tuple[int, bytes]]:
    """A session recorded by :class:`FirmwareServer` (``record_dir``): each chunk of bytes the
    device received, with the servo ticks done since its power-up when it arrived, in order.

    Raises:
        ValueError: a line is not ``TICK HEX`` or the ticks go backwards.
    """
    chunks: list[tuple[int, bytes]] = []
    for number, line in enumerate(Path(path).read_text(encoding="ascii").splitlines(), 1):
        fields = line.split(" ")
        try:
            tick, data = int(fields[0]), bytes.fromhex(fields[1])
        except (IndexError, ValueError):
            raise ValueError(f"{path}:{number}: {line[:40]!r} is not `TICK HEX`") from None
        if len(fields) != 2 or tick < 0 or (chunks and tick < chunks[-1][0]):
            raise ValueError(f"{path}:{number}: tick {fields[0]} out of order")
        chunks.append((tick, data))
    return chunks



@dataclass(slots=True)
class FirmwareEndpoint:
    """Where one emulated device is served.

    Fields:
        index: the device's number, from 0.
        host, port: its TCP address (``url`` gives ``socket://host:port``).
        flash: the file holding its flash.
        path: its pseudo-terminal, when served on one (else ``""``).
    """

    index: int
    host: str
    port: int
    flash: Path
    path: str = ""
    name: str = ""
    """The device's name, as it answered ``18 -1`` at start."""
    recording: Path | None = None
    """The file of the bytes it received with their ticks, when recording."""
    _process: subprocess.Popen[bytes] | None = None
    _pty: PtyEndpoint | None = None
    _link: socket.socket | None = None
    _to_device: Outbox = field(default_factory=Outbox)

    @property
    def dropped_bytes(self) -> int:
        """Device output its terminal's client did not take (none connected, or one that
        did not read)."""
        return self._pty.dropped_bytes if self._pty is not None else 0

    @property
    def url(self) -> str:
        """The device as a pyserial URL: its pseudo-terminal, else ``socket://host:port``."""
        return self.path or f"socket://{self.host}:{self.port}"


class FirmwareServer:
    """Serve ``count`` emulated devices in real time, each on a TCP port (``serve.js``).

    With ``pty=True`` each device also gets a pseudo-terminal (:mod:`usbmotion.serving`:
    one client at a time, clients may come and go; output while none is connected, or
    beyond what one leaves unread, is dropped): a thread relays between it and the
    device's TCP port. Use as a context manager, or call :meth:`start` and :meth:`close`.

    Parameters:
        uf2: the firmware image (the ELF beside it, or ``elf``).
        count: how many devices.
        tcp_port: device ``i`` listens on ``tcp_port + i``; 0 picks free ports.
        host: the address to bind (loopback by default).
        pty: also serve each device on a pseudo-terminal.
        flash_dir: folder for the devices' flash files (kept across runs:
            ``device-<i>.flash``, or named after the device's name in ``names``); default: a
            temporary folder removed by :meth:`close`.
        names: device names (up to 25 printable ASCII characters) for the first devices,
            written to their flash (call 18) when it holds another.
        record_dir: write every byte each device receives, with the servo tick it arrived
            at, to ``<flash file's stem>.rec`` there (lines ``TICK HEX``; see
            :func:`read_recording`), for a deterministic replay of the session.
        bootrom: the RP2040 boot ROM image (default: :func:`default_bootrom`).
        on_notice: where a notice goes (a second program on a device's terminal); dropped
            by default. Called from the relay's thread.
        node: the Node.js executable.
        start_timeout_s: longest wait for a device to listen.

    Raises:
        FileNotFoundError: the image, its ELF, the boot ROM or the emulator's packages are
            missing.
        DeviceError: an emulator failed to start.
    """

    def __init__(
        self,
        uf2: Path | str,
        count: int,
        *,
        elf: Path | str | None = None,
        tcp_port: int = 0,
        host: str = "127.0.0.1",
        pty: bool = False,
        flash_dir: Path | str | None = None,
        names: Sequence[str] = (),
        record_dir: Path | str | None = None,
        bootrom: Path | str | None = None,
        on_notice: Callable[[str], None] | None = None,
        node: str = "node",
        start_timeout_s: float = 30.0,
    ) -> None:
        if count < 1:
            raise ValueError(f"count {count!r} of devices; at least 1")
        if len(names) > count:
            raise ValueError(f"{len(names)} names for {count} devices")
        for name in names:
            problem = device_name_problem(name, allow_empty=False)
            if problem is not None:
                raise ValueError(problem)
        self.names = tuple(names)
        self.record_dir = Path(record_dir) if record_dir is not None else None
        self.uf2, self.elf = _check_image(Path(uf2), Path(elf) if elf is not None else None)
        self.bootrom = check_bootrom(bootrom)
        self._notice = on_notice or (lambda text: None)
        self.count = count
        self.tcp_port = tcp_port
        self.host = host
        self.pty = pty
        self.node = node
        self.start_timeout_s = start_timeout_s
        self._temporary: tempfile.TemporaryDirectory[str] | None = None
        if flash_dir is None:
            self._temporary = tempfile.TemporaryDirectory(prefix="usbmotion-flash-")
            flash_dir = self._temporary.name
        self.flash_dir = Path(flash_dir)
        self.endpoints: list[FirmwareEndpoint] = []
        self._stderr = tempfile.TemporaryFile()  # noqa: SIM115 - closed by close()
        self._serving: Serving | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._closed = False
        self._final_messages = ""

    def start(self) -> FirmwareServer:
        """Start the emulators (and the pseudo-terminal relay); returns once all listen."""
        if self.endpoints:
            return self
        self.flash_dir.mkdir(parents=True, exist_ok=True)
        if self.record_dir is not None:
            self.record_dir.mkdir(parents=True, exist_ok=True)
        script = _script("serve.js")
        try:
            for index in range(self.count):
                self.endpoints.append(self._start_device(index, script))
            if self.pty:
                self._start_relay()
        except BaseException:
            self.close()
            raise
        return self

    def _start_device(self, index: int, script: Path) -> FirmwareEndpoint:
        wanted = self.names[index] if index < len(self.names) else ""
        stem = (re.sub(r"[^A-Za-z0-9]+", "-", wanted).strip("-").lower() or f"device-{index}"
                if wanted else f"device-{index}")
        flash = self.flash_dir / f"{stem}.flash"
        port = self.tcp_port + index if self.tcp_port else 0
        process = subprocess.Popen(
            [
                self.node,
                str(script),
                "--uf2",
                str(self.uf2),
                "--elf",
                str(self.elf),
                "--flash",
                str(flash),
                "--tcp",
                str(port),
                "--host",
                self.host,
                "--bootrom",
                str(self.bootrom),
                "--exit-with-stdin",
                "1",
                *(["--record", str(self.record_dir / f"{stem}.rec")]
                  if self.record_dir is not None else []),
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._stderr,
        )
        endpoint = FirmwareEndpoint(index, self.host, port, flash, _process=process)
        if self.record_dir is not None:
            endpoint.recording = self.record_dir / f"{stem}.rec"
        assert process.stdout is not None
        reader = _LineReader(process.stdout)
        try:
            line = reader.readline(self.start_timeout_s).decode("ascii", "replace").strip()
        except (TimeoutError, EOFError):
            _stop_process(process)
            raise DeviceError(
                f"emulated device {index} did not start: {self._stderr_text()}",
                device=str(self.uf2),
            ) from None
        finally:
            reader.close()
        address = line.removeprefix("listening ")
        if address == line or ":" not in address:
            _stop_process(process)
            raise DeviceError(f"emulated device {index} printed {line!r}", device=str(self.uf2))
        endpoint.port = int(address.rsplit(":", 1)[1])
        try:
            endpoint.name = self._name_device(endpoint, wanted)
        except BaseException:
            _stop_process(process)
            raise
        return endpoint

    def _name_device(self, endpoint: FirmwareEndpoint, wanted: str) -> str:
        """Asks the device its name over its TCP port, first writing ``wanted`` to its flash
        when it holds another; returns the name it answers."""
        deadline = time.monotonic() + self.start_timeout_s
        with socket.create_connection((self.host, endpoint.port), timeout=5.0) as link:
            link.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            received = bytearray()

            def ask() -> str:
                link.sendall(encode_call(CallNumber.SET_DEVICE_NAME, -1))
                while True:
                    for line in bytes(received).split(b"\n")[:-1]:
                        if line.startswith(b"DEVICE_NAME "):
                            received.clear()
                            return line[len(b"DEVICE_NAME "):].decode("ascii", "replace")
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        raise DeviceTimeoutError(
                            f"emulated device {endpoint.index} gave no name", device=str(self.uf2))
                    link.settimeout(remaining)
                    chunk = link.recv(_READ_CHUNK)
                    if not chunk:
                        raise DeviceError(f"emulated device {endpoint.index} closed its port",
                                          device=str(self.uf2))
                    received.extend(chunk)

            name = ask()
            if wanted and name != wanted:
                link.sendall(encode_device_name(wanted))
                name = ask()
                if name != wanted:
                    raise DeviceError(f"emulated device {endpoint.index} kept the name {name!r} "
                                      f"when given {wanted!r}", device=str(self.uf2))
        return name

    def _stderr_text(self) -> str:
        self._stderr.seek(0)
        return self._stderr.read().decode("utf-8", "replace").strip() or "(no message)"

    def stopped(self) -> str:
        """Why an emulated device stopped (its process exited), or ``""`` while all run."""
        for endpoint in self.endpoints:
            process = endpoint._process
            if process is not None and process.poll() is not None:
                return (f"emulated device {endpoint.index} exited with status "
                        f"{process.returncode}: {self._stderr_text()}")
        return ""

    def messages(self) -> str:
        """What the emulators wrote on their standard error so far (that one fell behind
        real time, and after :meth:`close` how often), ``""`` if nothing."""
        if self._stderr.closed:
            return self._final_messages
        self._stderr.seek(0)
        return self._stderr.read().decode("utf-8", "replace").strip()

    # pseudo-terminals

    def _start_relay(self) -> None:
        serving = Serving()
        self._serving = serving
        for endpoint in self.endpoints:
            endpoint._pty = PtyEndpoint(label=str(endpoint.index))
            serving.add(endpoint._pty)
            endpoint.path = endpoint._pty.path
            link = socket.create_connection((self.host, endpoint.port), timeout=5.0)
            link.setblocking(False)
            link.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            endpoint._link = link
            serving.add_reader(link)
        self._thread = threading.Thread(target=self._relay, name="firmware-pty-relay", daemon=True)
        self._thread.start()

    def _relay(self) -> None:
        serving = self._serving
        assert serving is not None
        by_link = {id(endpoint._link): endpoint for endpoint in self.endpoints}
        by_pty = {id(endpoint._pty): endpoint for endpoint in self.endpoints}
        while not self._stop.is_set():
            for event in serving.wait(0.05):
                if event.kind is EventKind.DATA:
                    by_pty[id(event.endpoint)]._to_device.add(event.data)
                elif event.kind is EventKind.READABLE:
                    self._from_device(by_link[id(event.source)])
                elif event.kind is EventKind.SECOND_CLIENT:
                    self._notice(f"emulated device {by_pty[id(event.endpoint)].index}: a second"
                                 f" program opened {event.detail} while a host has it, without"
                                 " locking it: its bytes and the host's mix")
            for endpoint in self.endpoints:
                if endpoint._link is not None:
                    with contextlib.suppress(OSError):  # the emulator exited: recv says so
                        endpoint._to_device.write_to(endpoint._link.send)
            serving.flush()

    def _from_device(self, endpoint: FirmwareEndpoint) -> None:
        assert endpoint._link is not None and endpoint._pty is not None
        try:
            data = endpoint._link.recv(_READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return
        if not data:  # the emulator exited
            if self._serving is not None:
                self._serving.remove_reader(endpoint._link)
            endpoint._link.close()
            endpoint._link = None
            return
        endpoint._pty.send(data)

    def close(self) -> None:
        """Stop the relay and the emulators, close the terminals. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self._serving is not None:
            self._serving.close()
        for endpoint in self.endpoints:
            if endpoint._link is not None:
                endpoint._link.close()
            if endpoint._process is not None:
                _stop_process(endpoint._process)
                endpoint._process = None
        self._final_messages = self.messages()
        self._stderr.close()
        if self._temporary is not None:
            self._temporary.cleanup()

    def __enter__(self) -> FirmwareServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
