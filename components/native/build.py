"""Compile-on-first-use and cache of a component's C++ kernel library, loaded with ctypes.

Why not ``torch.utils.cpp_extension``: parsing the torch headers costs about a minute, whereas
the kernels have a plain C ABI and build with the system compiler in about a second. Each
:class:`NativeLibrary` (the ``cpu`` rasterizer's, the medium's per-pixel read-out) is cached
under ``$TRIDEHAZE_CACHE/kernels`` (else ``~/.cache/tridehaze/kernels``) with a name hashing the
source text, the flags, the compiler's version and the machine, so an edit, an upgrade or another
CPU gives a fresh build. It is written to a temporary file and renamed into place, so concurrent
processes never load a half-written library. This module imports no torch (the concurrency test
loads it alone).

Two parallel builds: ``openmp`` (preferred) links ``libgomp.so.1``; loaded after torch, the
dynamic loader resolves that soname to the copy torch already loaded, so kernel and torch share one
thread pool whose workers are already awake (measured fastest, docs/rasterizer.md "Speed").
``threads`` (std::thread) is the fallback for compilers without OpenMP.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import re
import shutil
import subprocess
import tempfile
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

CACHE_ENV_VAR = "TRIDEHAZE_CACHE"
PARALLEL_ENV_VAR = "TRIDEHAZE_CPU_PARALLEL"
"""``openmp`` or ``threads`` forces one build variant (default: the first that builds)."""

# -ffast-math lets the lane loops vectorise (reassociation, no NaN checks); it is passed at the
# compile step only: linking with it would pull in crtfastmath.o, whose constructor switches the
# whole process (torch included) to flush-denormals-to-zero.
COMPILE_FLAGS: tuple[str, ...] = (
    "-O3",
    "-march=native",
    "-ffast-math",
    "-fopenmp-simd",
    "-std=c++17",
    "-fPIC",
)
LINK_FLAGS: tuple[str, ...] = ("-shared", "-pthread")


@dataclass(frozen=True)
class Variant:
    name: str
    compile_flags: tuple[str, ...] = ()
    link_flags: tuple[str, ...] = ()


VARIANTS: tuple[Variant, ...] = (
    Variant("openmp", ("-fopenmp", "-DTDH_OPENMP"), ("-fopenmp",)),
    Variant("threads"),
)

BUILD_COUNT = 0
"""How many times this process ran the compiler (tests check that the cache is reused)."""

_lock = threading.Lock()
_cache: dict[tuple, ctypes.CDLL | Exception] = {}


class KernelUnavailable(RuntimeError):
    """The kernel cannot be built or loaded here; the message says why, in one line."""


def find_compiler() -> str:
    """``$CXX`` if set (it must exist), else the first of ``g++``, ``c++``, ``clang++`` on PATH."""
    env = os.environ.get("CXX")
    if env:
        path = shutil.which(env)
        if path is None:
            raise KernelUnavailable(f"compiler CXX={env!r} not found")
        return path
    for name in ("g++", "c++", "clang++"):
        path = shutil.which(name)
        if path:
            return path
    raise KernelUnavailable("no C++ compiler (g++, c++ or clang++) on PATH")


def cache_dir() -> Path:
    env = os.environ.get(CACHE_ENV_VAR)
    root = Path(env).expanduser() if env else Path.home() / ".cache" / "tridehaze"
    return root / "kernels"


def _machine_tag() -> str:
    """CPU model and feature flags: ``-march=native`` code only runs on such a CPU."""
    parts = [platform.machine(), platform.system()]
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.startswith(("model name", "flags", "Features")):
                    parts.append(line.strip())
                if not line.strip():
                    break  # the first processor is enough
    except OSError:
        parts.append(platform.processor())
    return "\n".join(parts)


def _compiler_version(cxx: str) -> str:
    try:
        res = subprocess.run([cxx, "--version"], capture_output=True, text=True, timeout=60, check=True)
    except (OSError, subprocess.SubprocessError) as err:
        raise KernelUnavailable(f"compiler {cxx} does not run: {err}") from err
    return res.stdout


def local_includes(source: Path) -> list[Path]:
    """``source`` and every file it pulls in with ``#include "..."``, recursively: all of them go
    into the cache key, so an edited shared header rebuilds the kernels that use it."""
    seen: list[Path] = []
    todo = [source.resolve()]
    while todo:
        f = todo.pop()
        if f in seen:
            continue
        seen.append(f)
        for name in _INCLUDE.findall(f.read_text(encoding="utf-8")):
            todo.append((f.parent / name).resolve())
    return seen


_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.MULTILINE)


def _commands(cxx: str, variant: Variant, source: Path, obj: Path, lib: Path) -> list[list[str]]:
    return [
        [cxx, *COMPILE_FLAGS, *variant.compile_flags, "-c", str(source), "-o", str(obj)],
        [cxx, *LINK_FLAGS, *variant.link_flags, str(obj), "-o", str(lib)],
    ]


@dataclass(frozen=True)
class NativeLibrary:
    """One C++ source built into one shared library, checked by its ABI version on load.

    ``declare`` sets the ctypes signatures of the library's entry points (their ``argtypes`` and
    ``restype``); the component owning the source owns its signatures.
    """

    name: str
    source: Path
    abi_symbol: str
    """Entry point returning the source's ABI version (an int, no arguments)."""
    abi_version: int
    """Must equal what ``abi_symbol`` returns; guards against a stale cached library."""
    declare: Callable[[ctypes.CDLL], None] | None = None

    def library_path(self, cxx: str, variant: Variant) -> Path:
        """Where the build for this source, variant, flags, compiler and machine is cached."""
        h = hashlib.sha256()
        for part in (
            *(f.read_bytes() for f in local_includes(self.source)),
            repr(_commands("", variant, Path(), Path(), Path())).encode(),
            cxx.encode(),
            _compiler_version(cxx).encode(),
            _machine_tag().encode(),
        ):
            h.update(part)
            h.update(b"\0")
        return cache_dir() / f"{self.name}-{variant.name}-{h.hexdigest()[:20]}.so"

    def _compile(self, cxx: str, variant: Variant, out: Path) -> None:
        global BUILD_COUNT
        out.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=out.stem + "-", suffix=".tmp", dir=out.parent)
        os.close(fd)
        tmp = Path(tmp_name)
        obj = tmp.with_suffix(".o")
        BUILD_COUNT += 1
        try:
            for cmd in _commands(cxx, variant, self.source, obj, tmp):
                res = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
                if res.returncode != 0:
                    last = (res.stderr.strip().splitlines() or ["(no output)"])[-1]
                    raise KernelUnavailable(f"compiling {self.source.name} failed: {last}")
            os.replace(tmp, out)  # atomic: readers see no file or the whole new one
        except (OSError, subprocess.SubprocessError) as err:
            raise KernelUnavailable(f"compiling {self.source.name} failed: {err}") from err
        finally:
            for p in (tmp, obj):
                p.unlink(missing_ok=True)

    def _load_variant(self, cxx: str, variant: Variant) -> ctypes.CDLL:
        path = self.library_path(cxx, variant)
        failed = path.with_suffix(".failed")  # a variant that does not build here is not retried
        if failed.exists():
            raise KernelUnavailable(failed.read_text(encoding="utf-8", errors="replace").strip())
        if not path.exists():
            try:
                self._compile(cxx, variant, path)
            except KernelUnavailable as err:
                try:
                    failed.write_text(str(err), encoding="utf-8")
                except OSError:
                    pass
                raise
        try:
            lib = ctypes.CDLL(str(path))
        except OSError as err:
            raise KernelUnavailable(f"loading {path.name} failed: {err}") from err
        abi = getattr(lib, self.abi_symbol)
        abi.restype, abi.argtypes = ctypes.c_int, []
        if abi() != self.abi_version:
            raise KernelUnavailable(
                f"cached {self.name} kernel has a different ABI version; delete the kernel cache"
            )
        lib.tdh_variant = variant.name
        if self.declare is not None:
            self.declare(lib)
        return lib

    def load(self) -> ctypes.CDLL:
        """The loaded library, compiled on first use; raises :class:`KernelUnavailable`.

        Tries the build variants in order (``$TRIDEHAZE_CPU_PARALLEL`` picks one). The outcome,
        library or failure, is remembered per process and setting, so a missing compiler costs one
        lookup, not one per call.
        """
        forced = os.environ.get(PARALLEL_ENV_VAR, "")
        key = (self.name, os.environ.get("CXX"), os.environ.get(CACHE_ENV_VAR), forced)
        with _lock:
            hit = _cache.get(key)
            if hit is None:
                variants = [v for v in VARIANTS if v.name == forced] if forced else list(VARIANTS)
                hit = KernelUnavailable(f"{PARALLEL_ENV_VAR}={forced!r} is not one of openmp, threads")
                try:
                    cxx = find_compiler()
                    for variant in variants:
                        try:
                            hit = self._load_variant(cxx, variant)
                            break
                        except KernelUnavailable as err:
                            hit = err
                except KernelUnavailable as err:
                    hit = err
                except OSError as err:  # e.g. the source file was not installed with the package
                    hit = KernelUnavailable(f"{type(err).__name__}: {err}")
                _cache[key] = hit
        if isinstance(hit, Exception):
            raise hit
        return hit


def forget() -> None:
    """Drop the per-process memo of every library (tests use it to exercise a fresh lookup)."""
    with _lock:
        _cache.clear()
