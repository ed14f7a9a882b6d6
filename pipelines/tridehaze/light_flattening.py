"""One light for a run judged one light, from the freeze on.

The one-light verdict says the medium's light is the same along every ray, yet the learnt light
keeps a direction dependence (room-uniform: 2.6 % spread against the truth's 1.4 %), and a test
view looking where it is dimmer gets too little in-scattering: its clean render carries a
per-view colour offset (session 58). At the freeze the light is replaced by its mean over the
training pixels, so every view shares one brightness; Stage II refits the Gaussians through it.
Where opaque haze shows the light itself, its direction dependence is observed and stays.
"""

from __future__ import annotations

from torch import Tensor

from pipelines.engine.contract import Decision
from pipelines.tridehaze.once_at_step import OnceAtStep


class LightFlattening(OnceAtStep):
    """Flattens the light once, at the freeze, where the run was judged one light (the flat light
    itself is the medium's)."""

    def __init__(self, enabled: bool, step: int, seen_share: float = 1.0) -> None:
        super().__init__(enabled, step)
        self.seen_share = seen_share

    def decide(
        self, one_light: bool, seen: float | None, mean_light: Tensor | None, spread: float | None
    ) -> Tensor | None:
        """The light [3] to flatten to (the medium's mean per-ray light ``mean_light``), or None
        where the run is not one light, its opaque pixels (share ``seen`` of the verdict window's)
        show the light, or nothing measured it; says which once."""
        self.mark_done()
        why = None
        if not one_light:
            why = "not judged one light"
        elif seen is not None and seen > self.seen_share:
            why = f"{seen:.0%} of the pixels see it through opaque haze (over {self.seen_share:.0%})"
        elif mean_light is None:
            why = "no pixel has enough haze to read the light on"
        if why is not None:
            self.decisions.append(Decision(f"light kept direction-dependent: {why}", {"flat_light": None}))
            return None
        rgb = ", ".join(f"{v:.3f}" for v in mean_light.tolist())
        spread_text = "" if spread is None else f" (it varied by {spread:.1%} over the training pixels)"
        self.decisions.append(
            Decision(
                f"one light: the medium's light set to its mean ({rgb}) for every ray{spread_text}",
                {"flat_light": mean_light.tolist(), "light_spread_before": spread},
            )
        )
        return mean_light
