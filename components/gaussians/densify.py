"""Adaptive density control of 3DGS: clone, split, prune and opacity reset.

Same schedule and thresholds as the 3DGS paper / gsplat's default strategy (screen-space
gradient of the projected centres in NDC units, a size test against the scene extent), written
against our :class:`GaussianModel` and named per-parameter Adam optimizers. Optimizer moments of
new Gaussians start at zero; pruned ones are dropped, so training continues smoothly.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor, nn

from components.gaussians.model import GaussianModel, logit
from components.rasterizers.base import RasterizeOutput
from components.rasterizers.projection import quat_to_rotmat
from tridehaze_plugin.errors import ConfigError


@dataclass
class DensifyConfig:
    """When and how the Gaussian set grows and shrinks during training."""

    enabled: bool = True
    """Turn adaptive density control on or off (off: the seed cloud's count stays fixed)."""
    refine_start: int = 500
    """First step at which Gaussians are cloned, split or pruned."""
    refine_stop: int | None = None
    """No refinement after this step (None: half of the run, as 15k of 3DGS's 30k steps)."""
    refine_every: int = 100
    """Steps between two refinements."""
    reset_every: int = 3000
    """Steps between opacity resets (which let occluded floaters be pruned); resets come only up
    to ``refine-stop``, so with its default (half the run) a run under 6000 steps has none, as
    tri-dehaze's 3000. Measured on tri-dehaze (docs/results/medium_recovery.md, session 36): one
    reset at the medium's freeze is a tie, one while the medium learns costs 2.4 dB (the medium
    takes the image meanwhile)."""
    grow_grad2d: float = 0.0002
    """Mean screen-space gradient (NDC units) above which a Gaussian is cloned or split."""
    grow_scale3d: float = 0.01
    """Gaussians larger than this fraction of the scene extent are split, smaller ones cloned."""
    prune_opacity: float = 0.005
    """Gaussians more transparent than this are removed."""
    prune_scale3d: float = 0.1
    """After the first opacity reset, Gaussians larger than this fraction of the extent are removed
    (never in a run without a reset)."""
    max_gaussians: int = 1_000_000
    """Hard cap on the number of Gaussians; growth beyond it keeps the highest-gradient candidates."""
    growth: Literal["schedule", "plateau"] = "schedule"
    """schedule: clone and split at every refinement until refine_stop (as 3DGS); plateau: stop
    growing for good at the first refinement where the photometric loss no longer improves (pruning
    goes on), so the Gaussian count follows what the scene needs."""
    plateau_min_improvement: float = 0.02
    """For plateau growth: the relative decrease of the mean photometric loss over the last
    refine_every steps, against the window before, below which growth stops."""

    def check_values(self, prefix: str = "--pipeline.densify.") -> None:
        if not 0.0 <= self.plateau_min_improvement <= 1.0:
            raise ConfigError(
                f"{prefix}plateau-min-improvement must be in [0, 1], got {self.plateau_min_improvement}"
            )


class Densifier:
    """Collects per-Gaussian statistics after each backward pass and edits the model on schedule."""

    def __init__(self, config: DensifyConfig, scene_extent: float, max_steps: int) -> None:
        self.config = config
        self.scene_extent = scene_extent
        self.refine_stop = config.refine_stop if config.refine_stop is not None else max_steps // 2
        self.grad_sum: Tensor | None = None  # [N]
        self.count: Tensor | None = None  # [N]
        self.loss_sum = torch.zeros((), dtype=torch.float64)  # photometric loss since the last refinement
        self.loss_steps = 0
        self.plateau = torch.tensor([-1.0, -1.0], dtype=torch.float64)
        """[step growth stopped at (-1: growing), mean loss of the previous window (-1: none yet)]; a
        tensor so the owning pipeline can keep it in its checkpoints (resume continues the same
        decision). Finite on purpose: checkpoints are checked for non-finite values."""
        self.decisions: list[str] = []
        """Human-readable growth decisions, newest last (the trainer prints them)."""

    # ------------------------------------------------------------------ statistics
    def collect(self, out: RasterizeOutput, weight: Tensor | None = None) -> None:
        """Accumulate the NDC-space gradient norm of visible Gaussians (call after backward).

        ``weight [C, N]`` multiplies each Gaussian's gradient norm first; the Tri-DehazeGS pipeline
        uses it to take out the transmittance compensation (docs/medium.md).
        """
        grad = out.means2d.grad
        if grad is None:
            return
        c, n = out.radii.shape
        if self.grad_sum is None or self.grad_sum.shape[0] != n:
            self._reset_stats(n, grad.device)
        scale = torch.tensor([out.width / 2.0 * c, out.height / 2.0 * c], device=grad.device)
        norms = (grad.detach() * scale).norm(dim=-1)  # [C, N]
        if weight is not None:
            norms = norms * weight
        visible = out.radii > 0  # [C, N]
        self.grad_sum += (norms * visible).sum(0)
        self.count += visible.sum(0)

    def observe_loss(self, loss: Tensor) -> None:
        """Add one step's photometric loss (a scalar tensor; kept on its device until a refinement)."""
        self.loss_sum = self.loss_sum.to(loss.device) + loss.detach().double()
        self.loss_steps += 1

    @property
    def growth_stopped_at(self) -> int | None:
        step = int(self.plateau[0])
        return step if step >= 0 else None

    def _growth_allowed(self, done: int) -> bool:
        """Under ``plateau`` growth: compare this window's mean loss with the previous one."""
        if self.config.growth != "plateau":
            return True
        if self.growth_stopped_at is not None:
            return False
        if self.loss_steps == 0:
            return True
        mean = float(self.loss_sum) / self.loss_steps
        prev = float(self.plateau[1])
        self.plateau[1] = mean
        self.loss_sum = torch.zeros((), dtype=torch.float64)
        self.loss_steps = 0
        if prev <= 0 or done < self.config.refine_start:
            return True
        gain = (prev - mean) / prev
        if gain < self.config.plateau_min_improvement:
            self.plateau[0] = float(done)
            self.decisions.append(
                f"step {done}: densification stops growing: photometric loss {prev:.5f} -> {mean:.5f} "
                f"over the last {self.config.refine_every} steps ({100 * gain:+.1f} %, threshold "
                f"{100 * self.config.plateau_min_improvement:.1f} %)"
            )
            return False
        return True

    def _reset_stats(self, n: int, device: torch.device) -> None:
        self.grad_sum = torch.zeros(n, device=device)
        self.count = torch.zeros(n, device=device)

    # ------------------------------------------------------------------ schedule
    def step(self, step: int, model: GaussianModel, optimizers: dict[str, torch.optim.Optimizer]) -> dict:
        """Apply the refinements due after optimizer step ``step`` (0-based); returns counts for the log."""
        cfg = self.config
        done = step + 1
        log: dict[str, int] = {}
        if not cfg.enabled:
            return log
        if cfg.growth == "plateau" and done < cfg.refine_start and done % cfg.refine_every == 0:
            self._growth_allowed(done)  # the window before the first refinement sets the reference
        if cfg.refine_start <= done <= self.refine_stop and done % cfg.refine_every == 0:
            log.update(self._refine(done, model, optimizers))
        if done % cfg.reset_every == 0 and done <= self.refine_stop:
            self._reset_opacity(model, optimizers)
            log["opacity_reset"] = 1
        return log

    @torch.no_grad()
    def _refine(self, done: int, model: GaussianModel, optimizers) -> dict[str, int]:
        cfg = self.config
        n = model.num_gaussians
        if self.grad_sum is None or self.grad_sum.shape[0] != n:
            self._reset_stats(n, model.means.device)
        avg = self.grad_sum / self.count.clamp_min(1)
        high = avg > cfg.grow_grad2d  # [N]
        if not self._growth_allowed(done):
            high = torch.zeros_like(high)
        big = model.scales.max(dim=-1).values > cfg.grow_scale3d * self.scene_extent
        room = max(cfg.max_gaussians - n, 0)
        clone, split = high & ~big, high & big
        clone, split = _cap(clone, split, avg, room)
        n_clone, n_split = int(clone.sum()), int(split.sum())
        if n_clone:
            self._apply(model, optimizers, lambda p, name: torch.cat([p, p[clone]]), grow=n_clone)
            split = torch.cat([split, torch.zeros(n_clone, dtype=torch.bool, device=split.device)])
        if n_split:
            self._split(model, optimizers, split)
        op = model.opacities
        prune = op < cfg.prune_opacity
        if done > cfg.reset_every:
            prune |= model.scales.max(dim=-1).values > cfg.prune_scale3d * self.scene_extent
        n_prune = int(prune.sum())
        if n_prune and n_prune < model.num_gaussians:
            keep = ~prune
            self._apply(model, optimizers, lambda p, name: p[keep], keep=keep)
        self._reset_stats(model.num_gaussians, model.means.device)
        return {"cloned": n_clone, "split": n_split, "pruned": n_prune}

    @torch.no_grad()
    def prune(self, model: GaussianModel, optimizers: dict[str, torch.optim.Optimizer], mask: Tensor) -> int:
        """Remove the Gaussians where ``mask`` [N] is set (never all of them), carrying Adam moments
        and the growth statistics of the rest; returns how many were removed."""
        n_prune = int(mask.sum())
        if n_prune == 0 or n_prune >= model.num_gaussians:
            return 0
        keep = ~mask
        self._apply(model, optimizers, lambda p, name: p[keep], keep=keep)
        if self.grad_sum is not None and self.grad_sum.shape[0] == keep.shape[0]:
            self.grad_sum, self.count = self.grad_sum[keep], self.count[keep]
        return n_prune

    def _split(self, model: GaussianModel, optimizers, sel: Tensor) -> None:
        """Replace each selected Gaussian by two samples from it, 1.6x smaller."""
        scales = model.scales[sel]  # [M, 3]
        rot = quat_to_rotmat(model.normalized_quats[sel])  # [M, 3, 3]
        offsets = torch.einsum(
            "mij,smj->smi", rot, torch.randn(2, *scales.shape, device=scales.device) * scales
        )
        keep = ~sel

        def make(p: Tensor, name: str) -> Tensor:
            if name == "means":
                new = (p[sel][None] + offsets).reshape(-1, 3)  # [2M, 3]
            elif name == "log_scales":
                new = (p[sel] - math.log(1.6)).repeat(2, 1)
            else:
                new = p[sel].repeat(2, *[1] * (p.dim() - 1))
            return torch.cat([p[keep], new])

        self._apply(model, optimizers, make, keep=keep, grow=2 * int(sel.sum()))

    def _reset_opacity(self, model: GaussianModel, optimizers) -> None:
        cap = logit(2.0 * self.config.prune_opacity)
        new = nn.Parameter(model.opacity_logits.detach().clamp_max(cap))
        _swap(
            optimizers["opacity_logits"], model.params["opacity_logits"], new, lambda s: torch.zeros_like(s)
        )
        model.replace_params({"opacity_logits": new})

    @staticmethod
    def _apply(
        model: GaussianModel,
        optimizers: dict[str, torch.optim.Optimizer],
        make: Callable[[Tensor, str], Tensor],
        keep: Tensor | None = None,
        grow: int = 0,
    ) -> None:
        """Rebuild every parameter with ``make`` and carry Adam moments: kept rows move, new rows are 0."""
        new_params = {}
        for name in model.param_names:
            old = model.params[name]
            new = nn.Parameter(make(old.detach(), name).contiguous())

            def moments(s: Tensor) -> Tensor:
                kept = s[keep] if keep is not None else s
                return torch.cat([kept, s.new_zeros((grow, *s.shape[1:]))])

            _swap(optimizers[name], old, new, moments)
            new_params[name] = new
        model.replace_params(new_params)


def _swap(opt: torch.optim.Optimizer, old: nn.Parameter, new: nn.Parameter, moments: Callable) -> None:
    """Point ``opt`` at ``new`` and remap its Adam moments (``step`` is kept)."""
    state = opt.state.pop(old, None)
    for group in opt.param_groups:
        group["params"] = [new if p is old else p for p in group["params"]]
    if state:
        for key in ("exp_avg", "exp_avg_sq"):
            if key in state:
                state[key] = moments(state[key])
        opt.state[new] = state


def _cap(clone: Tensor, split: Tensor, score: Tensor, room: int) -> tuple[Tensor, Tensor]:
    """Limit growth to ``room`` new Gaussians (a split adds one net), keeping the highest scores."""
    if int(clone.sum()) + int(split.sum()) <= room:
        return clone, split
    cand = clone | split
    order = torch.argsort(torch.where(cand, score, torch.full_like(score, -1.0)), descending=True)
    allowed = torch.zeros_like(cand)
    allowed[order[:room]] = True
    return clone & allowed, split & allowed
