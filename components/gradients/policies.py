"""Transmittance gradient compensation: rescale only the gradient entering J by 1 / clamp(T, T_min).

From I = J*T + S, dL/dJ = T dL/dI: where haze is dense the clean branch starves. The policies
differ only in *when* they compensate (docs/medium.md):

* ``none``   never;
* ``tgc``    from the first step (the medium may then lower T to inflate its own gradients);
* ``md-tgc`` only once the medium is frozen (Stage II), the paper's choice.

The forward pass is never changed: :class:`ScaleGradient` is the identity going forward.
"""

from __future__ import annotations

from typing import ClassVar

import torch
from torch import Tensor

from tridehaze_plugin.registry import register


class ScaleGradient(torch.autograd.Function):
    """Identity forward; backward multiplies the incoming gradient by ``scale`` (not differentiated)."""

    @staticmethod
    def forward(ctx, x: Tensor, scale: Tensor) -> Tensor:  # type: ignore[override]
        ctx.save_for_backward(scale)
        return x.view_as(x)

    @staticmethod
    def backward(ctx, grad: Tensor) -> tuple[Tensor, None]:  # type: ignore[override]
        (scale,) = ctx.saved_tensors
        return grad * scale, None


def compensation(transmittance: Tensor, t_min: float) -> Tensor:
    """The per-pixel gradient factor 1 / clamp(T, T_min) (T detached: the factor is a constant)."""
    return 1.0 / transmittance.detach().clamp(min=t_min)


class GradientPolicy:
    """Decides, per stage, whether the clean radiance's gradient is compensated."""

    name: ClassVar[str] = "none"

    def __init__(self, t_min: float = 0.1) -> None:
        if not 0.0 < t_min <= 1.0:
            raise ValueError(f"t_min must be in (0, 1], got {t_min}")
        self.t_min = t_min

    def active(self, stage: int) -> bool:
        """Whether compensation applies in ``stage`` (1: joint fitting, 2: medium frozen)."""
        return False

    def apply(self, clean: Tensor, transmittance: Tensor, stage: int) -> Tensor:
        """``clean`` [..., 3] unchanged forward; its gradient scaled where the policy is active."""
        if not self.active(stage) or not clean.requires_grad:
            return clean
        return ScaleGradient.apply(clean, compensation(transmittance, self.t_min))


class TGC(GradientPolicy):
    """Rescale the gradient reaching J by 1 / clamp(T, t_min) from the first step."""

    name = "tgc"

    def active(self, stage: int) -> bool:
        return True


class MDTGC(GradientPolicy):
    """Medium-decoupled TGC: the 1 / clamp(T, t_min) rescaling only once the medium is frozen (Stage II)."""

    name = "md-tgc"

    def active(self, stage: int) -> bool:
        return stage >= 2


register("gradient_policy", "none", GradientPolicy)
register("gradient_policy", "tgc", TGC)
register("gradient_policy", "md-tgc", MDTGC)
