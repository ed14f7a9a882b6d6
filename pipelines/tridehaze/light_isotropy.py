"""The dark-channel term's weight, raised once the medium's light proves the same along every ray.

Nothing in hazy photos pins the haze light's brightness where no pixel sees it (a room, a
courtyard: docs/results/medium_recovery.md, session 18); the light then starts from the dark
channel's airlight, which is too dim there, and the medium ends too dense. A strong own-light
dark-channel bound corrects that. Where the light depends on the direction (sunlit,
forward-scattering haze), the sky and the sun's side show it and the photos do pin it; a strong
bound there only thins the field along the sky and brightens the light (session 28). Which case
a scene is shows in the medium's own light a few hundred steps into Stage I: the spread of its
per-ray light (S / (1 - T)) over the pixels it scatters into. Dense haze is the exception: its
opaque pixels show the light itself (I ~ L), which pins the brightness, and there the bound is only
its own margin (T >= 1 - omega against a true ~0), so it thins the medium; the share of such
pixels over the same window holds a one-light run at the weak weight (session 40).
"""

from __future__ import annotations

import torch
from torch import nn

from components.medium.compositing import MediumRender
from pipelines.engine.contract import Decision

MIN_HAZE = 0.2
"""Pixels whose rendered 1 - T is below this say little about the light (S / (1 - T) is noise)."""
OPAQUE_LEVELS = (0.02, 0.05, 0.1, 0.15)
"""Rendered-T levels under which a pixel counts as seeing the haze light itself (I ~ S), logged at
the decision as the share of the window's pixels below each."""
NO_MEASUREMENT = -2.0
"""The ``decided`` buffer's value when no pixel had enough haze in the window (the weight stays weak)."""


class LightIsotropy(nn.Module):
    """Collects the per-ray light's spread over a window of steps and judges it once: one light or
    not. Two things read the verdict: the dark-channel weight (``strong`` after a one-light verdict;
    0 keeps ``weak``) and the clean render's fill (``clean-fill auto``); ``measures`` is off where
    neither does or the medium never learns.

    The sums are buffers, so a run resumed inside the window or after the decision goes on as an
    uninterrupted one would (the decision is kept, not made again)."""

    def __init__(
        self,
        weak: float,
        strong: float,
        threshold: float,
        window: tuple[int, int],
        measures: bool = True,
        seen_light: tuple[float, float] = (0.05, 1.0),
        ramp: tuple[float, float] | None = None,
    ) -> None:
        super().__init__()
        self.weak, self.strong, self.threshold = weak, strong, threshold
        if ramp is not None and not 0.0 <= ramp[0] < ramp[1]:
            raise ValueError(f"light-weight ramp {ramp} must rise: 0 <= start < end")
        self.ramp = ramp
        """Spreads (start, end) over which the weight falls geometrically from ``strong`` to
        ``weak`` instead of stepping at ``threshold``: a spread read near the threshold then moves
        the weight a little, not by 10x (None: the step)."""
        self.seen_level, self.seen_share = seen_light
        """A one-light run keeps the weak weight where more than ``seen_share`` of the window's
        pixels rendered T under ``seen_level``: those pixels see the haze light itself and pin its
        brightness, which is what the strong bound would otherwise supply (1.0: never)."""
        if self.seen_level not in OPAQUE_LEVELS:
            raise ValueError(f"seen-light level {self.seen_level} is not one of {OPAQUE_LEVELS}")
        self.measures = measures
        """Whether the verdict is taken at all."""
        self.start, self.decision_step = window
        self.register_buffer("sums", torch.zeros(3, dtype=torch.float64))  # count, sum, sum of squares
        # pixels seen in the window, then those under each of OPAQUE_LEVELS
        self.register_buffer("opaque", torch.zeros(1 + len(OPAQUE_LEVELS), dtype=torch.float64))
        # -1: not decided yet; NO_MEASUREMENT: decided without one (checkpoints hold finite values only)
        self.register_buffer("decided", torch.tensor(-1.0, dtype=torch.float64))  # else the cv
        self.decisions: list[str | Decision] = []
        """The decision, once made (the trainer prints it and writes it to logs/decisions.jsonl)."""
        self._weight: float | None = None  # the decided buffer read once, not at every step

    def observe(self, step: int, med: MediumRender) -> None:
        """Add one step's per-ray light (nothing is computed outside the window)."""
        if not self.measures or not self.start <= step < self.decision_step:
            return
        haze = 1.0 - med.pixel_transmittance().detach()  # [H, W, 1]
        light = med.ray_light(1e-6).detach().mean(dim=-1)  # [H, W] luminance of the ray's light
        keep = (haze[..., 0] >= MIN_HAZE).to(light.dtype)  # [H, W] a weight: no host sync
        light = light.double()
        keep = keep.double()
        self.sums += torch.stack([keep.sum(), (keep * light).sum(), (keep * light * light).sum()])
        T = 1.0 - haze[..., 0]  # [H, W]
        below = [(T < level).sum() for level in OPAQUE_LEVELS]
        self.opaque += torch.stack([T.new_tensor(T.numel()), *below]).double()

    def weight(self, step: int) -> float:
        """The dark-channel weight at ``step``: ``weak`` until the decision, then the one decided.
        (Strong from the start and weak after an anisotropic verdict does not work: sunlit scenes
        do not recover from the strong bound's first steps, session 30.)"""
        if not self.measures or step < self.decision_step:
            return self.weak
        if self._weight is None:
            if float(self.decided) == -1.0:
                self._decide(step)
            self._weight = self._decided_weight()
        return self._weight

    def raised(self, step: int) -> bool:
        """Whether the decision taken by ``step`` raised the weight: one light, not seen through
        opaque haze (the step), or a spread under the ramp's end."""
        self.weight(step)  # takes the decision at its step
        return self.measures and step >= self.decision_step and self._raises_weight()

    def measured_cv(self) -> float | None:
        """The light's spread the decision was made on; None before the decision or where no
        pixel had enough haze to measure it."""
        cv = float(self.decided)
        return cv if cv >= 0.0 else None

    def judged_one_light(self) -> bool:
        """Whether the run has decided that its medium's light is one light (false before the
        decision, without one, and where nothing is measured)."""
        cv = self.measured_cv()
        return self.measures and cv is not None and cv < self.threshold

    def sees_light(self) -> bool:
        """Whether the window's pixels saw the haze light itself (opaque haze) often enough to pin
        its brightness: more than ``seen_share`` of them under ``seen_level``."""
        return self.seen_light_share() > self.seen_share

    def seen_light_share(self) -> float:
        """The share of the window's pixels whose rendered T was under ``seen_level``."""
        return self.opaque_shares()[f"opaque_{self.seen_level:g}"]

    def _raises(self) -> bool:
        """Whether the decision raises the weight: one light, not seen through opaque haze."""
        return self.judged_one_light() and not self.sees_light() and self.strong > 0.0

    def _ramps(self) -> bool:
        """Whether the ramp sets the weight (one is given, a spread was measured, a strong weight
        is set and no opaque haze shows the light); otherwise the step at ``threshold`` does."""
        return (
            self.ramp is not None
            and self.measured_cv() is not None
            and self.strong > 0.0
            and not self.sees_light()
        )

    def _raises_weight(self) -> bool:
        if self._ramps():
            return self.measured_cv() < self.ramp[1]
        return self._raises()

    def _decided_weight(self) -> float:
        """The weight the decision sets: the step at ``threshold``, or the ramp's value."""
        if not self._ramps():
            return self.strong if self._raises() else self.weak
        return ramped_weight(self.measured_cv(), self.ramp, self.weak, self.strong)

    def opaque_shares(self) -> dict[str, float]:
        """The share of the window's pixels whose rendered T was under each of ``OPAQUE_LEVELS``."""
        total, *below = (float(v) for v in self.opaque)
        return {
            f"opaque_{level:g}": b / total if total > 0 else 0.0
            for level, b in zip(OPAQUE_LEVELS, below, strict=True)
        }

    def _decide(self, step: int) -> None:
        n, s, ss = (float(v) for v in self.sums)
        cv = None
        if n >= 1.0:
            mean = s / n
            cv = max(ss / n - mean * mean, 0.0) ** 0.5 / max(mean, 1e-12)
        # no pixel with enough haze: nothing for the bound to correct, and nothing to decide on
        self.decided.fill_(NO_MEASUREMENT if cv is None else cv)
        one_light = cv is not None and cv < self.threshold
        seen = one_light and self.sees_light()
        weight = self._decided_weight()
        if cv is None:
            text = "no pixel has enough haze to measure the medium's light on"
        elif seen:
            text = (
                f"the medium's light varies by {cv:.1%} over the rays (under {self.threshold:.1%}): one "
                f"light, but {self.seen_light_share():.0%} of the pixels see it through opaque haze (T < {self.seen_level:g}), "
                "which pins its brightness"
            )
        elif self.ramp is not None:
            text = (
                f"the medium's light varies by {cv:.1%} over the rays (weight ramp "
                f"{self.ramp[0]:.1%} to {self.ramp[1]:.1%})"
            )
        elif one_light:
            text = (
                f"the medium's light varies by {cv:.1%} over the rays (under {self.threshold:.1%}): "
                "one light, which only the dark channel pins"
            )
        else:
            text = f"the medium's light varies by {cv:.1%} over the rays (not under {self.threshold:.1%})"
        self.decisions.append(
            Decision(
                f"{text}; dark-channel weight {weight:g} from step {step}",
                {"light_cv": cv, "dcp_weight": weight, **self.opaque_shares()},
            )
        )

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:  # noqa: ANN001
        # checkpoints from before this module: not decided yet, nothing collected
        state_dict.setdefault(prefix + "sums", self.sums.clone())
        state_dict.setdefault(prefix + "decided", self.decided.clone())
        state_dict.setdefault(prefix + "opaque", self.opaque.clone())
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        self._weight = None


def ramped_weight(cv: float, ramp: tuple[float, float], weak: float, strong: float) -> float:
    """``strong`` at spreads up to ``ramp[0]``, ``weak`` from ``ramp[1]``, geometric between (the
    weights span a decade, so a linear blend would sit near ``strong`` over most of the ramp)."""
    start, end = ramp
    share = (cv - start) / (end - start)
    if share <= 0.0 or share >= 1.0:
        return strong if share <= 0.0 else weak
    if weak <= 0.0:
        return strong * (1.0 - share)
    return strong * (weak / strong) ** share
