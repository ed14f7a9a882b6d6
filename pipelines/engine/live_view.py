"""What the trainer may expect of a live view (the browser viewer is one): the engine declares
it, the viewer implements it, and the tool that starts a run plugs it in."""

from __future__ import annotations

from abc import ABC, abstractmethod
from contextlib import AbstractContextManager
from typing import TYPE_CHECKING

from rich.console import Console

if TYPE_CHECKING:
    from pipelines.engine.config import TrainerConfig
    from pipelines.engine.contract import Pipeline
    from pipelines.engine.datamanager import DataManager


class LiveView(ABC):
    """A view of a run while it trains. The trainer steps under :attr:`lock`, so the view can
    render between steps; :meth:`update` may block (a pause from the browser)."""

    lock: AbstractContextManager
    url: str

    @abstractmethod
    def update(self, step: int, metrics: dict[str, float]) -> None:
        """Called after every completed step with its metrics."""

    @abstractmethod
    def finish(self) -> None:
        """Training ended: show the final state."""

    @abstractmethod
    def serve_forever(self) -> None:
        """Keep serving until interrupted (``--viewer.wait-at-end``)."""

    @abstractmethod
    def close(self) -> None:
        """Stop serving; called once, whatever happened."""


class LiveViewProvider(ABC):
    """Starts a :class:`LiveView` for a run, or declines (``--vis none``)."""

    def preflight(self, cfg: TrainerConfig) -> None:  # noqa: B027 - optional hook
        """Fail before any data is loaded or a run folder made (e.g. a port already in use)."""

    @abstractmethod
    def start(
        self, cfg: TrainerConfig, pipeline: Pipeline, datamanager: DataManager, console: Console
    ) -> LiveView | None:
        """The started view, or None when this run has none."""
