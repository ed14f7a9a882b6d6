"""The contract between the training engine and a pipeline.

The trainer, the evaluator and the viewer only talk to :class:`Pipeline`; they never
know which model, medium or rasterizer a method uses. Outputs are named tensors so that a
viewer can list whatever a pipeline returns.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import torch
from torch import Tensor, nn

from components.data.cameras import Cameras
from tridehaze_plugin.errors import ConfigError

if TYPE_CHECKING:
    from components.gaussians.model import GaussianModel
    from components.medium.base import MediumField
    from pipelines.engine.datamanager import DataManager


@dataclass
class PipelineConfig:
    """Base of every pipeline's config: the trainer builds its pipeline with :meth:`setup` and
    checks values with :meth:`check_values`, knowing nothing else of it. Methods fill
    ``TrainerConfig.pipeline`` with a subclass (the Tri-DehazeGS one is ``GaussianPipelineConfig``)."""

    def check_values(self) -> None:
        """Reject values that cannot work, naming the flag (called right after parsing)."""

    def resolve(self, datamanager: DataManager, seed: int) -> tuple[PipelineConfig, list[Decision]]:
        """Settle the choices left to the data (e.g. a haze probe picking the medium) before
        :meth:`setup`: returns the config to build and to save, so a reloaded or resumed run never
        decides again, and the decisions taken (printed and logged by the trainer)."""
        return self, []

    def setup(
        self, datamanager: DataManager, seed: int = 0, max_steps: int = 30_000, training: bool = True
    ) -> Pipeline:
        """Build the pipeline; ``training=False`` (reloading a run to render it) may skip training-only work."""
        raise ConfigError(
            "the config names no pipeline", fix="start from a method preset: td-train METHOD (see td-info)"
        )


@dataclass
class StepResult:
    """What one training step produced."""

    loss: Tensor  # [] scalar with grad
    metrics: dict[str, float | Tensor] = field(default_factory=dict)
    """Scalar diagnostics for the progress bar and logs: floats or detached 0-dim tensors. The trainer
    reads the tensors in one transfer per step (a ``float()`` each would stall a GPU once per value)."""


@dataclass
class Decision:
    """A choice a pipeline made on its own: one line for the console, and its numbers for
    ``logs/decisions.jsonl`` (e.g. the haze probe's class, backend and confidence)."""

    message: str
    data: dict = field(default_factory=dict)
    """JSON-serialisable fields written next to the message."""


class Pipeline(nn.Module, ABC):
    """A trainable method: data access, model(s), losses and per-step hooks."""

    @abstractmethod
    def train_loss(self, step: int) -> StepResult:
        """Render one training batch and return its loss (backward is the trainer's job)."""

    @abstractmethod
    def param_groups(self) -> dict[str, tuple[nn.Parameter, float]]:
        """Trainable parameters by name with their base learning rates."""

    def adam_eps(self) -> dict[str, float]:
        """Adam epsilon per parameter group (names of :meth:`param_groups`) where it differs from
        the optimizer config's; none by default."""
        return {}

    def lr_scales(self, step: int) -> dict[str, float]:
        """Factors on the base learning rates of the named groups at ``step`` (a function of the
        step, so a resumed run gets the same rates); none by default."""
        return {}

    def after_backward(self, step: int) -> None:  # noqa: B027 - optional hook
        """Hook after ``loss.backward()`` (e.g. collect densification statistics)."""

    def after_optimizer_step(self, step: int, optimizers: dict[str, torch.optim.Optimizer]) -> None:  # noqa: B027
        """Hook after the optimizers stepped (e.g. densify/prune, editing optimizer state)."""

    @abstractmethod
    def render(self, camera: Cameras, step: int | None = None) -> dict[str, Tensor]:
        """Render one camera ([1]) into named outputs, each [H, W, C]."""

    @abstractmethod
    def output_names(self) -> list[str]:
        """Names :meth:`render` returns (e.g. clean, hazy, depth, alpha)."""

    @property
    def composites_medium(self) -> bool:
        """True when ``render`` composites a medium (its ``hazy`` differs from ``clean``); its
        outputs then also hold ``transmittance`` [H, W, 1] and ``scattering`` [H, W, 3], which the
        evaluation's medium-recovery protocol compares with the dataset's true maps."""
        return False

    def milestone_steps(self) -> tuple[int, ...]:
        """Steps (counted as completed steps, like checkpoint names) whose checkpoint the trainer
        always writes and never rotates away: a stage boundary that analyses and ablations of the
        later stage resume from (``benchmarks/stage_two_arm.py``). None by default."""
        return ()

    def stats(self) -> dict[str, float | int]:
        """Scalars worth showing (e.g. Gaussian count)."""
        return {}

    def describe(self) -> str:
        """One line on how the pipeline was set up (e.g. data-driven initial values), or ''."""
        return ""

    def scene_gaussians(self) -> GaussianModel | None:
        """The clean scene's Gaussians, for export (None: the method has none)."""
        return None

    def medium_field(self) -> MediumField | None:
        """The medium, for export (None: the method has none)."""
        return None

    def medium_at_depth(self, camera: Cameras, depth: Tensor) -> tuple[Tensor, Tensor] | None:
        """T [H, W, 1] and S [H, W, 3] of the method's medium marched from ``camera`` to the given
        z-depth [H, W, 1] (the run's normalised units) instead of its own rendered depth; None: the
        method has no medium. The evaluation marches it to the dataset's true depth, so that the
        medium's own error is measured apart from the error of the depth it is marched to."""
        return None

    def pop_decisions(self) -> list[str | Decision]:
        """Choices the pipeline made on its own since the last call (a haze probe's verdict,
        densification that stopped growing), each one line; the trainer prints and logs them."""
        return []

    @property
    def device(self) -> torch.device:
        for p in self.parameters():
            return p.device
        return torch.device("cpu")
