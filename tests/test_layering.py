"""The layering holds: the host knows only ports, and calls are named, not numbered.

These scan the source tree, so a change that breaks the layering fails here at once.
"""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "usbmotion"

HOST_SIDE = ("host", "motion", "automation", "session", "grbl", "web", "autotune", "robot",
             "tuning")
"""Packages (and modules) that drive devices through ports and must not know how a device
is made."""

FORBIDDEN = ("usbmotion.sim", "usbmotion.device")

NUMBERED = ("protocol", "device")
"""Where call numbers are defined (the table) and implemented (the Python device)."""

CALL_TAKERS = frozenset({
    "command", "query", "send", "encode_call", "check_call", "set_sim_value", "sim_value",
    "_check_range", "_await_answer", "set_debug_flag", "debug_flag", "spec",
})
"""Functions whose first argument is a call number."""

CALL_KEYWORDS = frozenset({"call", "number"})

LINE_TEXT = re.compile(r"^\d{1,2}(?: -?\d+)*(?: |\\n|\n|$)")
"""A protocol line written out as text (``"20 -1"``, ``f"18 {n} ..."``)."""


def _python_files(*packages: str) -> Iterator[Path]:
    for package in packages:
        module = SRC / f"{package}.py"
        if module.is_file():
            yield module
        else:
            yield from sorted((SRC / package).rglob("*.py"))


def _imports(tree: ast.AST) -> Iterator[tuple[int, str]]:
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom) and node.module is not None:
            if node.level:
                continue
            yield node.lineno, node.module
            for alias in node.names:
                yield node.lineno, f"{node.module}.{alias.name}"


def layering_violations(paths: list[Path]) -> list[str]:
    """``file:line imports module`` for every import of the simulator or the device."""
    found: dict[tuple[str, int], str] = {}
    for path in paths:
        tree = ast.parse(path.read_text(), filename=str(path))
        where = _where(path)
        for line, module in _imports(tree):
            if module.startswith(FORBIDDEN):
                found.setdefault((where, line), f"{where}:{line} imports {module}")
    return sorted(found.values())


def _where(path: Path) -> str:
    return str(path.relative_to(SRC.parent)) if path.is_relative_to(SRC) else path.name


def _int_literal(node: ast.AST | None) -> bool:
    return (isinstance(node, ast.Constant) and type(node.value) is int) or (
        isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub)
        and _int_literal(node.operand))


def _callee(node: ast.Call) -> str:
    if isinstance(node.func, ast.Attribute):
        return node.func.attr
    if isinstance(node.func, ast.Name):
        return node.func.id
    return ""


def _text_start(node: ast.AST) -> str | None:
    if isinstance(node, ast.Constant) and isinstance(node.value, str | bytes):
        value = node.value
        return value.decode("latin-1") if isinstance(value, bytes) else value
    if isinstance(node, ast.JoinedStr) and node.values:
        first = node.values[0]
        if isinstance(first, ast.Constant) and isinstance(first.value, str):
            return first.value
    return None


def literal_call_numbers(paths: list[Path]) -> list[str]:
    """``file:line what`` for every call number written as a literal."""
    found: list[str] = []
    for path in paths:
        tree = ast.parse(path.read_text(), filename=str(path))
        where = _where(path)
        for node in ast.walk(tree):
            if isinstance(node, ast.Call):
                name = _callee(node)
                if name in CALL_TAKERS and node.args and _int_literal(node.args[0]):
                    found.append(f"{where}:{node.lineno} {name}({ast.unparse(node.args[0])}, ...)")
                for keyword in node.keywords:
                    if keyword.arg in CALL_KEYWORDS and _int_literal(keyword.value):
                        value = ast.unparse(keyword.value)
                        found.append(f"{where}:{node.lineno} {keyword.arg}={value}")
            elif isinstance(node, ast.Subscript):
                if (isinstance(node.value, ast.Name) and node.value.id == "BY_NUMBER"
                        and _int_literal(node.slice)):
                    found.append(f"{where}:{node.lineno} BY_NUMBER[{ast.unparse(node.slice)}]")
            elif isinstance(node, ast.Compare):
                left = node.left
                if (isinstance(left, ast.Attribute) and left.attr == "call"
                        and any(_int_literal(c) for c in node.comparators)):
                    found.append(f"{where}:{node.lineno} {ast.unparse(node)}")
            else:
                text = _text_start(node)
                if text is not None and LINE_TEXT.match(text) and (
                        isinstance(node, ast.JoinedStr) or text.endswith("\n")):
                    found.append(f"{where}:{node.lineno} line text {text!r}")
    return sorted(set(found))


def _all_but(*packages: str) -> list[Path]:
    return [path for path in sorted(SRC.rglob("*.py"))
            if path.relative_to(SRC).parts[0] not in packages]


def test_the_host_side_imports_neither_the_simulator_nor_the_device() -> None:
    assert layering_violations(list(_python_files(*HOST_SIDE))) == []


def _in_fresh_python(code: str) -> str:
    """What ``code`` prints, run in a Python process of its own (nothing imported yet)."""
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True).stdout.strip()


def test_importing_the_host_loads_neither_the_simulator_nor_the_device() -> None:
    assert _in_fresh_python(
        "import usbmotion.host, usbmotion.host.machine, usbmotion.host.stream, sys;"
        " print(sorted(m for m in sys.modules"
        " if m.startswith(('usbmotion.sim', 'usbmotion.device'))))") == "[]"


def test_the_command_lines_help_imports_nothing_it_does_not_use() -> None:
    """``usbmotion --help`` (the command line, before any command runs) loads neither
    numpy, numba nor matplotlib, nor the simulator, the device, the session or the links,
    nor the web server: each command imports those when it runs."""
    heavy = ("numpy", "numba", "matplotlib", "usbmotion.sim", "usbmotion.device",
             "usbmotion.session", "usbmotion.host", "usbmotion.web", "starlette", "uvicorn")
    assert _in_fresh_python(
        "import sys, usbmotion.cli.main;"
        f" print(sorted({{m.split('.')[0] if not m.startswith('usbmotion') else m"
        f" for m in sys.modules if m.startswith({heavy!r})}}))") == "[]"


@pytest.mark.parametrize("command", [
    ["status"], ["jog", "X+1"], ["get", "X", "kp"], ["home"],
])
def test_an_operator_command_on_a_real_machine_loads_no_simulator(
        tmp_path: Path, command: list[str]) -> None:
    """An operator command on a machine of real devices (here on TCP ports nothing
    listens on: it fails to connect) imports neither numba, matplotlib, the simulator's
    world nor the device: only the ``sim://`` URL checks of the machine file."""
    machine = tmp_path / "machine.toml"
    served = (Path(__file__).parents[1] / "examples" / "served-machine.toml").read_text()
    machine.write_text(served.replace("socket://127.0.0.1:700", "socket://127.0.0.1:1"))
    script = (
        "import runpy, sys; sys.argv = ['usbmotion', *sys.argv[1:]]\n"
        "try:\n    runpy.run_module('usbmotion', run_name='__main__')\n"
        "except SystemExit:\n    pass\n"
        "heavy = ('numba', 'matplotlib', 'usbmotion.sim.world', 'usbmotion.device',"
        " 'usbmotion.web', 'starlette')\n"
        "sys.stderr.write(repr(sorted(m for m in sys.modules if m.startswith(heavy))))\n")
    done = subprocess.run([sys.executable, "-c", script, *command, "--machine", str(machine)],
                          check=False, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "USBMOTION_STATE_DIR": str(tmp_path / "state")})
    assert done.stderr.splitlines()[-1] == "[]", done.stderr


@pytest.mark.parametrize("command", [["status"], ["get", "X", "kp"], ["set", "X", "kp", "0.2"]])
def test_an_operator_command_that_moves_nothing_on_the_simulated_machine_loads_no_numba(
        tmp_path: Path, command: list[str]) -> None:
    """On the built-in simulated machine, a command that moves nothing answers from the
    devices' reference path: importing numba and loading the kernel (about 0.3 s, as long as
    the rest of the command) wait for a device's first long block."""
    script = (
        "import runpy, sys; sys.argv = ['usbmotion', *sys.argv[1:]]\n"
        "try:\n    runpy.run_module('usbmotion', run_name='__main__')\n"
        "except SystemExit as done:\n    code = done.code\n"
        "sys.stderr.write(f'{code} ' + repr(sorted(m for m in sys.modules"
        " if m.startswith(('numba', 'llvmlite', 'matplotlib')))))\n")
    done = subprocess.run([sys.executable, "-c", script, *command], check=False,
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, "USBMOTION_STATE_DIR": str(tmp_path / "state"),
                               "USBMOTION_KERNEL": ""})
    assert done.stderr.splitlines()[-1] == "0 []", done.stderr


def test_importing_the_host_leaves_pyserials_url_handlers_alone() -> None:
    assert _in_fresh_python(
        "import serial; before = list(serial.protocol_handler_packages);"
        " import usbmotion.host.device, usbmotion.host.machine;"
        " print(serial.protocol_handler_packages == before)") == "True"


def test_no_literal_call_numbers_outside_the_protocol_and_the_device() -> None:
    assert literal_call_numbers(_all_but(*NUMBERED)) == []


@pytest.mark.parametrize("source, caught", [
    ("from usbmotion.sim.world import SimWorld\n", "imports usbmotion.sim.world"),
    ("import usbmotion.device\n", "imports usbmotion.device"),
    ("from usbmotion import sim\n", "imports usbmotion.sim"),
])
def test_the_import_check_catches_an_import_of_the_simulator(
        tmp_path: Path, source: str, caught: str) -> None:
    module = tmp_path / "planted.py"
    module.write_text(source)
    found = layering_violations([module])
    assert len(found) == 1 and caught in found[0]


@pytest.mark.parametrize("source", [
    "client.command(29, 5)\n",
    "client.query(20, -1)\n",
    "encode_call(2, -1)\n",
    "raise OutOfRangeError('x', call=18)\n",
    "spec = BY_NUMBER[38]\n",
    "if reply.call == 38: pass\n",
    "line = f'18 {len(name)} {codes}\\n'\n",
    "port.write(b'21 0\\n')\n",
])
def test_the_call_number_check_catches_a_literal(tmp_path: Path, source: str) -> None:
    module = tmp_path / "planted.py"
    module.write_text(source)
    found = literal_call_numbers([module])
    assert len(found) == 1, found


SERVING = SRC / "serving.py"
"""The one module that serves bytes on pseudo-terminals and TCP ports."""

SERVING_CALLS = frozenset({"openpty", "setraw", "listen", "accept"})
"""What opening a terminal or a listening port takes; only the serving module does it."""
TERMINAL_MODES = frozenset({"TIOCEXCL", "TIOCNXCL"})
"""A terminal's exclusive mode, the serving module's to handle."""


def serving_calls(paths: list[Path]) -> list[str]:
    """``file:line name`` for every call of :data:`SERVING_CALLS` (or use of
    :data:`TERMINAL_MODES`)."""
    found: list[str] = []
    for path in paths:
        tree = ast.parse(path.read_text(), filename=str(path))
        # An awaited accept is a WebSocket's handshake on a connection the server took,
        # not a listening socket's accept.
        handshakes = {id(node.value) for node in ast.walk(tree) if isinstance(node, ast.Await)}
        for node in ast.walk(tree):
            name = (_callee(node) if isinstance(node, ast.Call) else
                    node.attr if isinstance(node, ast.Attribute) else "")
            if name == "accept" and (id(node) in handshakes or any(
                    id(parent) in handshakes for parent in ast.walk(tree)
                    if isinstance(parent, ast.Call) and parent.func is node)):
                continue
            if name in SERVING_CALLS or name in TERMINAL_MODES:
                found.append(f"{_where(path)}:{node.lineno} {name}")
    return sorted(set(found))


def test_the_serving_module_sits_below_grbl_and_sim() -> None:
    tree = ast.parse(SERVING.read_text(), filename=str(SERVING))
    ours = sorted({module for _, module in _imports(tree) if module.startswith("usbmotion")})
    assert ours == ["usbmotion.errors", "usbmotion.errors.ArgumentError"]


def test_only_the_serving_module_opens_terminals_and_listens() -> None:
    others = [path for path in sorted(SRC.rglob("*.py")) if path != SERVING]
    assert serving_calls(others) == []
    assert serving_calls([SERVING]), "the check looks for what the module does"


@pytest.mark.parametrize("source", [
    "master, slave = os.openpty()\n",
    "tty.setraw(slave)\n",
    "listener.listen(1)\n",
    "client, _ = listener.accept()\n",
    "fcntl.ioctl(fd, termios.TIOCEXCL)\n",
])
def test_the_serving_check_catches_a_server_of_its_own(tmp_path: Path, source: str) -> None:
    module = tmp_path / "planted.py"
    module.write_text(source)
    assert len(serving_calls([module])) == 1


# --- no import circle -----------------------------------------------------------------------------

def _module_of(path: Path, root: Path) -> str:
    parts = path.relative_to(root.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_circles(root: Path, packages: tuple[str, ...]) -> list[list[str]]:
    """Every circle of imports (at module level or inside functions) among the modules of
    ``packages`` under ``root`` (the ``usbmotion`` folder), each as its modules in order."""
    graph: dict[str, set[str]] = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            module = _module_of(path, root)
            imported = {name for _, name in _imports(ast.parse(path.read_text()))}
            graph[module] = imported
    for module, imported in graph.items():
        graph[module] = {other for other in graph if other != module and (
            other in imported or any(name.startswith(other + ".") for name in imported))
            and not module.startswith(other + ".")}
    circles: list[list[str]] = []
    state: dict[str, int] = {}
    trail: list[str] = []

    def visit(module: str) -> None:
        state[module] = 1
        trail.append(module)
        for other in sorted(graph[module]):
            if state.get(other) == 1:
                circles.append([*trail[trail.index(other):], other])
            elif other not in state:
                visit(other)
        trail.pop()
        state[module] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module)
    return circles


def test_no_import_circle_in_session_or_cli() -> None:
    assert import_circles(SRC, ("session", "cli")) == []


def test_the_circle_check_catches_a_circle(tmp_path: Path) -> None:
    root = tmp_path / "usbmotion"
    (root / "session").mkdir(parents=True)
    (root / "session" / "__init__.py").write_text("")
    (root / "session" / "run.py").write_text("from usbmotion.session.live import Live\n")
    (root / "session" / "live.py").write_text(
        "def f() -> None:\n    from usbmotion.session import run\n")
    assert import_circles(root, ("session",)) == [
        ["usbmotion.session.live", "usbmotion.session.run", "usbmotion.session.live"]]
