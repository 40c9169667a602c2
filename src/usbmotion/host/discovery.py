"""Find devices by the name in their flash: open each candidate port, ask call 18, close it.

A USB Motion Device keeps its name in flash (call 18), so a machine's configuration names
its axes' devices rather than their ports, which change from boot to boot. Discovery
searches any explicit URLs (``socket://host:port`` of ``usbmotion sim --tcp``, ``sim://``
devices), the pseudo-terminals running ``usbmotion sim --pty`` servers announce
(:func:`announced_ptys`) and the computer's serial ports (``serial.tools.list_ports``),
takes each link over as a new host does (diagnostics off, then
:meth:`~usbmotion.host.device.DeviceClient.resynchronise`, so lines a dead host left in
flight are skipped), sends ``18 -1`` and reads the ``DEVICE_NAME`` answer, each within a
short timeout.

Serial port listings do not include pseudo-terminals, and probing every ``/dev/pts/N``
would write into other programs' terminals; so each server keeps, while it serves, a
symbolic link per device in the folder :func:`pty_dir` (``$USBMOTION_PTY_DIR``, else
``$XDG_RUNTIME_DIR/usbmotion/ptys``, else ``/tmp/usbmotion-UID/ptys``), named
``PID-INDEX`` and pointing at the terminal (``usbmotion.sim.pty_dir.announced`` makes
them). Links of a server that died without removing them are ignored and removed.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from serial.tools import list_ports

from usbmotion.errors import (
    DeviceError,
    DeviceNotFoundError,
    DeviceTimeoutError,
    LinkLostError,
    UnexpectedReplyError,
)
from usbmotion.host.device import DeviceClient
from usbmotion.host.transport import LineTransport, open_problem
from usbmotion.protocol import DEFAULT_DEVICE_NAME, parse_reply

PROBE_TIMEOUT_S = 0.5
"""How long a port has to answer each query of the probe, seconds."""

_KEPT_LINES = 16
"""How many skipped lines a probe keeps to say what a port that is no device answered."""


@dataclass(frozen=True, slots=True)
class PortAnswer:
    """What one searched port answered.

    Fields:
        url: the port path or URL.
        name: the device name it answered with, or ``None``.
        problem: why there is no name: ``"no answer within 0.5 s"``, ``"busy: another
            program has it open"``, ``"no such port"``, ``"answered 'xyz', not a device
            name"``, ``"no device name: ..."``; empty when a name came back.
    """

    url: str
    name: str | None
    problem: str = ""

    def describe(self) -> str:
        """One phrase: ``/dev/ttyACM0: 'X AXIS'`` or ``/dev/ttyS0: no answer within 0.5 s``."""
        if self.name is not None:
            return f"{self.url}: {self.name!r}"
        return f"{self.url}: {self.problem}"


def serial_ports() -> list[str]:
    """The computer's serial ports (device paths), sorted."""
    return sorted(port.device for port in list_ports.comports())


def pty_dir() -> Path:
    """The folder of the announced pseudo-terminals."""
    explicit = os.environ.get("USBMOTION_PTY_DIR")
    if explicit:
        return Path(explicit)
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime:
        return Path(runtime) / "usbmotion" / "ptys"
    return Path(tempfile.gettempdir()) / f"usbmotion-{os.getuid()}" / "ptys"


def announced_ptys() -> list[str]:
    """The terminals live servers announced, in the order they were announced; stale
    links (their server gone, or their terminal) are removed."""
    folder = pty_dir()
    try:
        links = sorted(folder.iterdir(), key=_order)
    except OSError:
        return []
    found: list[str] = []
    for link in links:
        try:
            target = os.readlink(link)
        except OSError:
            continue
        if _alive(link.name) and Path(target).exists():
            found.append(target)
        else:
            with contextlib.suppress(OSError):
                link.unlink()
    return found


def _order(link: Path) -> tuple[int, int, str]:
    pid, _, index = link.name.partition("-")
    return (int(pid), int(index), "") if pid.isdigit() and index.isdigit() else (0, 0, link.name)


def _alive(name: str) -> bool:
    pid = name.partition("-")[0]
    if not pid.isdigit():
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def probe(url: str, *, timeout_s: float = PROBE_TIMEOUT_S) -> PortAnswer:
    """Open ``url``, take the link over, ask the device's name (call 18), close it.

    Lines that are not the answer (diagnostics, echoes and answers meant for an earlier
    host, an ``ERR`` for a stale partial line) are skipped by the resynchronisation;
    each query has ``timeout_s`` to be answered, measured on the port's clock. Never
    raises for a port that is missing, busy, silent or no device: the answer says what
    happened.
    """
    try:
        transport = LineTransport.open(url)
    except LinkLostError as error:
        return PortAnswer(url, None, open_problem(error.__cause__ or error))
    skipped: list[bytes] = []

    def keep(line: bytes) -> None:
        if len(skipped) < _KEPT_LINES:
            skipped.append(line)

    with DeviceClient(transport, timeout_s=timeout_s) as client:
        try:
            client.resynchronise(stop_diagnostics=True, on_skipped=keep)
            return PortAnswer(url, client.device_name())
        except DeviceTimeoutError:
            pass
        except (UnexpectedReplyError, DeviceError) as error:
            return PortAnswer(url, None, f"no device name: {error}")
        except LinkLostError as error:
            return PortAnswer(url, None, f"link lost: {error}")
    other = next((line for line in skipped if not _is_reply(line)), None)
    if other is not None:
        shown = other.decode("ascii", errors="replace")[:40]
        return PortAnswer(url, None, f"answered {shown!r}, not a device name")
    return PortAnswer(url, None, f"no answer within {timeout_s:g} s")


def _is_reply(line: bytes) -> bool:
    try:
        parse_reply(line)
    except UnexpectedReplyError:
        return False
    return True


def scan(urls: Iterable[str], *, timeout_s: float = PROBE_TIMEOUT_S) -> list[PortAnswer]:
    """Probe every URL (each once, in order) and return what each answered."""
    answers: list[PortAnswer] = []
    seen: set[str] = set()
    for url in urls:
        if url not in seen:
            seen.add(url)
            answers.append(probe(url, timeout_s=timeout_s))
    return answers


def discover(
    names: Iterable[str],
    *,
    urls: Sequence[str] = (),
    search_ports: bool = True,
    timeout_s: float = PROBE_TIMEOUT_S,
) -> dict[str, str]:
    """Find each device name among ``urls``, the announced pseudo-terminals and the serial
    ports; returns name -> URL.

    Parameters:
        names: the device names to find (as written to flash with call 18).
        urls: ports or URLs to search first (``socket://...``, ``sim://...``, paths).
        search_ports: also search the terminals ``usbmotion sim --pty`` servers announce
            (:func:`announced_ptys`) and the computer's serial ports.
        timeout_s: how long each port has to answer.

    Raises:
        DeviceNotFoundError: a name is on no searched port, or on more than one; the
            message lists every port searched and what it answered.
    """
    wanted = list(dict.fromkeys(names))
    if not wanted:
        return {}
    candidates = list(urls) + (announced_ptys() + serial_ports() if search_ports else [])
    answers = scan(candidates, timeout_s=timeout_s)
    return match_names(wanted, answers)


def match_names(names: Sequence[str], answers: Sequence[PortAnswer]) -> dict[str, str]:
    """Pair each wanted name with the one port that answered it.

    Raises:
        DeviceNotFoundError: as :func:`discover`; when devices that were never named
            answered (the default name), the message says how to name one.
    """
    searched = tuple(answer.url for answer in answers)
    report = "; ".join(answer.describe() for answer in answers) or "no ports to search"
    fresh = [answer.url for answer in answers if answer.name == DEFAULT_DEVICE_NAME]
    if fresh:
        report += (f"; {len(fresh)} of them answer the default name of a device never named:"
                   " give each the name its axis has in the machine file, once (usbmotion"
                   " name AXIS PORT --machine FILE)")
    found: dict[str, list[str]] = {}
    for answer in answers:
        if answer.name is not None:
            found.setdefault(answer.name, []).append(answer.url)
    result: dict[str, str] = {}
    for name in names:
        where = found.get(name, [])
        if not where:
            raise DeviceNotFoundError(
                f"device {name!r} not found; searched {len(answers)} port(s): {report}",
                name=name, searched=searched,
            )
        if len(where) > 1:
            raise DeviceNotFoundError(
                f"device {name!r} answers on {len(where)} ports ({', '.join(where)}); give each"
                " device its own name (call 18) so every axis is found on one port",
                name=name, searched=searched,
            )
        result[name] = where[0]
    return result

