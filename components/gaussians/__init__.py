"""The Gaussian scene model. Importing this package registers the built-in models."""

from components.gaussians import model  # noqa: F401  (registers "3dgs")
from components.gaussians.model import PARAM_NAMES, GaussianModel, GaussianModelConfig
from components.gaussians.sh import eval_sh, rgb_to_sh, sh_to_colors, sh_to_rgb

__all__ = [
    "PARAM_NAMES",
    "GaussianModel",
    "GaussianModelConfig",
    "eval_sh",
    "rgb_to_sh",
    "sh_to_colors",
    "sh_to_rgb",
]
