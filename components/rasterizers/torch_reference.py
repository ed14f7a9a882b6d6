"""Pure-PyTorch reference rasterizer (backend ``torch``): any device, float32 or float64, autograd.

It reproduces gsplat's classic forward pass (docs/rasterizer.md) without custom kernels:

1. project (``projection.py``) and order each camera's visible Gaussians front to back;
2. walk them front to back in chunks. For each chunk, *without grad*: list the candidate
   (pixel, Gaussian) pairs -- pixels of the tiles the radius box overlaps (gsplat's tile
   binning), cut to the box where ``opacity * exp(-sigma)`` can still reach 1/255 -- drop the
   pairs gsplat skips (``sigma < 0`` or ``alpha < 1/255``) or whose pixel already stopped, sort
   them per pixel and apply the exclusive ``T <= 1e-4`` stop rule with the transmittance carried
   over from earlier chunks;
3. *with grad*: recompute alpha for the surviving pairs only and composite them with a per-pixel
   exclusive cumulative product. The graph therefore holds contributing pairs only, and
   Gaussians whose box only covers finished pixels are never expanded (opaque scenes stay cheap).

The skip / stop decisions are constants for autograd, exactly like gsplat's backward kernel.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import torch
from torch import Tensor

from components.gaussians.sh import sh_to_colors
from components.rasterizers.base import RasterizeOutput, Rasterizer, RasterizerConfig, check_inputs
from components.rasterizers.projection import ALPHA_MIN, camera_centers, project_gaussians
from tridehaze_plugin.registry import register

ALPHA_MAX = 0.999
"""Per-Gaussian alpha is clamped here so one splat never makes a pixel fully opaque."""
T_MIN = 1e-4
"""A pixel stops at the first Gaussian that would bring its transmittance to <= this (exclusive)."""


class TorchRasterizer(Rasterizer):
    """Reference rasterizer in plain PyTorch: slow-ish but exact, portable and differentiable."""

    name = "torch"

    def __init__(self, config: RasterizerConfig | None = None, *, chunk_elems: int = 1 << 20) -> None:
        super().__init__(config)
        self.chunk_elems = int(chunk_elems)
        """Bound on the elements of each intermediate chunk (pairs, padded scan rows): memory knob."""

    def rasterize(
        self,
        means: Tensor,
        quats: Tensor,
        scales: Tensor,
        opacities: Tensor,
        colors: Tensor,
        viewmats: Tensor,
        Ks: Tensor,
        width: int,
        height: int,
        background: Tensor | None = None,
        sh_degree: int | None = None,
    ) -> RasterizeOutput:
        check_inputs(means, quats, scales, opacities, colors, viewmats, Ks, sh_degree)
        cfg = self.config
        width, height = int(width), int(height)
        proj = project_gaussians(
            means,
            quats,
            scales,
            viewmats,
            Ks,
            width,
            height,
            cfg.near_plane,
            cfg.far_plane,
            cfg.eps2d,
            opacities=opacities,
        )
        means2d = proj.means2d  # [C, N, 2]
        if means2d.requires_grad:
            means2d.retain_grad()  # densification reads the screen-space gradient
        if sh_degree is not None:
            dirs = means[None, :, :] - camera_centers(viewmats)[:, None, :]  # [C, N, 3]
            colors = sh_to_colors(sh_degree, colors[None], dirs)  # [C, N, 3]
        rgb, alpha, depth_accum = composite(
            means2d,
            proj.conics,
            proj.depths,
            proj.radii,
            proj.cov2d_diag,
            opacities,
            colors,
            width,
            height,
            cfg.tile_size,
            background,
            self.chunk_elems,
        )
        depth = depth_accum / alpha.clamp_min(1e-10)  # [C, H, W, 1], 0 where nothing was hit
        radii = proj.radii.amax(dim=-1)  # [C, N]
        return RasterizeOutput(
            rgb=rgb,
            depth=depth,
            alpha=alpha,
            means2d=means2d,
            radii=radii,
            visible=radii > 0,
            depth_accum=depth_accum,
            depths=proj.depths,
        )


register("rasterizer", "torch", TorchRasterizer)


# --------------------------------------------------------------------------------------
# compositing


def composite(
    means2d: Tensor,  # [C, N, 2]
    conics: Tensor,  # [C, N, 3]
    depths: Tensor,  # [C, N]
    radii: Tensor,  # [C, N, 2] int box half-extents (x, y)
    cov2d_diag: Tensor,  # [C, N, 2]
    opacities: Tensor,  # [N]
    colors: Tensor,  # [N, D] or [C, N, D]
    width: int,
    height: int,
    tile_size: int = 16,
    background: Tensor | None = None,  # [C, D] or [D]
    chunk_elems: int = 1 << 20,
) -> tuple[Tensor, Tensor, Tensor]:
    """Front-to-back alpha compositing -> rgb [C, H, W, D], alpha [C, H, W, 1], depth_accum [C, H, W, 1]."""
    C, N = radii.shape[:2]
    D = colors.shape[-1]
    hw = height * width
    # packed per-Gaussian attributes: one gather per chunk and side; unbind (not column slicing)
    # keeps the backward to a single stack
    geom = torch.cat([means2d, conics, opacities[None, :, None].expand(C, N, 1)], dim=-1).reshape(C * N, 6)
    payload = torch.cat([depths[..., None], colors.expand(C, N, D)], dim=-1).reshape(C * N, 1 + D)
    frontier = _Frontier(means2d, conics, depths, radii, cov2d_diag, opacities, width, height, tile_size)
    trans = geom.new_ones(C * hw)  # [C*H*W] transmittance so far (differentiable)
    acc = geom.new_zeros(C * hw, 1 + D)  # [C*H*W, 1 + D] accumulated depth and colour
    done = torch.zeros(C * hw, dtype=torch.bool, device=geom.device)  # pixel already stopped
    needs_grad = torch.is_grad_enabled() and geom.requires_grad
    for pix, gid, alpha_nograd in frontier.chunks(chunk_elems, done):
        with torch.no_grad():  # stop rule; pix is sorted, each pixel's pairs front to back
            _, seg = torch.unique_consecutive(pix, return_counts=True)
            t_excl, _ = _segmented_exclusive_cumprod(1.0 - alpha_nograd, seg, chunk_elems)
            t = trans.detach().index_select(0, pix) * t_excl
            keep = t * (1.0 - alpha_nograd) > T_MIN  # transmittance is monotone: a per-pixel prefix
            done[pix[~keep]] = True
            pix, gid = pix[keep], gid[keep]
            upix, seg = torch.unique_consecutive(pix, return_counts=True)
        if pix.numel() == 0:
            continue
        if needs_grad:  # recompute alpha on the graph; the values equal alpha_nograd[keep] exactly
            mx, my, ca, cb, cc, op = geom.index_select(0, gid).unbind(-1)  # [K] each
            px = (pix % width).to(geom.dtype) + 0.5
            py = ((pix // width) % height).to(geom.dtype) + 0.5
            dx, dy = mx - px, my - py
            sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
            alpha = torch.clamp_max(op * torch.exp(-sigma), ALPHA_MAX)  # [K]
        else:
            alpha = alpha_nograd[keep]
        t_excl, t_seg = _segmented_exclusive_cumprod(1.0 - alpha, seg, chunk_elems)
        w = alpha * (trans.index_select(0, pix) * t_excl)  # [K] blending weights
        acc = acc.index_add(0, pix, w[:, None] * payload.index_select(0, gid))
        trans = trans.index_put((upix,), trans.index_select(0, upix) * t_seg)
    if not acc.requires_grad and torch.is_grad_enabled() and (geom.requires_grad or payload.requires_grad):
        # nothing visible: keep the outputs attached to the graph so backward() still works
        acc = acc + 0.0 * (geom.sum() + payload.sum())
    dacc = acc[:, :1].reshape(C, hw, 1)
    rgb = acc[:, 1:].reshape(C, hw, D)
    trans = trans.reshape(C, hw, 1)
    if background is not None:
        bg = background.to(rgb).expand(C, D)  # [C, D]
        rgb = rgb + trans * bg[:, None, :]
    return (
        rgb.reshape(C, height, width, D),
        (1.0 - trans).reshape(C, height, width, 1),
        dacc.reshape(C, height, width, 1),
    )


class _Frontier:
    """Visible Gaussians front to back with their pixel boxes; expands them chunk by chunk.

    Pixel ids are ``camera * H * W + y * W + x``, Gaussian ids ``camera * N + n``.
    """

    @torch.no_grad()
    def __init__(
        self,
        means2d: Tensor,
        conics: Tensor,
        depths: Tensor,
        radii: Tensor,
        cov2d_diag: Tensor,
        opacities: Tensor,
        width: int,
        height: int,
        tile_size: int,
    ) -> None:
        C, N = radii.shape[:2]
        self.C, self.H, self.W = C, height, width
        device = radii.device
        dtype = self.dtype = means2d.dtype
        # visible Gaussians of each camera, front to back (ties keep the index order, like gsplat)
        visible = radii.amax(dim=-1) > 0  # [C, N]
        key = depths.detach().masked_fill(~visible, math.inf)  # [C, N]
        order = torch.argsort(key, dim=1, stable=True)  # [C, N]
        vis = visible.gather(1, order)
        self.gids = gids = (order + torch.arange(C, device=device)[:, None] * N)[vis]  # [G] camera-major
        self.cam = gids // N
        m = means2d.detach().reshape(-1, 2).index_select(0, gids)  # [G, 2]
        con = conics.detach().reshape(-1, 3).index_select(0, gids)  # [G, 3]
        var = cov2d_diag.reshape(-1, 2).index_select(0, gids)  # [G, 2]
        op = opacities.detach().to(dtype).index_select(0, gids % N)  # [G]
        mx, my = m[:, 0], m[:, 1]

        # pixel box = tiles overlapped by the radius box (gsplat's binning) ∩ bounding box of the
        # ellipse where alpha can reach 1/255 (sigma <= log(255 o)): |dx| <= sqrt(2 log(255 o) var_x).
        # The radius box is that same box rounded up, so the tiles only matter at rounding level.
        # The small margin absorbs rounding (a too-large box only costs time; the alpha test is exact).
        ts = float(tile_size)
        tiles_w, tiles_h = math.ceil(width / tile_size), math.ceil(height / tile_size)
        r = radii.reshape(-1, 2).index_select(0, gids).to(dtype) / ts  # [G, 2] in tiles
        log_reach = torch.log(op * 255.0)
        ext = torch.sqrt(2.0 * log_reach.clamp_min(0.0)[:, None] * var) * (1.0 + 1e-4) + 1e-3  # [G, 2]
        rx, ry = r[:, 0], r[:, 1]
        x0 = torch.maximum(
            torch.floor(mx - 0.5 - ext[:, 0]), torch.floor(mx / ts - rx).clamp(0, tiles_w) * ts
        )
        x1 = torch.minimum(
            torch.floor(mx - 0.5 + ext[:, 0]) + 1, torch.ceil(mx / ts + rx).clamp(0, tiles_w) * ts
        )
        y0 = torch.maximum(
            torch.floor(my - 0.5 - ext[:, 1]), torch.floor(my / ts - ry).clamp(0, tiles_h) * ts
        )
        y1 = torch.minimum(
            torch.floor(my - 0.5 + ext[:, 1]) + 1, torch.ceil(my / ts + ry).clamp(0, tiles_h) * ts
        )
        x0, x1 = x0.clamp(0, width), x1.clamp(0, width)
        y0, y1 = y0.clamp(0, height), y1.clamp(0, height)
        self.bw = (x1 - x0).clamp_min(0).long()
        bh = (y1 - y0).clamp_min(0).long()
        self.counts = self.bw * bh  # [G]; opacities below 1/255 are already culled by the projection
        self.box = torch.stack([x0, x1, y0, y1], dim=-1).long()  # [G, 4]
        self.base = self.cam * (height * width) + self.box[:, 2] * width + self.box[:, 0]  # [G] box corner
        self.attr = torch.stack([mx, my, con[:, 0], con[:, 1], con[:, 2], op, x0, y0], dim=-1)  # [G, 8]

    @torch.no_grad()
    def chunks(self, chunk_elems: int, done: Tensor) -> Iterator[tuple[Tensor, Tensor, Tensor]]:
        """Yield ``(pix, gid, alpha)`` of the non-skipped candidates, a few Gaussians at a time.

        Each chunk is sorted by pixel (front to back within a pixel) and excludes pixels marked in
        ``done``, which the consumer updates between chunks; Gaussians whose whole box is done are
        never expanded (done only grows, so that check stays valid).
        """
        G, W, device, dtype = self.gids.numel(), self.W, self.gids.device, self.dtype
        start, n_done = 0, 0
        while start < G:
            cnt_rest = self.counts[start:]
            now_done = int(done.sum()) if start > 0 else 0
            if now_done > n_done:
                cnt_rest = cnt_rest * _box_has_open_pixel(
                    done, self.C, self.H, W, self.cam[start:], self.box[start:]
                )
                n_done = now_done
            cum = torch.cumsum(cnt_rest, 0)
            take = min(max(int(torch.searchsorted(cum, chunk_elems, right=True)), 1), G - start)
            n_pairs = int(cum[take - 1])
            if n_pairs > 0:
                cnt = cnt_rest[:take]
                rep = torch.repeat_interleave(torch.arange(take, device=device), cnt, output_size=n_pairs)
                local = torch.arange(n_pairs, device=device) - (cum[:take] - cnt).index_select(0, rep)
                w_rep = self.bw[start : start + take].index_select(0, rep)
                ly = torch.div(local, w_rep, rounding_mode="floor")
                lx = local - ly * w_rep
                pix = self.base[start : start + take].index_select(0, rep) + ly * W + lx
                a = self.attr[start : start + take].index_select(0, rep)  # [P, 8]
                dx = a[:, 0] - ((a[:, 6] + lx.to(dtype)) + 0.5)  # same values as pix % W + 0.5
                dy = a[:, 1] - ((a[:, 7] + ly.to(dtype)) + 0.5)
                sigma = 0.5 * (a[:, 2] * dx * dx + a[:, 4] * dy * dy) + a[:, 3] * dx * dy
                alpha = torch.clamp_max(a[:, 5] * torch.exp(-sigma), ALPHA_MAX)
                ok = (sigma >= 0) & (alpha >= ALPHA_MIN)  # gsplat's skip rule
                if n_done > 0:
                    ok &= ~done.index_select(0, pix)
                pix, alpha, g = pix[ok], alpha[ok], rep[ok] + start
                if pix.numel() > 0:
                    pix, perm = torch.sort(pix, stable=True)  # stable: still front to back per pixel
                    yield pix, self.gids.index_select(0, g.index_select(0, perm)), alpha.index_select(0, perm)
            start += take


def _box_has_open_pixel(done: Tensor, C: int, H: int, W: int, cam: Tensor, box: Tensor) -> Tensor:
    """Whether each box ``[x0, x1) x [y0, y1)`` of camera ``cam`` still has an unfinished pixel."""
    open_ = (~done).view(C, H, W).to(torch.int32)
    integral = torch.zeros(C, H + 1, W + 1, dtype=torch.int32, device=done.device)
    integral[:, 1:, 1:] = open_.cumsum(1).cumsum(2)
    flat = integral.view(-1)
    base = cam * ((H + 1) * (W + 1))
    x0, x1, y0, y1 = box.unbind(-1)

    def at(y: Tensor, x: Tensor) -> Tensor:
        return flat.index_select(0, base + y * (W + 1) + x)

    return (at(y1, x1) - at(y0, x1) - at(y1, x0) + at(y0, x0)) > 0


def _segmented_exclusive_cumprod(values: Tensor, counts: Tensor, chunk_elems: int) -> tuple[Tensor, Tensor]:
    """Exclusive running product within consecutive segments, and each segment's total product.

    ``values [K]`` holds the segments back to back, ``counts [S]`` their lengths (all > 0).
    Segments are padded to rows of a dense matrix so ``torch.cumprod`` does the sequential
    product (same rounding as a per-pixel loop); rows are chunked to bound memory.
    """
    S = counts.numel()
    if S == 0:
        return values.new_empty(0), values.new_ones(0)
    device = values.device
    seg = torch.repeat_interleave(torch.arange(S, device=device), counts, output_size=values.numel())
    ends = torch.cumsum(counts, 0)
    starts = ends - counts
    rank = torch.arange(values.numel(), device=device) - starts.index_select(0, seg)
    lmax = int(counts.max())
    rows = max(1, chunk_elems // (lmax + 1))
    excl, total = [], []
    for s0 in range(0, S, rows):
        s1 = min(S, s0 + rows)
        k0, k1 = int(starts[s0]), int(ends[s1 - 1])
        cols = int(counts[s0:s1].max()) + 1 if s1 - s0 < S else lmax + 1
        r, c = seg[k0:k1] - s0, rank[k0:k1]
        mat = values.new_ones(s1 - s0, cols).index_put((r, c + 1), values[k0:k1])  # [rows, L+1]
        cp = torch.cumprod(mat, dim=1)
        excl.append(cp[r, c])
        total.append(cp[:, -1])
    if len(excl) == 1:
        return excl[0], total[0]
    return torch.cat(excl), torch.cat(total)
