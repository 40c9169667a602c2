"""Build the portable firmware sources for this machine, for tests that compare them with the
Python device without an emulator (a shared library for ctypes, or an executable).

The portable code (``firmware/src/device``) has no hardware in it; compiled here with the
same warnings as the firmware (errors included), it runs the same integer operations. The
emulator tests (``tests/firmware/test_emulated_*``) prove the RP2040 build itself.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import threading
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DEVICE_SOURCES = ROOT / "firmware" / "src" / "device"
CACHE = ROOT / "build" / "native"
FLAGS = ("-std=c11", "-O2", "-Wall", "-Wextra", "-Werror", "-Wshadow", "-Wconversion",
         "-Wno-sign-conversion", "-fno-strict-aliasing", "-ffp-contract=off")


def compiler() -> str:
    """The C compiler to use (``CC``, else cc or gcc)."""
    found = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if not found:
        raise RuntimeError("no C compiler: install gcc (apt-get install gcc) or set CC")
    return found


def build(name: str, sources: Sequence[Path], *, shared: bool,
          defines: Sequence[str] = ()) -> Path:
    """Compile ``sources`` (and the headers beside them) once; returns the output's path.

    The output is cached under ``build/native`` by a hash of every source and header and of
    the flags, so an edit rebuilds and an unchanged tree does not. Each source is compiled
    to an object file of its own, cached by the same hash with its own text in place of the
    others', and the objects are linked: builds that differ in one source (the mutants of
    test_native_servo) compile only that one.
    """
    digest = hashlib.sha256()
    headers = sorted({h for s in sources for h in s.parent.glob("*.h")})
    for path in [*sources, *headers]:
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    options = [*FLAGS, *(f"-D{d}" for d in defines)]
    digest.update(" ".join(options).encode())
    digest.update(b"shared" if shared else b"exe")
    suffix = ".so" if shared else ""
    out = CACHE / f"{name}-{digest.hexdigest()[:16]}{suffix}"
    if out.exists():
        return out
    CACHE.mkdir(parents=True, exist_ok=True)
    includes = sorted({f"-I{s.parent}" for s in sources})
    position = ["-fPIC"] if shared else []
    objects = [_object(source, headers, [*options, *position], includes) for source in sources]
    partial = f"{out}.{os.getpid()}.{threading.get_ident()}.tmp"
    command = [compiler(), *options, *(["-shared", "-fPIC"] if shared else []), "-o", partial,
               *map(str, objects), "-lm"]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"linking {name} failed:\n{' '.join(command)}\n{result.stderr}")
    os.replace(partial, out)
    return out


def _object(source: Path, headers: Sequence[Path], options: Sequence[str],
            includes: Sequence[str]) -> Path:
    """``source`` compiled with ``options``, its headers found through ``includes`` (once:
    cached by its text, the headers' and the options, wherever the files lie)."""
    digest = hashlib.sha256()
    for path in [source, *headers]:
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    digest.update(" ".join(options).encode())
    out = CACHE / "objects" / f"{source.stem}-{digest.hexdigest()[:16]}.o"
    if out.exists():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = f"{out}.{os.getpid()}.{threading.get_ident()}.tmp"
    command = [compiler(), *options, *includes, "-c", "-o", partial, str(source)]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise RuntimeError(f"compiling {source} failed:\n{' '.join(command)}\n{result.stderr}")
    os.replace(partial, out)
    return out


def load(name: str, sources: Sequence[Path], *, defines: Sequence[str] = ()) -> ctypes.CDLL:
    """Build ``sources`` as a shared library and load it."""
    return ctypes.CDLL(str(build(name, sources, shared=True, defines=defines)))
