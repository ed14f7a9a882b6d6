"""The top-level training config (what ``td-train METHOD`` parses) and its value checks."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import tyro

from components.data.config import DataConfig
from pipelines.gaussian_pipeline import PipelineConfig
from pipelines.optimizers import OptimizerConfig
from tridehaze_plugin.errors import ConfigError


@dataclass
class TrainerConfig:
    """Everything one training run needs; methods are presets of this."""

    method_name: tyro.conf.Suppress[str] = "unnamed"
    """Name of the method preset (set by the preset, not on the command line)."""
    dataset: Annotated[DataConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=DataConfig)
    """Dataset options (flattened to ``--data``, ``--downscale``, ... on the command line)."""
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    """Model, rasterizer and losses."""
    optimizer: OptimizerConfig = field(default_factory=OptimizerConfig)
    """Optimizer settings shared by all parameter groups."""
    output_dir: Path = Path("outputs")
    """Runs are written to OUTPUT_DIR/<scene>/<method>/<timestamp>/."""
    timestamp: str | None = None
    """Run folder name; default: the current local time (YYYY-mm-dd_HHMMSS)."""
    max_steps: int = 3000
    """Number of optimisation steps."""
    seed: int = 42
    """Random seed for initialisation, view order and anything stochastic."""
    vis: Literal["none"] = "none"
    """Visualisation: ``none`` (progress bar only). The live viewer is added by the viewer component."""
    device: str = "auto"
    """Torch device: ``auto`` (CUDA when available, else CPU), ``cpu``, ``cuda`` or ``cuda:N``."""
    threads: int | None = None
    """CPU threads for torch (default: all cores). Oversubscription costs 2-5x on shared machines."""
    steps_per_log: int = 10
    """Write a line of metrics to logs/metrics.jsonl every N steps."""
    steps_per_save: int = 1000
    """Write a checkpoint every N steps (and always at the end)."""
    eval_at_end: bool = True
    """Evaluate on the test split when training finishes and print the metrics."""

    def check_values(self) -> None:
        """Reject values that cannot work, naming the flag; called right after parsing."""
        _positive("--max-steps", self.max_steps)
        _positive("--steps-per-log", self.steps_per_log)
        _positive("--steps-per-save", self.steps_per_save)
        _positive("--downscale", self.dataset.downscale)
        if self.dataset.test_every < 0:
            raise ConfigError(f"--test-every must be >= 0, got {self.dataset.test_every}")
        if self.threads is not None:
            _positive("--threads", self.threads)
        if self.device not in ("auto", "cpu") and not self.device.startswith("cuda"):
            raise ConfigError(f"--device must be auto, cpu, cuda or cuda:N, got {self.device!r}")
        self.pipeline.check_values()


def _positive(flag: str, value: int | float) -> None:
    if value < 1:
        raise ConfigError(f"{flag} must be >= 1, got {value}")
