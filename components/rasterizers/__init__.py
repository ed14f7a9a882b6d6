"""Gaussian rasterizers. Importing this package registers the built-in backends."""

from components.rasterizers import (  # noqa: F401  (register "cpu", "gsplat", "torch")
    cpu_rasterizer,
    gsplat_backend,
    torch_reference,
)
from components.rasterizers.base import RasterizeOutput, Rasterizer, RasterizerConfig, resolve_backend
from components.rasterizers.cpu_rasterizer import CpuRasterizer
from components.rasterizers.torch_reference import TorchRasterizer

__all__ = [
    "CpuRasterizer",
    "RasterizeOutput",
    "Rasterizer",
    "RasterizerConfig",
    "TorchRasterizer",
    "resolve_backend",
]
