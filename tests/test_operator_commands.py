"""The operator's commands: status, home, jog, get and set by name, devices, --version;
their help; one line, never a traceback, for a bad file or port.

In virtual time on the built-in simulated machine (each command finds it fresh), and in
real time on devices served by ``usbmotion sim --pty 3`` in another process."""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import serial
import typer.main
from tests.reliability.bench import bench_machine, served
from typer.testing import CliRunner

from usbmotion import __version__
from usbmotion.cli.main import app
from usbmotion.cli.run import default_machine
from usbmotion.session import MachineState
from usbmotion.session.live import AxisNow
from usbmotion.session.live import LiveSnapshot as Progress
from usbmotion.session.operator import parse_steps
from usbmotion.sim.machine import connect_session, load_machine_file


def _every_command() -> Iterator[tuple[list[str], Any]]:
    """Every command and group under the root, with the words that call it."""
    waiting: list[tuple[list[str], Any]] = [([], typer.main.get_command(app))]
    while waiting:
        words, command = waiting.pop()
        yield words, command
        for name, sub in getattr(command, "commands", {}).items():
            waiting.append(([*words, name], sub))


COMMANDS = sorted(words for words, _ in _every_command())
"""Every command and group, by the words that call it (the root's are none)."""
MACHINE_COMMANDS = (
    ["status"], ["home"], ["jog", "X", "1", "--feed", "60"], ["get"], ["get", "X", "kp"],
    ["set", "X", "kp", "0.2"],
)
"""Every command that acts on a machine file's machine, with arguments that would work."""


def invoke(*args: str) -> tuple[int, str, str]:
    result = CliRunner().invoke(app, list(args), env={"COLUMNS": "120"})
    assert not isinstance(result.exception, Exception) or isinstance(
        result.exception, SystemExit), result.exception
    return result.exit_code, result.stdout, result.stderr


# --- help and version -----------------------------------------------------------------------


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: " ".join(c) or "usbmotion")
def test_help_reads_cleanly(command: list[str]) -> None:
    code, out, _ = invoke(*command, "--help")
    assert code == 0
    for wrong in ("``", "<bool>", "default: -1", "<int>", "<float>", "<list[str]>",
                  "<str>", "<path>", "<text>", "<integer>", "<file>", "<directory>"):
        assert wrong not in out, f"{wrong!r} in the help of {command}:\n{out}"
    assert not re.search(r"\{[A-Z_]+\}", out), f"a braced argument in {command}:\n{out}"


def test_help_shows_square_brackets_as_written() -> None:
    """The help is rendered with rich's markup, which took ``[joints]`` for a style and
    dropped it: every bracketed word of a command's help and of its parameters' help is
    in what ``--help`` prints."""
    checked = 0
    for words, command in _every_command():
        texts = [command.help or "", *(getattr(p, "help", None) or "" for p in command.params)]
        out = re.sub(r"[\s│]", "", invoke(*words, "--help")[1])
        for text in texts:
            written = re.sub(r"\\\[", "[", text)
            for bracketed in re.findall(r"\[[^\]]*\]", written):
                checked += 1
                assert re.sub(r"\s", "", bracketed) in out, (
                    f"{bracketed!r} missing from the help of {words}:\n{out}")
    assert checked >= 3


def test_help_names_arguments_and_values_as_they_are_typed() -> None:
    """Many values read ``[AXES]...``, a required argument its name alone, a whole number
    ``N`` with its range."""
    assert "usbmotion home [OPTIONS] [AXES]..." in invoke("home", "--help")[1]
    assert "usbmotion jog [OPTIONS] STEPS..." in invoke("jog", "--help")[1]
    run_help = invoke("run", "--help")[1]
    assert "usbmotion run [OPTIONS] PROGRAM " in run_help
    assert "--from-line             N [x>=1]" in run_help


def test_the_machine_commands_say_the_default_machine_is_fresh_each_time() -> None:
    for command in ("status", "home", "jog", "get", "set"):
        out = invoke(command, "--help")[1]
        assert "built-in simulated machine" in " ".join(out.split()), command


def test_version_on_the_root_command_and_as_a_command() -> None:
    assert invoke("--version") == (0, f"{__version__}\n", "")
    assert invoke("version")[1] == f"{__version__}\n"


# --- status, get, set on the built-in machine -------------------------------------------------


def test_status_lists_every_axis_state_position_and_fault() -> None:
    code, out, _ = invoke("status")
    assert code == 0
    lines = out.splitlines()
    assert lines[0] == "simulated XYZ: Idle, not homed"
    assert lines[1].split()[:4] == ["axis", "state", "homed", "position"]
    assert [line.split()[:3] for line in lines[2:]] == [[a, "Idle", "no"] for a in "XYZ"]
    assert all(line.split()[-1] == "none" for line in lines[2:])


def test_get_lists_every_parameter_with_unit_and_storage() -> None:
    code, out, _ = invoke("get", "X")
    assert code == 0
    assert "axis X: X (X AXIS) on sim://X" in out
    assert re.search(r"^  kp +[0-9.]+ V/count +RAM", out, re.M)
    assert re.search(r"^  watchdog_ms +\d+ ms +RAM", out, re.M)
    assert re.search(r"^  name +'X AXIS' +flash", out, re.M), "the name as text"
    assert re.search(r"^  default_mode +position +flash", out, re.M), "modes as words"
    assert "lost at power-off" in out
    assert invoke("get", "Y", "name") == (0, "Y name 'Y AXIS'\n", "")
    everyone = invoke("get", "kp")[1].splitlines()
    assert [line.split()[:2] for line in everyone] == [[a, "kp"] for a in "XYZ"]


def test_set_answers_with_the_value_the_device_holds_and_where_it_is_kept() -> None:
    code, out, _ = invoke("set", "X", "kp", "0.25")
    assert code == 0
    assert out.startswith("X kp 0.25 V/count (RAM: lost at power-off")
    code, out, _ = invoke("set", "Z", "name", "SPINDLE Z")
    assert (code, out) == (0, "Z name 'SPINDLE Z' (kept in flash)\n")


@pytest.mark.parametrize(("args", "words"), [
    (["X", "watchdog_ms", "700000"], "watchdog_ms 700000 is out of range; allowed 0..600000 ms"),
    (["X", "kp", "0.1234"], "more than 3 significant digits; allowed 0, or 1e-12..999e6"),
    (["X", "kp", "-1"], "is negative"),
    (["X", "kp", "fast"], "kp 'fast' is not a finite number"),
    (["X", "default_mode", "fast"], "allowed position, velocity, curve"),
    (["X", "name", "X" * 26], "allowed up to 25 printable ASCII characters"),
    (["X", "servo_interval_us", "150"], "allowed 100..1000000 us in steps of 100"),
])
def test_a_refused_value_is_one_line_naming_parameter_value_and_range(
        args: list[str], words: str) -> None:
    code, out, err = invoke("set", *args)
    assert code == 2 and out == ""
    assert err.count("\n") == 1, err
    assert err.startswith(f"usbmotion set: axis X {args[1]} {args[2]!r} refused: "), err
    assert words in err


def test_an_unknown_axis_or_parameter_is_named_with_those_there_are() -> None:
    code, _, err = invoke("get", "Q", "kp")
    assert code == 2 and "no axis 'Q'" in err and "has X, Y, Z" in err
    code, _, err = invoke("set", "X", "gain", "1")
    assert code == 2 and "no parameter 'gain'; the parameters are kp, ki, kd" in err
    code, _, err = invoke("set", "X", "watchdog", "2000")
    assert code == 2
    assert err.startswith("usbmotion set: no parameter 'watchdog'; did you mean"
                          " 'watchdog_ms'? the parameters are kp, ki, kd"), err
    code, _, err = invoke("get", "X", "Following_Error")
    assert code == 2 and "did you mean 'following_error_limit_counts'?" in err


def _with_watchdog(folder: Path, watchdog_ms: int) -> Path:
    text, count = re.subn(r"(?m)^watchdog_ms = \d+", f"watchdog_ms = {watchdog_ms}",
                          default_machine().read_text())
    assert count == 1
    path = folder / "machine.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(("args", "words"), [
    (["X", "watchdog_ms", "100"], "watchdog_ms: 100 ms is shorter than a full motion queue"
     " lasts (1000 values x 1 ms = 1000 ms) plus 250 ms"),
    (["X", "motion_scalar", "2"], "watchdog_ms: 2000 ms is shorter than a full motion queue"
     " lasts (1000 values x 2 ms = 2000 ms) plus 250 ms"),
    (["Y", "servo_interval_us", "2000"], "watchdog_ms: 2000 ms is shorter than a full motion"
     " queue lasts (1000 values x 2 ms = 2000 ms)"),
])
def test_set_refuses_what_the_machine_file_would_refuse(
        args: list[str], words: str, tmp_path: Path) -> None:
    machine = _with_watchdog(tmp_path, 2000)
    code, out, err = invoke("set", *args, "-m", str(machine))
    assert (code, out) == (2, "")
    assert err.count("\n") == 1, err
    assert err.startswith(f"usbmotion set: axis {args[0]} {args[1]} {args[2]!r} refused as"
                          f" the machine file would refuse it: {machine}:"), err
    assert words in err
    code, out, err = invoke("get", args[0], args[1], "-m", str(machine))
    assert code == 0 and args[2] not in out.split(), "nothing was sent"


def test_set_takes_what_the_machine_file_allows(tmp_path: Path) -> None:
    machine = _with_watchdog(tmp_path, 2000)
    for args in (["X", "watchdog_ms", "1250"], ["X", "watchdog_ms", "0"],
                 ["Y", "following_error_limit_counts", "480"], ["Z", "kd", "0.003"]):
        code, out, err = invoke("set", *args, "-m", str(machine))
        assert code == 0, err
        assert out.startswith(f"{args[0]} {args[1]} {args[2]}"), out


# --- home and jog on the built-in machine (virtual time) ------------------------------------


def test_home_homes_every_axis_or_those_named() -> None:
    code, out, _ = invoke("home")
    assert code == 0
    assert re.fullmatch(r"homed X, Y, Z in [0-9.]+ s: X 0\.000  Y 0\.000  Z 0\.000 mm"
                        r" \(machine coordinates\)\n", out), out
    code, out, _ = invoke("home", "Z", "x")
    assert code == 0 and out.startswith("homed Z, X in ")
    code, _, err = invoke("home", "XQ")
    assert code == 2 and "no axis 'Q'" in err


def test_jog_moves_by_the_distance_at_the_feed_from_home() -> None:
    code, out, err = invoke("jog", "X", "10", "Y-0", "--feed", "600")
    assert code == 0, err
    assert "homing first" in err
    match = re.fullmatch(r"jogged X \+10\.000, Y \+0\.000 mm at 600 mm/min in ([0-9.]+) s:"
                         r" X 10\.000  Y 0\.000  Z 0\.000 mm \(machine coordinates\)\n", out)
    assert match, out
    assert 1.0 <= float(match.group(1)) <= 1.3, "10 mm at 10 mm/s, with its ramps"


def test_a_continuous_jog_runs_to_the_first_soft_limit_on_its_way() -> None:
    code, out, err = invoke("jog", "X", "1", "Y", "1", "--continuous", "--feed", "600", "-q")
    assert code == 0, err
    assert out == "jogged to the soft limit: X 200.000  Y 200.000  Z 0.000 mm (machine" \
        " coordinates)\n", out
    code, _, err = invoke("jog", "X", "1", "--continuous", "--no-home", "--feed", "600")
    assert code == 2 and "needs a homed machine" in err


def test_a_jog_beyond_the_travel_is_refused_naming_the_axis_and_limit() -> None:
    code, out, err = invoke("jog", "Z", "5", "--feed", "300")  # up from the top of Z
    assert (code, out) == (2, "")
    assert err.endswith("usbmotion jog: axis Z to 5.000 mm (+5.000 from 0.000) is beyond its"
                        " upper limit 0.000 mm (travel -100..0 mm); nothing moved\n"), err


@pytest.mark.parametrize(("args", "words"), [
    (["X", "--feed", "60", "--fed", "3"], "'X --fed 3' is no AXIS DISTANCE pair"),
    (["X", "1", "X", "2", "--feed", "60"], "axis X is given twice"),
    (["A", "1", "--feed", "60"], "cannot jog A"),
    (["X", "1", "--feed", "0"], "--feed 0.0 must be a speed > 0 mm/min"),
])
def test_bad_jogs_are_one_line(args: list[str], words: str) -> None:
    code, _, err = invoke("jog", *args)
    assert code == 2 and words in err and err.count("\n") == 1, err


def test_parse_steps() -> None:
    assert parse_steps(["X", "10", "y-2.5", "Z=+1e1"]) == {"X": 10.0, "Y": -2.5, "Z": 10.0}
    with pytest.raises(ValueError, match="at least one"):
        parse_steps([])


# --- progress -------------------------------------------------------------------------------


def test_the_session_reports_state_line_and_position_while_homing_and_running() -> None:
    seen: list[Progress] = []
    with connect_session(load_machine_file(default_machine())) as session:
        session.home(on_progress=seen.append)
        homing = list(seen)
        seen.clear()
        prepared = session.prepare("p.ngc", text="G1 X10 F600\nG1 Y5\nM2\n")
        session.run(prepared, on_progress=seen.append)
    assert homing and all(p.state is MachineState.HOMING and p.line == 0 for p in homing)
    assert set(homing[-1].machine_mm()) == {"X", "Y", "Z"}
    assert all(p.state is MachineState.RUN and not p.at_rest for p in seen[:-1])
    assert {p.line for p in seen} == {1, 2} and len(seen) > 10, "the line executing"
    last = seen[-1]
    assert last.state is MachineState.IDLE and last.at_rest, "the run's end, published"
    assert last.machine_mm()["X"] == pytest.approx(10.0, abs=0.01)
    assert last.describe().startswith("Idle  line 2 of 3  X 10.000  Y ")


def test_progress_describes_itself_in_one_line() -> None:
    axes = {"X": AxisNow(measured_mm=1.5), "Z": AxisNow(measured_mm=-2.0)}
    assert Progress(MachineState.HOMING, axes=axes).describe() == "Homing  X 1.500  Z -2.000 mm"
    assert Progress(MachineState.RUN, axes=axes, line=7, lines_total=40).describe() == (
        "Run  line 7 of 40  X 1.500  Z -2.000 mm")


# --- a bad file or port: one line, never a traceback ----------------------------------------


def _machine_with_urls(folder: Path, urls: dict[str, str]) -> Path:
    text = default_machine().read_text()
    for letter, url in urls.items():
        text = text.replace(f'url = "sim://{letter}"', f'url = "{url}"')
    path = folder / "machine.toml"
    path.write_text(text)
    return path


@pytest.fixture
def bad_files(tmp_path: Path) -> dict[str, Path]:
    (tmp_path / "folder.toml").mkdir()
    (tmp_path / "binary.toml").write_bytes(b"\xff\xfe\x00garbage")
    (tmp_path / "typo.toml").write_text(default_machine().read_text().replace(
        "motion_scalar", "motion_scaler"))
    return {"missing": tmp_path / "missing.toml", "folder": tmp_path / "folder.toml",
            "binary": tmp_path / "binary.toml", "typo": tmp_path / "typo.toml"}


OTHER_COMMANDS = (["run", "--no-plot", "-q"], ["console"], ["tune", "-a", "X"])
"""The commands before these, acting on a machine file's machine too."""


def _with_program(command: list[str], folder: Path) -> list[str]:
    if command[0] != "run":
        return command
    program = folder / "line.ngc"
    program.write_text("G1 X1 F60\nM2\n")
    return [*command, str(program)]


@pytest.mark.parametrize("command", [*MACHINE_COMMANDS, *OTHER_COMMANDS, ["devices"]],
                         ids=" ".join)
def test_a_missing_or_unreadable_machine_file_is_one_line_naming_it(
        command: list[str], bad_files: dict[str, Path], tmp_path: Path) -> None:
    command = _with_program(command, tmp_path)
    for kind, path in bad_files.items():
        code, _, err = invoke(*command, "--machine", str(path))
        assert code == 2, (kind, err)
        assert err.count("\n") == 1 and str(path) in err, (kind, err)
        assert err.startswith(f"usbmotion {command[0]}: "), err


@pytest.fixture
def refused_port() -> Iterator[int]:
    """A TCP port on which nothing listens."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    yield port


@pytest.mark.parametrize("command", [*MACHINE_COMMANDS, *OTHER_COMMANDS], ids=" ".join)
def test_a_missing_busy_or_refusing_port_is_one_line_naming_it(
        command: list[str], tmp_path: Path, refused_port: int) -> None:
    command = _with_program(command, tmp_path)
    master, slave = os.openpty()
    busy_path = os.ttyname(slave)
    try:
        with serial.Serial(busy_path, exclusive=True):
            for url, words in ((str(tmp_path / "ttyACM9"), "no such port"),
                               (busy_path, "busy: another program has it open"),
                               (f"socket://127.0.0.1:{refused_port}",
                                "connection refused: nothing serves that address")):
                machine = _machine_with_urls(tmp_path, {"X": url})
                code, _, err = invoke(*command, "--machine", str(machine))
                assert code == 1, (url, err)
                assert err == f"usbmotion {command[0]}: cannot open {url!r}: {words}\n", err
    finally:
        os.close(master)
        os.close(slave)


def test_devices_reports_a_busy_or_missing_port_and_exits_1_when_none_answers(
        tmp_path: Path, refused_port: int, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("USBMOTION_PTY_DIR", str(tmp_path / "ptys"))
    monkeypatch.setattr("usbmotion.host.discovery.serial_ports", lambda: [])
    missing = str(tmp_path / "ttyACM9")
    refused = f"socket://127.0.0.1:{refused_port}"
    code, out, _ = invoke("devices", "-p", missing, "-p", refused)
    assert code == 1
    width = max(len(missing), len(refused))
    assert out.splitlines() == [
        f"{missing:<{width}}  no such port",
        f"{refused:<{width}}  connection refused: nothing serves that address",
        "0 device(s) on 2 port(s) probed"]


def test_sim_on_a_busy_tcp_port_is_one_line() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = subprocess.run([sys.executable, "-m", "usbmotion", "sim", "--tcp", str(port)],
                                capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 1
    assert result.stderr == (f"usbmotion sim: cannot listen on 127.0.0.1:{port}: Address"
                             " already in use\n")


# --- on devices served in real time ---------------------------------------------------------


def _cli(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "usbmotion", *args], capture_output=True,
                          text=True, timeout=120, env=env, check=False)


@pytest.mark.realtime
def test_the_commands_on_devices_served_on_pseudo_terminals(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("USBMOTION_PTY_DIR", str(tmp_path / "ptys"))
    env = dict(os.environ)
    with served(tmp_path / "flash") as paths:
        machine = str(bench_machine(tmp_path, paths, watchdog_ms=0))
        found = _cli("devices", env=env)
        assert found.returncode == 0, found.stderr
        for name, path in paths.items():
            assert re.search(rf"^{re.escape(path)} +'{name}'$", found.stdout, re.M), found.stdout
        before = _cli("status", "-m", machine, env=env)
        assert before.stdout.splitlines()[0] == "simulated XYZ: Idle, not homed"
        homed = _cli("home", "-m", machine, env=env)
        assert homed.returncode == 0 and homed.stdout.startswith("homed X, Y, Z in "), homed
        jogged = _cli("jog", "X", "5", "Y", "2", "--feed", "600", "-m", machine, env=env)
        assert jogged.returncode == 0, jogged.stderr
        assert "homing first" not in jogged.stderr, "the devices stayed homed"
        status = _cli("status", "-m", machine, env=env).stdout.splitlines()
        assert status[0] == "simulated XYZ: Idle, homed"
        rows = {line.split()[0]: line.split() for line in status[2:]}
        assert float(rows["X"][3]) == pytest.approx(5.0, abs=0.05)
        assert float(rows["Y"][3]) == pytest.approx(2.0, abs=0.05)
        refused = _cli("jog", "X", "-50", "--feed", "600", "-m", machine, env=env)
        assert refused.returncode == 2 and "beyond its lower limit 0.000 mm" in refused.stderr
        changed = _cli("set", "Y", "watchdog_ms", "1500", "-m", machine, env=env)
        assert changed.returncode == 0, changed.stderr
        assert _cli("get", "Y", "watchdog_ms", "-m", machine, env=env).stdout == (
            "Y watchdog_ms 1500 ms\n"), "the device keeps it between commands"
        with serial.Serial(paths["Z AXIS"], exclusive=True):
            busy = _cli("status", "-m", machine, env=env)
        assert busy.returncode == 1
        assert busy.stderr == (f"usbmotion status: cannot open {paths['Z AXIS']!r}: busy:"
                               " another program has it open\n")


def test_a_jog_is_in_machine_coordinates_whatever_the_work_offsets(tmp_path: Path) -> None:
    machine = tmp_path / "machine.toml"
    machine.write_text(default_machine().read_text())
    with connect_session(load_machine_file(machine)) as session:
        session.set_work_origin({"X": 50.0, "Y": 20.0})
    code, out, err = invoke("jog", "X", "5", "--feed", "600", "-m", str(machine))
    assert code == 0, err
    assert out.endswith(": X 5.000  Y 0.000  Z 0.000 mm (machine coordinates)\n"), out
