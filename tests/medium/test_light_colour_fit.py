"""The light colour fit at the freeze: the fixed-effects light from points seen through varying
haze, when it declines, and the medium's per-channel recolouring (exact, kept in checkpoints)."""

from __future__ import annotations

import pytest
import torch

from components.medium.base import FieldBounds, MediumConfig
from components.medium.fields import TriplaneField
from pipelines.tridehaze.light_colour_fit import (
    MAX_LIGHT_SPREAD,
    MAX_REL_STDERR,
    LightColourFit,
    PointObservations,
    chroma,
    fit_light,
    light_spread,
    ray_light,
)

LIGHT = torch.tensor([0.62, 0.70, 0.81])  # a bluish haze light


def _observations(
    light: torch.Tensor = LIGHT,
    points: int = 400,
    views: int = 5,
    noise: float = 0.004,
    t_range=(0.15, 0.9),
    seed=0,
) -> PointObservations:
    """Each point, of a random clean colour, seen by ``views`` views through random haze."""
    g = torch.Generator().manual_seed(seed)
    J = torch.rand(points, 3, generator=g)  # [M, 3]
    pid = torch.arange(points).repeat_interleave(views)  # [O]
    lo, hi = t_range
    T = lo + (hi - lo) * torch.rand(len(pid), generator=g)  # [O]
    hazy = J[pid] * T[:, None] + light * (1.0 - T[:, None])  # [O, 3]
    hazy = hazy + noise * torch.randn(hazy.shape, generator=g)
    return PointObservations(pid, hazy, T)


def test_the_fit_recovers_the_light_from_points_seen_through_varying_haze():
    fit = fit_light(_observations())
    assert fit is not None and fit.points == 400 and fit.observations == 2000
    torch.testing.assert_close(fit.light, LIGHT, atol=0.01, rtol=0)
    assert fit.rel_stderr < 0.01


def test_no_fit_without_haze_variation_or_enough_points():
    even = _observations(t_range=(0.5, 0.5))  # every view sees each point through the same haze
    assert fit_light(even) is None
    few = _observations(points=20)
    assert fit_light(few) is None
    once = _observations(views=2)  # points seen by fewer than three views say too little
    assert fit_light(once) is None


def test_the_gain_gives_the_fitted_colour_at_the_medium_s_own_brightness():
    module = LightColourFit(enabled=True, step=10)
    assert not module.due(9) and module.due(10)
    grey = torch.tensor([0.74, 0.73, 0.72])  # the medium's mean light: grey, and dimmer
    gain = module.gain(_observations(), grey, spread=0.02)
    assert gain is not None
    recoloured = grey * gain
    torch.testing.assert_close(chroma(recoloured), chroma(LIGHT), atol=0.01, rtol=0)
    assert float(recoloured.mean()) == pytest.approx(float(grey.mean()), abs=1e-6)
    assert not module.due(11)  # once only
    (decision,) = module.decisions
    assert decision.data["light_gain"] == pytest.approx(gain.tolist())
    assert "recoloured by" in decision.message


def test_a_fit_the_data_do_not_pin_is_not_applied():
    module = LightColourFit(enabled=True, step=0)
    noisy = _observations(noise=0.5, t_range=(0.85, 0.9))  # little haze variation, much noise
    fit = fit_light(noisy)
    assert fit is not None and fit.rel_stderr > MAX_REL_STDERR
    assert module.gain(noisy, torch.tensor([0.7, 0.7, 0.7]), spread=0.02) is None
    assert "not applied" in module.decisions[0].message and module.decisions[0].data["light_gain"] is None
    assert not module.due(1)
    dark = LightColourFit(enabled=True, step=0)  # colours that darken towards the haze: no light fits
    assert (
        dark.gain(_observations(light=torch.tensor([-0.2, 0.5, 0.6])), torch.tensor([0.7] * 3), 0.02) is None
    )
    assert "at or below zero" in dark.decisions[0].message
    off = LightColourFit(enabled=False, step=0)
    assert not off.due(100)


def test_not_applied_where_the_medium_s_light_is_not_one_light():
    """A light that varies over the rays (a sun's glow, a sky) breaks the fit's one-light
    assumption: the fit declines, whatever its data say."""
    T = torch.full((4, 8), 0.5)  # [H, W]
    even = torch.full((4, 8, 3), 0.35)  # S: every ray's light 0.7
    assert light_spread([ray_light(T, even)]) == pytest.approx(0.0, abs=1e-6)
    ramp = torch.linspace(0.2, 0.45, 32).reshape(4, 8, 1).expand(4, 8, 3)  # lights 0.4-0.9
    spread = light_spread([ray_light(T, ramp)])
    assert spread > MAX_LIGHT_SPREAD
    thin = torch.full((4, 8), 0.9)  # 10 % haze: no pixel says anything about the light
    assert len(ray_light(thin, ramp)) == 0 and light_spread([ray_light(thin, ramp)]) is None
    module = LightColourFit(enabled=True, step=0)
    assert module.gain(_observations(), torch.tensor([0.7, 0.7, 0.7]), spread) is None
    assert "assumes one light" in module.decisions[0].message and not module.due(1)


def test_a_resumed_run_does_not_fit_again():
    module = LightColourFit(enabled=True, step=5)
    module.gain(_observations(), torch.tensor([0.7, 0.7, 0.7]), spread=None)
    resumed = LightColourFit(enabled=True, step=5)
    resumed.load_state_dict(module.state_dict())
    assert not resumed.due(6)
    old = LightColourFit(enabled=True, step=5)
    old.load_state_dict({})  # a checkpoint from before the fit existed
    assert old.due(6)


def _field() -> TriplaneField:
    torch.manual_seed(0)
    bounds = FieldBounds(torch.zeros(3), torch.ones(3))
    return TriplaneField(MediumConfig(backend="triplane", light="mlp", light_space="global"), bounds)


def test_recolouring_multiplies_the_light_exactly_and_survives_a_checkpoint():
    field = _field()
    assert field.recolours_light
    x = torch.rand(64, 3) * 2 - 1  # [P, 3]
    dirs = torch.nn.functional.normalize(torch.randn(64, 3), dim=-1)
    before = field(x, dirs)
    gain = torch.tensor([0.9, 1.0, 1.1])
    field.recolour_light(gain)
    after = field(x, dirs)
    torch.testing.assert_close(after.light, before.light * gain, atol=0, rtol=0)
    torch.testing.assert_close(after.beta, before.beta, atol=0, rtol=0)  # the extinction is untouched
    pts = x.reshape(8, 8, 3)
    rays = field.sample_rays(pts, dirs[:8])  # the march's path
    torch.testing.assert_close(
        rays.light, before.light[:8, None, :].expand(-1, 8, -1) * gain, atol=1e-6, rtol=0
    )
    reloaded = _field()
    reloaded.load_state_dict(field.state_dict())
    torch.testing.assert_close(reloaded(x, dirs).light, after.light, atol=0, rtol=0)


def test_a_checkpoint_from_before_recolouring_loads_with_the_head_s_light():
    field = _field()
    state = {k: v for k, v in field.state_dict().items() if not k.endswith("light_gain")}
    field.recolour_light(torch.tensor([0.9, 1.0, 1.1]))
    field.load_state_dict(state)
    assert torch.equal(field.heads.light_gain, torch.ones(3))
    x, dirs = torch.zeros(4, 3), torch.nn.functional.normalize(torch.ones(4, 3), dim=-1)
    torch.testing.assert_close(field(x, dirs).light, _field()(x, dirs).light, atol=0, rtol=0)
