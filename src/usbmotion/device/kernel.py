"""The fast path: core1's servo block compiled to machine code with numba.

:func:`servo_block` has the signature and the meaning of
:func:`usbmotion.device.core1.servo_block`: it is that very source, compiled unchanged by
``numba.njit`` with the functions it calls (the ``usbmotion.scimath`` core, the motor step,
the int32 wrap) registered as jitable, so it is bit-for-bit equal to the reference
(``tests/device/test_kernel.py`` proves it). It runs a block of servo ticks in one call:
core0 calls it up to the next pending command, queue event or diagnostics line.

numba is optional (the ``fast`` extra). :func:`use_kernel` decides which path a device
runs: the kernel when numba is installed, unless the environment variable
``USBMOTION_KERNEL`` says otherwise (``0``: always the reference path; ``1``: the kernel or
an error). Without numba the reference path runs and a one-line notice (a warning on the
``usbmotion.device.kernel`` logger, printed once per process) says so.

Importing numba and loading the kernel take about 0.3 s, more than a command that moves
nothing takes in all, so neither happens before a device needs it: :func:`load` does both,
when a device first runs a long block (``usbmotion.device.core0``), or at once for a world
that keeps pace with the wall clock and cannot stand still for it (:func:`preload`). An
installed numba that fails to import is found then, and the device runs the reference
path, with the notice.

What the devices run (:func:`load`, :func:`block_function`) is that compilation's machine
code, kept in a file and loaded without importing numba (:mod:`usbmotion.device.kernel_code`:
importing numba and setting up its compiler take about 0.45 s of every process; reading
and linking the file take about 2 ms on Linux x86-64, where it is linked without
llvmlite). numba is imported only to make the file, the first time a device needs the
kernel after an install or a change (a few seconds; ``BENCHMARKS.md`` gives the figures),
or where such a file cannot be used: then the devices run numba's dispatcher,
:func:`compile_kernel`, as fast once loaded.

The dispatcher's code is cached on disk too (numba's ``cache=True``: ``__pycache__`` next to
this module, or numba's user cache directory when that is not writable). numba's cache only
checks the file of the function it compiles, not the files of the functions it calls; the
cache key here also carries a hash of ``core1.py``, ``motor.py``, ``stepper.py``,
``scimath.py`` and ``protocol/table.py``, so an edit to any of them compiles afresh instead
of loading stale machine code (when the sources cannot be read, nothing is cached); the
machine code's file is named by a hash of the same sources, this module's and
``kernel_code.py``'s.
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import logging
import os
import sys
import threading
from collections.abc import Callable
from types import ModuleType
from typing import Any, Final

from usbmotion import scimath
from usbmotion.device import core1, kernel_code, motor, stepper
from usbmotion.device.core1 import IntArray
from usbmotion.errors import DeviceParameterError
from usbmotion.protocol import table

ENVIRONMENT_VARIABLE: Final = "USBMOTION_KERNEL"
"""``0``: every device runs the reference core1; ``1``: the kernel is required; unset or
empty: the kernel when numba is importable."""
NOTICE: Final = (
    "usbmotion: numba is not installed, so simulated devices run the reference servo loop"
    " (pure Python, about 100 times slower); pip install 'usbmotion[fast]' for the kernel"
)

BlockFunction = Callable[[IntArray, IntArray, IntArray, IntArray, int], int]
"""The signature of :func:`usbmotion.device.core1.servo_block` and of :func:`servo_block`."""

_log = logging.getLogger(__name__)
_lock = threading.Lock()
_load_lock = threading.Lock()
_compiled: BlockFunction | None = None
_jit_block: Any = None
"""``core1.servo_block`` jitted (not cached by itself): what the cached wrapper calls."""
_noticed = False
_loaded: BlockFunction | None = None
"""The kernel the devices run, once loaded (:func:`load`)."""


def _numba_installed() -> bool:
    """Whether numba is installed (found on the path), without importing it."""
    try:
        return importlib.util.find_spec("numba") is not None
    except (ImportError, ValueError):  # a broken parent, or a module set to None
        return False


def _numba_problem() -> BaseException | None:
    """Why numba cannot be used, or None (the first call imports it)."""
    try:
        import numba  # noqa: F401, PLC0415 - optional dependency
    except Exception as error:  # not installed, or an install broken in any way
        return error
    return None


def numba_available() -> bool:
    """True when numba can be imported (the first call imports it: about 0.4 s)."""
    return _numba_problem() is None


def _environment_choice() -> bool | None:
    raw = os.environ.get(ENVIRONMENT_VARIABLE, "")
    value = raw.strip()
    if value == "":
        return None
    if value in ("0", "1"):
        return value == "1"
    raise DeviceParameterError(
        f"environment variable {ENVIRONMENT_VARIABLE}={raw!r} is not allowed; use 0 (the"
        " reference servo loop), 1 (the compiled kernel) or leave it unset (the kernel when"
        " numba is installed)"
    )


def requested(fast: bool | None = None) -> bool | None:
    """What ``fast``, else ``USBMOTION_KERNEL``, asks for: True the kernel (and an error
    without it), False the reference, None whichever numba's presence gives.

    Raises:
        DeviceParameterError: ``fast`` is not a bool or None, or ``USBMOTION_KERNEL`` holds
            something other than ``0``, ``1`` or nothing.
    """
    if fast is not None and not isinstance(fast, bool):
        raise DeviceParameterError(f"fast {fast!r} is not True, False or None")
    return fast if fast is not None else _environment_choice()


def use_kernel(fast: bool | None = None) -> bool:
    """Whether a device should run the compiled kernel.

    Parameters:
        fast: True requires the kernel (and loads it now: its machine code's file, numba
            imported only when there is none), False chooses the reference path, None (the
            default) follows ``USBMOTION_KERNEL`` and otherwise takes the kernel when numba
            is installed, printing :data:`NOTICE` once per process when it is not (with
            the import error when numba is installed but broken).

    Raises:
        DeviceParameterError: ``fast`` is not a bool or None; the kernel is required
            (``fast=True`` or ``USBMOTION_KERNEL=1``) but numba cannot be imported; or
            ``USBMOTION_KERNEL`` holds something other than ``0``, ``1`` or nothing.
    """
    choice = requested(fast)
    if choice is False:
        return False
    if _numba_installed() and (choice is None or _loaded_or_machine_code()):
        return True  # None: loaded when a device first needs the kernel (load)
    problem = _numba_problem()
    if problem is None:
        return True
    if choice is True:
        missing = isinstance(problem, ModuleNotFoundError)
        why = "numba is not installed" if missing else f"numba cannot be imported ({problem})"
        source = "fast=True" if fast else f"{ENVIRONMENT_VARIABLE}=1"
        raise DeviceParameterError(
            f"{source} asks for the compiled servo kernel, but {why};"
            " pip install 'usbmotion[fast]', or use the reference path"
            f" (fast=False or {ENVIRONMENT_VARIABLE}=0)"
        )
    _notice(problem)
    return False


def _notice(problem: BaseException) -> None:
    """The notice that the reference path runs, once per process (naming ``problem`` when
    numba is installed but does not import)."""
    global _noticed  # noqa: PLW0603 - the notice is printed once per process
    if not _noticed:
        _noticed = True
        missing = isinstance(problem, ModuleNotFoundError)
        _log.warning(NOTICE if missing else f"{NOTICE} [{problem}]")


def loaded() -> bool:
    """Whether the kernel the devices run is loaded in this process (:func:`load`)."""
    return _loaded is not None


def load() -> BlockFunction | None:
    """The kernel the devices run, loaded if that has not happened yet in this process:
    its machine code from its file (made first, numba imported, when there is none), or
    numba's dispatcher where the file cannot serve; None when numba does not import after
    all and there is no file (the reference path runs then: the notice says so, once)."""
    global _loaded  # noqa: PLW0603 - one loaded kernel per process
    if not _loaded_or_machine_code():
        with _load_lock:
            if _loaded is None:
                problem = _numba_problem()
                if problem is not None:
                    _notice(problem)
                    return None
                warm_up()
                _loaded = compile_kernel()
    return _loaded


def block_function() -> BlockFunction:
    """The kernel the devices run (:func:`load`).

    Raises:
        ImportError: the kernel cannot be loaded (numba does not import, and there is no
            machine code to load).
    """
    function = load()
    if function is None:
        raise ImportError("the compiled servo kernel cannot be loaded: numba does not import")
    return function


def _loaded_or_machine_code() -> bool:
    """Whether a kernel is loaded, its machine code tried now when none is (numba is not
    imported when its file is there)."""
    global _loaded  # noqa: PLW0603 - one loaded kernel per process
    if _loaded is None:
        with _load_lock:
            if _loaded is None:
                _loaded = _machine_code()
    return _loaded is not None


def _machine_code() -> BlockFunction | None:
    """The kernel's machine code, from its file, or made now (numba imported) and kept;
    None when it cannot be had here (no numba and no file; sources that cannot be read;
    an object format or a symbol this process lacks: :mod:`kernel_code`)."""
    sources = _source_text((*SOURCES, kernel_code, _this_module()))
    if sources is None:
        return None
    try:
        path = kernel_code.cache_folder() / kernel_code.cache_key(sources)
        code = kernel_code.read(path)
        if code is None:
            if _numba_problem() is not None:
                return None
            import numba  # noqa: PLC0415 - optional dependency, imported on first use

            compile_kernel()
            code = kernel_code.object_code(numba, _jit_block)
            kernel_code.write(path, code)
        return kernel_code.load(code)
    except ImportError:  # llvmlite, numba's code generator, missing or broken
        return None
    except Exception as error:
        _log.debug("the kernel's machine code is not used here: %s", error)
        return None


def _this_module() -> ModuleType:
    return sys.modules[__name__]


def preload() -> None:
    """Load the kernel now when the devices made in this process run it (:func:`use_kernel`):
    for a world that keeps pace with the wall clock, which cannot stand still for the
    loading (about 0.3 s) at its first motion."""
    if use_kernel():
        load()


SOURCES: Final = (core1, motor, stepper, scimath, table)
"""The modules whose source the compiled kernel depends on (code and constants)."""


def _source_text(modules: tuple[ModuleType, ...]) -> bytes | None:
    """The sources of ``modules``, one after the other, or None when one cannot be read."""
    parts = []
    for module in modules:
        try:
            parts.append(inspect.getsource(module).encode("utf-8"))
        except (OSError, TypeError):
            return None
    return b"\0".join(parts)


def source_hash() -> int | None:
    """A positive 62-bit hash of :data:`SOURCES`, or None when a source cannot be read."""
    text = _source_text(SOURCES)
    if text is None:
        return None
    digest = hashlib.sha256(text).digest()
    return int.from_bytes(digest[:8], "little") >> 2 | 1


def _cached_wrapper(numba: ModuleType, fingerprint: int) -> BlockFunction:
    """``_jit_block`` behind a cached jitted wrapper whose cache key carries ``fingerprint``.

    numba's cache key hashes the bytecode and the closure of the function it caches:
    ``fingerprint`` is the whole closure, so other sources mean another key.
    """

    def servo_kernel(
        state: IntArray, params: IntArray, queue: IntArray, curve: IntArray, n_ticks: int
    ) -> int:
        if fingerprint == 0:
            return 0
        ticks: int = _jit_block(state, params, queue, curve, n_ticks)
        return ticks

    compiled: BlockFunction = numba.njit(cache=True, nogil=True)(servo_kernel)
    return compiled


def compile_kernel() -> BlockFunction:
    """The compiled block function (compiled, or loaded from the cache, on the first call).

    The machine code is built when it is first called with arrays; :func:`warm_up` does
    that at once.

    Raises:
        ImportError: numba is not installed.
    """
    global _compiled, _jit_block  # noqa: PLW0603 - one compiled kernel per process
    if _compiled is not None:
        return _compiled
    with _lock:
        if _compiled is None:
            import numba  # noqa: PLC0415 - optional dependency, imported on first use
            from numba.extending import register_jitable  # noqa: PLC0415

            for function in (
                *scimath.NUMBA_CORE,
                core1.wrap_int32,
                core1.trunc_div,
                core1.shift_edges,
                core1.probe_closed,
                core1.apply_outputs,
                core1.drop_pending_outputs,
                core1.outputs_off,
                motor._trunc_div,
                motor.motor_step,
                stepper.trunc_div,
                stepper.travel,
                stepper.speed_change,
                stepper.sine_at,
                stepper.encoder_microsteps,
                stepper.stepper_step,
            ):
                register_jitable(function)
            _jit_block = numba.njit(nogil=True)(core1.servo_block)
            fingerprint = source_hash()
            if fingerprint is None:
                _compiled = numba.njit(nogil=True)(core1.servo_block)
            else:
                _compiled = _cached_wrapper(numba, fingerprint)
        return _compiled


def warm_up() -> None:
    """Compile (or load from numba's cache) the dispatcher's kernel now, by running it on a
    0-tick block.

    Raises:
        ImportError: numba is not installed.
    """
    function = compile_kernel()
    empty = core1.new_state()[:0]
    function(core1.new_state(), core1.new_params(), empty.copy(), empty, 0)


def servo_block(
    state: IntArray,
    params: IntArray,
    queue: IntArray,
    curve: IntArray,
    n_ticks: int,
) -> int:
    """Run up to ``n_ticks`` servo ticks in compiled code; as ``core1.servo_block`` exactly.

    Parameters:
        state, params, queue, curve, n_ticks: as :func:`usbmotion.device.core1.servo_block`
            (``numpy.int64`` arrays, C-contiguous).

    Returns the number of ticks run.

    Raises:
        ImportError: numba is not installed.
    """
    return compile_kernel()(state, params, queue, curve, n_ticks)
