"""Built-in data parsers; importing this package registers them under kind ``dataparser``."""

from components.data.parsers import blender, colmap, nerfstudio
from components.data.parsers.base import DataParser

AUTO_ORDER: tuple[str, ...] = (
    nerfstudio.NerfstudioParser.name,
    blender.BlenderParser.name,
    colmap.ColmapParser.name,
)
"""Auto-detection priority; parsers registered by plugins are tried after these, by name."""

__all__ = ["AUTO_ORDER", "DataParser"]
