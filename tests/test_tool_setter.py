"""A tool-length setter (``[tool_setter]``): the tool in the spindle lowered onto a fixed
probe button, its contact against the reference tool's its length, written into the tool
table where the next ``G43`` reads it. On the simulated machine the button is Z's probe
surface (``sim.probe_below_mm``); a longer tool touches it higher, as moving the surface
up by the extra length shows."""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest

from usbmotion.console import Console
from usbmotion.errors import ConfigError
from usbmotion.grbl.protocol import GrblProtocol
from usbmotion.grbl.session_machine import SessionMachine
from usbmotion.host.config import load_config
from usbmotion.motion.tools import load_tool_table, with_tool_length
from usbmotion.session.operator import Operator
from usbmotion.session.probing import ProbeFailedError
from usbmotion.session.session import MachineSession
from usbmotion.sim.machine import connect_session
from usbmotion.web.dashboard import Dashboard, RefusedError

ROUTER = Path(__file__).resolve().parents[1] / "examples" / "router.toml"
BUTTON_MM = -20.0
"""Where the setter's button is for the simulated tool (router.toml's probe_below_mm)."""
SETTER = """
[tool_setter]
position_mm = [190.0, 190.0]
start_z_mm = -10.0
lowest_z_mm = -40.0
feed_mm_min = 60.0
reference_z_mm = -25.0
"""


def _machine(folder: Path, setter: str = SETTER) -> Path:
    text = ROUTER.read_text()
    assert f"probe_below_mm = {BUTTON_MM}" in text
    assert 'name = "simulated router"' in text
    text = text.replace('name = "simulated router"',
                        'name = "simulated router"\ntool_table = "tool.tbl"', 1)
    path = folder / "router.toml"
    path.write_text(text + setter)
    (folder / "tool.tbl").write_text("T1 P1 Z12.5 D6 ;a 6 mm end mill\n")
    return path


def test_a_tool_is_measured_and_its_length_written_where_g43_reads_it(
        tmp_path: Path) -> None:
    config = load_config(_machine(tmp_path))
    assert config.tool_setter is not None
    with connect_session(config) as session:
        session.home()
        measured = session.measure_tool(3)
        # The reference touched at -25 mm; this tool at the button, 5 mm higher.
        assert measured.contact_z_mm == pytest.approx(BUTTON_MM, abs=1.0 / 240)
        assert measured.length_mm == pytest.approx(5.0, abs=1.0 / 240)
        table = load_tool_table(tmp_path / "tool.tbl")
        assert table.tools[3].offset_mm[2] == pytest.approx(measured.length_mm, abs=1e-4)
        assert table.tools[1].offset_mm[2] == 12.5 and table.tools[1].comment == (
            "a 6 mm end mill"), "the other tools as they were"
        where = session.live.read().machine_mm()
        assert where["Z"] == pytest.approx(0.0, abs=0.01), "Z lifted to the top again"
        # A tool 2 mm longer touches 2 mm higher.
        z = session.machine.axis("Z")
        side, counts = z.config.sim_probe_counts
        z.client.set_sim_probe(side, counts + round(2.0 * 240))
        longer = session.measure_tool(3)
        assert longer.length_mm == pytest.approx(7.0, abs=1.0 / 240)
        # G43 with T3 now puts the tool tip where the program says.
        prepared = session.prepare("g43.ngc", text="G21 G90\nT3 M6\nG43\nG0 Z-30\nM2\n")
        assert prepared.plan.vertices_mm[-1][2] == pytest.approx(
            -30.0 + longer.length_mm, abs=1e-3)
        session.shutdown()


def test_the_console_measures_the_tool_in_the_spindle(tmp_path: Path) -> None:
    config = load_config(_machine(tmp_path))
    said: list[str] = []
    with connect_session(config) as session:
        console = Console(session, said.append)
        try:
            for line in ("$r", "$tls 2", "$tls x"):
                console.handle(line)
                assert console.operator.wait_idle(120)
        finally:
            console.close()
            session.shutdown()
    assert any(text.startswith("T2 touched the setter at machine Z -20.0") and
               "length 5.0" in text for text in said), said[-4:]
    assert "error: $tls x: a tool number ($tls 3), or nothing for the tool in the spindle" \
        in said
    assert load_tool_table(tmp_path / "tool.tbl").tools[2].offset_mm[2] == pytest.approx(
        5.0, abs=1.0 / 240)


def test_without_a_reference_the_contact_is_said_and_nothing_written(tmp_path: Path) -> None:
    config = load_config(_machine(tmp_path, SETTER.replace("reference_z_mm = -25.0\n", "")))
    with connect_session(config) as session:
        session.home()
        measured = session.measure_tool(1)
        assert measured.length_mm is None and "reference_z_mm" in measured.describe()
        assert measured.contact_z_mm == pytest.approx(BUTTON_MM, abs=1.0 / 240)
        assert load_tool_table(tmp_path / "tool.tbl").tools[1].offset_mm[2] == 12.5
        session.shutdown()


def test_a_tool_that_never_touches_is_an_error_and_z_goes_back_up(tmp_path: Path) -> None:
    config = load_config(_machine(tmp_path, SETTER.replace("lowest_z_mm = -40.0",
                                                           "lowest_z_mm = -15.0")))
    with connect_session(config) as session:
        session.home()
        with pytest.raises(ProbeFailedError, match="without the probe touching"):
            session.measure_tool(1)
        assert session.live.read().machine_mm()["Z"] == pytest.approx(0.0, abs=0.01)
        session.shutdown()


def test_the_setter_table_is_checked(tmp_path: Path) -> None:
    for old, new, says in (
        ("position_mm = [190.0, 190.0]", "position_mm = [190.0, 250.0]",
         "Y 250.0 is outside axis Y's travel_mm [0, 200]"),
        ("position_mm = [190.0, 190.0]", "position_mm = 190.0", "is not two numbers"),
        ("lowest_z_mm = -40.0", "lowest_z_mm = -5.0", "lowest_z_mm: -5.0 is out of range"),
        ("feed_mm_min = 60.0", "feed_mm_min = 6000.0", "feed_mm_min: 6000.0 is out of range"),
    ):
        with pytest.raises(ConfigError, match="tool_setter") as caught:
            load_config(_machine(tmp_path, SETTER.replace(old, new)))
        assert says in str(caught.value), str(caught.value)
    config = load_config(_machine(tmp_path, ""))
    with connect_session(config) as session:
        session.home()
        with pytest.raises(ConfigError, match="no \\[tool_setter\\] table"):
            session.measure_tool(1)


def test_a_tool_table_gets_a_tools_length_and_keeps_everything_else() -> None:
    text = "; the shop's tools\nT1 P1 Z12.5 D6 ;end mill\nT2 P2 D3\n"
    assert with_tool_length(text, 1, 20.25, comment="x") == (
        "; the shop's tools\nT1 P1 Z20.2500 D6 ;end mill\nT2 P2 D3\n")
    assert with_tool_length(text, 2, 5, comment="x").splitlines()[2] == "T2 P2 D3 Z5.0000"
    assert with_tool_length(text, 7, 1.5, comment="measured").splitlines()[-1] == (
        "T7 P7 Z1.5000 ;measured")
    assert with_tool_length("", 1, 2, comment="m") == "T1 P1 Z2.0000 ;m\n"


def test_the_dashboard_measures_a_tool(tmp_path: Path) -> None:
    config = load_config(_machine(tmp_path))
    with connect_session(config) as session:
        operator = Operator(session, file="<web>")
        dashboard = Dashboard(operator)
        try:
            with pytest.raises(RefusedError) as refused:
                dashboard.measure_tool(0)
            assert refused.value.status == 400
            session.home()
            answer = dashboard.measure_tool(4)
            assert answer["tool"] == 4 and answer["length_mm"] == pytest.approx(
                5.0, abs=1.0 / 240)
            assert answer["table"] == str(tmp_path / "tool.tbl")
        finally:
            operator.close()
            session.shutdown()


def test_the_console_refuses_to_measure_at_a_pause_that_is_no_tool_change(
        tmp_path: Path) -> None:
    """A program waits at an M0: $tls says what it measures instead of queueing behind the
    paused run."""
    config = load_config(_machine(tmp_path))
    said: list[str] = []
    with connect_session(config) as session:
        console = _paused_console(session, tmp_path, said, "G21 G90\nG0 X10\nM0\nG0 X20\nM2\n")
        try:
            console.handle("$tls")
            assert said[-1] == ("error: $tls measures while the machine is idle, or the new"
                                " tool at a program's M6 pause (as $tls alone); it waits at"
                                " an M0 pause now: ~ resumes, $x stops"), said
            console.handle("$x")
            assert console.operator.wait_idle(120)
        finally:
            console.close()
            session.shutdown()

TOOL_CHANGE = "G21 G90\nG0 X10 Y10 Z-5\nT1 M6\nG43 H1\nG0 X20 Z-20\nM2\n"
"""A tool change at line 3 and the G43 that takes the new tool's length at line 4: the
last position is Z -20 with T1's length added (12.5 mm in the table, 5 mm measured)."""


def _wait_paused(session: MachineSession, said: list[str]) -> None:
    deadline = time.monotonic() + 60
    while not session.held:
        assert time.monotonic() < deadline, said[-3:]
        time.sleep(0.01)


def _paused_console(session: MachineSession, folder: Path, said: list[str],
                    text: str) -> Console:
    """A console on ``session`` that homed, loaded ``text`` and started it: the program
    waits at its first pause (the console closed if it never gets there)."""
    program = folder / "program.ngc"
    program.write_text(text)
    console = Console(session, said.append)
    try:
        for line in ("$r", f"$l {program}"):
            console.handle(line)
            assert console.operator.wait_idle(120)
        console.handle("$c")
        _wait_paused(session, said)
    except BaseException:
        console.close()
        raise
    return console


def test_the_console_measures_the_new_tool_at_a_tool_change_and_goes_on(
        tmp_path: Path) -> None:
    """grblHAL's semi-automatic tool change: at the M6 pause, $tls ends the run there,
    measures the new tool on the setter and runs the program on from the next line,
    interpreted again, so its G43 takes the measured length."""
    config = load_config(_machine(tmp_path))
    said: list[str] = []
    with connect_session(config) as session:
        console = _paused_console(session, tmp_path, said, TOOL_CHANGE)
        try:
            assert session.paused is not None and session.paused.line == 3
            console.handle("$tls 3")
            assert said[-1].startswith("error: $tls measures while the machine is idle, or"
                                       " the new tool"), "a number is not the new tool's"
            console.handle("$tls")
            assert said[-1] == ("measuring T1 on the tool setter; the program then goes on"
                                " from line 4"), said[-3:]
            assert console.operator.wait_idle(120)
            end = session.live.read().machine_mm(measured=False)
        finally:
            console.close()
            session.shutdown()
    measured = next(text for text in said if text.startswith("T1 touched the setter"))
    assert "length 5.0000 mm" in measured, measured
    joined = said.index(next(text for text in said if "joining it at line 4" in text))
    assert said.index(measured) < joined, "measured before the program went on"
    assert said[-1] == "done", said[-4:]
    assert load_tool_table(tmp_path / "tool.tbl").tools[1].offset_mm[2] == pytest.approx(
        5.0, abs=1.0 / 240)
    assert end["X"] == pytest.approx(20.0, abs=1e-3) and end["Y"] == pytest.approx(10.0)
    assert end["Z"] == pytest.approx(-20.0 + 5.0, abs=1.0 / 240), "G43 H1 read the new length"


def test_a_failed_measurement_at_a_tool_change_says_how_to_go_on(tmp_path: Path) -> None:
    config = load_config(_machine(tmp_path, SETTER.replace("lowest_z_mm = -40.0",
                                                           "lowest_z_mm = -15.0")))
    said: list[str] = []
    with connect_session(config) as session:
        console = _paused_console(session, tmp_path, said, TOOL_CHANGE)
        try:
            console.handle("$tls")
            assert console.operator.wait_idle(120)
            assert session.live.read().machine_mm()["Z"] == pytest.approx(0.0, abs=0.01)
        finally:
            console.close()
            session.shutdown()
    assert said[-2].startswith("error: measuring T1: G38.2: the move ended without"), said[-3:]
    assert said[-1] == ("the program stopped at its tool change (line 3): $tls measures the"
                        " tool, then $c 4 runs the program on"), said[-3:]


def test_the_dashboard_measures_the_new_tool_at_a_tool_change(tmp_path: Path) -> None:
    config = load_config(_machine(tmp_path))
    with connect_session(config) as session:
        operator = Operator(session, file="<web>")
        dashboard = Dashboard(operator)
        try:
            session.home()
            dashboard.upload("change.ngc", TOOL_CHANGE.encode())
            dashboard.run()
            _wait_paused(session, [])
            with pytest.raises(RefusedError) as refused:
                dashboard.measure_tool(4)
            assert refused.value.status == 400
            assert dashboard.measure_tool() == {"tool": 1, "at_tool_change": 3,
                                                "from_line": 4}
            assert operator.wait_idle(120)
            report = operator.last_report
            assert report is not None and report.completed, report
            end = session.live.read().machine_mm(measured=False)
            assert end["Z"] == pytest.approx(-15.0, abs=1.0 / 240)
        finally:
            operator.close()
            session.shutdown()


def test_the_grbl_front_measures_with_tls_and_applies_the_length_as_g43_1(
        tmp_path: Path) -> None:
    """``$TLS`` (grblHAL's ``$TPW`` for a fixed setter): from Idle, the tool in the spindle
    measured, ``[MSG:...]`` with its length, then ``ok``; the length is the active tool
    length offset (``G43.1``: ``[TLO:5.000]`` in ``$#``), so the next move places the tip."""
    config = load_config(_machine(tmp_path))
    with connect_session(config) as session:
        operator = Operator(session, file="<grbl>")
        session.home()
        out: list[bytes] = []
        front = GrblProtocol(SessionMachine(operator), out.append)
        front.connect()

        def exchange(data: bytes, until: bytes = b"ok\r\n") -> str:
            out.clear()
            front.receive(data)
            deadline = time.monotonic() + 120
            while until not in b"".join(out):
                assert time.monotonic() < deadline, b"".join(out)
                front.poll()
                time.sleep(0.005)
            return b"".join(out).decode()

        try:
            answer = exchange(b"$TLS\n")
            found = re.search(r"\[MSG:T0 touched the setter at machine Z ([-\d.]+) mm: length"
                              r" ([-\d.]+) mm\]\r\nok\r\n$", answer)
            assert found is not None, answer
            assert float(found.group(1)) == pytest.approx(BUTTON_MM, abs=1.0 / 240)
            assert float(found.group(2)) == pytest.approx(5.0, abs=1.0 / 240)
            tlo = re.search(r"\[TLO:([-\d.]+)\]", exchange(b"$#\n"))
            assert tlo is not None and float(tlo.group(1)) == pytest.approx(5.0, abs=1.0 / 240)
            exchange(b"G21 G90 G0 Z-10\n")
            assert operator.wait_idle(60)
            assert session.live.read().machine_mm(measured=False)["Z"] == pytest.approx(
                -5.0, abs=1.0 / 240)
        finally:
            operator.close()
            session.shutdown()


def test_the_grbl_fronts_tls_is_refused_without_a_setter_and_alarms_without_contact(
        tmp_path: Path) -> None:
    """No ``[tool_setter]``: error:5 naming it; a tool that never touches: ALARM:5, as a
    probe that finds nothing (grbl's), with Z back up."""
    for setter, expected in (("", "error:5"),
                             (SETTER.replace("lowest_z_mm = -40.0", "lowest_z_mm = -15.0"),
                              "ALARM:5")):
        config = load_config(_machine(tmp_path, setter))
        with connect_session(config) as session:
            operator = Operator(session, file="<grbl>")
            session.home()
            out: list[bytes] = []
            front = GrblProtocol(SessionMachine(operator), out.append)
            front.connect()
            out.clear()
            try:
                front.receive(b"$TLS\n")
                deadline = time.monotonic() + 120
                while expected.encode() not in b"".join(out):
                    assert time.monotonic() < deadline, b"".join(out)
                    front.poll()
                    time.sleep(0.005)
                answer = b"".join(out).decode()
                if not setter:
                    assert answer == ("[MSG:no (tool_setter) table in the machine file: no"
                                      " tool to measure on]\r\nerror:5\r\n"), answer
                else:
                    assert "without the probe touching" in answer, answer
                    assert operator.wait_idle(60)
                    assert session.live.read().machine_mm()["Z"] == pytest.approx(
                        0.0, abs=0.01)
            finally:
                operator.close()
                session.shutdown()
