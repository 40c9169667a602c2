"""``usbmotion run`` writes its plot, by default, into the working directory: a program may
sit where nothing should be written (a demo inside the package)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from commands import invoke


def test_the_default_plot_goes_to_the_working_directory(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    program = tmp_path / "programs" / "square.ngc"
    program.parent.mkdir()
    program.write_text("G21 G90\nG1 X5 F600\nG1 Y5\nM2\n", encoding="utf-8")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    code, out, err = invoke("run", str(program), "-q")
    assert code == 0, err
    assert (work / "square.png").stat().st_size > 0
    assert not (program.parent / "square.png").exists()
    assert "plot           square.png" in out
    assert os.listdir(program.parent) == ["square.ngc"]
