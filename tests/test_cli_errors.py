"""Every command's errors as a new user meets them: one line on standard error, naming the
command, the parameter and the file plainly; status 2 for a usage error. And the state the
commands keep: one machine loader, the built-in machine's parameter file in the state
folder, the built-in machine and ``usbmotion sim``'s flash held by one command at a time."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from usbmotion.cli.machines import default_machine, load_machine, state_dir
from usbmotion.cli.main import app, app_for

SRC = Path(__file__).resolve().parents[1] / "src" / "usbmotion"


def invoke(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(app, list(args), env={"COLUMNS": "120"})
    assert not isinstance(result.exception, Exception) or isinstance(
        result.exception, SystemExit), result.exception
    return result.exit_code, result.stdout, result.stderr


USAGE_ERRORS = [
    (["run"], "usbmotion run: missing argument PROGRAM (usbmotion run --help)"),
    (["run", "--bogus", "x.ngc"], "usbmotion run: no such option --bogus (usbmotion run"
     " --help)"),
    (["run", "--plo", "x.ngc"], "usbmotion run: no such option --plo; did you mean --no-plot"
     " or --plot or --report? (usbmotion run --help)"),
    (["bogus"], "usbmotion: no such command bogus; the commands are version, run, play,"
     " console, tune, sim, grbl, web, zero, status, home, jog, get, set, devices, name, gcode"
     " (usbmotion --help)"),
    (["sim", "--pty", "abc"], "usbmotion sim: --pty 'abc' is not a whole number (usbmotion"
     " sim --help)"),
    (["run", "x.ngc", "--from-line", "0"], "usbmotion run: --from-line 0 is out of range;"
     " allowed: 1 or more (usbmotion run --help)"),
    (["sim", "--pty=abc"], "usbmotion sim: --pty 'abc' is not a whole number (usbmotion"
     " sim --help)"),
    (["sim", "--pty"], "usbmotion sim: option --pty requires an argument (usbmotion sim"
     " --help)"),
    (["sim"], "usbmotion sim: give exactly one of --pty N or --tcp PORT (usbmotion sim"
     " --help)"),
    (["jog", "X", "1"], "usbmotion jog: missing option --feed (usbmotion jog --help)"),
    (["jog", "X", "1", "--feed", "fast"], "usbmotion jog: --feed 'fast' is not a number"
     " (usbmotion jog --help)"),
    (["tune"], "usbmotion tune: missing option --axis (usbmotion tune --help)"),
    (["set", "X", "kp"], "usbmotion set: missing argument VALUE (usbmotion set --help)"),
    (["gcode", "moves"], "usbmotion gcode moves: missing argument FILE (usbmotion gcode"
     " moves --help)"),
    (["gcode", "bogus"], "usbmotion gcode: no such command bogus; the commands are moves"
     " (usbmotion gcode --help)"),
    (["rn"], "usbmotion: no such command rn; did you mean run? the commands are version,"
     " run, play, console, tune, sim, grbl, web, zero, status, home, jog, get, set, devices, name,"
     " gcode (usbmotion --help)"),
    (["run", "--no-home=3", "x.ngc"], "usbmotion run: option --no-home does not take a"
     " value (usbmotion run --help)"),
    (["run", "--origin", "Q1", "x.ngc"], "usbmotion run: --origin: Q1 is not an origin;"
     " allowed: axis words in machine mm, such as 'X100 Y100 Z-40' (usbmotion run --help)"),
]


@pytest.mark.parametrize(("args", "line"), USAGE_ERRORS, ids=lambda a: " ".join(a)
                         if isinstance(a, list) else "")
def test_a_usage_error_is_one_line_with_status_2(args: list[str], line: str,
                                                  tmp_path: Path) -> None:
    if args[-1] == "x.ngc" and args != ["run", "--bogus", "x.ngc"]:
        (tmp_path / "x.ngc").write_text("M2\n")
        args = [*args[:-1], str(tmp_path / "x.ngc")]
    code, out, err = invoke(*args)
    assert (code, out, err) == (2, "", line + "\n")


COMMANDS = ["version", "run", "play", "console", "tune", "sim", "grbl", "web", "zero",
            "status", "home", "jog", "get", "set", "devices", "name", "gcode"]


@pytest.mark.parametrize("args", [*([name, "--help"] for name in COMMANDS),
                                  ["gcode", "moves", "--help"], ["gcode", "bogus"],
                                  *(args for args, _ in USAGE_ERRORS)],
                         ids=" ".join)
def test_a_command_run_alone_says_what_the_whole_application_says(args: list[str]) -> None:
    """``usbmotion`` builds only the command it is asked for (:func:`app_for`): its help
    and its errors are those of the whole application."""
    alone = app_for(args)
    assert (alone is app) == (args[0] not in COMMANDS)
    results = [CliRunner().invoke(whole, args, env={"COLUMNS": "120"})
               for whole in (app, alone)]
    assert [(r.exit_code, r.stdout, r.stderr) for r in results[1:]] == [
        (results[0].exit_code, results[0].stdout, results[0].stderr)]
    assert app_for(["--help"]) is app and app_for([]) is app


@pytest.mark.parametrize("command", [
    "version", "run", "console", "tune", "sim", "grbl", "zero", "status", "home", "jog",
    "get", "set", "devices", "name", "gcode moves"])
def test_every_command_says_an_unknown_option_in_one_line(command: str) -> None:
    code, out, err = invoke(*command.split(), "--no-such-option")
    assert (code, out) == (2, "")
    if command in ("jog", "set"):  # they take words like -5 as arguments, not options
        assert err.count("\n") == 1 and err.startswith(f"usbmotion {command}: missing")
        assert err.endswith(f"(usbmotion {command} --help)\n")
        return
    assert err == (f"usbmotion {command}: no such option --no-such-option (usbmotion"
                   f" {command} --help)\n")


@pytest.mark.parametrize(("args", "what"), [
    (["run"], "run"), (["gcode", "moves"], "gcode moves")])
def test_a_program_that_cannot_be_read_is_named_plainly(args: list[str], what: str,
                                                        tmp_path: Path) -> None:
    missing = tmp_path / "nofile.ngc"
    code, out, err = invoke(*args, str(missing))
    assert (code, out) == (2, "")
    assert err == f"usbmotion {what}: cannot read {missing}: no such file or directory\n"
    code, _, err = invoke(*args, str(tmp_path))
    assert (code, err) == (2, f"usbmotion {what}: cannot read {tmp_path}: a folder, not a"
                              " file\n")


def test_a_missing_machine_file_is_named_plainly(tmp_path: Path) -> None:
    missing = tmp_path / "nofile.toml"
    code, _, err = invoke("status", "-m", str(missing))
    assert (code, err) == (2, f"usbmotion status: cannot read the machine file {missing}:"
                              " no such file or directory\n")
    assert "Errno" not in err and "'" not in err


def test_the_real_entry_point_says_it_in_one_line_too() -> None:
    done = subprocess.run([sys.executable, "-m", "usbmotion", "run"], capture_output=True,
                          text=True, timeout=60, check=False)
    assert (done.returncode, done.stdout) == (2, "")
    assert done.stderr == "usbmotion run: missing argument PROGRAM (usbmotion run --help)\n"


def test_help_keeps_its_layout_and_no_arguments_show_it() -> None:
    code, out, _ = invoke("run", "--help")
    assert code == 0 and "Usage: usbmotion run [OPTIONS] PROGRAM" in out
    code, out, err = invoke()
    assert code == 2 and "Usage: usbmotion [OPTIONS] COMMAND" in out and err == ""


# --- one machine loader, the built-in machine's state in the state folder -----------------


def test_every_command_loads_its_machine_through_the_one_loader() -> None:
    """No module of the command but ``cli/machines.py`` reads a machine file itself or
    says where the built-in machine is."""
    found = []
    for path in sorted((SRC / "cli").glob("*.py")):
        if path.name == "machines.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.FunctionDef) and node.name in (
                    "load_machine", "default_machine", "state_dir"):
                found.append(f"{path.name}:{node.lineno} defines {node.name}")
            if isinstance(node, ast.Call) and getattr(node.func, "id", "") in (
                    "load_machine_file", "load_config"):
                found.append(f"{path.name}:{node.lineno} calls {node.func.id}")  # type: ignore[attr-defined]
    assert found == []


def test_the_built_in_machine_keeps_its_parameter_file_in_the_state_folder(
        own_state: Path) -> None:
    config = load_machine(None, "test")
    assert config.parameter_path == state_dir() / "machine.var"
    assert state_dir() == own_state / "usbmotion"
    code, out, err = invoke("zero", "X")
    assert code == 0, err
    assert out.endswith(f"saved in {state_dir() / 'machine.var'}\n")
    assert "5221\t" in (state_dir() / "machine.var").read_text()
    assert not default_machine().with_suffix(".var").exists()


def test_a_test_and_the_processes_it_starts_have_a_state_folder_of_their_own(
        own_state: Path) -> None:
    assert Path(os.environ["USBMOTION_STATE_DIR"]).is_relative_to(own_state)
    assert Path(os.environ["XDG_STATE_HOME"]).is_relative_to(own_state)
    assert not state_dir().is_relative_to(Path.home())
    child = subprocess.run(
        [sys.executable, "-c", "from usbmotion.cli.machines import state_dir;"
         " print(state_dir())"], capture_output=True, text=True, check=True)
    assert child.stdout.strip() == str(state_dir())


# --- one command at a time on the built-in machine and on a flash folder ------------------


@pytest.fixture
def console_on_the_built_in_machine() -> Iterator[subprocess.Popen[str]]:
    """``usbmotion console`` on the built-in machine, waiting for input (holding it)."""
    process = subprocess.Popen([sys.executable, "-m", "usbmotion", "console"],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        assert process.stdout is not None
        assert process.stdout.readline().startswith("usbmotion console on simulated XYZ")
        yield process
    finally:
        if process.stdin is not None and not process.stdin.closed:
            process.stdin.close()
        process.wait(timeout=60)
        for stream in (process.stdout, process.stderr):
            if stream is not None:
                stream.close()


def test_a_second_command_on_the_built_in_machine_is_refused_naming_the_first(
        console_on_the_built_in_machine: subprocess.Popen[str], tmp_path: Path) -> None:
    console = console_on_the_built_in_machine
    for command in (["zero", "X"], ["status"], ["get", "X", "kp"]):
        code, out, err = invoke(*command)
        assert (code, out) == (1, ""), err
        assert err == (f"usbmotion {command[0]}: the built-in machine is in use by usbmotion"
                       f" console (process {console.pid}); wait for it to end, or give"
                       " --machine FILE for another machine\n")
    machine = tmp_path / "machine.toml"
    machine.write_text(default_machine().read_text())
    assert invoke("status", "-m", str(machine))[0] == 0, "a machine file is not held"
    assert console.stdin is not None
    console.stdin.close()
    assert console.wait(timeout=60) == 0
    code, _, err = invoke("zero", "X")
    assert code == 0, err
    assert (state_dir() / "machine.var").exists()


def test_one_command_holds_the_built_in_machine_once_and_lets_go_at_its_end() -> None:
    for _ in range(2):
        code, _, err = invoke("status")
        assert code == 0, err
    lock = state_dir() / "machine.lock"
    assert lock.read_text().split() == [str(os.getpid()), "status"]


def test_a_second_sim_on_the_same_flash_folder_is_refused() -> None:
    first = subprocess.Popen([sys.executable, "-m", "usbmotion", "sim", "--pty", "1"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert first.stdout is not None
        assert first.stdout.readline().startswith("GENERIC USB MOTION DEVICE /dev/pts/")
        started = time.monotonic()
        second = subprocess.run([sys.executable, "-m", "usbmotion", "sim", "--pty", "1"],
                                capture_output=True, text=True, timeout=60, check=False)
        assert time.monotonic() - started < 30
        folder = state_dir() / "flash"
        assert (second.returncode, second.stdout) == (1, "")
        assert second.stderr == (f"usbmotion sim: the flash folder {folder} is in use by"
                                 f" usbmotion sim (process {first.pid}); give this server"
                                 " another --flash-dir\n")
    finally:
        first.terminate()
        first.communicate(timeout=30)
