"""The kernel's machine code in its file: made once, loaded without numba, checked.

``test_kernel.py`` proves the code equal to the reference bit for bit; these tests cover
the file: a later process loads it without importing numba, a damaged or foreign file is
not loaded, code this process cannot link leaves the devices on numba's dispatcher, and an
exception inside the block reaches the caller.
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from usbmotion.device import Device, core1, kernel, kernel_code
from usbmotion.device.kernel_code import KernelCodeError, MachineKernel

needs_numba = pytest.mark.skipif(not kernel.numba_available(), reason="numba is not installed")

_LOAD = (
    "import sys; from usbmotion.device import kernel, kernel_code;"
    " function = kernel.load();"
    " print(type(function).__name__, 'numba' in sys.modules, 'llvmlite' in sys.modules,"
    " sorted(p.name for p in kernel_code.cache_folder().glob('kernel-*.code')))"
)
LINKED_HERE = sys.platform == "linux" and platform.machine() == "x86_64"
"""Where :func:`kernel_code.link_here` links the code (elsewhere llvmlite does)."""


def _fresh_process(cache: Path) -> list[str]:
    done = subprocess.run([sys.executable, "-c", _LOAD], capture_output=True, text=True,
                          env={**os.environ, "NUMBA_CACHE_DIR": str(cache)}, timeout=600,
                          check=True)
    return done.stdout.strip().split(maxsplit=3)


@pytest.fixture(scope="module")
def code() -> bytes:
    """The machine code, as a process with its file already made loads it."""
    kernel.block_function()
    sources = kernel._source_text((*kernel.SOURCES, kernel_code, kernel._this_module()))
    assert sources is not None
    data = kernel_code.read(kernel_code.cache_folder() / kernel_code.cache_key(sources))
    assert data is not None
    return data


@needs_numba
def test_the_file_is_made_once_and_a_later_process_loads_it_without_numba(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    """(Two compilations give the same instructions, not the same bytes: numba numbers the
    functions' names in the order a process compiles them.)"""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(kernel, "_loaded", None)
    assert isinstance(kernel.load(), MachineKernel)
    made = sorted((tmp_path / "usbmotion").glob("kernel-*.code"))
    assert len(made) == 1 and kernel_code.read(made[0]) is not None
    assert _fresh_process(tmp_path) == ["MachineKernel", "False", str(not LINKED_HERE),
                                        f"['{made[0].name}']"]


@needs_numba
def test_a_damaged_file_is_not_loaded(code: bytes, tmp_path: Path) -> None:
    path = tmp_path / "kernel-x.code"
    assert kernel_code.write(path, code)
    assert kernel_code.read(path) == code
    whole = path.read_bytes()
    for damaged in (whole[:-1], whole[:-1] + bytes([whole[-1] ^ 1]), b"", whole[5:]):
        path.write_bytes(damaged)
        assert kernel_code.read(path) is None
    assert kernel_code.read(tmp_path / "none.code") is None


@needs_numba
def test_the_code_needs_only_what_the_process_has(code: bytes) -> None:
    """The entry point catches every exception, so numba's exception machinery (in numba's
    own extension modules, absent without numba) is not among what the code needs."""
    needed = kernel_code.undefined_symbols(code)
    assert not any(name.startswith(("numba_", "Py")) for name in needed), needed
    assert set(kernel_code._resolve(code)) == set(needed)
    with pytest.raises(KernelCodeError, match="not 64-bit little-endian ELF"):
        kernel_code.undefined_symbols(b"\xcf\xfa\xed\xfe" + code[4:])
    with pytest.raises(KernelCodeError, match="symbol table is unreadable"):
        kernel_code.undefined_symbols(code[:100])


@needs_numba
def test_code_that_cannot_be_linked_leaves_the_devices_on_the_dispatcher(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def unlinkable(_code: bytes) -> MachineKernel:
        raise KernelCodeError("the kernel's code needs 'nowhere', which this process lacks")

    monkeypatch.setattr(kernel_code, "load", unlinkable)
    monkeypatch.setattr(kernel, "_loaded", None)
    function = kernel.block_function()
    assert function is kernel.compile_kernel()


@needs_numba
def test_an_exception_in_the_block_reaches_the_caller(code: bytes) -> None:
    """Parameters all zero divide by zero in the first tick: the reference raises, and the
    machine code stops and says so rather than returning ticks it did not run."""
    state, params = core1.new_state(), core1.new_params()
    empty = np.zeros(0, dtype=np.int64)
    with pytest.raises(ZeroDivisionError):
        core1.servo_block(state.copy(), params, empty.copy(), empty, 10)
    with pytest.raises(ArithmeticError, match="the servo kernel raised"):
        kernel_code.load(code)(state, params, empty.copy(), empty, 10)


@needs_numba
def test_arrays_it_cannot_take_are_refused(code: bytes) -> None:
    function = kernel_code.load(code)
    state, params = core1.new_state(), core1.new_params()
    empty = np.zeros(0, dtype=np.int64)
    for bad in (state.astype(np.int32), state[::2], np.zeros((2, 3), dtype=np.int64)):
        with pytest.raises(TypeError, match="1-D C-contiguous int64 arrays it may write"):
            function(bad, params, empty.copy(), empty, 0)
    read_only = state.copy()
    read_only.flags.writeable = False
    with pytest.raises(TypeError, match="it may write"):
        function(read_only, params, empty.copy(), empty, 0)
    with pytest.raises(TypeError, match="1-D C-contiguous int64 arrays; got"):
        function(state, params, empty.copy(), np.arange(4.0), 0)


def test_the_file_goes_beside_numba_s_cache(monkeypatch: pytest.MonkeyPatch,
                                            tmp_path: Path) -> None:
    """NUMBA_CACHE_DIR when set; else the package's __pycache__ when writable; else the
    user's cache folder (an installed package in a folder the user cannot write)."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    assert kernel_code.cache_folder() == tmp_path / "numba" / "usbmotion"
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    beside = Path(kernel_code.__file__).with_name("__pycache__")
    monkeypatch.setattr(os, "access", lambda path, mode: True)
    assert kernel_code.cache_folder() == beside
    monkeypatch.setattr(os, "access", lambda path, mode: False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert kernel_code.cache_folder() == tmp_path / "cache" / "usbmotion"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert kernel_code.cache_folder() == tmp_path / "home" / ".cache" / "usbmotion"


def _moving(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A device's arrays in the middle of a motion: enabled, its queue full of a ramp."""
    device = Device()
    device.feed(b"3 1\n")
    values = (np.arange(900) * (seed + 3)).astype(np.int64)
    device.feed(b"1 900 " + b" ".join(b"%d" % v for v in values) + b"\n")
    device.run(50)
    return device._state.copy(), device._params.copy(), device._queue.copy()


@needs_numba
@pytest.mark.skipif(not LINKED_HERE, reason="linked by llvmlite on this platform")
def test_code_linked_here_runs_as_llvmlite_links_it(code: bytes) -> None:
    """The same blocks from the same arrays, linked in this process and by llvmlite: every
    array equal after every block, and the ticks run."""
    addresses = kernel_code._resolve(code)
    here = MachineKernel(kernel_code._PROTOTYPE(kernel_code.link_here(code, addresses)))
    llvmlite = kernel_code.link_by_llvmlite(code, addresses)
    empty = np.zeros(0, dtype=np.int64)
    for seed in range(4):
        ours, theirs = _moving(seed), _moving(seed)
        for ticks in (1, 7, 600, 3000):
            assert here(*ours, empty, ticks) == llvmlite(*theirs, empty, ticks)
            for mine, other in zip(ours, theirs, strict=True):
                assert np.array_equal(mine, other)


@needs_numba
@pytest.mark.skipif(not LINKED_HERE, reason="linked by llvmlite on this platform")
def test_an_object_the_linker_does_not_take_is_refused(code: bytes) -> None:
    """A relocation of another type is refused; so is a file that is not an x86-64 object,
    or is cut short."""
    sections = kernel_code.struct.unpack_from("<Q", code, 0x28)[0]
    entry_size, count = kernel_code.struct.unpack_from("<HH", code, 0x3A)
    rela = next(offset for offset in (sections + i * entry_size for i in range(count))
                if kernel_code.struct.unpack_from("<I", code, offset + 4)[0] == 4)
    first = kernel_code.struct.unpack_from("<Q", code, rela + 24)[0]  # its first entry
    changed = bytearray(code)
    changed[first + 8] = 10  # R_X86_64_32
    addresses = kernel_code._resolve(code)
    with pytest.raises(KernelCodeError, match="relocation type 10 is not linked here"):
        kernel_code.link_here(bytes(changed), addresses)
    with pytest.raises(KernelCodeError, match="not a 64-bit x86 relocatable object"):
        kernel_code.link_here(code[:18] + b"\xb7\x00" + code[20:], addresses)  # Arm64
    with pytest.raises(KernelCodeError, match="unreadable"):
        kernel_code.link_here(code[:0x200], addresses)


@needs_numba
def test_where_the_code_is_not_linked_here_llvmlite_links_it(
        code: bytes, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    """Another processor or system: llvmlite's linker, and the same blocks."""
    linked = kernel_code.load(code)
    monkeypatch.setattr(kernel_code.platform, "machine", lambda: "aarch64")
    with caplog.at_level("DEBUG", logger=kernel_code.__name__):
        other = kernel_code.load(code)
    assert "linked by llvmlite: no linker here for" in caplog.text
    empty = np.zeros(0, dtype=np.int64)
    ours, theirs = _moving(1), _moving(1)
    assert linked(*ours, empty, 2000) == other(*theirs, empty, 2000)
    assert all(np.array_equal(a, b) for a, b in zip(ours, theirs, strict=True))
