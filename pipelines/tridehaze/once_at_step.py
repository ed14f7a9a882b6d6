"""A decision a run takes once, at a given step, and keeps across a resume."""

from __future__ import annotations

import torch
from torch import nn

from pipelines.engine.contract import Decision


class OnceAtStep(nn.Module):
    """Due from ``step`` on until :meth:`mark_done`. ``done`` is a buffer, so a run resumed after the
    step does not decide again; ``decisions`` holds what was decided for the trainer to print and
    log (logs/decisions.jsonl)."""

    def __init__(self, enabled: bool, step: int) -> None:
        super().__init__()
        self.enabled, self.step = enabled, step
        self.register_buffer("done", torch.tensor(False))
        self.decisions: list[str | Decision] = []
        self._done: bool | None = None  # the buffer read once, not at every step

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:  # noqa: ANN001
        # checkpoints from before the decision existed: not taken yet
        state_dict.setdefault(prefix + "done", self.done.clone())
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        self._done = None

    def due(self, step: int) -> bool:
        if not self.enabled or step < self.step:
            return False
        if self._done is None:
            self._done = bool(self.done)
        return not self._done

    def mark_done(self) -> None:
        self.done.fill_(True)
        self._done = True
