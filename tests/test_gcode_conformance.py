"""The interpreter against LinuxCNC's own cases in ``shared/gcode-conformance``.

Every case folder of both sets is run: the 21 first cases and the 20 of
``offsets-tools-cycles/`` (work offsets, G53, G28/G30, G92, tool lengths, canned cycles,
pauses), whose ``tools.tbl`` is read as LinuxCNC's standalone interpreter reads it, in inches.
The set is skipped only outside CI when ``shared`` is absent; in CI (``CI`` set) its absence
fails. A folder with ``motion.jsonl`` must be accepted and its moves,
written by our JSON writer, must pass the case's own ``compare_motion.py`` (end points
and centres within 1e-6 mm; plane, direction and turns equal). A folder with
``expected_error`` must be rejected at the offending line with an error that means the
same. Where the curator provides ``test.basic.ngc`` (the ``[..]`` expression replaced by
its value) it is the program; the original ``test.ngc`` is then rejected as unsupported.
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import json
import os
import re
from pathlib import Path
from types import ModuleType

import pytest

from usbmotion.errors import UnsupportedGCodeError
from usbmotion.motion import cycles
from usbmotion.motion.gcode import (
    GCodeProgram,
    interpret_until_error,
    move_record,
    read_gcode_text,
)
from usbmotion.motion.offsets import WorkOffsets
from usbmotion.motion.tools import NO_TOOLS, ToolTable, load_tool_table

CONFORMANCE = Path(__file__).resolve().parents[1].parent / "shared" / "gcode-conformance"
SECOND_SET = CONFORMANCE / "offsets-tools-cycles"
FIRST_SET_SIZE, SECOND_SET_SIZE = 21, 20
MM_PER_INCH = 25.4  # the reference interpreter is an inch machine: its tool table is inches

pytestmark = pytest.mark.skipif(
    not CONFORMANCE.is_dir() and not os.environ.get("CI"),
    reason=f"the LinuxCNC conformance cases are not present at {CONFORMANCE}",
)


def _case_folders() -> list[Path]:
    if not CONFORMANCE.is_dir():
        return []
    folders = [path for path in CONFORMANCE.iterdir() if (path / "test.ngc").is_file()]
    if SECOND_SET.is_dir():
        folders += [path for path in SECOND_SET.iterdir() if (path / "test.ngc").is_file()]
    return sorted(folders)


CASES = _case_folders()
ACCEPTED = [case for case in CASES if (case / "motion.jsonl").is_file()]
REJECTED = [case for case in CASES if (case / "expected_error").is_file()]

# What LinuxCNC's message means, as words our message must contain.
MEANINGS = {
    "Radius to end of arc differs from radius to start": ("radius", "differs"),
    "R i j k words all missing for arc": ("R, I, J and K are all missing",),
    "Cannot do g1 with zero feed rate": ("G1", "feed rate 0"),
    "R less than z in cycle in xy plane": ("G81", "R0", "less than", "Z1", "XY plane"),
}


def _program(case: Path) -> Path:
    basic = case / "test.basic.ngc"
    return basic if basic.is_file() else case / "test.ngc"


def _compare_motion() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "compare_motion", CONFORMANCE / "compare_motion.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _reference_error(case: Path) -> dict[str, object] | None:
    for line in (case / "motion.jsonl").read_text().splitlines():
        if line.strip():
            record = json.loads(line)
            if record.get("type") == "interpreter_error":
                return dict(record)
    return None


def _offending_line(program: Path) -> int:
    """The line LinuxCNC stops at: in these upstream files, the last block of the file."""
    lines = read_gcode_text(program).splitlines()
    for number in range(len(lines), 0, -1):
        code = lines[number - 1].split(";", 1)[0].strip()
        if code and not (code.startswith("(") and code.endswith(")")):
            return number
    raise AssertionError(f"{program} holds no block")


def _tools(case: Path) -> ToolTable:
    table = case / "tools.tbl"
    return load_tool_table(table, mm_per_unit=MM_PER_INCH) if table.is_file() else NO_TOOLS


def _interpret(case: Path, *, offsets: WorkOffsets | None = None,
               text: str | None = None) -> tuple[GCodeProgram, Exception | None]:
    program_path = _program(case)
    return interpret_until_error(
        read_gcode_text(program_path) if text is None else text, file=str(program_path),
        tools=_tools(case), offsets=offsets,
    )


def _agrees(case: Path, program: GCodeProgram, tmp_path: Path) -> tuple[int, str]:
    """compare_motion.py's verdict on our moves: (exit status, its report)."""
    candidate = tmp_path / "candidate.jsonl"
    candidate.write_text("".join(json.dumps(move_record(m)) + "\n" for m in program.moves))
    report = io.StringIO()
    with contextlib.redirect_stdout(report):
        status = _compare_motion().main([str(case / "motion.jsonl"), str(candidate)])
    return status, report.getvalue()


def test_both_sets_are_present() -> None:
    assert CONFORMANCE.is_dir(), f"the conformance cases must be at {CONFORMANCE} (CI has them)"
    first = [case for case in CASES if case.parent == CONFORMANCE]
    second = [case for case in CASES if case.parent == SECOND_SET]
    assert (len(first), len(second)) == (FIRST_SET_SIZE, SECOND_SET_SIZE)


def test_every_case_folder_is_a_known_kind() -> None:
    assert CASES, f"no case folders in {CONFORMANCE}"
    unknown = [case.name for case in CASES if case not in ACCEPTED and case not in REJECTED]
    assert not unknown, f"case folders with neither motion.jsonl nor expected_error: {unknown}"


@pytest.mark.parametrize("case", ACCEPTED, ids=lambda case: case.name)
def test_accepted_case_matches_linuxcnc_motion(case: Path, tmp_path: Path) -> None:
    program_path = _program(case)
    program, error = _interpret(case)
    reference_error = _reference_error(case)
    if reference_error is None:
        assert error is None, f"LinuxCNC accepts {program_path}; we refuse it: {error}"
        assert program.ended_by in {"M2", "M30", "%"}
    else:
        assert error is not None, f"LinuxCNC stops at {reference_error}; we do not"
        if program_path.name == "test.ngc":
            assert getattr(error, "line", None) == reference_error["line"], (
                error, reference_error)
    status, report = _agrees(case, program, tmp_path)
    assert status == 0, report


@pytest.mark.parametrize("case", REJECTED, ids=lambda case: case.name)
def test_rejected_case_fails_at_the_same_line_for_the_same_reason(case: Path) -> None:
    program_path = _program(case)
    expected = (case / "expected_error").read_text().strip()
    _program_result, error = interpret_until_error(
        read_gcode_text(program_path), file=str(program_path), tools=_tools(case)
    )
    assert error is not None, f"LinuxCNC rejects {program_path} ({expected}); we accept it"
    assert error.file == str(program_path)
    assert error.line == _offending_line(program_path), error
    assert not isinstance(error, UnsupportedGCodeError), error
    meaning = next((words for key, words in MEANINGS.items() if expected.startswith(key)), None)
    assert meaning is not None, f"add the meaning of {expected!r} to MEANINGS"
    for words in meaning:
        assert words.lower() in error.message.lower(), (words, error.message)
    # The radii LinuxCNC reports (program units, 4 decimals) are ours too.
    for name in ("r1", "r2"):
        found = re.search(rf"\b{name}=([0-9.]+)", expected)
        if found:
            assert f"{name}={found.group(1)}" in error.message, error.message


@pytest.mark.parametrize(
    "case",
    [case for case in CASES if (case / "test.basic.ngc").is_file()],
    ids=lambda case: case.name,
)
def test_original_with_an_expression_is_rejected_as_unsupported(case: Path) -> None:
    original = case / "test.ngc"
    program, error = interpret_until_error(read_gcode_text(original), file=str(original))
    assert isinstance(error, UnsupportedGCodeError), error
    lines = read_gcode_text(original).splitlines()
    bracket = next(n for n, line in enumerate(lines, 1) if "[" in line and line[0] != ";")
    assert (error.line, error.column) == (bracket, lines[bracket - 1].index("i[") + 1)
    assert error.word == "I[" and "expressions" in error.message
    assert [m.line for m in program.moves] == [error.line - 1]  # the G0 before it


# --- the comparison catches mistakes ----------------------------------------------------------


def test_a_wrong_g54_offset_fails_the_comparison(tmp_path: Path) -> None:
    """A G54 offset 0.00001 mm off (as a stale parameter file would give) is caught."""
    case = SECOND_SET / "g92-family"
    program, error = _interpret(case)
    assert error is None and _agrees(case, program, tmp_path)[0] == 0
    stale = WorkOffsets().with_g5x(1, (1e-5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    program, error = _interpret(case, offsets=stale)
    status, report = _agrees(case, program, tmp_path)
    assert error is None and status == 1 and "problems" in report


def test_a_wrong_offset_in_the_program_fails_the_comparison(tmp_path: Path) -> None:
    case = SECOND_SET / "g10-l2-g54-g59"
    text = read_gcode_text(case / "test.ngc").replace("G10 L2 P2 X-30", "G10 L2 P2 X-30.00001")
    program, error = _interpret(case, text=text)
    assert error is None and _agrees(case, program, tmp_path)[0] == 1


def test_tool_lengths_read_in_mm_instead_of_inches_fail_the_comparison(tmp_path: Path) -> None:
    case = SECOND_SET / "g43-tool-table"
    program, error = interpret_until_error(
        read_gcode_text(case / "test.ngc"), tools=load_tool_table(case / "tools.tbl"))
    assert error is None and _agrees(case, program, tmp_path)[0] == 1


@pytest.mark.parametrize("case", ["g73-chipbreak", "g83-peck"])
def test_a_wrong_peck_retract_fails_the_comparison(
    case: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(cycles, "CHIP_BREAK_MM", 0.25)
    program, error = _interpret(SECOND_SET / case)
    assert error is None and _agrees(SECOND_SET / case, program, tmp_path)[0] == 1
