"""The ``cpu`` rasterizer's C++ kernel: its source, ABI and ctypes signatures (built by
:mod:`components.native.build`)."""

from __future__ import annotations

import ctypes
from pathlib import Path

from components.native.build import KernelUnavailable, NativeLibrary

SOURCE = Path(__file__).with_name("csrc") / "cpu_raster.cpp"
ABI_VERSION = 4
"""Must equal ``tdh_abi_version()`` of the source; guards against a stale cached library."""

__all__ = ["ABI_VERSION", "LIBRARY", "SOURCE", "KernelUnavailable", "load_kernel"]


def _declare(lib: ctypes.CDLL) -> None:
    i32, ptr = ctypes.c_int, ctypes.c_void_p
    lib.tdh_max_channels.restype = i32
    lib.tdh_pack_stride.restype = i32
    lib.tdh_pack_stride.argtypes = [i32]
    lib.tdh_bin.argtypes = [i32] * 4 + [ptr] * 4
    lib.tdh_pack.argtypes = [i32] * 4 + [ptr] * 6  # leading int: threads
    lib.tdh_forward.argtypes = [i32] * 7 + [ptr] * 7
    lib.tdh_backward.argtypes = [i32] * 7 + [ptr] * 9 + [i32]  # trailing int: fixed schedule
    for fn in (lib.tdh_bin, lib.tdh_pack, lib.tdh_forward, lib.tdh_backward):
        fn.restype = None


LIBRARY = NativeLibrary("cpu_raster", SOURCE, "tdh_abi_version", ABI_VERSION, _declare)


def load_kernel() -> ctypes.CDLL:
    """The rasterizer's loaded kernel, compiled on first use; raises :class:`KernelUnavailable`."""
    return LIBRARY.load()
