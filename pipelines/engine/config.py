"""The top-level training config (what ``td-train METHOD`` parses) and its value checks."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import tyro

from components.data.config import DataConfig
from pipelines.engine.contract import PipelineConfig
from pipelines.engine.device import check_device_name
from pipelines.engine.early_stop import EarlyStopConfig
from pipelines.engine.optimizers import OptimizerConfig
from tridehaze_plugin.config import SEED_RANGE, Range
from tridehaze_plugin.errors import ConfigError


@dataclass
class ViewerConfig:
    """The live browser viewer (``--vis viewer`` in td-train, always in td-viewer)."""

    host: str = "127.0.0.1"
    """Address to serve on; ``0.0.0.0`` lets other machines connect (no authentication: trusted
    networks only)."""
    port: int = 7007
    """TCP port of the viewer (HTTP and websocket); 0 picks a free one. A port in use is an error."""
    max_resolution: int = 512
    """Longest image side, in pixels, of a render while the camera rests (never above the browser's
    canvas)."""
    moving_resolution: int = 160
    """Longest image side while the camera moves, so that dragging stays responsive."""
    rest_seconds: float = 0.25
    """A camera unchanged for this long counts as resting and gets a full-resolution render."""
    render_share: float = 0.2
    """Most of the wall time viewer renders may take while training runs (training waits during a
    render), so training slows by at most 1 / (1 - share); 1 disables the limit."""
    refresh_seconds: float = 2.0
    """While training runs, re-render a resting view at most this often to show progress."""
    jpeg_quality: int = 85
    """JPEG quality of the frames sent to the browser."""
    thumbnail_size: int = 64
    """Longest side of the training images shown in the camera frustums; 0: frustums without images."""
    wait_at_end: bool = True
    """td-train ``--vis viewer``: keep serving after training ends until Ctrl-C (the run is complete
    either way). ``--vis auto`` never waits, so scripts run from a terminal still end."""

    def check_values(self, prefix: str = "--viewer.") -> None:
        """``prefix``: how the flags are spelled (``--`` in td-viewer, which flattens them)."""
        if not 0 <= self.port <= 65535:
            raise ConfigError(f"{prefix}port must be in 0..65535, got {self.port}")
        for name in ("max_resolution", "moving_resolution"):
            if getattr(self, name) < 16:
                raise ConfigError(
                    f"{prefix}{name.replace('_', '-')} must be >= 16, got {getattr(self, name)}"
                )
        if not 0 < self.render_share <= 1:
            raise ConfigError(f"{prefix}render-share must be in (0, 1], got {self.render_share}")
        if not 1 <= self.jpeg_quality <= 100:
            raise ConfigError(f"{prefix}jpeg-quality must be in 1..100, got {self.jpeg_quality}")
        for name in ("rest_seconds", "refresh_seconds", "thumbnail_size"):
            if getattr(self, name) < 0:
                raise ConfigError(f"{prefix}{name.replace('_', '-')} must be >= 0, got {getattr(self, name)}")


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
    max_steps: Annotated[int, Range(1)] = 3000
    """Number of optimisation steps."""
    seed: Annotated[int, SEED_RANGE] = 42
    """Random seed for initialisation, view order and anything stochastic."""
    vis: Literal["auto", "none", "viewer"] = "auto"
    """Visualisation: ``viewer`` (live browser viewer, see --viewer.*), ``none`` (progress bar only),
    ``auto``: the viewer when stdout is a terminal, else none (pipes, CI, tests)."""
    viewer: ViewerConfig = field(default_factory=ViewerConfig)
    """Options of the live viewer (used with --vis viewer or auto)."""
    device: str = "auto"
    """Torch device: ``auto`` (CUDA when available, else CPU), ``cpu``, ``cuda`` or ``cuda:N``."""
    threads: Annotated[int | None, Range(1)] = None
    """CPU threads for torch and the CPU rasterizer's kernel (default: all cores). Oversubscription
    costs 2-5x on shared machines."""
    steps_per_log: Annotated[int, Range(1)] = 10
    """Write a line of metrics to logs/metrics.jsonl every N steps."""
    steps_per_save: Annotated[int, Range(1)] = 1000
    """Write a checkpoint every N steps (and always at the end)."""
    checkpoints_to_keep: Annotated[int, Range(0)] = 2
    """How many of the newest checkpoints stay on disk (0: all of them, e.g. to study how a run
    evolves; each holds the whole scene and medium)."""
    minutes_per_save: float = 5.0
    """Also write one when this many minutes have passed since the last (the first after a fifth
    of it), so a killed run loses at most that much work; 0: by steps only. Each checkpoint's cost
    is logged in logs/checkpoints.jsonl."""
    eval_at_end: bool = True
    """Evaluate on the test split when training finishes and print the metrics."""
    early_stop: EarlyStopConfig = field(default_factory=EarlyStopConfig)
    """Stop before ``--max-steps`` when the held-out views' loss plateaus (``--early-stop.enabled``)."""

    def check_values(self) -> None:
        """Reject values that cannot work, naming the flag; called right after parsing (after
        :func:`check_numbers`, which covers the fields' declared ranges)."""
        if not 0 <= self.minutes_per_save <= 1e6:
            raise ConfigError(f"--minutes-per-save must be in [0, 1e6], got {self.minutes_per_save}")
        _positive("--downscale", self.dataset.downscale)
        if self.dataset.test_every < 0:
            raise ConfigError(f"--test-every must be >= 0, got {self.dataset.test_every}")
        check_device_name(self.device)
        if self.timestamp is not None:
            check_folder_name("--timestamp", self.timestamp)
        self.viewer.check_values()
        self.early_stop.check_values()
        self.pipeline.check_values()


def check_folder_name(flag: str, name: str) -> None:
    """One plain folder name: a run folder must stay inside ``--output-dir``."""
    bad = (
        not name
        or name in (".", "..")
        or any(sep in name for sep in ("/", "\\"))
        or any(ord(ch) < 32 for ch in name)
        or len(name.encode("utf-8", "surrogateescape")) > 200
    )
    if bad:
        raise ConfigError(
            f"{flag} must be one plain folder name (no path separators, '.', '..' or control characters; at most 200 bytes), "
            f"got {name!r}",
            fix=f"use e.g. {flag} run-1",
        )


def _positive(flag: str, value: int | float) -> None:
    if value < 1:
        raise ConfigError(f"{flag} must be >= 1, got {value}")
