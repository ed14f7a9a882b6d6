"""Gaussian rasterizers. Importing this package registers the built-in backends."""

from components.rasterizers import torch_reference  # noqa: F401  (registers "torch")
from components.rasterizers.base import RasterizeOutput, Rasterizer, RasterizerConfig, resolve_backend
from components.rasterizers.torch_reference import TorchRasterizer

__all__ = ["RasterizeOutput", "Rasterizer", "RasterizerConfig", "TorchRasterizer", "resolve_backend"]
