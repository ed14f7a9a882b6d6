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
pixels over the same window holds a one-light run at the weak weight (session 40). A bright
surface whose colour is the light's looks the same in one image (beer's floor: session 41), but
structure from motion matched it across views: the seed points land on it about as often as on
the rest of the image, and hardly ever on opaque haze (session 42).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

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
        seen_located: float = 1.0,
    ) -> None:
        super().__init__()
        self.weak, self.strong, self.threshold = weak, strong, threshold
        self.seen_level, self.seen_share = seen_light
        """A one-light run keeps the weak weight where more than ``seen_share`` of the window's
        pixels rendered T under ``seen_level``: those pixels see the haze light itself and pin its
        brightness, which is what the strong bound would otherwise supply (1.0: never)."""
        self.seen_located = seen_located
        """The opaque pixels count as haze only where the seed points land on them at under this
        fraction of their rate over all the window's pixels (1.0: any rate; no seed points at
        all: the gate cannot tell haze from surface, and the bound stays strong)."""
        if self.seen_level not in OPAQUE_LEVELS:
            raise ValueError(f"seen-light level {self.seen_level} is not one of {OPAQUE_LEVELS}")
        self.measures = measures
        """Whether the verdict is taken at all."""
        self.start, self.decision_step = window
        self.register_buffer("sums", torch.zeros(3, dtype=torch.float64))  # count, sum, sum of squares
        # pixels seen in the window, then those under each of OPAQUE_LEVELS
        self.register_buffer("opaque", torch.zeros(1 + len(OPAQUE_LEVELS), dtype=torch.float64))
        # located pixels seen in the window, and those of them under seen_level
        self.register_buffer("located", torch.zeros(2, dtype=torch.float64))
        # -1: not decided yet; NO_MEASUREMENT: decided without one (checkpoints hold finite values only)
        self.register_buffer("decided", torch.tensor(-1.0, dtype=torch.float64))  # else the cv
        self.decisions: list[str | Decision] = []
        """The decision, once made (the trainer prints it and writes it to logs/decisions.jsonl)."""
        self._strong: bool | None = None  # the decided buffer read once, not at every step

    def observe(self, step: int, med: MediumRender, located: Tensor | None = None) -> None:
        """Add one step's per-ray light and opaque pixels; ``located`` [H, W] bool: where the view's
        seed points land (nothing is computed outside the window)."""
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
        if located is not None:
            seen = located & (T < self.seen_level)  # [H, W]
            self.located += torch.stack([located.sum(), seen.sum()]).double()

    def weight(self, step: int) -> float:
        """The dark-channel weight at ``step``: ``weak`` until the decision, then the one decided.
        (Strong from the start and weak after an anisotropic verdict does not work: sunlit scenes
        do not recover from the strong bound's first steps, session 30.)"""
        if not self.measures or step < self.decision_step:
            return self.weak
        if self._strong is None:
            if float(self.decided) == -1.0:
                self._decide(step)
            self._strong = self._raises()
        return self.strong if self._strong else self.weak

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
        its brightness: more than ``seen_share`` of them under ``seen_level``, and, with
        ``seen_located`` under 1, seed points landing on those under that fraction of their rate
        over all pixels."""
        if self.seen_light_share() <= self.seen_share:
            return False
        if self.seen_located >= 1.0:
            return True
        rate = self.located_rate()
        return rate is not None and rate < self.seen_located

    def located_rate(self) -> float | None:
        """How often the seed points land on the window's opaque pixels (T under ``seen_level``),
        relative to all its pixels: about 1 for surfaces read as haze, near 0 for opaque haze;
        None without seed points or opaque pixels."""
        total, opaque = float(self.opaque[0]), float(self.opaque[1 + OPAQUE_LEVELS.index(self.seen_level)])
        located, located_opaque = (float(v) for v in self.located)
        if located <= 0.0 or opaque <= 0.0:
            return None
        return (located_opaque / opaque) / (located / total)

    def seen_light_share(self) -> float:
        """The share of the window's pixels whose rendered T was under ``seen_level``."""
        return self.opaque_shares()[f"opaque_{self.seen_level:g}"]

    def _raises(self) -> bool:
        """Whether the decision raises the weight: one light, not seen through opaque haze."""
        return self.judged_one_light() and not self.sees_light() and self.strong > 0.0

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
        weight = self.strong if self._raises() else self.weak
        located = {"located_rate": self.located_rate()} if self.seen_located < 1.0 else {}
        if cv is None:
            text = "no pixel has enough haze to measure the medium's light on"
        elif seen:
            text = (
                f"the medium's light varies by {cv:.1%} over the rays (under {self.threshold:.1%}): one "
                f"light, but {self.seen_light_share():.0%} of the pixels see it through opaque haze (T < {self.seen_level:g}), "
                f"which pins its brightness{self._located_text()}"
            )
        elif one_light:
            text = (
                f"the medium's light varies by {cv:.1%} over the rays (under {self.threshold:.1%}): "
                f"one light, which only the dark channel pins{self._located_text()}"
            )
        else:
            text = f"the medium's light varies by {cv:.1%} over the rays (not under {self.threshold:.1%})"
        self.decisions.append(
            Decision(
                f"{text}; dark-channel weight {weight:g} from step {step}",
                {"light_cv": cv, "dcp_weight": weight, **self.opaque_shares(), **located},
            )
        )

    def _located_text(self) -> str:
        """The located check's reading, where it was taken and the share alone would gate."""
        rate = self.located_rate()
        if self.seen_located >= 1.0 or self.seen_light_share() <= self.seen_share:
            return ""
        if rate is None:
            return " (no seed points to tell opaque haze from a surface of the light's colour)"
        if rate < self.seen_located:
            return f" (seed points land on those pixels at {rate:.2f}x their rate elsewhere)"
        return (
            f" ({self.seen_light_share():.0%} of the pixels render as opaque haze, but seed points land on them "
            f"at {rate:.2f}x their rate elsewhere: surfaces of the light's colour, not haze)"
        )

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:  # noqa: ANN001
        # checkpoints from before this module: not decided yet, nothing collected
        state_dict.setdefault(prefix + "sums", self.sums.clone())
        state_dict.setdefault(prefix + "decided", self.decided.clone())
        state_dict.setdefault(prefix + "opaque", self.opaque.clone())
        state_dict.setdefault(prefix + "located", self.located.clone())
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        self._strong = None
