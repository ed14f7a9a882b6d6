"""Rasterizer interface shared by every backend, its output record and its config.

Backends (``torch``: the reference; ``cpu``: the compiled CPU kernel, the default; ``gsplat``: CUDA)
implement the same semantics, gsplat's *classic* 3DGS mode, so they can be swapped and compared
against the reference with explicit tolerances (docs/rasterizer.md).
"""

from __future__ import annotations

import abc
import sys
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar

import torch
from torch import Tensor

from tridehaze_plugin.config import ComponentConfig, NonNegative, Positive, Range, RegistryChoice
from tridehaze_plugin.cuda_probe import cuda_available
from tridehaze_plugin.errors import ConfigError
from tridehaze_plugin.registry import REGISTRY, Registry

AUTO_ORDER: tuple[str, ...] = ("gsplat", "cpu", "torch")
"""Preference order of ``backend="auto"``: the first registered and available name wins."""


@dataclass
class RasterizeOutput:
    """What a rasterizer returns for C cameras of one size (H x W) and N Gaussians."""

    rgb: Tensor  # [C, H, W, D] composited colour (D = 3 for RGB), background included
    depth: Tensor  # [C, H, W, 1] expected camera-z: depth_accum / alpha, 0 where alpha == 0
    alpha: Tensor  # [C, H, W, 1] accumulated opacity, 1 - final transmittance
    means2d: (
        Tensor  # [C, N, 2] projected centres (pixels; meaningless where culled); .grad filled by backward
    )
    radii: Tensor  # [C, N] int32 screen radius in pixels, 0 = culled
    visible: Tensor  # [C, N] bool, radii > 0
    depth_accum: Tensor | None = None  # [C, H, W, 1] alpha-weighted camera-z, not normalised
    depths: Tensor | None = None  # [C, N] camera-space z of each Gaussian centre

    @property
    def num_cameras(self) -> int:
        return self.rgb.shape[0]

    @property
    def width(self) -> int:
        return self.rgb.shape[2]

    @property
    def height(self) -> int:
        return self.rgb.shape[1]


class Rasterizer(abc.ABC):
    """Renders 3D Gaussians into C pinhole cameras that share one image size.

    Cameras of different sizes are rasterized in separate calls by the caller. Backends register
    their class under kind ``"rasterizer"``; :meth:`RasterizerConfig.setup` builds ``cls(config)``.
    """

    name: ClassVar[str] = ""
    fallback: ClassVar[str | None] = None
    """Backend to use instead when this one is asked for but unavailable (None: it is an error)."""

    def __init__(self, config: RasterizerConfig | None = None) -> None:
        self.config = config if config is not None else RasterizerConfig(backend=self.name or "auto")

    @classmethod
    def available(cls) -> bool:
        """Whether this backend can run in the current process (compiled extension, device...)."""
        return True

    @classmethod
    def unavailable_reason(cls) -> str | None:
        """Why :meth:`available` is False (one short phrase), or None when it is available."""
        return None if cls.available() else "not available here"

    @classmethod
    def runs_on(cls, device: torch.device) -> bool:
        """Whether it renders tensors on ``device`` (``auto`` only picks a backend that does)."""
        return True

    @abc.abstractmethod
    def rasterize(
        self,
        means: Tensor,  # [N, 3] world
        quats: Tensor,  # [N, 4] (w, x, y, z), need not be normalised
        scales: Tensor,  # [N, 3] activated (positive)
        opacities: Tensor,  # [N] activated, in [0, 1]
        colors: Tensor,  # [N, D] or [C, N, D] colours, or [N, K, 3] SH coefficients when sh_degree is set
        viewmats: Tensor,  # [C, 4, 4] world-to-camera, OpenCV axes
        Ks: Tensor,  # [C, 3, 3]
        width: int,
        height: int,
        background: Tensor | None = None,  # [C, D] or [D]; None = black
        sh_degree: int | None = None,
    ) -> RasterizeOutput:
        """Project, sort front to back and alpha-composite the Gaussians."""

    def __call__(self, *args: Any, **kwargs: Any) -> RasterizeOutput:
        return self.rasterize(*args, **kwargs)


def check_inputs(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    colors: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    sh_degree: int | None,
) -> None:
    """Shape checks shared by backends, so a wrong layout fails with a readable message."""
    n = means.shape[0]
    c = viewmats.shape[0]
    expect = {
        "means": (means, (n, 3)),
        "quats": (quats, (n, 4)),
        "scales": (scales, (n, 3)),
        "opacities": (opacities, (n,)),
        "viewmats": (viewmats, (c, 4, 4)),
        "Ks": (Ks, (c, 3, 3)),
    }
    for name, (t, shape) in expect.items():
        if tuple(t.shape) != shape:
            raise ValueError(f"{name} must have shape {list(shape)}, got {list(t.shape)}")
    if sh_degree is not None:
        if colors.dim() != 3 or colors.shape[0] != n or colors.shape[2] != 3:
            raise ValueError(
                f"with sh_degree, colors must be SH coefficients [N, K, 3], got {list(colors.shape)}"
            )
    elif not (colors.dim() == 2 and colors.shape[0] == n) and not (
        colors.dim() == 3 and colors.shape[:2] == (c, n)
    ):
        raise ValueError(f"colors must be [N, D] or [C, N, D], got {list(colors.shape)}")


def resolve_backend(name: str, registry: Registry | None = None, device: torch.device | None = None) -> str:
    """Turn ``auto`` into the best registered and available backend for ``device`` (the run's;
    None: CUDA when available, else CPU); check explicit names."""
    registry = registry or REGISTRY
    if device is None:
        device = torch.device("cuda" if cuda_available() else "cpu")
    if name != "auto":
        cls = registry.get("rasterizer", name)
        if cls.available() and not cls.runs_on(device):
            raise ConfigError(
                f"rasterizer backend {name!r} does not render on {device.type} tensors",
                where="--pipeline.rasterizer.backend",
                fix="use auto, or the device this backend needs (--device cuda for gsplat)",
            )
        if not cls.available():
            reason = cls.unavailable_reason() or "not available here"
            if cls.fallback and ("rasterizer", cls.fallback) in registry:
                print(
                    f"warning: {name} rasterizer unavailable ({reason}); using {cls.fallback}",
                    file=sys.stderr,
                )
                return cls.fallback
            raise ConfigError(
                f"rasterizer backend {name!r} is not available here ({reason})",
                where="--pipeline.rasterizer.backend",
                fix="use auto (or torch, which always works)",
            )
        return name
    for cand in AUTO_ORDER:
        if ("rasterizer", cand) not in registry:
            continue
        cls = registry.get("rasterizer", cand)
        if cls.runs_on(device) and cls.available():
            return cand
    raise ConfigError("no rasterizer backend is available", fix="import components.rasterizers first")


@dataclass
class RasterizerConfig(ComponentConfig):
    """Which rasterizer backend to use and the projection / culling constants they share."""

    backend: Annotated[str, RegistryChoice("rasterizer", allow=("auto",))] = "auto"
    """Backend: ``auto``, ``torch`` (pure PyTorch reference), ``cpu`` or ``gsplat`` once registered.
    ``auto`` picks gsplat for a run on CUDA when it is installed, else cpu, else torch."""
    near_plane: Annotated[float, Positive] = 0.01
    """Gaussians whose centre has camera z <= this are culled."""
    far_plane: Annotated[float, Positive] = 1e10
    """Gaussians whose centre has camera z >= this are culled."""
    eps2d: Annotated[float, NonNegative] = 0.3
    """Low-pass filter: added to the diagonal of every 2D covariance (pixels^2), as in 3DGS."""
    tile_size: Annotated[int, Range(1, 1024)] = 16
    """Tile edge in pixels for binning. The image does not depend on it (each Gaussian's box holds
    every pixel its alpha reaches 1/255 in); 16 as gsplat, and what the cpu kernel is tuned for."""

    def check_values(self, prefix: str = "--pipeline.rasterizer.") -> None:
        if self.far_plane <= self.near_plane:
            raise ConfigError(
                f"{prefix}far-plane ({self.far_plane:g}) must be greater than {prefix}near-plane "
                f"({self.near_plane:g})"
            )

    def setup(self, device: torch.device | None = None, **kwargs: Any) -> Rasterizer:
        """Build the backend instance (``auto`` resolved now, in this process, for the run's device)."""
        name = resolve_backend(self.backend, device=device)
        return REGISTRY.get("rasterizer", name)(self, **kwargs)
