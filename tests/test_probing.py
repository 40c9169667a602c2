"""Probing. The probe input of a machine file's simulated axis (``sim.probe_below_mm``: a
plate under a Z probe), sent to its device by call 40: moved onto the plate, the device
latches the count of contact (call 41) at the plate's height to the count, however long the
host takes to look; lifted off, the input opens again. G38.2 to G38.5 a line at a time, as
the console, a grbl sender (cncjs's probe widget) and the dashboard's MDI send them."""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from usbmotion.cli.machines import default_machine
from usbmotion.errors import ConfigError, GCodeError
from usbmotion.grbl.protocol import GrblProtocol
from usbmotion.grbl.session_machine import SessionMachine
from usbmotion.host.config import load_config
from usbmotion.session import MachineSession
from usbmotion.session.operator import Operator
from usbmotion.session.probing import ProbeFailedError
from usbmotion.sim.machine import connect_session

PLATE_MM = -20.0


def _machine_with_plate(folder: Path, probe: str = f"probe_below_mm = {PLATE_MM}") -> Path:
    text = default_machine().read_text()
    old = "sim = { start_mm = -50.0"
    assert old in text, "the default machine's Z no longer starts at -50 mm"
    path = folder / "plate.toml"
    path.write_text(text.replace(old, f"sim = {{ {probe}, start_mm = -50.0", 1))
    return path


def test_a_plate_under_z_latches_the_contact_at_its_height(tmp_path: Path) -> None:
    config = load_config(_machine_with_plate(tmp_path))
    z = config.axis("Z")
    assert z.sim is not None and (z.sim.probe_side, z.sim.probe_mm) == (1, PLATE_MM)
    with connect_session(config) as session:
        session.home()
        client = session.machine.axis("Z").client
        assert client.sim_probe() == z.sim_probe_counts
        before = client.probe()  # homing lifted Z off the plate it powered up under
        assert not before.closed and before.edges == 1, "Z at the top, far above the plate"
        session.jog({"Z": PLATE_MM - 2.0}, feed_mm_min=120, absolute=True)
        touched = client.probe()
        assert touched.closed and touched.edges == 2 and touched.edge_closed
        contact_mm = session.machine.axis("Z").scale.to_mm(touched.position_counts)
        assert contact_mm == pytest.approx(PLATE_MM, abs=1.5 / z.counts_per_mm), (
            "the first count at or below the plate, at 2 mm/s (a count a tick is 4 mm/s)")
        session.jog({"Z": PLATE_MM + 5.0}, feed_mm_min=600, absolute=True)
        lifted = client.probe()
        assert not lifted.closed and lifted.edges == 3 and not lifted.edge_closed
        for name in ("X", "Y"):
            assert session.machine.axis(name).client.probe().edges == 0, "no plate there"


def test_a_probe_surface_is_one_and_within_the_travel(tmp_path: Path) -> None:
    both = _machine_with_plate(tmp_path, "probe_below_mm = -20.0, probe_above_mm = -10.0")
    with pytest.raises(ConfigError, match=r"probe_below_mm .* or probe_above_mm, not both"):
        load_config(both)
    beyond = _machine_with_plate(tmp_path, "probe_below_mm = -120.0")
    with pytest.raises(ConfigError, match=r"axes\.Z\.sim\.probe_below_mm: -120"):
        load_config(beyond)


# --- G38.2 to G38.5, a line at a time ---------------------------------------------------------

@contextmanager
def _operated(folder: Path) -> Iterator[tuple[MachineSession, Operator, list[str]]]:
    """The machine with the plate, homed, behind an operator (as the console and the fronts
    drive it); the operator's messages."""
    messages: list[str] = []
    with connect_session(load_config(_machine_with_plate(folder))) as session, \
            Operator(session, on_message=messages.append) as operator:
        session.home()
        yield session, operator, messages


def _send(operator: Operator, *lines: str) -> None:
    """Each line as a sender writes it: again while the operator says wait."""
    for line in lines:
        deadline = time.monotonic() + 60
        while not operator.submit(line):
            assert time.monotonic() < deadline, f"{line!r} never taken"
            time.sleep(0.005)
    assert operator.wait_idle(60)


def test_g38_2_stops_on_the_plate_and_a_g10_after_it_zeroes_there(tmp_path: Path) -> None:
    """cncjs's probe widget's lines: the contact is the latched count (the plate to the
    count); the machine stands on it after the probe, so G10 L20 P1 Z0 puts work Z0 on the
    plate; the lines after the probe wait for it and go on from there."""
    with _operated(tmp_path) as (session, operator, messages):
        _send(operator, "G21 G90", "G0 X50 Y50", "G91", "G38.2 Z-40 F50")
        probe = session.last_probe
        assert probe is not None and probe.tripped and probe.latched == ("Z",)
        scale = session.machine.axis("Z").scale
        latched = session.machine.axis("Z").client.probe()
        assert probe.position_mm["Z"] == scale.to_mm(latched.position_counts)
        assert abs(latched.position_counts - scale.to_counts(PLATE_MM)) <= 1
        assert (probe.position_mm["X"], probe.position_mm["Y"]) == (50.0, 50.0)
        _send(operator, "G90", "G10 L20 P1 Z0", "G91 G0 Z5", "G90")
        assert session.work_offsets().g5x[0][2] == pytest.approx(probe.position_mm["Z"])
        now = session.live.read().machine_mm(measured=False)
        assert now["Z"] == pytest.approx(probe.position_mm["Z"] + 5.0)
        assert any(m.startswith("G38.2: contact at Z-20.0") for m in messages), messages
        assert operator.last_failure is None


def test_no_contact_is_an_error_for_g38_2_and_quiet_for_g38_3(tmp_path: Path) -> None:
    with _operated(tmp_path) as (session, operator, messages):
        _send(operator, "G21 G90", "G38.3 Z-10 F300")
        quiet = session.last_probe
        assert quiet is not None and not quiet.tripped and operator.last_failure is None
        assert session.live.read().machine_mm(measured=False)["Z"] == pytest.approx(-10.0)
        _send(operator, "G38.2 Z-15 F300")
        failure = operator.last_failure
        assert isinstance(failure, ProbeFailedError) and not failure.at_start
        assert "G38.2: the move ended without the probe touching" in str(failure)
        assert messages[-1] == f"error: {failure}"
        operator.last_failure = None
        _send(operator, "G38.2 Z-30 F300")  # onto the plate; then already touching:
        assert operator.last_failure is None
        _send(operator, "G38.2 Z-35 F300")
        failure = operator.last_failure
        assert isinstance(failure, ProbeFailedError)
        assert failure.at_start and "already touches" in str(failure)


def test_g38_4_stops_where_the_probe_leaves_the_plate(tmp_path: Path) -> None:
    with _operated(tmp_path) as (session, operator, _):
        _send(operator, "G21 G90", "G38.2 Z-30 F300", "G38.4 Z-10 F60")
        probe = session.last_probe
        assert probe is not None and probe.tripped and probe.code == "G38.4"
        assert abs(probe.position_mm["Z"] - PLATE_MM) <= 1.5 / 240, "left the plate there"
        assert not session.machine.axis("Z").client.probe().closed
        stopped = session.live.read().machine_mm(measured=False)["Z"]
        assert PLATE_MM < stopped < PLATE_MM + 0.5, "stopped along its deceleration past it"


def test_a_program_with_a_probe_is_refused_with_where_probing_runs(tmp_path: Path) -> None:
    with _operated(tmp_path) as (session, _, _), \
            pytest.raises(GCodeError, match="probing runs a line at a time"):
        session.prepare("<p>", text="G21 G90\nG38.2 Z-30 F100\nM2\n")


def test_the_grbl_front_answers_a_probe_as_grbl_does(tmp_path: Path) -> None:
    """``[PRB:x,y,z:1]`` (machine coordinates) then ``ok`` once the probe has run, the same
    in ``$#``; a probe that finds nothing is ALARM:5, one that starts touching ALARM:4."""
    with _operated(tmp_path) as (_, operator, _):
        out: list[bytes] = []
        front = GrblProtocol(SessionMachine(operator), out.append)
        front.connect()

        def exchange(data: bytes, until: bytes, times: int = 1) -> str:
            out.clear()
            front.receive(data)
            deadline = time.monotonic() + 60
            while b"".join(out).count(until) < times:
                assert time.monotonic() < deadline, b"".join(out)
                front.poll()
                time.sleep(0.005)
            return b"".join(out).decode()

        exchange(b"$X\n", b"ok")
        answer = exchange(b"G21 G90\nG38.2 Z-30 F100\n", b"ok\r\n", times=2)
        found = re.search(r"\[PRB:([-\d.]+),([-\d.]+),([-\d.]+):1\]\r\nok\r\n$", answer)
        assert found is not None, answer
        assert float(found.group(3)) == pytest.approx(PLATE_MM, abs=1.5 / 240)
        assert found.group(0) in exchange(b"$#\n", b"ok")
        operator.wait_idle(30)
        operator.keep_alive()  # at rest, on the plate: the idle read sees the probe closed
        touching = exchange(b"?", b">")
        assert re.search(r"\|Pn:[XYZ]*P[|>]", touching), touching
        alarm = exchange(b"G38.2 Z-35 F100\n", b"ALARM:")
        assert "ALARM:4" in alarm, alarm
        exchange(b"$X\n", b"ok")
        failed = exchange(b"G0 Z-10\nG38.2 Z-12 F100\n", b"ALARM:")
        assert "ALARM:5" in failed, failed
        operator.wait_idle(30)
        operator.keep_alive()
        lifted = exchange(b"?", b">")
        assert "Pn:" not in lifted, "Z at -10 mm, 10 mm above the plate: the probe open"
