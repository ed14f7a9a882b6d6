"""``td-viewer --load-config RUN/config.yml``: explore a saved run in the browser.

    td-viewer --load-config outputs/scene/tri-dehaze/RUN/config.yml [--host 127.0.0.1 --port 7007]

Serves the run's newest checkpoint until Ctrl-C; open the printed URL. The viewer is the same one
``td-train --vis viewer`` starts (see docs/viewer.md), without the training readouts.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import tyro

from pipelines.engine.config import ViewerConfig
from pipelines.engine.device import check_device_name, resolve_device
from pipelines.engine.run_loader import load_run
from tridehaze_plugin.cli.common import run_cli
from tridehaze_plugin.config import check_numbers
from tridehaze_plugin.errors import ConfigError


@dataclass
class ServeConfig(ViewerConfig):
    """The viewer options that apply to a saved run."""

    wait_at_end: tyro.conf.Suppress[bool] = True
    """(td-train only: td-viewer always serves until Ctrl-C.)"""


@dataclass
class ViewerArgs:
    """Serve a trained (or interrupted) run in the browser."""

    load_config: Path
    """The run's config.yml (written by td-train)."""
    viewer: Annotated[ServeConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=ServeConfig)
    """Viewer options (flattened to --host, --port, ...)."""
    device: str = "auto"
    """Torch device: auto, cpu or cuda."""
    threads: int | None = None
    """CPU threads for torch (default: all cores)."""


def main(argv: list[str] | None = None) -> None:
    args = tyro.cli(ViewerArgs, args=sys.argv[1:] if argv is None else argv, prog="td-viewer")
    check_numbers(args)
    args.viewer.check_values(prefix="--")
    if not args.load_config.is_file():
        raise ConfigError("no such config file", where=str(args.load_config), fix="pass RUN/config.yml")
    check_device_name(args.device)
    if args.threads is not None and args.threads < 1:
        raise ConfigError(f"--threads must be >= 1, got {args.threads}")
    import torch

    from pipelines.viewer.server import Viewer

    if args.threads is not None:
        torch.set_num_threads(args.threads)
    run = load_run(args.load_config, device=resolve_device(args.device))
    viewer = Viewer(args.viewer, run.pipeline, run.datamanager, training=False)
    url = viewer.start()
    viewer.update(run.step, dict(run.pipeline.stats()))
    print(f"td-viewer: {run.config.method_name} run {run.run_dir} at step {run.step}")
    print(f"viewer: {url} (open in a browser; Ctrl-C to stop)", flush=True)
    try:
        viewer.serve_forever()
    finally:
        viewer.close()


def entrypoint() -> None:
    run_cli(main)


if __name__ == "__main__":
    entrypoint()
