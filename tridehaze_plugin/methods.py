"""Methods: named presets of the trainer config, registered under kind ``method``.

A method is only a function that returns a fully-populated :class:`TrainerConfig`; presets
derive from one another by ``dataclasses.replace`` so no settings are copied between them.
Third-party packages register theirs via the ``tridehaze.methods`` entry-point group.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from pipelines.config import TrainerConfig
from tridehaze_plugin.registry import register


@dataclass(frozen=True)
class MethodSpec:
    """A registered method: its CLI name, a one-paragraph description and a config factory."""

    name: str
    description: str
    config_factory: Callable[[], TrainerConfig]

    def make_config(self) -> TrainerConfig:
        cfg = self.config_factory()
        if cfg.method_name != self.name:
            cfg.method_name = self.name
        return cfg


def vanilla_gs() -> TrainerConfig:
    """Haze-agnostic 3D Gaussian splatting: the baseline every dehazing method is compared with."""
    return TrainerConfig(method_name="vanilla-gs")


register(
    "method",
    "vanilla-gs",
    MethodSpec(
        name="vanilla-gs",
        description=(
            "Haze-agnostic 3D Gaussian splatting (L1 + SSIM on the input views). "
            "It reproduces haze in the scene: the baseline for dehazing methods."
        ),
        config_factory=vanilla_gs,
    ),
)
