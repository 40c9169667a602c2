"""The grbl front's machine on a session (:class:`SessionMachine`), in virtual time: what
``$$`` shows of the machine file, settings written back unchanged, the alarm before homing
and ``$X``, and
settings changed with ``$N=value``: checked as the machine file is, taken for the next
motion and kept in the file."""

from __future__ import annotations

import difflib
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from usbmotion.cli.run import default_machine
from usbmotion.grbl.interface import (
    Admission,
    GrblMachine,
    JogMove,
    MotionState,
    Rejected,
    Taken,
)
from usbmotion.grbl.session_machine import SessionMachine
from usbmotion.host.config import load_config
from usbmotion.session.operator import Operator
from usbmotion.sim.machine import connect_session


@pytest.fixture
def machine() -> Iterator[SessionMachine]:
    with connect_session(load_config(default_machine())) as session, \
            Operator(session) as operator:
        yield SessionMachine(operator)


def test_it_is_a_grbl_machine_whose_settings_are_the_machine_file(
        machine: SessionMachine) -> None:
    assert isinstance(machine, GrblMachine)
    settings = machine.settings()
    x = settings.axes[0]
    assert (x.counts_per_mm, x.max_rate_mm_min, x.accel_mm_s2, x.max_travel_mm) == (
        240.0, 1200.0, 500.0, 200.0)
    assert settings.junction_deviation_mm == 0.01 and settings.homing


@pytest.fixture
def kept(tmp_path: Path) -> Iterator[SessionMachine]:
    """A session on a copy of the default machine file, its settings written back to it."""
    path = tmp_path / "machine.toml"
    shutil.copy(default_machine(), path)
    with connect_session(load_config(path)) as session, Operator(session) as operator:
        yield SessionMachine(operator, keep_settings=True)


def _homed(machine: SessionMachine) -> None:
    machine.home()
    assert machine.operator.wait_idle(60)
    assert machine.state() is MotionState.IDLE


def test_a_setting_written_back_unchanged_is_taken_and_changes_nothing(
        machine: SessionMachine) -> None:
    before = Path(default_machine()).read_text()
    for number, value in ((110, 1200.0), (11, 0.010), (130, 200.0), (20, 1.0),
                          (23, 3.0)):  # X and Y home down (bits 0, 1), Z up
        assert machine.set_setting(number, value) is None, number
    assert machine.config.path == Path(default_machine())
    assert Path(default_machine()).read_text() == before


def test_a_changed_setting_is_checked_taken_and_kept_in_the_machine_file(
        kept: SessionMachine) -> None:
    path = Path(kept.config.path)
    before = path.read_text()
    assert kept.set_setting(110, 1000.0) is None
    assert kept.settings().axes[0].max_rate_mm_min == pytest.approx(1000.0, abs=1e-3)
    assert kept.session.config.axis("X").max_velocity_mm_s == pytest.approx(16.666667)
    text = path.read_text()
    assert "max_velocity_mm_s = 16.666667" in text
    assert [line for line in difflib.ndiff(before.splitlines(), text.splitlines())
            if line.startswith(("+", "-"))] == ["- max_velocity_mm_s = 20.0",
                                                "+ max_velocity_mm_s = 16.666667"], \
        "one line changed, comments and layout kept"
    assert load_config(path).axis("X").max_velocity_mm_s == pytest.approx(16.666667)


def test_a_setting_beyond_what_the_motor_reaches_is_refused_and_the_file_kept(
        kept: SessionMachine) -> None:
    path = Path(kept.config.path)
    before = path.read_text()
    refused = kept.set_setting(110, 3000.0)
    assert isinstance(refused, Rejected) and refused.code == 3
    assert "$110=3000 refused" in refused.message and "max_velocity_mm_s" in refused.message
    assert "faster than the motor can go" in refused.message, refused.message
    refused = kept.set_setting(100, 0.0)
    assert isinstance(refused, Rejected) and "counts_per_mm" in refused.message
    assert path.read_text() == before
    assert kept.settings().axes[0].max_rate_mm_min == 1200.0


def test_the_travel_sets_the_soft_limits_of_the_next_lines(kept: SessionMachine) -> None:
    _homed(kept)
    assert kept.set_setting(130, 150.0) is None
    assert kept.session.config.axis("X").travel_mm == (0.0, 150.0)
    refused = kept.submit("G0X180", None)
    assert isinstance(refused, Rejected) and refused.code == 33
    assert kept.submit("G0X140", None) is Admission.ACCEPTED
    assert kept.operator.wait_idle(60)
    assert kept.status().machine_position_mm[0] == pytest.approx(140.0, abs=0.01)


def test_a_new_scale_needs_homing_again(kept: SessionMachine) -> None:
    _homed(kept)
    taken = kept.set_setting(100, 250.0)
    assert isinstance(taken, Taken) and "home again" in taken.message and "X" in taken.message
    assert kept.state() is MotionState.ALARM
    assert not kept.session.homed["X"] and kept.session.homed["Y"]
    _homed(kept)
    assert kept.settings().axes[0].counts_per_mm == 250.0


def test_homing_settings_apply_to_every_axis_and_fixed_ones_say_why(
        kept: SessionMachine) -> None:
    assert kept.set_setting(25, 480.0) is None
    assert kept.set_setting(27, 1.5) is None
    assert [kept.session.config.axis(a).homing.speed_mm_s for a in "XYZ"] == [8.0] * 3
    assert [kept.session.config.axis(a).homing.pull_off_mm for a in "XYZ"] == [1.5] * 3
    refused = kept.set_setting(20, 0.0)
    assert isinstance(refused, Rejected) and "travel" in refused.message
    refused = kept.set_setting(23, 9.0)
    assert isinstance(refused, Rejected) and "0..7" in refused.message
    refused = kept.set_setting(140, 1.0)
    assert isinstance(refused, Rejected) and "no setting" in refused.message


def test_on_the_built_in_machine_a_change_holds_for_the_session(
        machine: SessionMachine) -> None:
    before = Path(default_machine()).read_text()
    taken = machine.set_setting(120, 400.0)
    assert isinstance(taken, Taken) and "this session" in taken.message
    assert machine.session.config.axis("X").max_accel_mm_s2 == 400.0
    assert isinstance(machine.set_setting(110, 1000.0), Taken)
    assert machine.session.config.axis("X").max_accel_mm_s2 == 400.0, "the first one kept"
    assert machine.settings().axes[0].max_rate_mm_min == pytest.approx(1000.0, abs=1e-3)
    assert Path(default_machine()).read_text() == before


def test_alarm_until_homed_or_unlocked(machine: SessionMachine) -> None:
    assert machine.state() is MotionState.ALARM
    machine.unlock()
    assert machine.state() is MotionState.IDLE


def test_offsets_set_by_lines_show_in_hash_and_a_soft_reset_clears_g92_as_grbl(
        machine: SessionMachine) -> None:
    """A G54 set by G10 L20 through the front shows in ``$#`` at once (the lines' own
    offsets, not only the parameter file's), and so does a G92; grbl's soft reset puts
    the lines' modal state back to power-on and clears G92, the G54 kept."""
    _homed(machine)
    here = machine.status().machine_position_mm
    for line in ("G10L20P1X0Y0", "G92Z1"):
        assert machine.submit(line, None) is Admission.ACCEPTED
    offsets = machine.work_offsets()
    assert offsets.coordinate_systems[0][:2] == pytest.approx(here[:2], abs=0.01)
    assert offsets.g92[2] == pytest.approx(here[2] - 1.0 - offsets.coordinate_systems[0][2],
                                           abs=0.01)
    machine.soft_reset()
    assert machine.operator.wait_idle(30)
    offsets = machine.work_offsets()
    assert offsets.g92 == (0.0, 0.0, 0.0), "G92 is volatile in grbl"
    assert offsets.coordinate_systems[0][:2] == pytest.approx(here[:2], abs=0.01), "G54 kept"
    assert machine.modal_state().distance == "G90"


def test_a_refused_jog_answers_an_error_at_once(machine: SessionMachine) -> None:
    """A jog the session would refuse in its worker (an unhomed machine has no soft limits)
    is refused by the front itself, so the sender gets error:N and not ok."""
    refused = machine.jog(JogMove({"X": 5.0}, 600.0, incremental=True,
                                  machine_coordinates=True))
    assert isinstance(refused, Rejected) and refused.code == 15
    _homed(machine)
    beyond = machine.jog(JogMove({"X": 500.0}, 600.0, incremental=True,
                                 machine_coordinates=True))
    assert isinstance(beyond, Rejected) and beyond.code == 15
    taken = machine.jog(JogMove({"X": 5.0}, 600.0, incremental=True, machine_coordinates=True))
    assert taken is Admission.ACCEPTED
    assert machine.operator.wait_idle(30)
