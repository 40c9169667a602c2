"""The RP2040 firmware in the emulator answers byte for byte as the Python device.

Every scripted session of ``test_native_device`` (the device tests' replies, debug lines,
errors, over-long lines, tokens, huge integers, servo scenarios, call 38) replayed on the
Python device and on the firmware built for the chip (``make firmware``), running on an
emulated RP2040 (``firmware/emulator``): identical lines, each at the same servo tick.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from . import test_native_device as native
from .emulated import EmulatedFirmware, emulated_driver
from .sessions import Run, lines
from .test_native_device import (  # the scripted sessions, run here on the emulated chip
    test_a_fault_alarm_and_the_refusal_to_enable,
    test_a_load_beyond_the_pull_out_torque_loses_steps_open_loop,
    test_a_load_beyond_the_pull_out_torque_stalls_the_closed_loop,
    test_a_long_run_of_leading_zeros,
    test_a_set_value_is_queried_back,
    test_a_stale_derivative_history_after_rest,
    test_a_stale_derivative_history_tick_by_tick,
    test_alarms_of_every_fault,
    test_an_open_loop_beyond_its_pull_out_speed_loses_steps,
    test_bad_values,
    test_calls_23_and_37_shift_a_step_drive,
    test_counts_before_ranges_and_query_forms,
    test_diagnostics_lines_at_their_ticks,
    test_every_debug_flag_of_every_call,
    test_every_debug_line,
    test_every_query_after_settings,
    test_every_query_at_power_up,
    test_huge_integers_everywhere,
    test_integers_of_any_length,
    test_long_lines_of_many_inputs,
    test_messages_of_refused_calls,
    test_outputs_on_their_ticks,
    test_over_long_lines,
    test_replacing_the_queue_future,
    test_replies_in_order_and_any_split,
    test_seed_000_strings,
    test_status_after_a_move,
    test_step_drives_follow_moves_in_every_mode,
    test_stopping_on_time_and_late,
    test_the_60_s_reset_of_velocity_mode_in_a_step_drive,
    test_the_crc_acknowledgement_of_a_full_queue,
    test_the_crc_of_a_batch_that_wraps_the_queue_ring,
    test_the_peak_of_diagnostics_lines,
    test_the_probe_edge_in_velocity_mode_and_its_counter_reset,
    test_the_probe_input,
    test_the_step_drive_calls_refuse_and_answer,
    test_tokens_shown_as_python_repr_shows_them,
)

SCRIPTED = (
    test_a_fault_alarm_and_the_refusal_to_enable,
    test_a_load_beyond_the_pull_out_torque_loses_steps_open_loop,
    test_a_load_beyond_the_pull_out_torque_stalls_the_closed_loop,
    test_a_long_run_of_leading_zeros,
    test_a_set_value_is_queried_back,
    test_a_stale_derivative_history_after_rest,
    test_a_stale_derivative_history_tick_by_tick,
    test_alarms_of_every_fault,
    test_an_open_loop_beyond_its_pull_out_speed_loses_steps,
    test_bad_values,
    test_calls_23_and_37_shift_a_step_drive,
    test_counts_before_ranges_and_query_forms,
    test_diagnostics_lines_at_their_ticks,
    test_every_debug_flag_of_every_call,
    test_every_debug_line,
    test_every_query_after_settings,
    test_every_query_at_power_up,
    test_huge_integers_everywhere,
    test_integers_of_any_length,
    test_long_lines_of_many_inputs,
    test_messages_of_refused_calls,
    test_outputs_on_their_ticks,
    test_over_long_lines,
    test_replacing_the_queue_future,
    test_replies_in_order_and_any_split,
    test_seed_000_strings,
    test_status_after_a_move,
    test_step_drives_follow_moves_in_every_mode,
    test_stopping_on_time_and_late,
    test_the_60_s_reset_of_velocity_mode_in_a_step_drive,
    test_the_crc_acknowledgement_of_a_full_queue,
    test_the_crc_of_a_batch_that_wraps_the_queue_ring,
    test_the_peak_of_diagnostics_lines,
    test_the_probe_edge_in_velocity_mode_and_its_counter_reset,
    test_the_probe_input,
    test_the_step_drive_calls_refuse_and_answer,
    test_tokens_shown_as_python_repr_shows_them,
)


@pytest.fixture(scope="module")
def driver() -> Iterator[EmulatedFirmware]:
    """One emulated chip for the module; each session powers up a fresh one on blank flash."""
    yield from emulated_driver()


GENERATED = {"test_random_bytes", "test_random_integer_lines", "test_extreme_parameters",
             "test_fuzz_sessions", "test_fuzz_sessions_with_diagnostics"}
"""The native module's hypothesis tests: test_emulated_fuzz runs them with its own budgets."""


def test_every_session_of_the_native_tests_runs_here() -> None:
    """A session added to test_native_device for any build (``driver: Driver``) runs here."""
    shared = {name for name, function in vars(native).items()
              if name.startswith("test_") and callable(function)
              and getattr(function, "__annotations__", {}).get("driver") == "Driver"}
    assert shared == {function.__name__ for function in SCRIPTED} | GENERATED


# --- sessions of the chip's own: the budget's worst cases ----------------------------------


def _ramp(count: int, step: int) -> str:
    return " ".join(str(step * k) for k in range(1, count + 1))


def test_every_mode_at_10_khz_with_diagnostics_every_tick(driver: EmulatedFirmware) -> None:
    """Position, velocity and curve mode at a 100 us period, a D line after every tick and
    the statistics counting: the cases benchmarks/firmware_budget.py measures. A curve's
    first tick of a segment takes longer than the period on the chip; the harness holds the
    timer while core1 works, so the ticks stay one period apart as the Python's."""
    native.assert_same(driver, [
        lines("5 1", "21 1", "3 1", f"1 1000 {_ramp(1000, 3)}"), Run(300),
        lines("35 -1", "7 2", "3 1", f"1 500 {' '.join(['20000'] * 500)}"), Run(300),
        lines("7 3", "3 1", "25 20 400 0 0", "25 10 -100 512 -512", "25 30 2000 100 -100",
              "25 25 -3000 0 0"), Run(900), lines("20 -1", "35 -1", "27 -1"),
    ])
    assert driver.device.status().tick == 1500


def test_the_step_drives_at_10_khz_with_diagnostics_every_tick(driver: EmulatedFirmware) -> None:
    """Both step drives at a 100 us period in one 100 us integration step a tick, a D line
    after every tick: position (a ramp at up to the tick's most steps), velocity and curve
    mode, the cases benchmarks/firmware_budget.py measures."""
    for drive in (1, 2):
        native.assert_same(driver, [
            lines("5 1", "12 1", "17 1 -5", "33 20 0", "16 4000", f"44 {drive}", "21 1", "3 1",
                  f"1 600 {_ramp(600, 8)}"), Run(300),
            lines("35 -1", "48 -1", "7 2", "3 1", f"1 300 {' '.join(['40000'] * 300)}"), Run(300),
            lines("48 -1", "7 3", "3 1", "25 20 400 0 0", "25 10 -100 512 -512",
                  "25 30 2000 100 -100"), Run(700), lines("20 -1", "35 -1", "48 -1"),
        ])

