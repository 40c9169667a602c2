"""Flash: the name and default mode persist, writes are atomic and counted."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from usbmotion.device import Device, FileFlash, MemoryFlash
from usbmotion.errors import FlashError

from .helpers import send


def _name_line(name: str) -> str:
    return f"18 {len(name)} " + " ".join(str(ord(c)) for c in name)


def test_name_and_default_mode_persist_across_devices(tmp_path: Path) -> None:
    path = tmp_path / "x.json"
    device = Device(flash=FileFlash(path))
    assert device.name == "GENERIC USB MOTION DEVICE"
    assert not path.exists(), "blank flash is not written until a call writes it"
    send(device, _name_line("ROBOT LEFT LEG"), "19 2")
    again = Device(flash=FileFlash(path))
    assert again.name == "ROBOT LEFT LEG"
    assert send(again, "18 -1", "19 -1", "7 -1") == [
        "DEVICE_NAME ROBOT LEFT LEG",
        "DEFAULT_CONTROL_MODE 2",
        "CONTROL_MODE 2",
    ]
    assert json.loads(path.read_text())["writes"] == 2


def test_the_write_counter_persists_and_counts_every_write(tmp_path: Path) -> None:
    path = tmp_path / "x.json"
    for round_ in range(3):
        device = Device(flash=FileFlash(path))
        assert device.settings.flash_writes == 2 * round_
        send(device, _name_line(f"AXIS {round_}"), "19 1")
    assert FileFlash(path).read().writes == 6


def test_erasing_the_name_answers_to_the_default(tmp_path: Path) -> None:
    path = tmp_path / "x.json"
    device = Device(flash=FileFlash(path))
    send(device, _name_line("Z"), "18 0")
    assert Device(flash=FileFlash(path)).name == "GENERIC USB MOTION DEVICE"


def test_a_crash_before_the_rename_keeps_the_old_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "x.json"
    device = Device(flash=FileFlash(path))
    send(device, _name_line("OLD NAME"))

    def crash(src: object, dst: object) -> None:
        raise OSError("power lost")

    monkeypatch.setattr(os, "replace", crash)
    reply = send(device, _name_line("NEW NAME"))
    assert len(reply) == 1
    assert reply[0].startswith("ERR 18 flash write failed, value unchanged:")
    assert "power lost" in reply[0]
    assert device.name == "OLD NAME"
    assert send(device, "3 -1") == ["SERVO_ENABLE 0"], "the device keeps serving"
    monkeypatch.undo()
    assert Device(flash=FileFlash(path)).name == "OLD NAME"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.json"], "no temporary file left"


_KILLED_WRITER = """
import os, signal, sys
from usbmotion.device import FileFlash
flash = FileFlash(sys.argv[1])
os.replace = lambda src, dst: os.kill(os.getpid(), signal.SIGKILL)
flash.write(name="NEW")
"""


def test_a_writer_killed_before_the_rename_leaves_the_old_name(tmp_path: Path) -> None:
    path = tmp_path / "x.json"
    FileFlash(path).write(name="OLD")
    result = subprocess.run(
        [sys.executable, "-c", _KILLED_WRITER, str(path)], check=False, timeout=60
    )
    assert result.returncode == -signal.SIGKILL
    leftovers = [p.name for p in tmp_path.iterdir() if p.name != "x.json"]
    assert len(leftovers) == 1, "the temporary file of the killed write"
    flash = FileFlash(path)
    assert (flash.read().name, flash.read().writes) == ("OLD", 1)
    assert Device(flash=flash).name == "OLD"


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("{not json", "not valid JSON"),
        ("[1, 2]", "expected a JSON object"),
        ('{"format": 1, "name": "A", "colour": 3}', "unknown keys"),
        ('{"format": 2, "name": "A"}', "format 2"),
        ('{"format": 1, "name": "' + "N" * 26 + '"}', "bad name"),
        ('{"format": 1, "default_control_mode": 0}', "bad default_control_mode"),
        ('{"format": 1, "writes": -1}', "bad writes"),
    ],
)
def test_a_corrupt_file_is_a_flash_error_naming_it(
    tmp_path: Path, text: str, problem: str
) -> None:
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(FlashError, match=problem) as raised:
        FileFlash(path)
    assert "bad.json" in str(raised.value)


def test_an_unwritable_directory_is_an_err_reply_not_a_crash(tmp_path: Path) -> None:
    path = tmp_path / "missing-dir" / "x.json"
    device = Device(flash=FileFlash(path))
    reply = send(device, _name_line("A"))
    assert reply[0].startswith("ERR 18 flash write failed")
    assert device.name == "GENERIC USB MOTION DEVICE"


def test_memory_flash_survives_restart_only() -> None:
    flash = MemoryFlash()
    device = Device(flash=flash)
    send(device, _name_line("MEM"))
    device.restart()
    assert device.name == "MEM"
    assert Device().name == "GENERIC USB MOTION DEVICE"
    assert flash.read().writes == 1
