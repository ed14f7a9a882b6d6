"""Each pixel's T and S read from the coarse rays' tables: a torch reference and a C++ kernel.

The compositor marches a coarse grid of rays and keeps one table row per interval boundary; each
pixel then reads its four nearest rays at its own depth (the torch path below says how). On CPU
that read-out was the medium's largest cost: some thirty elementwise ops on [4, H*W] tensors per
direction, each allocating and filling a full tensor. The kernel
(``csrc/pixel_readout.cpp``) does the same arithmetic in one pass per pixel, forward and backward,
for float32 and float64, with the gradient into the table and (where asked) into each pixel's
depth; the torch path stays the reference and serves every other case (CUDA, other dtypes, no
compiler). Parity and gradients:
tests/medium/test_pixel_readout.py; speed: benchmarks/iteration_cost.py.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from components.native.build import KernelUnavailable, NativeLibrary
from components.native.pointers import tensor_ptr as _ptr

ROW = 9
"""Table columns per boundary: Tau, tau, T, S (3), L (3)."""


def _declare(lib: ctypes.CDLL) -> None:
    i64, i32, ptr = ctypes.c_int64, ctypes.c_int, ctypes.c_void_p
    for suffix in ("f32", "f64"):
        fwd = getattr(lib, f"tdh_readout_forward_{suffix}")
        fwd.argtypes, fwd.restype = [i64, i32, i32] + [ptr] * 10, None
        bwd = getattr(lib, f"tdh_readout_backward_{suffix}")
        bwd.argtypes, bwd.restype = [i64, i32, i64, i32] + [ptr] * 12, None


LIBRARY = NativeLibrary(
    "pixel_readout",
    Path(__file__).with_name("csrc") / "pixel_readout.cpp",
    "tdh_readout_abi_version",
    2,
    _declare,
)


@dataclass
class ReadoutGrid:
    """What a per-pixel read needs from the coarse march of one view."""

    table: Tensor  # [R * (K + 1), 9] Tau_k, tau_k, T_k, S_k (3), L_k (3) per ray and boundary
    rays: Tensor  # [4, P] integer: the four nearest coarse rays of each pixel
    wgt: Tensor  # [4, P] their bilinear weights
    pix_len: Tensor  # [P] path length per unit z of each pixel's own ray
    ray_len: Tensor  # [R] the same for each coarse ray
    zfar: Tensor  # [R] z each coarse ray was marched to (detached)
    K: int  # intervals per ray


def kernel_available() -> bool:
    try:
        LIBRARY.load()
    except KernelUnavailable:
        return False
    return True


def read_torch(
    grid: ReadoutGrid, zq: Tensor, last_light: bool = False
) -> tuple[Tensor, Tensor, Tensor | None]:
    """Optical depth [P], scattering [P, 3] and (``last_light``) the light of the last interval
    read [P, 3] at z ``zq`` [1, P]: each neighbour read at the pixel's depth and rescaled to the
    pixel's own path length (exact for a homogeneous medium). Autograd reaches ``zq`` too."""
    K, rays, wgt = grid.K, grid.rays, grid.wgt
    zfar_r = grid.zfar[rays]  # [4, P]
    r = grid.pix_len[None] / grid.ray_len[rays]  # [4, P] ~1: obliquity of the pixel vs the coarse ray
    P = rays.shape[1]
    pos = (zq / zfar_r.clamp_min(1e-12)).clamp(0, 1) * K  # [4, P] position in intervals
    k = pos.detach().floor().clamp(max=K - 1).long()
    f = pos - k.to(pos)  # fraction of interval k covered
    row = grid.table.index_select(0, (rays * (K + 1) + k).reshape(-1)).reshape(4, P, ROW)
    # one split, not five slices: each slice's backward zero-fills a full [4, P, 9] gradient
    Tau_k, tau_k, T_k, S_k, L_k = row.split((1, 1, 1, 3, 3), dim=-1)
    Tau_k, tau_k, T_k = Tau_k[..., 0], tau_k[..., 0], T_k[..., 0]  # [4, P] each
    t_ray = Tau_k + f * tau_k  # [4, P] optical depth along the coarse ray to z
    s_ray = S_k + (T_k * -torch.expm1(-f * tau_k))[..., None] * L_k  # [4, P, 3]
    t_pix = t_ray * r
    # S is a light-weighted scattered fraction 1 - T: keep the weighting, rescale the fraction
    den = -torch.expm1(-t_ray)
    frac = torch.where(den > 1e-7, -torch.expm1(-t_pix) / den.clamp_min(1e-7), r)
    light = (wgt[..., None] * L_k).sum(0) if last_light else None  # [P, 3]
    return (wgt * t_pix).sum(0), ((wgt * frac)[..., None] * s_ray).sum(0), light


class _ReadoutFn(torch.autograd.Function):
    """The kernel's read; gradients reach the table and, where it asks for one, the depth ``zq``."""

    @staticmethod
    def forward(ctx, table: Tensor, grid: ReadoutGrid, zq: Tensor, last_light: bool, threads: int):
        lib, suffix = LIBRARY.load(), "f32" if table.dtype == torch.float32 else "f64"
        g = _contiguous(grid, table)
        P = g.rays.shape[1]
        ctx.zq_shape, ctx.zq_dtype = zq.shape, zq.dtype
        zq = zq.detach().reshape(-1).to(table.dtype).contiguous()
        tau, S = table.new_empty(P), table.new_empty(P, 3)
        L = table.new_empty(P, 3) if last_light else None
        getattr(lib, f"tdh_readout_forward_{suffix}")(
            P, g.K, threads, *map(_ptr, (g.table, g.rays, g.wgt, g.pix_len, g.ray_len, g.zfar, zq)),
            _ptr(tau), _ptr(S), _ptr(L),
        )  # fmt: skip
        ctx.grid, ctx.zq, ctx.threads, ctx.last_light = g, zq, threads, last_light
        if last_light:
            return tau, S, L
        return tau, S

    @staticmethod
    def backward(ctx, g_tau: Tensor, g_S: Tensor, g_L: Tensor | None = None):
        g = ctx.grid
        lib, suffix = LIBRARY.load(), "f32" if g.table.dtype == torch.float32 else "f64"
        R = g.ray_len.numel()
        grad = torch.empty_like(g.table)
        # contiguous copies bound to names: a temporary would be freed before the kernel runs
        g_tau, g_S = g_tau.contiguous(), g_S.contiguous()
        g_L = g_L.contiguous() if ctx.last_light and g_L is not None else None
        g_zq = torch.empty_like(ctx.zq) if ctx.needs_input_grad[2] else None
        getattr(lib, f"tdh_readout_backward_{suffix}")(
            g.rays.shape[1], g.K, R, ctx.threads,
            *map(_ptr, (g.table, g.rays, g.wgt, g.pix_len, g.ray_len, g.zfar, ctx.zq)),
            _ptr(g_tau), _ptr(g_S), _ptr(g_L), _ptr(grad), _ptr(g_zq),
        )  # fmt: skip
        if g_zq is not None:
            g_zq = g_zq.to(ctx.zq_dtype).reshape(ctx.zq_shape)
        return grad, None, g_zq, None, None


def _contiguous(grid: ReadoutGrid, table: Tensor) -> ReadoutGrid:
    """The grid in the table's dtype, every tensor contiguous (what the kernel's pointers assume)."""
    dt = table.dtype
    return ReadoutGrid(
        table=table.detach().contiguous(),
        rays=grid.rays.to(torch.int32).contiguous(),
        wgt=grid.wgt.detach().to(dt).contiguous(),
        pix_len=grid.pix_len.detach().reshape(-1).to(dt).contiguous(),
        ray_len=grid.ray_len.detach().reshape(-1).to(dt).contiguous(),
        zfar=grid.zfar.detach().reshape(-1).to(dt).contiguous(),
        K=grid.K,
    )


def uses_kernel(grid: ReadoutGrid, zq: Tensor) -> bool:
    """Whether :func:`read_pixels` takes the kernel for this read: CPU float32 / float64 and a
    compiler that built it."""
    t = grid.table
    if t.device.type != "cpu" or t.dtype not in (torch.float32, torch.float64):
        return False
    if t.numel() >= 2**31:  # the kernel indexes the table with int32
        return False
    return kernel_available()


def read_pixels(
    grid: ReadoutGrid, zq: Tensor, last_light: bool = False, fused: bool = True
) -> tuple[Tensor, Tensor, Tensor | None]:
    """:func:`read_torch`'s values, from the kernel where :func:`uses_kernel` allows and ``fused``."""
    if not (fused and uses_kernel(grid, zq)):
        return read_torch(grid, zq, last_light)
    out = _ReadoutFn.apply(grid.table, grid, zq, last_light, torch.get_num_threads())
    return (out[0], out[1], out[2]) if last_light else (out[0], out[1], None)
