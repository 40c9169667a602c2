"""The motor constants core0 derives on the chip are the Python's, to the last digit.

core0 derives the simulated motor's integration constants in double arithmetic
(``motor.derive_constants``: divisions, then ``decay_and_lag``'s fixed series, with a
subtraction that cancels almost everything for a slow motor); on the RP2040 that is soft
float, the compiler's (libgcc), not the SDK's pico_double, whose ``expm1`` (exp(x) - 1)
once made the lag of a 100 us step -8274e-15 where the Python has 1000e-17. Random motor
parameters (calls 5, 12-17, 32, 33) are given to the emulated firmware and the constants
core1 then runs on are read from its RAM (``servo_params``, by its ELF symbol, at the field
offsets the Arm compiler gives) and compared with ``Device.motor_constants``.
"""

from __future__ import annotations

import re
import shutil
import struct
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from usbmotion.device import Device

from .emulated import EmulatedFirmware, missing, require_emulator
from .native import ROOT

FIELDS = ("steps", "drive", "friction", "decay", "lag")


def _arm_offsets(tmp: Path) -> dict[str, int]:
    """offsetof(servo_params_t, field) as arm-none-eabi-gcc lays the struct out."""
    probe = tmp / "offsets.c"
    probe.write_text('#include <stddef.h>\n#include "servo.h"\n' + "".join(
        f"const int offset_{name} = offsetof(servo_params_t, {name});\n" for name in FIELDS))
    result = subprocess.run(
        ["arm-none-eabi-gcc", "-mcpu=cortex-m0plus", "-mthumb", "-std=c11", "-S", "-o", "-",
         f"-I{ROOT / 'firmware' / 'src' / 'device'}", str(probe)],
        capture_output=True, text=True, check=True)
    found = dict(re.findall(r"offset_(\w+):\s*\.word\s+(\d+)", result.stdout))
    return {name: int(found[name]) for name in FIELDS}


@pytest.fixture(scope="module")
def chip(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[EmulatedFirmware,
                                                                      dict[str, int]]]:
    require_emulator(missing() or (None if shutil.which("arm-none-eabi-gcc")
                                   else "no arm-none-eabi-gcc"))
    firmware = EmulatedFirmware()
    firmware.device.power_up(erase_flash=True)
    yield firmware, _arm_offsets(tmp_path_factory.mktemp("offsets"))
    firmware.close()


def _sci(coefficient_min: int) -> st.SearchStrategy[tuple[int, int]]:
    extremes = st.tuples(st.sampled_from([coefficient_min, 1, 9999]),
                         st.sampled_from([-12, -6, 0, 6]))
    return st.one_of(st.tuples(st.integers(coefficient_min, 9999), st.integers(-12, 6)),
                     extremes)


_PARAMETERS = st.fixed_dictionaries({
    5: st.one_of(st.integers(1, 10000), st.sampled_from([1, 3, 10, 10000])),
    12: st.one_of(st.integers(1, 10000), st.sampled_from([1, 3, 10, 10000])),
    13: _sci(1), 14: _sci(1), 15: _sci(1),
    16: st.one_of(st.integers(1, 1_000_000), st.sampled_from([1, 1920, 1_000_000])),
    17: _sci(1), 32: _sci(0), 33: _sci(0),
})


def _line(call: int, value: int | tuple[int, int]) -> bytes:
    values = value if isinstance(value, tuple) else (value,)
    return b" ".join(b"%d" % v for v in (call, *values)) + b"\n"


@settings(max_examples=80, deadline=None)
@given(_PARAMETERS)
def test_derived_constants_match(chip: tuple[EmulatedFirmware, dict[str, int]],
                                 parameters: dict[int, int | tuple[int, int]]) -> None:
    firmware, offsets = chip
    data = b"".join(_line(call, value) for call, value in parameters.items())
    device = Device()
    device.feed(data)
    firmware.device.feed(data)
    raw = firmware.device.read_symbol("servo_params")
    pair = lambda name: struct.unpack_from("<ii", raw, offsets[name])  # noqa: E731
    expected = device.motor_constants
    assert struct.unpack_from("<i", raw, offsets["steps"])[0] == expected.steps
    assert (pair("drive"), pair("friction")) == (expected.drive, expected.friction_speed)
    assert (pair("decay"), pair("lag")) == (expected.decay, expected.lag_s), data
