"""One Adam optimizer per named parameter group (so densification can edit each one's state)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import torch
from torch import nn

from tridehaze_plugin.config import Positive, Range


@dataclass
class OptimizerConfig:
    """Adam settings shared by every parameter group."""

    eps: Annotated[float, Positive] = 1e-15
    """Adam epsilon (3DGS uses 1e-15)."""
    means_lr_final_ratio: Annotated[float, Range(0.0, 1.0, lo_open=True)] = 0.01
    """The means' learning rate decays exponentially to this fraction of its start by the last step."""


class Optimizers:
    """Named Adam optimizers with an exponential schedule on the means."""

    def __init__(
        self,
        groups: dict[str, tuple[nn.Parameter, float]],
        config: OptimizerConfig,
        max_steps: int,
        eps: dict[str, float] | None = None,
    ):
        """``eps``: Adam epsilon by group name where a component asks for its own."""
        self.config = config
        self.max_steps = max(max_steps, 1)
        self.base_lr = {name: lr for name, (_, lr) in groups.items()}
        eps = eps or {}
        unknown = sorted(set(eps) - set(groups))
        if unknown:
            raise ValueError(f"Adam epsilon given for unknown parameter groups {unknown}")
        self.optimizers: dict[str, torch.optim.Optimizer] = {
            name: torch.optim.Adam([{"params": [p], "lr": lr, "name": name}], eps=eps.get(name, config.eps))
            for name, (p, lr) in groups.items()
        }

    def zero_grad(self) -> None:
        for opt in self.optimizers.values():
            opt.zero_grad(set_to_none=True)

    def step(self) -> None:
        for opt in self.optimizers.values():
            opt.step()

    def schedule(self, step: int, scales: dict[str, float] | None = None) -> None:
        """Set learning rates for ``step``: ``means`` decays; ``scales`` multiplies the base rate of
        the groups it names (a pipeline's :meth:`Pipeline.lr_scales`), the others keep theirs."""
        factors = dict(scales or {})
        unknown = sorted(set(factors) - set(self.optimizers))
        if unknown:
            raise ValueError(f"learning-rate scales given for unknown parameter groups {unknown}")
        if "means" in self.optimizers:
            decay = self.config.means_lr_final_ratio ** (min(step, self.max_steps) / self.max_steps)
            factors["means"] = factors.get("means", 1.0) * decay
        for name, factor in factors.items():
            for g in self.optimizers[name].param_groups:
                g["lr"] = self.base_lr[name] * factor

    def state_dict(self) -> dict:
        return {name: opt.state_dict() for name, opt in self.optimizers.items()}

    def load_state_dict(self, state: dict) -> None:
        """Load, then check every moment tensor has its parameter's shape: torch does not, and a
        mismatch would surface as a shape error inside Adam's first step."""
        for name, opt in self.optimizers.items():
            if name in state:
                opt.load_state_dict(state[name])
                _check_moments(name, opt)


def _check_moments(name: str, opt: torch.optim.Optimizer) -> None:
    for group in opt.param_groups:
        for p in group["params"]:
            for key, value in opt.state.get(p, {}).items():
                if isinstance(value, torch.Tensor) and value.dim() > 0 and value.shape != p.shape:
                    raise ValueError(
                        f"optimiser state '{key}' of {name} has shape {tuple(value.shape)}, "
                        f"its parameter {tuple(p.shape)}"
                    )
