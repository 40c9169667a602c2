"""The compiled kernel's machine code, kept in a file and loaded without numba.

numba's own cache gives back a compiled function only through numba: importing it and
setting up its compiler take about 0.45 s of every process that runs a simulated device,
more than the rest of a command that moves the simulated machine for a minute. So the
kernel the devices run is numba's compilation of ``core1.servo_block`` behind a C entry
point (``numba.cfunc``: each array as a pointer and a length, the ticks to run; the ticks
run back, or :data:`RAISED`), its machine code written once to an object file and linked
into later processes: on Linux x86-64 by :func:`link_here`, a few lines of relocation that
take 2 ms; elsewhere by llvmlite, numba's own code generator, whose library takes about
0.04 s to load. ctypes calls it and lets go of the interpreter's lock while it runs, as
numba's ``nogil`` does.

The code is numba's: the same source, compiled by the same compiler to the same
instructions; ``tests/device/test_kernel.py`` proves it equal to the reference bit for bit,
as it does numba's dispatcher, and ``tests/device/test_kernel_code.py`` the code linked
here equal to the code llvmlite links. The file's name is a hash of everything the code
depends on (:func:`cache_key`: the sources, numba's and llvmlite's versions, the processor
as the system describes it, Python); the file holds a digest of the code, checked before
loading. Every symbol the code needs from outside is resolved here, before it is linked: a
file that needs one this process lacks, or a platform whose objects are not ELF, is not
used, and the devices run numba's dispatcher instead (:mod:`usbmotion.device.kernel`).
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import mmap
import os
import platform
import struct
import sys
import tempfile
import threading
from pathlib import Path
from types import ModuleType
from typing import Any, Final

import numpy as np

from usbmotion.device.core1 import IntArray

SYMBOL: Final = "usbmotion_servo_block"
"""The entry point's name in the object file."""
RAISED: Final = -1
"""What the entry point returns when the block raised (the reference raises the same
exception): never a count of ticks."""
_MAGIC: Final = b"usbmotion servo kernel 2\n"
_DIGEST_BYTES: Final = 32
_ARRAYS: Final = 4

_PROTOTYPE = ctypes.CFUNCTYPE(ctypes.c_int64,
                              *((ctypes.c_void_p, ctypes.c_int64) * _ARRAYS), ctypes.c_int64)
_DESTRUCTOR = ctypes.CFUNCTYPE(None, ctypes.c_void_p)


def _no_destructor(_meminfo: int) -> None:
    """``NRT_MemInfo_call_dtor``: numba's release of an array it allocated. The entry point
    allocates none (its arrays view the caller's memory and own nothing), so nothing calls
    this; the code refers to it from the release it never reaches."""


_PROVIDED: Final = {"NRT_MemInfo_call_dtor": _DESTRUCTOR(_no_destructor)}
_lock = threading.Lock()
_log = logging.getLogger(__name__)
_engines: list[Any] = []
"""The llvmlite engines holding loaded code: kept for the life of the process."""


class KernelCodeError(Exception):
    """The machine code cannot be made or loaded here (the dispatcher runs instead)."""


def cache_folder() -> Path:
    """Where the object file is kept: beside numba's own cache, ``NUMBA_CACHE_DIR`` when
    set, else this package's ``__pycache__`` when writable, else the user's cache folder."""
    chosen = os.environ.get("NUMBA_CACHE_DIR", "")
    if chosen:
        return Path(chosen) / "usbmotion"
    beside = Path(__file__).with_name("__pycache__")
    if os.access(beside if beside.is_dir() else beside.parent, os.W_OK):
        return beside
    base = os.environ.get("XDG_CACHE_HOME", "") or str(Path.home() / ".cache")
    return Path(base) / "usbmotion"


def _llvm() -> Any:
    """llvmlite's binding to LLVM, ready to make and link code for this processor."""
    import llvmlite.binding as llvm  # noqa: PLC0415 - numba's code generator, on first use

    llvm.initialize_native_target()
    llvm.initialize_native_asmprinter()
    return llvm


def _version_file(package: str) -> bytes:
    """The text of ``package``'s version file (numba's: the compiler that made the code;
    llvmlite's: its code generator), found without importing it; empty when it cannot be
    read."""
    import importlib.util  # noqa: PLC0415

    try:
        spec = importlib.util.find_spec(package)
        locations = list(spec.submodule_search_locations or []) if spec else []
        return (Path(locations[0]) / "_version.py").read_bytes() if locations else b""
    except (ImportError, ValueError, OSError):
        return b""


_PROCESSOR_FIELDS: Final = frozenset({
    "vendor_id", "cpu family", "model", "model name", "stepping", "flags",  # x86
    "CPU implementer", "CPU architecture", "CPU variant", "CPU part", "Features"})  # Arm


def processor() -> bytes:
    """The processor the code is made for and run on (it uses the processor's own
    instructions): on Linux, the first processor's identity and flags as the system lists
    them, read without llvmlite; elsewhere llvmlite's name and features of it."""
    try:
        text = Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
    except OSError:
        text = ""
    first = text.strip().split("\n\n", 1)[0]
    kept = [line for line in first.splitlines()
            if line.split(":", 1)[0].strip() in _PROCESSOR_FIELDS]
    if kept:
        return "\n".join(kept).encode("utf-8")
    llvm = _llvm()
    return f"llvm {llvm.get_host_cpu_name()} {llvm.get_host_cpu_features().flatten()}".encode()


def cache_key(sources: bytes) -> str:
    """The object file's name for the kernel of ``sources`` (the text of every module the
    code is compiled from): with numba's and llvmlite's versions, the processor (the code
    uses its instructions), the platform and Python's version."""
    digest = hashlib.sha256(_MAGIC)
    for part in (sources, _version_file("numba"), _version_file("llvmlite"), processor(),
                 f"{sys.platform} {platform.machine()}".encode(), sys.version.encode()):
        digest.update(len(part).to_bytes(8, "little"))
        digest.update(part)
    return f"kernel-{digest.hexdigest()[:32]}.code"


def read(path: Path) -> bytes | None:
    """The object code kept at ``path``; None when there is none, or the file is not one
    this module wrote whole (its digest does not match)."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    head = len(_MAGIC) + _DIGEST_BYTES
    if len(data) <= head or not data.startswith(_MAGIC):
        return None
    code = data[head:]
    if hashlib.sha256(code).digest() != data[len(_MAGIC):head]:
        return None
    return code


def write(path: Path, code: bytes) -> bool:
    """Keep ``code`` at ``path`` (written aside, then renamed: a reader never sees half a
    file). False when the folder cannot be written (the code is then made again next time)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=".kernel-", delete=False) as f:
            f.write(_MAGIC + hashlib.sha256(code).digest() + code)
        os.chmod(f.name, 0o644)  # as numba's own cache files: not private to one user
        os.replace(f.name, path)
    except OSError:
        return False
    return True


def object_code(numba: ModuleType, block: Any) -> bytes:
    """Compile the C entry point around ``block`` (``core1.servo_block`` as numba jits it)
    and return its machine code as an ELF object file.

    The entry point catches what the block raises and returns :data:`RAISED`, so the code
    never calls into numba's exception machinery (which lives in numba's own extension
    modules, not loaded without numba).

    Raises:
        KernelCodeError: the code needs something from outside this module can not provide.
    """
    carray = numba.carray
    types = numba.types

    def servo_entry(state: Any, state_n: int, params: Any, params_n: int, queue: Any,
                    queue_n: int, curve: Any, curve_n: int, n_ticks: int) -> int:
        try:
            ticks: int = block(carray(state, (state_n,)), carray(params, (params_n,)),
                               carray(queue, (queue_n,)), carray(curve, (curve_n,)), n_ticks)
        except Exception:
            return RAISED
        return ticks

    pointer = types.CPointer(types.int64)
    signature = types.int64(*((pointer, types.int64) * _ARRAYS), types.int64)
    entry = numba.cfunc(signature, nogil=True)(servo_entry)
    llvm = _llvm()
    module = llvm.parse_assembly(entry.inspect_llvm())
    module.get_function(entry.native_name).name = SYMBOL
    module.verify()
    code: bytes = _target_machine(llvm).emit_object(module)
    _resolve(code)
    return code


def _target_machine(llvm: Any) -> Any:
    """This processor's code generator, set as numba's own JIT sets it (position-dependent
    code in the JIT's code model: position-independent code ran 3 % slower)."""
    target = llvm.Target.from_triple(llvm.get_process_triple())
    return target.create_target_machine(
        cpu=llvm.get_host_cpu_name(), features=llvm.get_host_cpu_features().flatten(),
        opt=3, reloc="default", codemodel="jitdefault")


_EM_X86_64: Final = 62
_ET_REL: Final = 1
_SHT_SYMTAB: Final = 2
_SHT_RELA: Final = 4
_SHT_NOBITS: Final = 8
_SHT_X86_64_UNWIND: Final = 0x70000001
_SHF_WRITE: Final = 1
_SHF_ALLOC: Final = 2
_SHN_UNDEF: Final = 0
_SHN_ABS: Final = 0xFFF1
_R_X86_64_64: Final = 1
_R_X86_64_PC32: Final = 2
_R_X86_64_PLT32: Final = 4
_PAGE: Final = mmap.PAGESIZE


def _sections(code: bytes) -> list[tuple[int, ...]]:
    """The section headers of an ELF64 little-endian object file, in order: (name, type,
    flags, address, offset, size, link, info, alignment, entry size)."""
    section_offset, = struct.unpack_from("<Q", code, 0x28)
    entry_size, count = struct.unpack_from("<HH", code, 0x3A)
    return [struct.unpack_from("<IIQQQQIIQQ", code, section_offset + i * entry_size)
            for i in range(count)]


def _symbols(code: bytes, sections: list[tuple[int, ...]]) -> list[tuple[str, int, int]]:
    """The symbol table of an object file, in order: each symbol's name (empty for none),
    the index of its section and its value; empty without a symbol table."""
    symtab = next((section for section in sections if section[1] == _SHT_SYMTAB), None)
    if symtab is None:
        return []
    strings = sections[symtab[6]]  # sh_link: its string table
    symbols: list[tuple[str, int, int]] = []
    for offset in range(symtab[4], symtab[4] + symtab[5], 24):
        name_at, _, _, index, value = struct.unpack_from("<IBBHQ", code, offset)
        name = ""
        if name_at:
            start = strings[4] + name_at
            name = code[start : code.index(b"\0", start)].decode("ascii")
        symbols.append((name, index, value))
    return symbols


def undefined_symbols(code: bytes) -> list[str]:
    """The symbols an ELF64 little-endian object file ``code`` uses but does not define.

    Raises:
        KernelCodeError: ``code`` is not such a file.
    """
    if code[:6] != b"\x7fELF\x02\x01":
        raise KernelCodeError("the object file is not 64-bit little-endian ELF")
    try:
        return [name for name, index, _ in _symbols(code, _sections(code))
                if name and index == _SHN_UNDEF]
    except (struct.error, IndexError, ValueError, UnicodeDecodeError) as error:
        raise KernelCodeError(f"the object file's symbol table is unreadable ({error})") from None


def _resolve(code: bytes) -> dict[str, int]:
    """Each symbol ``code`` needs, with its address in this process.

    Raises:
        KernelCodeError: one of them is nowhere in this process.
    """
    process = ctypes.CDLL(None)
    addresses: dict[str, int] = {}
    for name in undefined_symbols(code):
        provided = _PROVIDED.get(name)
        try:
            function = provided if provided is not None else getattr(process, name)
        except AttributeError:
            raise KernelCodeError(f"the kernel's code needs {name!r}, which this process"
                                  " lacks") from None
        address = ctypes.cast(function, ctypes.c_void_p).value
        if not address:
            raise KernelCodeError(f"the kernel's code needs {name!r}, at address 0 here")
        addresses[name] = address
    return addresses


def load(code: bytes) -> MachineKernel:
    """Link ``code`` (from :func:`object_code`) into this process: by :func:`link_here`
    where it can, else by llvmlite's linker.

    Raises:
        KernelCodeError: see :func:`undefined_symbols` and :func:`object_code`, or the
            entry point is missing.
    """
    addresses = _resolve(code)
    try:
        return MachineKernel(_PROTOTYPE(link_here(code, addresses)))
    except KernelCodeError as error:
        _log.debug("the kernel's code is linked by llvmlite: %s", error)
    return link_by_llvmlite(code, addresses)


def link_by_llvmlite(code: bytes, addresses: dict[str, int]) -> MachineKernel:
    """Link ``code`` with llvmlite's linker, ``addresses`` giving the symbols it needs.

    Raises:
        KernelCodeError: the entry point is missing.
    """
    llvm = _llvm()
    with _lock:
        for name, address in addresses.items():
            llvm.add_symbol(name, address)
        engine = llvm.create_mcjit_compiler(llvm.parse_assembly(""), _target_machine(llvm))
        engine.add_object_file(llvm.ObjectFileRef.from_data(code))
        engine.finalize_object()
        address = engine.get_function_address(SYMBOL)
        if not address:
            raise KernelCodeError(f"the object file has no {SYMBOL}")
        _engines.append(engine)
    return MachineKernel(_PROTOTYPE(address))


_linked: list[int] = []
"""The memory holding code linked here: mapped for the life of the process (a helper
thread may still be running a block while the interpreter ends)."""


def link_here(code: bytes, addresses: dict[str, int]) -> int:
    """Link an x86-64 ELF object ``code`` into this process without llvmlite (whose
    library takes about 40 ms to load, more than the devices of a short run take to
    start): its code and constants laid out in one mapping, relocated, then made
    executable and read-only. The entry point's address.

    Only what numba's code generator gives in the JIT's code model is taken: sections that
    are not written, 64-bit absolute relocations, and 32-bit relative ones within the
    mapping; the unwinding tables are left out (the entry point catches every exception).

    Raises:
        KernelCodeError: not Linux on x86-64, or an object this linker does not take (a
            written section, another relocation, a symbol it cannot place); llvmlite's
            linker is the way then.
    """
    if sys.platform != "linux" or platform.machine() != "x86_64":
        raise KernelCodeError(f"no linker here for {sys.platform} {platform.machine()}")
    try:
        kind, machine = struct.unpack_from("<HH", code, 0x10)
        if code[:6] != b"\x7fELF\x02\x01" or (kind, machine) != (_ET_REL, _EM_X86_64):
            raise KernelCodeError("the object file is not a 64-bit x86 relocatable object")
        sections = _sections(code)
        places: dict[int, int] = {}
        end = 0
        for index, section in enumerate(sections):
            _, kind, flags, _, _, size, _, _, align, _ = section
            if not flags & _SHF_ALLOC or kind == _SHT_X86_64_UNWIND or not size:
                continue
            if flags & _SHF_WRITE:
                raise KernelCodeError("the object file has a section the code writes")
            end = -(-end // max(1, align)) * max(1, align)
            places[index] = end
            end += size
        image = bytearray(-(-max(end, 1) // _PAGE) * _PAGE)
        for index, start in places.items():
            _, kind, _, _, offset, size, _, _, _, _ = sections[index]
            if kind != _SHT_NOBITS:
                image[start : start + size] = code[offset : offset + size]
        base = _map(len(image))
        symbols: list[int | None] = []
        entry: int | None = None
        for name, index, value in _symbols(code, sections):
            if index == _SHN_UNDEF:
                symbols.append(addresses.get(name) if name else None)
            elif index == _SHN_ABS:
                symbols.append(value)
            elif index in places:
                symbols.append(base + places[index] + value)
                if name == SYMBOL:
                    entry = base + places[index] + value
            else:
                symbols.append(None)  # in a section left out: nothing loaded may use it
        for section in sections:
            target = places.get(section[7])
            if section[1] != _SHT_RELA or target is None:
                continue
            for offset in range(section[4], section[4] + section[5], 24):
                where, info, addend = struct.unpack_from("<QQq", code, offset)
                symbol = symbols[info >> 32]
                if symbol is None:
                    raise KernelCodeError("a relocation names a symbol not placed here")
                at = target + where
                kind = info & 0xFFFFFFFF
                if kind == _R_X86_64_64:
                    struct.pack_into("<Q", image, at, (symbol + addend) % (1 << 64))
                elif kind in (_R_X86_64_PC32, _R_X86_64_PLT32):
                    distance = symbol + addend - (base + at)
                    if not -(1 << 31) <= distance < 1 << 31:
                        raise KernelCodeError("a 32-bit relative relocation out of reach")
                    struct.pack_into("<i", image, at, distance)
                else:
                    raise KernelCodeError(f"relocation type {kind} is not linked here")
        if entry is None:
            raise KernelCodeError(f"the object file has no {SYMBOL}")
    except (struct.error, IndexError, ValueError, UnicodeDecodeError) as error:
        raise KernelCodeError(f"the object file is unreadable ({error})") from None
    ctypes.memmove(base, bytes(image), len(image))
    if _libc().mprotect(base, len(image), mmap.PROT_READ | mmap.PROT_EXEC) != 0:
        raise KernelCodeError(f"the code's memory cannot be made executable (errno"
                              f" {ctypes.get_errno()})")
    return entry


def _libc() -> Any:
    """The C library's ``mmap`` and ``mprotect``, typed."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.mmap.restype = ctypes.c_void_p
    libc.mmap.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int, ctypes.c_int,
                          ctypes.c_int, ctypes.c_long)
    libc.mprotect.restype = ctypes.c_int
    libc.mprotect.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
    return libc


def _map(size: int) -> int:
    """``size`` bytes of fresh memory, readable and writable, never unmapped.

    Raises:
        KernelCodeError: the system gives none.
    """
    address = _libc().mmap(None, size, mmap.PROT_READ | mmap.PROT_WRITE,
                           mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS, -1, 0)
    if not address or address == ctypes.c_void_p(-1).value:
        raise KernelCodeError(f"no memory mapped for the code (errno {ctypes.get_errno()})")
    _linked.append(address)
    return int(address)


class MachineKernel:
    """The loaded entry point as a block function: called as ``core1.servo_block`` is,
    ``(state, params, queue, curve, n_ticks)``, with C-contiguous writable ``int64``
    arrays (``curve`` may be read-only).

    The addresses of the arrays a device keeps (its state, parameters and queue) are
    remembered, each with the array itself, so that the same array is looked up once.

    Raises (on a call):
        TypeError: an array is not 1-D C-contiguous ``int64`` (writable, but for ``curve``).
        ArithmeticError: the block raised (:data:`RAISED`); the reference path names the
            exception.
    """

    __slots__ = ("_addresses", "_function")
    _REMEMBERED = 64

    def __init__(self, function: Any) -> None:
        self._function = function
        self._addresses: dict[int, tuple[IntArray, int]] = {}

    def _address(self, array: IntArray, writable: bool = True) -> int:
        known = self._addresses.get(id(array))
        if known is not None and known[0] is array:
            return known[1]
        if (not isinstance(array, np.ndarray) or array.dtype != np.int64 or array.ndim != 1
                or not array.flags.c_contiguous or (writable and not array.flags.writeable)):
            raise TypeError(
                "the servo kernel takes 1-D C-contiguous int64 arrays"
                f"{' it may write' if writable else ''}; got {type(array).__name__}"
                f" {getattr(array, 'dtype', '')} {getattr(array, 'shape', '')}")
        address: int = array.ctypes.data
        if writable:
            if len(self._addresses) >= self._REMEMBERED:
                self._addresses.clear()
            self._addresses[id(array)] = (array, address)
        return address

    def __call__(self, state: IntArray, params: IntArray, queue: IntArray, curve: IntArray,
                 n_ticks: int) -> int:
        curve_n = curve.size
        done: int = self._function(
            self._address(state), state.size, self._address(params), params.size,
            self._address(queue), queue.size,
            self._address(curve, writable=False) if curve_n else 0, curve_n, n_ticks)
        if done == RAISED:
            raise ArithmeticError("the servo kernel raised (the reference servo loop,"
                                  " USBMOTION_KERNEL=0, names the exception)")
        return done
