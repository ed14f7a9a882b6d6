"""Live browser viewer (viser) for training runs and saved runs.

``server`` (the viser server and GUI) is imported lazily so that runs without a viewer do not pay
for importing viser.
"""

from __future__ import annotations

import os
import sys
from typing import TYPE_CHECKING

from rich.console import Console

from pipelines.engine.live_view import LiveViewProvider
from pipelines.viewer.ports import check_port_free
from tridehaze_plugin.errors import UserError

__all__ = ["TrainingViewer", "check_port_free", "wants_viewer"]

if TYPE_CHECKING:
    from pipelines.engine.config import TrainerConfig
    from pipelines.engine.contract import Pipeline
    from pipelines.engine.datamanager import DataManager
    from pipelines.viewer.server import Viewer


def wants_viewer(vis: str) -> bool:
    """``--vis auto``: the viewer only for an interactive terminal, never under CI or pytest (a test
    run from a terminal with ``-s`` must not open a server)."""
    if vis != "auto":
        return vis == "viewer"
    interactive = sys.stdout.isatty()
    return interactive and not os.environ.get("CI") and "PYTEST_CURRENT_TEST" not in os.environ


class TrainingViewer(LiveViewProvider):
    """The browser viewer as the trainer's live view (``--vis viewer|auto``)."""

    def preflight(self, cfg: TrainerConfig) -> None:
        if cfg.vis == "viewer":  # a port in use fails now, not after loading data and making a run folder
            check_port_free(cfg.viewer.host, cfg.viewer.port)

    def start(
        self, cfg: TrainerConfig, pipeline: Pipeline, datamanager: DataManager, console: Console
    ) -> Viewer | None:
        """The viewer for a training run, started, or None when ``--vis`` resolves to none.

        With ``--vis auto`` a port in use only skips the viewer (with a warning); an explicit
        ``--vis viewer`` makes it an error.
        """
        if not wants_viewer(cfg.vis):
            return None
        from pipelines.viewer.server import Viewer

        viewer = Viewer(
            cfg.viewer, pipeline, datamanager, training=True, console=console, max_steps=cfg.max_steps
        )
        try:
            url = viewer.start()
        except UserError as exc:
            if cfg.vis == "viewer":
                raise
            console.print(f"[yellow]viewer not started[/]: {exc.one_line()}", highlight=False)
            return None
        console.print(f"viewer: [bold]{url}[/] (open in a browser)", highlight=False)
        return viewer
