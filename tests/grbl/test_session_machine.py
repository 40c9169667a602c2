"""The grbl front's machine on a session (:class:`SessionMachine`), in virtual time: what
``$$`` shows of the machine file, settings written back unchanged, the alarm before homing
and ``$X``."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from usbmotion.cli.run import default_machine
from usbmotion.grbl.interface import GrblMachine, MotionState, Rejected
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


def test_a_setting_written_back_unchanged_is_taken_and_a_change_is_refused_naming_the_file(
        machine: SessionMachine) -> None:
    assert machine.set_setting(110, 1200.0) is None
    assert machine.set_setting(11, 0.010) is None
    refused = machine.set_setting(110, 1000.0)
    assert isinstance(refused, Rejected) and refused.code == 3
    assert "machine.toml" in refused.message


def test_alarm_until_homed_or_unlocked(machine: SessionMachine) -> None:
    assert machine.state() is MotionState.ALARM
    machine.unlock()
    assert machine.state() is MotionState.IDLE
