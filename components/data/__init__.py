"""Datasets: parsers for each on-disk format and the shared loader that prepares them for training.

Importing this package registers the built-in data parsers (``nerfstudio``, ``blender``, ``colmap``).
"""

from components.data import parsers  # noqa: F401  (registers the built-in parsers)
from components.data.cameras import Cameras, opengl_to_opencv
from components.data.config import DataConfig
from components.data.dataset import ImageSet
from components.data.images import read_depth, read_image, write_image_atomic
from components.data.loader import DataWarning, load_scene
from components.data.scene import Frame, ParsedScene, SceneData, SceneTransform

__all__ = [
    "Cameras",
    "DataConfig",
    "DataWarning",
    "Frame",
    "ImageSet",
    "ParsedScene",
    "SceneData",
    "SceneTransform",
    "load_scene",
    "opengl_to_opencv",
    "read_depth",
    "read_image",
    "write_image_atomic",
]
