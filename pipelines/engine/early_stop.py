"""Early stopping on the held-out views: stop when their reconstruction loss no longer improves.

Only the hazy inputs of the test split are used (what a user has); the clean references, when a
dataset has them, stay for evaluation. Checks start late in the run (``start_fraction``) so that the
medium is fitted and the densification window is over before a plateau can end training.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from pipelines.engine.contract import Pipeline
from pipelines.engine.datamanager import DataManager
from tridehaze_plugin.errors import ConfigError


@dataclass
class EarlyStopConfig:
    """Stop training when the held-out loss plateaus (off by default)."""

    enabled: bool = False
    """Check the held-out views' loss during training and stop when it stops improving."""
    every: int = 100
    """Steps between two checks."""
    patience: int = 3
    """Checks in a row without an improvement after which training stops."""
    min_improvement: float = 0.005
    """Relative decrease of the held-out L1 (against the best so far) that counts as improving."""
    start_fraction: float = 0.5
    """No check before this fraction of ``--max-steps`` (the medium is fitted and the Gaussian set
    grown first)."""

    def check_values(self) -> None:
        if self.every < 1 or self.patience < 1:
            raise ConfigError("--early-stop.every and --early-stop.patience must be >= 1")
        if not 0.0 <= self.start_fraction <= 1.0 or self.min_improvement < 0:
            raise ConfigError(
                "--early-stop.start-fraction must be in [0, 1] and --early-stop.min-improvement >= 0"
            )


def heldout_views(dm: DataManager) -> list[int]:
    """Test views with a hazy input (views whose image is a clean reference are left out)."""
    return [i for i in dm.test_indices if dm.hazy_image(i) is not None]


@torch.no_grad()
def heldout_l1(pipeline: Pipeline, dm: DataManager, views: list[int]) -> float:
    """Mean L1 between each view's render as the input looks (composite when there is a medium,
    else the plain render) and its hazy input."""
    total = 0.0
    for i in views:
        out = pipeline.render(dm.camera(i))
        pred = out.get("hazy", out["clean"])  # [H, W, 3]
        total += float((pred - dm.image(i)).abs().mean())
    return total / max(len(views), 1)


class EarlyStopper:
    """Tracks the held-out loss and decides when to stop; each verdict is kept as a line."""

    def __init__(self, config: EarlyStopConfig, dm: DataManager, max_steps: int) -> None:
        self.config = config
        self.views = heldout_views(dm)
        if not self.views:
            raise ConfigError(
                "--early-stop.enabled needs held-out views with hazy inputs, and this dataset has none",
                where=str(dm.scene.root),
                fix="keep test views (--test-every N) or train without --early-stop.enabled",
            )
        self.start = int(math.ceil(config.start_fraction * max_steps))
        self.best = math.inf
        self.best_step = 0
        self.bad_checks = 0
        self.decisions: list[str] = []

    def due(self, done: int) -> bool:
        return done >= self.start and done % self.config.every == 0

    def update(self, done: int, loss: float) -> bool:
        """Record the held-out loss after ``done`` steps; True when training should stop."""
        if math.isinf(self.best) or loss < self.best * (1.0 - self.config.min_improvement):
            self.best, self.best_step, self.bad_checks = loss, done, 0
            return False
        self.best = min(self.best, loss)
        self.bad_checks += 1
        if self.bad_checks < self.config.patience:
            return False
        self.decisions.append(
            f"step {done}: early stop: held-out L1 {loss:.5f} has not improved by "
            f"{100 * self.config.min_improvement:.1f} % on {self.best:.5f} (step {self.best_step}) for "
            f"{self.bad_checks} checks ({len(self.views)} held-out views)"
        )
        return True
