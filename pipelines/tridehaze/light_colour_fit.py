"""The haze light's colour, read at the freeze from how each seed point's colour changes with its haze.

A surface point p seen by views k through transmittance T_kp shows I_kp = J_p T_kp + L (1 - T_kp).
With T known (the model's own, at the end of Stage I) and J_p free per point, that is linear in
the light: I / T = J_p + L (1 - T) / T, and the within-point (fixed-effects) regression of I / T
on (1 - T) / T gives L per channel. The joint gradient fit hardly moves the light along this
direction, where every Gaussian's colour can take up a change of the light's colour: in rooms it
ends grey where the truth and this estimate are blue, and the clean render takes the difference
as a cast (docs/results/medium_recovery.md, sessions 36 and 37). Only the colour is corrected:
the estimate's brightness assumes one light for every ray, which a direction-dependent or
dimming light is not.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from pipelines.engine.contract import Decision
from pipelines.tridehaze.once_at_step import OnceAtStep

MIN_VIEWS = 3
"""Points seen by fewer training views say too little about how their colour changes with haze."""
MIN_POINTS = 50
"""Fewer such points: no fit."""
MIN_T = 0.05
"""Observations through thicker haze are taken at this T (their I / T is mostly the photo's noise)."""
MAX_REL_STDERR = 0.02
"""A fit whose standard error exceeds this share of the light is not applied: the haze's
amount hardly varies within the points (thin or even haze), so nothing pins the colour. The
generated and real scenes measured so far fit within 0.002-0.013 (session 37)."""
GAIN_RANGE = (0.8, 1.25)
"""Per-channel limits on the correction: a larger one means the fit has gone wrong, not the light."""
MIN_HAZE = 0.3
"""Pixels whose rendered 1 - T is below this do not enter the model's mean light (S / (1 - T) is noise)."""
MAX_LIGHT_SPREAD = 0.05
"""The fit assumes one light for every ray. Where the medium's own per-ray light varies more than
this (its brightness's coefficient of variation over the training pixels with ``MIN_HAZE``), the
fit reads the light of the surfaces' rays, not of the sky's or the sun's, and is not applied. On
the 32 default runs of session 37 the courtyards, rooms and overcast streets spread 0.009-0.035,
the fields and sunlit streets 0.047-0.13; where the fit was applied above 0.06, the reconstruction
lost up to 2.3 dB (street-dense, 0.13) for no restoration gain."""


@dataclass
class PointObservations:
    """Every (point, view) pair where a training view sees a seed point."""

    point: Tensor  # [O] int64 index of the point
    colour: Tensor  # [O, 3] the hazy photo's colour at the point's pixel
    transmittance: Tensor  # [O] the model's T at that pixel


@dataclass
class LightFit:
    light: Tensor  # [3]
    rel_stderr: float
    """The largest channel's (statistical) standard error over the light's mean."""
    observations: int
    points: int


def fit_light(obs: PointObservations) -> LightFit | None:
    """The fixed-effects light [3] (weighted by T^2: the inversion multiplies the photo's error
    by 1 / T); None with fewer than ``MIN_POINTS`` points seen by ``MIN_VIEWS`` views or no
    variation of the haze within them."""
    pid, T = obs.point.cpu(), obs.transmittance.float().cpu().clamp(MIN_T, 1.0)
    y = obs.colour.float().cpu() / T[:, None]  # [O, 3]
    x = (1.0 - T) / T  # [O]
    w = T**2
    m = int(pid.max()) + 1 if len(pid) else 0
    count = torch.zeros(m).index_add_(0, pid, torch.ones_like(w))  # [M]
    keep = (count >= MIN_VIEWS)[pid]  # [O]
    points = int((count >= MIN_VIEWS).sum())
    if points < MIN_POINTS:
        return None
    sw = torch.zeros(m).index_add_(0, pid, w).clamp_min(1e-12)  # [M]
    x_mean = torch.zeros(m).index_add_(0, pid, w * x) / sw  # [M]
    y_mean = torch.zeros(m, 3).index_add_(0, pid, w[:, None] * y) / sw[:, None]  # [M, 3]
    xd, yd, wk = (x - x_mean[pid])[keep], (y - y_mean[pid])[keep], w[keep]
    sxx = float((wk * xd**2).sum())
    if sxx <= 1e-12:
        return None
    light = (wk[:, None] * xd[:, None] * yd).sum(dim=0) / sxx  # [3]
    resid = yd - xd[:, None] * light  # [O', 3]
    dof = max(len(wk) - points - 1, 1)
    stderr = ((wk[:, None] * resid**2).sum(dim=0) / dof / sxx).sqrt()  # [3]
    rel = float(stderr.max() / light.mean().abs().clamp_min(1e-6))
    return LightFit(light, rel, len(wk), points)


def chroma(rgb: Tensor) -> Tensor:
    """[3] each channel over the mean of the three."""
    return rgb / rgb.mean().clamp_min(1e-6)


def ray_light(T: Tensor, S: Tensor) -> Tensor:
    """S / (1 - T) [P, 3] at the pixels of T [H, W] and S [H, W, 3] with at least ``MIN_HAZE`` haze."""
    hazy = (1.0 - T) >= MIN_HAZE  # [H, W]
    return S[hazy] / (1.0 - T[hazy])[:, None]


def mean_ray_light(T: Tensor, S: Tensor) -> Tensor | None:
    """The mean of :func:`ray_light` [3]; None where no pixel has enough haze."""
    light = ray_light(T, S)
    return light.mean(dim=0) if len(light) else None


def mean_view_light(lights: list[Tensor]) -> Tensor | None:
    """The mean over views of each view's mean per-ray light ([P, 3] each) [3]; None where no view
    has a pixel with enough haze."""
    means = [x.mean(dim=0) for x in lights if len(x)]
    return torch.stack(means).mean(dim=0) if means else None


def light_spread(lights: list[Tensor]) -> float | None:
    """The coefficient of variation of the brightness of per-pixel lights ([P, 3] each)."""
    lum = torch.cat([x.mean(dim=-1) for x in lights]) if lights else torch.zeros(0)  # [P]
    if len(lum) < 2:
        return None
    return float(lum.std(unbiased=False) / lum.mean().clamp_min(1e-6))


class LightColourFit(OnceAtStep):
    """Makes the fit once, at the freeze, and says what it did (the gain itself is kept by the
    medium)."""

    def skip(self, why: str) -> None:
        """Mark the fit made without applying it, and say why."""
        self.mark_done()
        self.decisions.append(Decision(f"light colour fit not applied: {why}", {"light_gain": None}))

    def gain(
        self, obs: PointObservations | None, model_light: Tensor | None, spread: float | None
    ) -> Tensor | None:
        """The per-channel factor [3] that gives the medium's mean light ``model_light`` [3] the
        fitted light's colour at its own brightness; None (and a decision saying why) where the
        fit is not applied. ``spread``: :func:`light_spread` of the medium's per-ray light."""
        if spread is not None and spread > MAX_LIGHT_SPREAD:
            self.skip(
                f"the medium's light varies by {spread:.1%} over the rays (over {MAX_LIGHT_SPREAD:.0%}), "
                "and the fit assumes one light"
            )
            return None
        fit = fit_light(obs) if obs is not None and len(obs.point) else None
        why = None
        if fit is None:
            why = f"fewer than {MIN_POINTS} seed points seen by {MIN_VIEWS} views, or no haze variation"
        elif bool((fit.light <= 0.0).any()):
            why = (
                "the fitted light has a channel at or below zero (the haze's variation contradicts the model)"
            )
        elif fit.rel_stderr > MAX_REL_STDERR:
            why = f"its standard error is {fit.rel_stderr:.1%} of the light (over {MAX_REL_STDERR:.0%})"
        elif model_light is None:
            why = "no pixel has enough haze to read the medium's light on"
        if why is not None:
            self.skip(why)
            return None
        self.mark_done()
        gain = (chroma(fit.light) / chroma(model_light.float().cpu())).clamp(*GAIN_RANGE)  # [3]
        rgb = ", ".join(f"{g:.3f}" for g in gain.tolist())
        self.decisions.append(
            Decision(
                f"light colour fit on {fit.points} seed points ({fit.observations} observations): "
                f"the medium's light recoloured by ({rgb})",
                {
                    "light_gain": gain.tolist(),
                    "fitted_light": fit.light.tolist(),
                    "model_light": model_light.tolist(),
                    "rel_stderr": fit.rel_stderr,
                    "light_spread": spread,
                },
            )
        )
        return gain
