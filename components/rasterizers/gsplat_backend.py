"""``gsplat`` backend: gsplat's CUDA rasterization, used by ``auto`` when a GPU is present.

gsplat 1.5.x is an optional dependency (``pip install -e '.[cuda]'``); it JIT-compiles its
kernels on first use. Called in classic mode, non-packed, with expected depth ("RGB+ED") so its
outputs mean what the ``torch`` reference's do (docs/rasterizer.md). The call and the unpacking of
its outputs are checked on CPU against a stand-in made of gsplat's PyTorch code
(``tests/rasterizer/test_gsplat_glue.py``); the CUDA kernels' parity test
(``tests/rasterizer/test_gsplat_parity.py``, marker ``gpu``) passed on an H100 (docs/gpu.md).
"""

from __future__ import annotations

import importlib.util

import torch
from torch import Tensor

from components.rasterizers.base import RasterizeOutput, Rasterizer, check_inputs
from tridehaze_plugin.cuda_probe import cuda_available
from tridehaze_plugin.registry import register


class GsplatRasterizer(Rasterizer):
    """gsplat's CUDA rasterizer behind the common interface."""

    name = "gsplat"

    @classmethod
    def available(cls) -> bool:
        return cls.unavailable_reason() is None

    @classmethod
    def runs_on(cls, device: torch.device) -> bool:
        return device.type == "cuda"

    @classmethod
    def unavailable_reason(cls) -> str | None:
        if not cuda_available():
            return "no CUDA device"
        if importlib.util.find_spec("gsplat") is None:
            return "gsplat is not installed (pip install -e '.[cuda]')"
        return None

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
        from gsplat import rasterization  # imported lazily: it JIT-compiles CUDA code

        check_inputs(means, quats, scales, opacities, colors, viewmats, Ks, sh_degree)
        cfg = self.config
        c = viewmats.shape[0]
        d = 3 if sh_degree is not None else colors.shape[-1]
        bg = None
        if background is not None:
            bg = background.to(means).expand(c, d)  # [C, D]; gsplat appends the depth channel's 0
        render, alphas, meta = rasterization(
            means,
            quats,
            scales,
            opacities,
            colors,
            viewmats,
            Ks,
            int(width),
            int(height),
            near_plane=cfg.near_plane,
            far_plane=cfg.far_plane,
            eps2d=cfg.eps2d,
            sh_degree=sh_degree,
            packed=False,
            tile_size=cfg.tile_size,
            backgrounds=bg,
            render_mode="RGB+ED",
            rasterize_mode="classic",
        )
        means2d = meta["means2d"]  # [C, N, 2]
        if means2d.requires_grad:
            means2d.retain_grad()  # densification reads the screen-space gradient
        radii = meta["radii"].amax(dim=-1)  # [C, N] from the per-axis [C, N, 2]
        depth = render[..., d:]  # [C, H, W, 1] expected depth
        return RasterizeOutput(
            rgb=render[..., :d],
            depth=torch.where(alphas > 0, depth, torch.zeros_like(depth)),
            alpha=alphas,
            means2d=means2d,
            radii=radii.to(torch.int32),
            visible=radii > 0,
            depth_accum=depth * alphas,
            depths=meta.get("depths"),
        )


register("rasterizer", "gsplat", GsplatRasterizer)
