"""Flash: a crash at every step of a write leaves the old value or the new one, never a corrupt
one, and the write counter survives.

A device writes its name (call 18) in a child process that is killed with SIGKILL just
before one step of the write, for every step in turn: creating the temporary file, each
half of the data reaching it, the flush, the fsync of the data, closing it, the rename over
the old file, opening, syncing and closing the directory. SIGKILL runs no cleanup, so what
is on disk is what a crash at that instant leaves. A fresh device then powers up on the
file: it must find the old name with the old count when the rename had not happened, the
new name with the count plus one when it had, and it must be able to write again.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from usbmotion.device import Device, FileFlash

OLD = "OLD NAME"
NEW = "NEW NAME"

_WRITER = r"""
import os, signal, sys, tempfile, json
import usbmotion.device.flash as flash_module
from usbmotion.device import Device, FileFlash

path, crash_before, log = sys.argv[1], int(sys.argv[2]), sys.argv[3]
steps = []

def step(name):
    if len(steps) == crash_before:
        os.kill(os.getpid(), signal.SIGKILL)
    steps.append(name)

class File:
    def __init__(self, inner):
        self.inner = inner
    def __enter__(self):
        return self
    def __exit__(self, *exc):
        step("close the temporary file")
        self.inner.close()
    def write(self, text):
        half = len(text) // 2
        step("write the first half of the data")
        self.inner.write(text[:half])
        self.inner.flush()
        step("write the second half of the data")
        self.inner.write(text[half:])
        return len(text)
    def flush(self):
        step("flush the data")
        self.inner.flush()
    def fileno(self):
        return self.inner.fileno()

class Os:
    def __getattr__(self, name):
        return getattr(os, name)
    def fdopen(self, *args, **kwargs):
        return File(os.fdopen(*args, **kwargs))
    def fsync(self, fd):
        step("fsync the data" if not steps or "directory" not in steps[-1] else
             "fsync the directory")
        os.fsync(fd)
    def replace(self, src, dst):
        step("rename over the old file")
        os.replace(src, dst)
    def open(self, path, flags, *args):
        step("open the directory")
        return os.open(path, flags, *args)
    def close(self, fd):
        step("close the directory")
        os.close(fd)

class Tempfile:
    def __getattr__(self, name):
        return getattr(tempfile, name)
    def mkstemp(self, *args, **kwargs):
        step("create the temporary file")
        return tempfile.mkstemp(*args, **kwargs)

device = Device(flash=FileFlash(path))
flash_module.os = Os()
flash_module.tempfile = Tempfile()
name = sys.argv[4]
device.feed(("18 %d %s\n" % (len(name), " ".join(str(ord(c)) for c in name))).encode())
with open(log, "w") as handle:
    json.dump({"steps": steps, "output": device.take_output().decode()}, handle)
"""


def _write_in_child(path: Path, crash_before: int, log: Path) -> int:
    done = subprocess.run(
        [sys.executable, "-c", _WRITER, str(path), str(crash_before), str(log), NEW],
        check=False, timeout=60, capture_output=True, text=True,
    )
    assert done.returncode in (0, -signal.SIGKILL), done.stderr
    return done.returncode


def _name_line(name: str) -> bytes:
    return f"18 {len(name)} {' '.join(str(ord(c)) for c in name)}\n".encode("ascii")


@pytest.fixture(scope="module")
def steps(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    """The steps of one flash write, as the writer sees them (a run with no crash)."""
    folder = tmp_path_factory.mktemp("steps")
    path = folder / "flash.json"
    FileFlash(path).write(name=OLD)
    log = folder / "log.json"
    assert _write_in_child(path, -1, log) == 0
    record = json.loads(log.read_text())
    assert record["output"] == "", "the write succeeded silently"
    assert FileFlash(path).read().name == NEW
    return list(record["steps"])


def test_the_write_syncs_the_data_before_the_rename_and_the_directory_after(
    steps: list[str],
) -> None:
    assert steps == [
        "create the temporary file",
        "write the first half of the data",
        "write the second half of the data",
        "flush the data",
        "fsync the data",
        "close the temporary file",
        "rename over the old file",
        "open the directory",
        "fsync the directory",
        "close the directory",
    ]


def test_a_crash_before_any_step_leaves_the_old_or_the_new_value(
    steps: list[str], tmp_path: Path
) -> None:
    renamed_at = steps.index("rename over the old file")
    outcomes: list[str] = []
    for crash_before in range(len(steps) + 1):
        folder = tmp_path / f"crash-{crash_before}"
        folder.mkdir()
        path = folder / "flash.json"
        FileFlash(path).write(name=OLD)
        code = _write_in_child(path, crash_before, folder / "log.json")
        assert code == (0 if crash_before == len(steps) else -signal.SIGKILL)
        renamed = crash_before > renamed_at
        contents = FileFlash(path).read()
        expected = (NEW, 2) if renamed else (OLD, 1)
        assert (contents.name, contents.writes) == expected, steps[crash_before - 1]
        device = Device(flash=FileFlash(path))
        assert device.name == expected[0]
        assert device.settings.flash_writes == expected[1]
        device.feed(_name_line("AFTER"))
        assert device.take_output() == b"", "the flash takes the next write"
        again = FileFlash(path).read()
        assert (again.name, again.writes) == ("AFTER", expected[1] + 1)
        leftovers = [p.name for p in folder.iterdir() if p.name.endswith(".tmp")]
        assert len(leftovers) <= 1, leftovers
        outcomes.append(f"{crash_before}:{contents.name}")
    assert outcomes.count(f"{len(steps)}:{NEW}") == 1
    assert sum(NEW in outcome for outcome in outcomes) == len(steps) - renamed_at

