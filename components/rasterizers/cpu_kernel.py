"""Tile binning and the autograd Function around the C++ compositing kernel (``cpu`` backend).

Only compositing is compiled: projection, SH and the background stay in PyTorch autograd
(``projection.py``, ``sh.py``), so those semantics exist once. The kernel returns the
accumulated payload (colour channels + camera z) and the final transmittance; its backward
returns gradients for means2d, conics, opacities and the payload, like gsplat's
``rasterize_to_pixels``. Skip / stop decisions and tile coverage are constants, as in gsplat.
"""

from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass

import torch
from torch import Tensor

from components.native.pointers import tensor_ptr as _ptr

GRAD_GEOM = 6
"""Per-Gaussian gradient slots before the payload: mean x, mean y, conic a, b, c, opacity."""
FIXED_SCHEDULE = True
"""Backward hands tiles to threads round-robin (thread t: tiles t, t + T, ...) instead of first come,
first served, so each thread's gradient sums, and their total, are the same on every call."""


@dataclass
class Bins:
    """Per-tile lists of Gaussians, front to back (tiles numbered camera-major, then row-major)."""

    order: Tensor  # [C, N] int64 each camera's Gaussians front to back (culled last)
    offsets: Tensor  # [C * tiles_y * tiles_x + 1] int32, list of tile t = gids[offsets[t]:offsets[t+1]]
    gids: Tensor  # [P] int32 c * N + rank, rank = position in order[c]
    tile_size: int

    @property
    def num_pairs(self) -> int:
        return self.gids.numel()


@torch.no_grad()
def tile_rects(means2d: Tensor, radii: Tensor, width: int, height: int, tile_size: int) -> Tensor:
    """Tile range ``[x0, x1) x [y0, y1)`` [C, N, 4] int32 of each radius box; empty when culled.

    ``radii`` [C, N, 2] are the per-axis half-extents. Same float expressions as the reference's
    binning (``floor(x/ts - r/ts)`` .. ``ceil(x/ts + r/ts)``), so both backends cover the same tiles.
    """
    ts = float(tile_size)
    tiles_x, tiles_y = math.ceil(width / tile_size), math.ceil(height / tile_size)
    r = radii.to(means2d.dtype) / ts  # [C, N, 2]
    mx, my = means2d[..., 0], means2d[..., 1]
    rects = torch.stack(
        [
            torch.floor(mx / ts - r[..., 0]).clamp(0, tiles_x),
            torch.ceil(mx / ts + r[..., 0]).clamp(0, tiles_x),
            torch.floor(my / ts - r[..., 1]).clamp(0, tiles_y),
            torch.ceil(my / ts + r[..., 1]).clamp(0, tiles_y),
        ],
        dim=-1,
    ).to(torch.int32)  # [C, N, 4]
    return rects * (radii.amax(dim=-1) > 0)[..., None]


@torch.no_grad()
def bin_gaussians(
    lib: ctypes.CDLL, means2d: Tensor, depths: Tensor, radii: Tensor, width: int, height: int, tile_size: int
) -> Bins:
    """Front-to-back Gaussian lists of every tile (depth sort in torch, counting sort in C++)."""
    C, N = radii.shape[:2]
    tiles_x, tiles_y = math.ceil(width / tile_size), math.ceil(height / tile_size)
    rects = tile_rects(means2d.detach(), radii, width, height, tile_size).contiguous()  # [C, N, 4]
    area = (rects[..., 1] - rects[..., 0]).long() * (rects[..., 3] - rects[..., 2]).long()
    num_pairs = int(area.sum())
    if num_pairs >= 2**31 or C * N >= 2**31:
        raise ValueError(f"{num_pairs} tile-Gaussian pairs exceed the int32 kernel indices")
    # culled Gaussians sort last with an empty rect; ties keep the index order (stable), like gsplat
    key = depths.detach().masked_fill(radii.amax(dim=-1) <= 0, math.inf)
    order = torch.argsort(key, dim=1, stable=True).contiguous()  # [C, N] int64
    offsets = torch.empty(C * tiles_x * tiles_y + 1, dtype=torch.int32)
    gids = torch.empty(num_pairs, dtype=torch.int32)
    lib.tdh_bin(C, N, tiles_x, tiles_y, _ptr(order), _ptr(rects), _ptr(offsets), _ptr(gids))
    return Bins(order=order, offsets=offsets, gids=gids, tile_size=tile_size)


@torch.no_grad()
def composite_forward(
    lib: ctypes.CDLL,
    means2d: Tensor,  # [C, N, 2]
    conics: Tensor,  # [C, N, 3]
    opacities: Tensor,  # [C, N]
    payload: Tensor,  # [C, N, nc]
    bins: Bins,
    width: int,
    height: int,
    threads: int,
    count: bool = False,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor | None]:
    """Run the forward kernel: packed records, acc [C, H, W, nc], T [C, H, W, 1], end indices
    [C, H, W] and, with ``count``, the number of Gaussians blended into each pixel [C, H, W]."""
    C, N, nc = payload.shape
    ins = [t.detach().contiguous() for t in (means2d, conics, opacities, payload)]
    if any(t.dtype != torch.float32 or t.device.type != "cpu" for t in ins):
        raise TypeError("the cpu rasterizer kernel takes float32 CPU tensors")
    if nc > lib.tdh_max_channels():
        raise ValueError(f"the cpu kernel blends at most {lib.tdh_max_channels() - 1} colour channels")
    # one cache line per Gaussian, in depth order: tiles read one record per list entry
    packed = torch.empty(C * N, lib.tdh_pack_stride(nc))
    lib.tdh_pack(threads, C, N, nc, _ptr(bins.order), *map(_ptr, ins), _ptr(packed))
    acc = torch.empty(C, height, width, nc)
    trans = torch.empty(C, height, width, 1)
    last = torch.empty(C, height, width, dtype=torch.int32)
    counts = torch.empty(C, height, width, dtype=torch.int32) if count else None
    lib.tdh_forward(
        threads, C, N, height, width, bins.tile_size, nc, _ptr(packed), _ptr(bins.offsets), _ptr(bins.gids),
        _ptr(acc), _ptr(trans), _ptr(last), _ptr(counts),
    )  # fmt: skip
    return packed, acc, trans, last, counts


class CompositeFn(torch.autograd.Function):
    """``(means2d, conics, opacities, payload) -> (acc [C, H, W, nc], T [C, H, W, 1])`` on CPU float32.

    ``payload [C, N, nc]`` holds whatever is alpha-blended (colour channels, then camera z);
    ``T`` is the final transmittance, so ``alpha = 1 - T`` and the background adds ``T * bg``.
    """

    @staticmethod
    def forward(
        ctx,
        means2d: Tensor,  # [C, N, 2]
        conics: Tensor,  # [C, N, 3]
        opacities: Tensor,  # [C, N]
        payload: Tensor,  # [C, N, nc]
        lib: ctypes.CDLL,
        bins: Bins,
        width: int,
        height: int,
        threads: int,
    ) -> tuple[Tensor, Tensor]:
        packed, acc, trans, last, _ = composite_forward(
            lib, means2d, conics, opacities, payload, bins, width, height, threads
        )
        ctx.save_for_backward(packed, trans, last)
        ctx.lib, ctx.bins, ctx.threads, ctx.dims = lib, bins, threads, (*payload.shape, width, height)
        return acc, trans

    @staticmethod
    def backward(ctx, v_acc: Tensor, v_trans: Tensor):
        packed, trans, last = ctx.saved_tensors
        C, N, nc, width, height = ctx.dims
        bins = ctx.bins
        grads = torch.empty(C, N, GRAD_GEOM + nc)
        v_acc, v_trans = v_acc.float().contiguous(), v_trans.float().contiguous()  # alive during the call
        ctx.lib.tdh_backward(
            ctx.threads, C, N, height, width, bins.tile_size, nc, _ptr(packed), _ptr(bins.offsets), _ptr(bins.gids),
            _ptr(trans), _ptr(last), _ptr(v_acc), _ptr(v_trans), _ptr(bins.order), _ptr(grads),
            int(FIXED_SCHEDULE),
        )  # fmt: skip
        return (
            grads[..., 0:2],
            grads[..., 2:5],
            grads[..., 5],
            grads[..., GRAD_GEOM:],
            None,
            None,
            None,
            None,
            None,
        )
