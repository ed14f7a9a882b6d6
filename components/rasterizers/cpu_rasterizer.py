"""Backend ``cpu``: the torch reference's semantics with compositing in a compiled, threaded kernel.

Projection and SH run in PyTorch autograd (shared with the reference), binning is a counting sort
and forward / backward compositing are hand-written C++ (``csrc/cpu_raster.cpp``), compiled on
first use. The kernel is float32 on CPU; other inputs (float64, CUDA tensors) are rendered by the
torch reference, which honours their dtype and device. Without a working compiler the backend is
unavailable (``auto`` silently picks torch); built explicitly, it warns once and uses torch.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from typing import ClassVar

import torch
from torch import Tensor

from components.gaussians.sh import sh_to_colors
from components.rasterizers import cpu_build
from components.rasterizers.base import RasterizeOutput, Rasterizer, RasterizerConfig, check_inputs
from components.rasterizers.cpu_kernel import Bins, CompositeFn, bin_gaussians, composite_forward
from components.rasterizers.projection import Projected, camera_centers, project_gaussians
from components.rasterizers.torch_reference import TorchRasterizer
from tridehaze_plugin.registry import register

THREADS_ENV_VAR = "TRIDEHAZE_CPU_THREADS"
_warned: set[str] = set()


def default_threads() -> int:
    """``$TRIDEHAZE_CPU_THREADS``, else torch's intra-op threads (at most the cores this process may
    run on), so ``td-train --threads N`` bounds the kernel too. Taking every core regardless made
    each of a sweep's parallel runs start one kernel thread per core: two runs at once on 2 cores
    stepped 1.41x slower, and sixteen on a 16-core host stalled (docs/rasterizer.md "Thread settings")."""
    env = os.environ.get(THREADS_ENV_VAR)
    if env:
        return max(1, int(env))
    return max(1, min(available_cores(), torch.get_num_threads()))


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity on Linux, else the machine's count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _warn_once(reason: str) -> None:
    if reason not in _warned:
        _warned.add(reason)
        print(f"warning: cpu rasterizer unavailable ({reason}); using torch", file=sys.stderr)


def _visible_sh_colors(degree: int, coeffs: Tensor, means: Tensor, viewmats: Tensor, radii: Tensor) -> Tensor:
    """SH colours [C, N, 3] evaluated for visible Gaussians only (culled ones get 0, never blended).

    Same values as the reference's all-Gaussian evaluation; SH with its backward was a third of
    an iteration at 50k Gaussians, and typically a good part of a scene is outside each view.
    """
    C, N = radii.shape
    flat = (radii > 0).reshape(-1).nonzero().squeeze(1)  # [V] ids c * N + n
    cam, gid = flat // N, flat % N
    dirs = means.index_select(0, gid) - camera_centers(viewmats).index_select(0, cam)  # [V, 3]
    colors = sh_to_colors(degree, coeffs.index_select(0, gid), dirs)  # [V, 3]
    return colors.new_zeros(C * N, 3).index_put((flat,), colors).view(C, N, 3)


@dataclass
class _Prepared:
    """Everything before compositing: screen-space Gaussians, blended payload, tile lists."""

    proj: Projected
    payload: Tensor  # [C, N, D + 1] colours, then camera z
    opacities: Tensor  # [C, N]
    bins: Bins

    def kernel_inputs(self) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        return self.proj.means2d, self.proj.conics, self.opacities, self.payload


class CpuRasterizer(Rasterizer):
    """Compiled CPU rasterizer (float32), same outputs and gradients as :class:`TorchRasterizer`."""

    name = "cpu"
    fallback: ClassVar[str] = "torch"
    """What to use, after a one-line warning, when this backend is asked for but cannot run."""

    def __init__(self, config: RasterizerConfig | None = None, *, threads: int | None = None) -> None:
        super().__init__(config)
        self.threads = threads
        """Kernel threads (tiles are split among them); None = :func:`default_threads`."""
        self._torch = TorchRasterizer(self.config)

    @classmethod
    def available(cls) -> bool:
        return cls.unavailable_reason() is None

    @classmethod
    def unavailable_reason(cls) -> str | None:
        """Why the kernel cannot be built or loaded here (one line), None when it can."""
        try:
            cpu_build.load_kernel()
        except cpu_build.KernelUnavailable as err:
            return str(err)
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
        check_inputs(means, quats, scales, opacities, colors, viewmats, Ks, sh_degree)
        args = (means, quats, scales, opacities, colors, viewmats, Ks, width, height, background, sh_degree)
        if any(isinstance(t, Tensor) and (t.dtype != torch.float32 or t.device.type != "cpu") for t in args):
            return self._torch.rasterize(*args)  # float64 / GPU: the reference honours dtype and device
        try:
            lib = cpu_build.load_kernel()
        except cpu_build.KernelUnavailable as err:
            _warn_once(str(err))
            return self._torch.rasterize(*args)
        width, height = int(width), int(height)
        p = self._prepare(
            lib, means, quats, scales, opacities, colors, viewmats, Ks, width, height, sh_degree
        )
        means2d = p.proj.means2d  # [C, N, 2]
        if means2d.requires_grad:
            means2d.retain_grad()  # densification reads the screen-space gradient
        acc, trans = CompositeFn.apply(*p.kernel_inputs(), lib, p.bins, width, height, self._threads())
        D = p.payload.shape[-1] - 1
        rgb, depth_accum = acc[..., :D], acc[..., D:]  # [C, H, W, D], [C, H, W, 1]
        if background is not None:
            rgb = rgb + trans * background.to(rgb).expand(len(rgb), D)[:, None, None, :]
        alpha = 1.0 - trans  # [C, H, W, 1]
        radii = p.proj.radii.amax(dim=-1)  # [C, N]
        return RasterizeOutput(
            rgb=rgb,
            depth=depth_accum / alpha.clamp_min(1e-10),
            alpha=alpha,
            means2d=means2d,
            radii=radii,
            visible=radii > 0,
            depth_accum=depth_accum,
            depths=p.proj.depths,
        )

    @torch.no_grad()
    def blended_per_pixel(
        self, means, quats, scales, opacities, colors, viewmats, Ks, width, height, sh_degree=None
    ) -> Tensor:
        """How many Gaussians are composited into each pixel [C, H, W] int32, after the skip and
        stop rules: the work any backend does, for throughput figures. Float32 CPU inputs."""
        check_inputs(means, quats, scales, opacities, colors, viewmats, Ks, sh_degree)
        lib = cpu_build.load_kernel()
        width, height = int(width), int(height)
        p = self._prepare(
            lib, means, quats, scales, opacities, colors, viewmats, Ks, width, height, sh_degree
        )
        *_, counts = composite_forward(
            lib, *p.kernel_inputs(), p.bins, width, height, self._threads(), count=True
        )
        return counts

    def _prepare(self, lib, means, quats, scales, opacities, colors, viewmats, Ks, width, height, sh_degree):
        """Projection and colours in torch autograd (shared with the reference), then binning."""
        cfg = self.config
        proj = project_gaussians(
            means, quats, scales, viewmats, Ks, width, height, *_planes(cfg), opacities=opacities
        )
        C, N = proj.radii.shape[:2]
        if sh_degree is not None:
            radii = proj.radii.amax(dim=-1)  # [C, N]
            colors = _visible_sh_colors(sh_degree, colors, means, viewmats, radii)  # [C, N, 3]
        D = colors.shape[-1]
        payload = torch.cat([colors.expand(C, N, D), proj.depths[..., None]], dim=-1)  # [C, N, D + 1]
        bins = bin_gaussians(lib, proj.means2d, proj.depths, proj.radii, width, height, cfg.tile_size)
        return _Prepared(proj=proj, payload=payload, opacities=opacities[None].expand(C, N), bins=bins)

    def _threads(self) -> int:
        return self.threads or default_threads()


def _planes(cfg: RasterizerConfig) -> tuple[float, float, float]:
    return cfg.near_plane, cfg.far_plane, cfg.eps2d


register("rasterizer", "cpu", CpuRasterizer)
