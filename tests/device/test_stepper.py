"""The step/direction drives (call 44) on the simulated stepper: it follows its steps, loses
whole electrical cycles open loop beyond its pull-out torque while the counter says it
arrived, and closed loop stalls instead, catches up, or faults at the following-error limit.

The move of every test: 16,000 microsteps (five turns at 16 microsteps) in one second on a
cosine, on the power-up NEMA 17 with a 1e-5 kg m^2 shaft, 1 kHz servo, 100 us sub-steps.
"""

from __future__ import annotations

import math

import pytest

from usbmotion.device import Device
from usbmotion.device.stepper import (
    SINE,
    SINE_ONE,
    StepperParams,
    encoder_microsteps,
    max_steps_per_tick,
    sine_at,
)

from .helpers import send

MOVE = 16_000
CYCLE = 4 * 16
"""An electrical cycle at 16 microsteps: four full steps."""


RATE = {1: 1, 2: 10}
"""Ticks per millisecond of each drive's tests: a closed loop runs at 10 kHz (its rotor
rings at about 270 Hz; at 1 kHz the loop sees it too late to damp it well)."""


def _stepper(drive: int, *extra: str) -> Device:
    device = Device()
    send(device, f"44 {drive}", f"5 {10 // RATE[drive]}", "17 1 -5", "12 1", "16 4000",
         "9 1 -1", "10 1 0", "11 2 -3", *extra, "3 1")
    return device


def _move(device: Device, *, load_at: tuple[int, int] | None = None,
          load: str = "40 1") -> list[tuple[int, int, int]]:
    """Play the move (a load of ``load`` from tick ``load_at[0]`` to ``load_at[1]``), then
    half a second at rest; (desired, counter, shaft microsteps) after every tick (the
    device's clock is then the index plus the ticks its setup took)."""
    rate = 1000 // device.tick_us
    values = [round(MOVE * (1 - math.cos(math.pi * i / (1000 * rate))) / 2)
              for i in range(1000 * rate + 1)]
    seen: list[tuple[int, int, int]] = []
    for tick in range(1500 * rate + 1):
        if load_at is not None and tick == load_at[0] * rate:
            send(device, f"33 {load}")
        if load_at is not None and tick == load_at[1] * rate:
            send(device, "33 5 1")
        if tick < len(values):
            send(device, f"0 {values[tick]}")
        device.run(1)
        state = device.state
        seen.append((state.desired, state.actual, state.shaft_micro_counts // 1_000_000))
    return seen


@pytest.mark.parametrize("drive", [1, 2])
def test_the_shaft_follows_its_steps(drive: int) -> None:
    seen = _move(_stepper(drive))
    assert max(abs(shaft - desired) for desired, _, shaft in seen) <= 2 * 16  # full steps
    desired, actual, shaft = seen[-1]
    assert desired == actual == MOVE
    assert abs(shaft - MOVE) <= 1
    assert send(_stepper(drive), "48 -1") == [f"STEPS 0 0 {249 if drive == 1 else 24}"]


def test_open_loop_loses_whole_cycles_beyond_the_pull_out_torque_and_says_it_arrived(
) -> None:
    device = _stepper(1)
    seen = _move(device, load_at=(300, 600), load="1 3")
    desired, actual, shaft = seen[-1]
    assert desired == actual == MOVE, "open loop the counter is the steps issued"
    lost = MOVE - shaft
    assert lost >= 10 * CYCLE
    cycles = round(lost / CYCLE)
    assert abs(lost - cycles * CYCLE) <= 2, f"{lost} microsteps is no whole number of cycles"
    assert send(device, "48 -1") == [f"STEPS {MOVE} 0 249"]
    assert device.state.fault == 0
    print(f"open loop, 1 N m from tick 300 to 600: {lost} microsteps lost ({cycles} cycles)")


def test_closed_loop_follows_the_same_load() -> None:
    seen = _move(_stepper(2), load_at=(300, 600))
    desired, actual, shaft = seen[-1]
    assert desired == actual == MOVE and abs(shaft - MOVE) <= 1
    assert max(abs(actual - desired) for desired, actual, _ in seen) < 64


def test_closed_loop_stalls_rather_than_slips_and_catches_up() -> None:
    seen = _move(_stepper(2), load_at=(300, 600), load="1 3")
    stalled = [shaft for _, _, shaft in seen[3200:6000]]
    assert max(stalled) - min(stalled) <= 16, "a stalled rotor stays within a full step"
    assert all(abs(actual - shaft) <= 1 for _, actual, shaft in seen)
    after = [actual - desired for desired, actual, _ in seen[10_000:]]
    assert max(map(abs, after)) <= 16, "caught up: within a full step once the move ended"


def test_closed_loop_faults_at_the_following_error_limit_on_the_tick() -> None:
    device = _stepper(2, "29 400")
    start = device.state.clock
    seen = _move(device, load_at=(300, 600), load="1 3")
    state = device.state
    assert state.fault == 2 and state.enable == 0
    first = next(i for i, (desired, actual, _) in enumerate(seen) if desired - actual > 400)
    assert all(desired - actual <= 400 for desired, actual, _ in seen[:first])
    assert state.fault_tick == start + first + 1  # the clock after the tick it happened on
    assert send(device, "48 -1")[0].endswith(" 0 24"), "no steps after the fault"


def test_the_pull_out_torque_falls_above_the_corner_speed() -> None:
    """300 mNm against the rotor at constant speed: below the corner speed (760 rpm) the
    590 mNm holding torque carries it; at 2,000 rpm only 590 x 760 / 2000 = 224 mNm is
    left and the rotor falls out of step."""

    def lost_at(rpm: int) -> int:
        device = Device()
        send(device, "44 1", "17 1 -5", "12 1", "7 2", "33 3 2", "3 1")
        speed = rpm * 3200 // 60
        ramp = [speed * i // 400 for i in range(1, 401)]
        for value in (*ramp, *([speed] * 600)):
            send(device, f"0 {value}")
            device.run(1)
        state = device.state
        return state.actual - state.shaft_micro_counts // 1_000_000

    assert abs(lost_at(600)) <= 16
    assert lost_at(2000) > 1000


def test_calls_that_cannot_be_carried_out_are_refused_and_change_nothing() -> None:
    device = Device()
    send(device, "3 1")
    assert send(device, "44 1")[0].startswith("ERR 44 the servo is enabled")
    send(device, "3 0", "44 1")
    assert send(device, "46 1000000 0")[0].startswith("ERR 46 a 1000 us tick fits no step")
    assert send(device, "47 100 200 760")[0].startswith("ERR 47 detent torque 200 mNm")
    send(device, "46 100000 0")
    assert send(device, "5 1")[0].startswith("ERR 5 a 100 us tick fits no step")
    assert send(device, "44 -1", "46 -1 0", "47 -1 0 0", "5 -1") == [
        "DRIVE 1", "STEP_TIMING 100000 0", "SIM_STEPPER 590 20 760",
        "SERVO_UPDATE_INTERVAL_US 1000"]


def test_the_step_budget_of_a_tick() -> None:
    assert max_steps_per_tick(1000, 2000, 1000) == 249
    assert max_steps_per_tick(100, 100, 20) == 480
    assert max_steps_per_tick(100, 1_000_000, 0) == 0
    assert StepperParams().microsteps_per_revolution == 3200


def test_the_sine_table_and_the_floored_angles() -> None:
    assert (int(SINE[0]), int(SINE[256]), int(SINE[512]), int(SINE[768])) == (
        0, SINE_ONE, 0, -SINE_ONE)
    assert sine_at(-1, 1024) == int(SINE[1023]) and sine_at(1024 + 5, 1024) == int(SINE[5])
    assert encoder_microsteps(-1, 4000, 3200) == -2  # floored twice
    assert encoder_microsteps(3199, 4000, 3200) == 3198  # count 3998 is 3198.4 microsteps
    assert encoder_microsteps(4, 1000, 3200) == 3  # a 1000-count encoder: 3.2 microsteps


def test_after_a_fault_the_driver_holds_its_field_until_the_fault_is_cleared() -> None:
    """The stall that faulted left the field a full step ahead of the rotor: held, the rotor
    is pulled onto the field once the load goes; the steps have stopped."""
    device = _stepper(2, "29 400")
    _move(device, load_at=(300, 1400), load="1 3")
    assert device.state.fault == 2
    send(device, "33 5 1")
    device.run(2000)
    issued = int(send(device, "48 -1")[0].split()[1])
    shaft = device.state.shaft_micro_counts // 1_000_000
    assert abs(shaft - issued) <= 2, "the rotor sits on the field it is held by"
    send(device, "30 0")
    device.run(100)
    assert send(device, "48 -1")[0].split()[1:3] == [str(issued), "0"]
