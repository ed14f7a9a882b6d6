"""The dark-channel weight raised where the medium's light is the same along every ray: it decides
once, at its step, from the window's per-ray light, and a resumed run keeps the decision."""

from __future__ import annotations

import json
import math

import pytest
import torch

from components.medium.compositing import MediumRender
from pipelines.tridehaze.light_isotropy import LightIsotropy


def _maps(light: torch.Tensor, t: float = 0.5) -> MediumRender:
    """A medium render (transmittance ``t``) whose per-ray light is ``light`` [H, W]."""
    T = torch.full((*light.shape, 1), t)  # [H, W, 1]
    S = light[..., None].expand(*light.shape, 3) * (1.0 - T)  # [H, W, 3]
    return MediumRender(transmittance=T, scattering=S, end_depth=torch.ones_like(T))


def _run(light: torch.Tensor, steps: range, module: LightIsotropy, t: float = 0.5) -> list[float]:
    med = _maps(light, t)
    weights = []
    for step in steps:
        module.observe(step, med)
        weights.append(module.weight(step))
    return weights


def test_an_even_light_gets_the_strong_weight_from_the_decision_step():
    iso = LightIsotropy(weak=0.1, strong=1.0, threshold=0.065, window=(5, 10))
    light = 0.7 + 0.02 * torch.rand(8, 8, generator=torch.Generator().manual_seed(0))  # cv ~0.008
    weights = _run(light, range(15), iso)
    assert weights == [0.1] * 10 + [1.0] * 5
    assert len(iso.decisions) == 1
    assert iso.decisions[0].data["dcp_weight"] == 1.0
    assert iso.decisions[0].data["light_cv"] == pytest.approx(
        float(light.std(unbiased=False) / light.mean()), rel=1e-4
    )
    assert "one light" in iso.decisions[0].message and "weight 1 from step 10" in iso.decisions[0].message
    assert [iso.raised(s) for s in (9, 10, 14)] == [False, True, True]


def test_a_varying_light_is_never_raised():
    iso = LightIsotropy(weak=0.1, strong=1.0, threshold=0.03, window=(5, 10))
    light = torch.linspace(0.3, 0.9, 64).reshape(8, 8)  # cv ~0.3: not one light
    _run(light, range(12), iso)
    assert not any(iso.raised(s) for s in range(12))


def test_judged_one_light_only_after_an_even_verdict():
    """The clean render's fade (``composite.clean_fill`` auto) reads this verdict."""
    even = LightIsotropy(weak=0.1, strong=1.0, threshold=0.065, window=(0, 4))
    light = torch.full((8, 8), 0.7)
    _run(light, range(4), even)
    assert not even.judged_one_light() and even.measured_cv() is None  # not decided before the decision step
    _run(light, range(4, 6), even)
    assert even.judged_one_light() and even.measured_cv() == pytest.approx(0.0, abs=1e-6)
    spread = LightIsotropy(weak=0.1, strong=1.0, threshold=0.065, window=(0, 4))
    _run(torch.linspace(0.5, 0.9, 64).reshape(8, 8), range(6), spread)
    assert not spread.judged_one_light()
    off = LightIsotropy(weak=0.1, strong=1.0, threshold=0.065, window=(0, 4), measures=False)
    _run(light, range(6), off)
    assert not off.judged_one_light()


def test_a_light_that_varies_by_direction_keeps_the_weak_weight():
    iso = LightIsotropy(weak=0.1, strong=1.0, threshold=0.065, window=(0, 4))
    light = torch.linspace(0.5, 0.9, 64).reshape(8, 8)  # cv ~0.17, a sun on one side
    assert _run(light, range(8), iso) == [0.1] * 8
    data = {k: v for k, v in iso.decisions[0].data.items() if not k.startswith("opaque_")}
    assert data == {"light_cv": pytest.approx(0.17, abs=0.01), "dcp_weight": 0.1}
    assert (
        "varies by 16.8%" in iso.decisions[0].message and "weight 0.1 from step 4" in iso.decisions[0].message
    )


def test_only_the_window_counts_and_thin_haze_is_left_out():
    """Steps outside [start, decision) and pixels with under 20 % haze add nothing."""
    iso = LightIsotropy(weak=0.1, strong=1.0, threshold=0.065, window=(3, 6))
    even = torch.full((4, 4), 0.6)
    spread = _maps(torch.linspace(0.1, 1.0, 16).reshape(4, 4))  # a spread light ...
    for step in (0, 1, 2, 6, 7):  # ... outside the window
        iso.observe(step, spread)
    thin = _maps(torch.linspace(0.1, 1.0, 16).reshape(4, 4), t=0.9)  # ... or behind 10 % haze
    for step in (3, 4, 5):
        iso.observe(step, thin)
    assert float(iso.sums[0]) == 0.0
    _run(even, range(3, 6), iso)
    assert float(iso.sums[0]) == 3 * 16
    assert iso.weight(6) == 1.0


def test_no_hazy_pixel_decides_weak_and_the_record_is_json():
    iso = LightIsotropy(weak=0.1, strong=1.0, threshold=0.065, window=(0, 2))
    assert _run(torch.full((4, 4), 0.6), range(4), iso, t=0.95) == [0.1] * 4
    record = iso.decisions[0]
    assert record.data["light_cv"] is None
    json.dumps(record.data, allow_nan=False)  # logs/decisions.jsonl stays strict JSON
    assert all(torch.isfinite(b).all() for b in iso.buffers())  # checkpoints refuse non-finite values
    resumed = LightIsotropy(weak=0.1, strong=1.0, threshold=0.065, window=(0, 2))
    resumed.load_state_dict(iso.state_dict())
    assert resumed.weight(3) == 0.1 and not resumed.decisions


def test_the_verdict_does_not_depend_on_the_strong_weight():
    """The fill reads the verdict too: a strong weight of 0 (off) or equal to the weak one keeps the
    weight weak, but the light is still judged."""
    for strong in (0.0, 0.1):
        iso = LightIsotropy(weak=0.1, strong=strong, threshold=0.065, window=(0, 2))
        assert _run(torch.full((4, 4), 0.6), range(4), iso) == [0.1] * 4
        assert iso.judged_one_light() and iso.decisions[0].data["dcp_weight"] == 0.1
        assert "one light" in iso.decisions[0].message


def test_nothing_is_measured_where_nothing_reads_the_verdict():
    iso = LightIsotropy(weak=0.1, strong=1.0, threshold=0.065, window=(0, 2), measures=False)
    assert _run(torch.full((4, 4), 0.6), range(4), iso) == [0.1] * 4
    assert float(iso.sums[0]) == 0.0 and not iso.decisions and not iso.judged_one_light()


def test_a_resumed_run_keeps_the_decision_and_the_window_sums():
    light = torch.full((4, 4), 0.6)
    first = LightIsotropy(weak=0.1, strong=1.0, threshold=0.065, window=(0, 4))
    _run(light, range(2), first)  # stopped inside the window
    mid = LightIsotropy(weak=0.1, strong=1.0, threshold=0.065, window=(0, 4))
    mid.load_state_dict(first.state_dict())
    assert torch.equal(mid.sums, first.sums)
    _run(light, range(2, 6), mid)
    assert mid.weight(5) == 1.0
    after = LightIsotropy(weak=0.1, strong=1.0, threshold=0.065, window=(0, 4))
    after.load_state_dict(mid.state_dict())
    assert after.weight(5) == 1.0 and not after.decisions  # decided once, not again
    assert math.isclose(float(after.decided), float(mid.decided))


def test_checkpoints_from_before_the_module_load():
    old = {}  # a pipeline state dict without the module's buffers
    iso = LightIsotropy(weak=0.1, strong=1.0, threshold=0.065, window=(0, 4))
    iso.load_state_dict(old)
    assert float(iso.decided) == -1.0 and float(iso.sums[0]) == 0.0


def _opaque_in_part(share: float, t_opaque: float = 0.01) -> MediumRender:
    """An even light (0.6) over 8x8 pixels, ``share`` of them behind opaque haze (T ``t_opaque``)."""
    T = torch.full((8, 8, 1), 0.5)  # [H, W, 1]
    T.view(-1)[: round(share * 64)] = t_opaque
    S = 0.6 * (1.0 - T).expand(8, 8, 3)  # [H, W, 3]
    return MediumRender(transmittance=T, scattering=S, end_depth=torch.ones_like(T))


def _decide_on(med: MediumRender, **kwargs) -> LightIsotropy:
    iso = LightIsotropy(weak=0.1, strong=1.0, threshold=0.03, window=(0, 3), **kwargs)
    for step in range(5):
        iso.observe(step, med)
        iso.weight(step)
    return iso


def test_the_opaque_shares_are_logged_with_the_decision():
    iso = _decide_on(_opaque_in_part(0.25))
    data = iso.decisions[0].data
    assert data["opaque_0.02"] == pytest.approx(0.25) and data["opaque_0.15"] == pytest.approx(0.25)
    assert data["dcp_weight"] == 1.0  # not gated by default (seen share 1.0)
    json.dumps(data, allow_nan=False)


def test_a_one_light_run_that_sees_its_light_keeps_the_weak_weight():
    """Where opaque haze shows the light itself, the photos pin its brightness: no strong bound,
    but the run is still judged one light (the fill reads that)."""
    seen = _decide_on(_opaque_in_part(0.4), seen_light=(0.05, 0.2))
    assert seen.weight(4) == 0.1 and seen.judged_one_light() and seen.sees_light()
    assert "see it through opaque haze" in seen.decisions[0].message
    assert seen.decisions[0].data["dcp_weight"] == 0.1
    few = _decide_on(_opaque_in_part(0.1), seen_light=(0.05, 0.2))  # under the share: strong
    assert few.weight(4) == 1.0 and not few.sees_light()
    thin = _decide_on(_opaque_in_part(0.4, t_opaque=0.08), seen_light=(0.05, 0.2))  # T above the level
    assert thin.weight(4) == 1.0
    assert _decide_on(_opaque_in_part(0.4, t_opaque=0.08), seen_light=(0.1, 0.2)).weight(4) == 0.1


def test_the_seen_light_gate_survives_a_resume():
    first = _decide_on(_opaque_in_part(0.4), seen_light=(0.05, 0.2))
    after = LightIsotropy(weak=0.1, strong=1.0, threshold=0.03, window=(0, 3), seen_light=(0.05, 0.2))
    after.load_state_dict(first.state_dict())
    assert after.weight(6) == 0.1 and not after.decisions
    old = {k: v for k, v in first.state_dict().items() if k != "opaque"}  # a checkpoint from before
    before = LightIsotropy(weak=0.1, strong=1.0, threshold=0.03, window=(0, 3), seen_light=(0.05, 0.2))
    before.load_state_dict(old)
    assert before.weight(6) == 1.0  # decided as it was then: nothing measured, nothing gated


def test_an_unknown_seen_level_is_refused():
    with pytest.raises(ValueError, match="seen-light level"):
        LightIsotropy(weak=0.1, strong=1.0, threshold=0.03, window=(0, 3), seen_light=(0.07, 0.2))


def _light_with_cv(cv: float) -> torch.Tensor:
    """An 8x8 per-ray light of mean 0.6 whose spread (std / mean) is ``cv``: half the pixels above,
    half below."""
    light = torch.full((8, 8), 0.6)
    light.view(-1)[::2] += 0.6 * cv
    light.view(-1)[1::2] -= 0.6 * cv
    return light


@pytest.mark.parametrize(
    ("cv", "expected"),
    [(0.01, 1.0), (0.025, 1.0), (0.0375, 0.1**0.5), (0.051, 0.1), (0.09, 0.1)],
)
def test_the_ramp_falls_geometrically_between_its_spreads(cv, expected):
    iso = LightIsotropy(weak=0.1, strong=1.0, threshold=0.03, window=(0, 3), ramp=(0.025, 0.05))
    weights = _run(_light_with_cv(cv), range(5), iso)
    assert weights[:3] == [0.1] * 3  # weak until the decision, as without the ramp
    assert weights[3] == pytest.approx(expected, rel=1e-3) and weights[4] == weights[3]
    assert iso.decisions[0].data["dcp_weight"] == pytest.approx(expected, rel=1e-3)
    assert iso.raised(4) == (expected > 0.1 + 1e-9)
    assert "weight ramp 2.5% to 5.0%" in iso.decisions[0].message


def test_the_ramp_moves_the_weight_a_little_where_the_step_moves_it_tenfold():
    """Two runs of one scene reading 2.9 % and 3.1 %: the step gives 1 and 0.1, the ramp close weights."""
    step = [
        _run(_light_with_cv(cv), range(5), LightIsotropy(0.1, 1.0, 0.03, (0, 3)))[-1] for cv in (0.029, 0.031)
    ]
    ramp = [
        _run(_light_with_cv(cv), range(5), LightIsotropy(0.1, 1.0, 0.03, (0, 3), ramp=(0.025, 0.05)))[-1]
        for cv in (0.029, 0.031)
    ]
    assert step == [1.0, 0.1]
    assert 0.5 < ramp[1] < ramp[0] < 0.75 and ramp[0] / ramp[1] < 1.25  # 10^(0.08) against 10


def test_the_ramp_keeps_the_gates_and_survives_a_resume():
    seen = _decide_on(_opaque_in_part(0.4), seen_light=(0.05, 0.2), ramp=(0.025, 0.05))
    assert seen.weight(4) == 0.1  # opaque haze shows the light: weak, ramp or not
    iso = LightIsotropy(0.1, 1.0, 0.03, (0, 3), ramp=(0.025, 0.05))
    _run(_light_with_cv(0.0375), range(5), iso)
    after = LightIsotropy(0.1, 1.0, 0.03, (0, 3), ramp=(0.025, 0.05))
    after.load_state_dict(iso.state_dict())
    assert after.weight(6) == pytest.approx(0.1**0.5, rel=1e-3) and not after.decisions
    with pytest.raises(ValueError, match="must rise"):
        LightIsotropy(0.1, 1.0, 0.03, (0, 3), ramp=(0.05, 0.025))
