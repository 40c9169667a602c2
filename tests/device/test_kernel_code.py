"""The kernel's machine code in its file: made once, loaded without numba, checked.

``test_kernel.py`` proves the code equal to the reference bit for bit; these tests cover
the file: a later process loads it without importing numba, a damaged or foreign file is
not loaded, code this process cannot link leaves the devices on numba's dispatcher, and an
exception inside the block reaches the caller.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from usbmotion.device import core1, kernel, kernel_code
from usbmotion.device.kernel_code import KernelCodeError, MachineKernel

needs_numba = pytest.mark.skipif(not kernel.numba_available(), reason="numba is not installed")

_LOAD = (
    "import sys; from usbmotion.device import kernel, kernel_code;"
    " function = kernel.load();"
    " print(type(function).__name__, 'numba' in sys.modules,"
    " sorted(p.name for p in kernel_code.cache_folder().glob('kernel-*.code')))"
)


def _fresh_process(cache: Path) -> list[str]:
    done = subprocess.run([sys.executable, "-c", _LOAD], capture_output=True, text=True,
                          env={**os.environ, "NUMBA_CACHE_DIR": str(cache)}, timeout=600,
                          check=True)
    return done.stdout.strip().split(maxsplit=2)


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
    assert _fresh_process(tmp_path) == ["MachineKernel", "False", f"['{made[0].name}']"]


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
