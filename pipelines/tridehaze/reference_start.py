"""Start a trainable medium at the generator's true one (a diagnosis on td-synth data, never a
method): does training keep the true medium, or does it leave it for the one it ends at from the
dark channel's start? The first says the objective is right and the start is the lever; the
second says the losses prefer a wrong medium (docs/results/medium_recovery.md, session 55). With
``part="mean"``, the start is the true medium's box mean: one extinction and one light for every
point and direction, so its amount and light are right but not its layout (session 59);
``"extinction"`` keeps the true extinction with the mean light, ``"light"`` the true light with the
mean extinction, to tell which of the two the start has to carry (session 60)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import torch
from torch import Tensor

from components.data.scene import SceneTransform
from components.medium.base import MediumField
from components.medium.reference import true_medium

STEPS = 1500
"""Adam steps of the fit (enough for a relative extinction error of a few per cent on td-synth media)."""
POINTS = 8192
"""Random box points (and directions) per step."""

Part = Literal["all", "mean", "extinction", "light"]
"""What of the true medium the start takes: all of it, its box mean, its extinction (with the mean
light) or its light (with the mean extinction)."""
PARTS: dict[str, Part] = {
    "reference": "all",
    "reference-mean": "mean",
    "reference-extinction": "extinction",
    "reference-light": "light",
}
"""The part each ``--pipeline.medium-start`` value other than ``dark-channel`` takes."""


def fit_to_reference(
    field: MediumField, root: Path, transform: SceneTransform, seed: int = 0, part: Part = "all"
) -> dict[str, float]:
    """Fit ``field``'s extinction (in log) and light to the generator's medium of the dataset at
    ``root`` (or the ``part`` of it asked for), at uniform points of the field's box with uniform
    directions; returns the fit's final relative extinction error and light error (means over a
    fresh sample, against what was fitted)."""
    truth = true_medium(field.config, field.bounds, root, transform)
    gen = torch.Generator().manual_seed(seed)  # the run's own random stream is left as it was
    device = field.bounds_center.device
    if part != "all":
        truth = _Part(truth, _box_mean(truth, *_sample(field, gen, device)), part)
    params = [p for p, _ in field.param_groups().values()]
    opt = torch.optim.Adam(params, lr=0.01)
    for _ in range(STEPS):
        x, d = _sample(field, gen, device)
        with torch.no_grad():
            want = truth(x, d)
        got = field(x, d)
        loss = _log_error(got.beta, want.beta).square().mean() + (got.light - want.light).square().mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    x, d = _sample(field, gen, device)
    with torch.no_grad():
        got, want = field(x, d), truth(x, d)
        beta_err = float(_log_error(got.beta, want.beta).abs().mean())
        light_err = float((got.light - want.light).abs().mean())
    return {"reference_start_log_beta_mae": beta_err, "reference_start_light_mae": light_err}


class _Uniform:
    """A medium with one extinction and one light everywhere (called like a medium field)."""

    def __init__(self, beta: Tensor, light: Tensor) -> None:
        self.beta, self.light = beta, light  # [*S], [3]

    def __call__(self, x: Tensor, d: Tensor) -> _Uniform:
        n = x.shape[0]
        return _Uniform(self.beta.expand(n, *self.beta.shape), self.light.expand(n, 3))


class _Part:
    """The true medium with its extinction, its light or both replaced by their box mean."""

    def __init__(self, truth, mean: _Uniform, part: Part) -> None:  # noqa: ANN001 - a medium field
        self.truth, self.mean, self.part = truth, mean, part

    def __call__(self, x: Tensor, d: Tensor) -> _Uniform:
        flat = self.mean(x, d)
        if self.part == "mean":
            return flat
        true = self.truth(x, d)
        if self.part == "extinction":
            return _Uniform(true.beta, flat.light)
        return _Uniform(flat.beta, true.light)


def _box_mean(truth, x: Tensor, d: Tensor) -> _Uniform:  # noqa: ANN001 - a medium field
    """The medium ``truth``'s mean extinction and light over the points x [P, 3], directions d [P, 3]."""
    with torch.no_grad():
        got = truth(x, d)
        return _Uniform(got.beta.mean(dim=0), got.light.mean(dim=0))


def _sample(field: MediumField, gen: torch.Generator, device: torch.device) -> tuple[Tensor, Tensor]:
    """Uniform points of the field's box [P, 3] and uniform unit directions [P, 3]."""
    u = torch.rand(POINTS, 3, generator=gen) * 2.0 - 1.0
    x = field.bounds_center.cpu() + u * field.bounds_half.cpu()
    d = torch.nn.functional.normalize(torch.randn(POINTS, 3, generator=gen), dim=-1)
    return x.to(device), d.to(device)


def _log_error(beta: Tensor, target: Tensor) -> Tensor:
    return torch.log(beta.clamp_min(1e-6)) - torch.log(target.clamp_min(1e-6))
