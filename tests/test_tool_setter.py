"""A tool-length setter (``[tool_setter]``): the tool in the spindle lowered onto a fixed
probe button, its contact against the reference tool's its length, written into the tool
table where the next ``G43`` reads it. On the simulated machine the button is Z's probe
surface (``sim.probe_below_mm``); a longer tool touches it higher, as moving the surface
up by the extra length shows."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from usbmotion.console import Console
from usbmotion.errors import ConfigError
from usbmotion.host.config import load_config
from usbmotion.motion.tools import load_tool_table, with_tool_length
from usbmotion.session.operator import Operator
from usbmotion.session.probing import ProbeFailedError
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


def test_the_console_refuses_to_measure_at_a_program_pause(tmp_path: Path) -> None:
    """A program waits at its M6 pause: $tls says what to do instead of queueing behind
    the paused run."""
    config = load_config(_machine(tmp_path))
    program = tmp_path / "change.ngc"
    program.write_text("G21 G90\nG0 X10\nT1 M6\nG0 X20\nM2\n")
    said: list[str] = []
    with connect_session(config) as session:
        console = Console(session, said.append)
        try:
            for line in ("$r", f"$l {program}"):
                console.handle(line)
                assert console.operator.wait_idle(120)
            console.handle("$c")
            deadline = time.monotonic() + 60
            while not session.held:
                assert time.monotonic() < deadline, said[-3:]
                time.sleep(0.01)
            console.handle("$tls")
            assert said[-1].startswith("error: $tls measures while the machine is idle"), said
            console.handle("$x")
            assert console.operator.wait_idle(120)
        finally:
            console.close()
            session.shutdown()
