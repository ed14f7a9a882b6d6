"""The haze probe of ``--pipeline.medium.backend auto``: ``none`` only on positive evidence of a
clear capture, a medium for every hazy scene (including a haze model the probe was not designed
on), ``unsure`` (a medium) for impossible or unreliable estimates; the choice is written into the
run's config and logged with its confidence."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch
import yaml

from components.data.config import DataConfig
from components.data.loader import load_scene
from pipelines.engine.datamanager import DataManager
from pipelines.experiments.probe_set import degrade_points
from pipelines.tridehaze.probe import (
    CLEAR_HAZE_FLOOR,
    CLEAR_OPTICAL_DEPTH,
    MIN_CONFIDENCE,
    VARYING_EFFECT,
    VARYING_F,
    HazeProbe,
    _classify,
    probe_haze,
)
from tests.conftest import require_real
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args

PROBE_SCENE = {
    "num_views": 8,
    "width": 64,
    "height": 48,
    "samples": 16,
    "num_points": 1500,
    "seed_cloud": "clean",
}
"""Big enough for the probe's statistics (8 views: 28 pairs), a second to generate. The clean cloud
the probe was calibrated on; ``_probe(sparse=True)`` and the SfM-like cloud test below cover the
clouds real captures give."""
CASES = {
    ("street", "none"): "none",
    ("field", "none"): "none",
    ("courtyard", "uniform"): "homogeneous",
    ("room", "uniform"): "homogeneous",
    ("courtyard", "patchy"): "varying",
    ("room", "patchy"): "varying",
    ("courtyard", "sunlit"): "varying",
    ("room", "sunlit"): "varying",
}
"""Haze class per (layout, td-synth preset) where the probe has a margin; a clear courtyard or room
is ``unsure`` (its grey surfaces lift the dark channel: tested below)."""


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> dict[tuple[str, str], Path]:
    root = tmp_path_factory.mktemp("probe")
    wanted = {*CASES, ("courtyard", "none")}
    return {
        (layout, haze): tiny_hazy_scene(root / f"{layout}-{haze}", layout=layout, haze=haze, seed=1, **PROBE_SCENE)
        for layout, haze in wanted
    }  # fmt: skip


def _probe(path: Path, downscale: int = 1, sparse: bool = False):
    scene = load_scene(DataConfig(data=path, downscale=downscale))
    points = degrade_points(scene.points) if sparse else scene.points
    return probe_haze(DataManager(scene, torch.device("cpu")), scene.train_indices, points)


def test_sfm_like_seed_clouds_never_lose_the_haze(tmp_path):
    """td-synth's default cloud (sparse, noisy, outliers: what SfM on hazy photos gives): every hazy
    scene keeps a medium, whatever class the probe reads from the worse geometry."""
    for layout, haze in [k for k in CASES if k[1] != "none"]:
        path = tiny_hazy_scene(tmp_path / f"{layout}-{haze}", layout=layout, haze=haze, seed=1,
                               **{**PROBE_SCENE, "seed_cloud": "sfm", "num_points": None})  # fmt: skip
        p = _probe(path)
        assert p.backend == "triplane" and p.haze != "none", (layout, haze, p.message())


@pytest.mark.parametrize(("layout", "haze"), list(CASES))
def test_probe_chooses_the_medium_the_scene_has(scenes, layout, haze):
    p = _probe(scenes[layout, haze])
    assert p.haze == CASES[layout, haze], p.message()
    assert p.backend == ("none" if haze == "none" else "triplane")
    assert p.views == 7 and p.pairs >= 20  # 8 views, one held out for testing
    assert p.confidence >= MIN_CONFIDENCE
    if haze == "none":  # both measurements say clear, with a margin
        assert p.optical_depth_high < CLEAR_OPTICAL_DEPTH and p.haze_floor < 0.85 * CLEAR_HAZE_FLOOR
    else:  # a real extinction, well inside the margins of the decision
        assert p.optical_depth_low > 1.5 * CLEAR_OPTICAL_DEPTH and p.haze_floor > 2 * CLEAR_HAZE_FLOOR
    if haze == "uniform":
        assert p.variation_f < VARYING_F / 3 and p.variation_effect < VARYING_EFFECT
    if haze == "patchy":
        assert p.variation_f > 3 * VARYING_F and p.variation_effect > 2 * VARYING_EFFECT
    assert f"{p.haze} haze -> medium backend {p.backend}, confidence" in p.message() and math.isfinite(p.beta)
    assert 0 < p.seconds < 30


@pytest.mark.parametrize("haze", ["uniform", "patchy", "sunlit"])
def test_sparse_noisy_seed_clouds_still_find_the_haze(scenes, haze):
    p = _probe(scenes["courtyard", haze], sparse=True)
    assert p.backend == "triplane" and p.haze != "none", p.message()


def test_clear_but_grey_scene_is_unsure_and_keeps_a_medium(scenes):
    """The pair fit says clear, the dark channel's floor does not: no positive evidence, so a medium."""
    p = _probe(scenes["courtyard", "none"])
    assert p.optical_depth_high < CLEAR_OPTICAL_DEPTH and p.haze_floor > CLEAR_HAZE_FLOOR
    assert p.haze == "unsure" and p.backend == "triplane" and "disagrees" in p.reason


def _measured(**kw) -> HazeProbe:
    base = dict(haze="homogeneous", reason="", beta=0.1, median_distance=5.0, optical_depth=0.5,
                optical_depth_low=0.4, optical_depth_high=0.6, haze_floor=0.6, distance_spread=2.0,
                variation_f=1.0, variation_effect=0.1, pairs=20, views=8)  # fmt: skip
    return HazeProbe(**{**base, **kw})


@pytest.mark.parametrize(
    ("od", "lo", "hi", "floor"),
    [
        (-1.365, -1.9, -0.8, 0.65),  # the held-out scene of issue 17 read as "T 3.91"
        (-1.365, -1.9, -0.8, 0.05),  # ... even where the dark channel looks clear
        (-0.3, -0.45, -0.15, 0.1),
    ],
)
def test_impossible_estimate_is_unsure_never_none(od, lo, hi, floor):
    p = _measured(optical_depth=od, optical_depth_low=lo, optical_depth_high=hi, haze_floor=floor)
    _classify(p, clear_share=0.0)
    assert p.haze == "unsure" and p.backend == "triplane"
    assert "impossible estimate" in p.reason and "T " in p.reason


def test_slightly_negative_fit_with_a_hazy_floor_keeps_a_medium():
    """Issue 17's other held-out scene: optical depth -0.015 (T 1.01) on fog of mean T 0.47."""
    p = _measured(optical_depth=-0.015, optical_depth_low=-0.06, optical_depth_high=0.03, haze_floor=0.55)
    _classify(p, clear_share=0.0)
    assert p.haze == "unsure" and p.backend == "triplane" and "disagrees" in p.reason


@pytest.mark.parametrize("share", [0.0, 0.5, MIN_CONFIDENCE - 0.01])
def test_low_confidence_clear_verdict_is_unsure(share):
    p = _measured(optical_depth=0.02, optical_depth_low=-0.02, optical_depth_high=0.06, haze_floor=0.1)
    _classify(p, clear_share=share)
    assert p.haze == "unsure" and p.backend == "triplane" and "resampled views agree" in p.reason
    assert p.confidence == pytest.approx(1.0 - share)


def test_confident_clear_verdict_is_none():
    p = _measured(optical_depth=0.02, optical_depth_low=-0.02, optical_depth_high=0.06, haze_floor=0.1)
    _classify(p, clear_share=0.97)
    assert p.haze == "none" and p.backend == "none" and p.confidence == pytest.approx(0.97)


def test_object_centred_capture_abstains():
    """Points all at one distance: extinction is not measurable, whatever the fit says."""
    p = _measured(optical_depth=0.0, optical_depth_low=-0.01, optical_depth_high=0.01, haze_floor=0.05,
                  distance_spread=1.1)  # fmt: skip
    _classify(p, clear_share=1.0)
    assert p.haze == "unsure" and p.backend == "triplane" and "too similar distances" in p.reason
    assert p.confidence == 0.0  # an abstention: nothing was measured


def test_probe_without_seed_points_keeps_the_field(scenes):
    scene = load_scene(DataConfig(data=scenes["courtyard", "uniform"]))
    p = probe_haze(DataManager(scene, torch.device("cpu")), scene.train_indices, None)
    assert p.haze == "unsure" and p.backend == "triplane" and "no seed points" in p.reason
    assert p.confidence == 0.0


@pytest.mark.parametrize("name", ["statue", "beer"])
def test_object_centred_real_photos_keep_a_medium(name):
    """Both real sets orbit one object (point distance spread 1.07 / 1.24): the probe cannot tell
    clear from hazy there and keeps a medium (it used to call them clear from no evidence)."""
    p = _probe(require_real(name), downscale=8)
    assert p.haze == "unsure" and p.backend == "triplane" and "too similar distances" in p.reason, p.message()


def test_auto_backend_is_resolved_saved_and_logged(scenes, tmp_path):
    from pipelines.engine.trainer import Trainer

    cfg = parse_args([
        "tri-dehaze", "--data", str(scenes["courtyard", "patchy"]), "--output-dir", str(tmp_path),
        "--max-steps", "4", "--pipeline.medium.backend", "auto", "--pipeline.rasterizer.backend", "torch",
        "--threads", "1", "--no-eval-at-end",
    ])  # fmt: skip
    t = Trainer(cfg)
    t.setup()
    t.train()
    saved = yaml.safe_load((t.run_dir / "config.yml").read_text())
    assert saved["pipeline"]["medium"]["backend"] == "triplane"  # reloading never probes again
    assert type(t.pipeline.medium).__name__ == "TriplaneField"
    logged = [json.loads(x) for x in (t.run_dir / "logs" / "decisions.jsonl").read_text().splitlines()]
    [d] = [r for r in logged if "haze_probe" in r]  # (the medium light's decision is the other)
    assert d["step"] == 0 and "varying haze -> medium backend triplane, confidence" in d["message"]
    probe = d["haze_probe"]
    assert (
        probe["haze"] == "varying"
        and probe["backend"] == "triplane"
        and probe["confidence"] >= MIN_CONFIDENCE
    )


def test_resolve_returns_a_new_config_and_leaves_the_preset_alone(scenes):
    """The probe runs in ``resolve`` (before setup): the caller's config keeps ``auto``, the returned
    one names the medium, and a concrete backend resolves to itself with no decision."""
    import torch

    from components.data.loader import load_scene
    from pipelines.engine.datamanager import DataManager

    cfg = parse_args(["tri-dehaze-fast", "--data", str(scenes["courtyard", "patchy"])])
    dm = DataManager(load_scene(cfg.dataset), torch.device("cpu"), seed=0)
    resolved, decisions = cfg.pipeline.resolve(dm, seed=0)
    assert cfg.pipeline.medium.backend == "auto" and resolved is not cfg.pipeline
    assert resolved.medium.backend == "triplane" and len(decisions) == 1
    assert decisions[0].data["haze_probe"]["backend"] == "triplane"
    again, none = resolved.resolve(dm, seed=0)
    assert again is resolved and none == []


@pytest.mark.parametrize("light", [(), ("--pipeline.airlight", "0.7", "0.72", "0.75")])
def test_the_probes_dark_channels_are_reused_by_setup(scenes, monkeypatch, light):
    """resolve() + setup() estimate each training view's dark channel once, not twice (also with a
    known light, which both calls must use)."""
    import torch

    from components.data.loader import load_scene
    from pipelines.engine.datamanager import DataManager
    from pipelines.tridehaze import priors

    cfg = parse_args(["tri-dehaze-fast", "--data", str(scenes["courtyard", "patchy"]),
                      "--pipeline.rasterizer.backend", "torch", *light])  # fmt: skip
    dm = DataManager(load_scene(cfg.dataset), torch.device("cpu"), seed=0)
    calls = []
    real = priors.estimate_dcp
    monkeypatch.setattr(priors, "estimate_dcp", lambda img, **kw: (calls.append(1), real(img, **kw))[1])
    resolved, _ = cfg.pipeline.resolve(dm, seed=0)
    pipe = resolved.setup(dm, seed=0, max_steps=10)
    assert len(calls) == len(dm.train_indices)
    if light:
        given = torch.tensor([float(v) for v in light[1:]])
        assert pipe.priors and all(torch.allclose(p.airlight.cpu(), given) for p in pipe.priors.values())
    assert dm not in priors._HANDED_OVER  # taken by setup, not held through training


@pytest.mark.parametrize(("layout", "haze", "weight"), [("room", "uniform", 0.1), ("room", "patchy", 0.0)])
def test_homogeneous_haze_gets_the_smoothness_prior(scenes, layout, haze, weight):
    """``--pipeline.homogeneous-tv-weight``: resolve() probes the views and sets the medium's TV
    weight only where one extinction explains every pair of views; the decision is logged, the
    caller's config is left alone and the resolved config does not probe again."""
    from pipelines.engine.datamanager import DataManager

    cfg = parse_args(
        ["tri-dehaze", "--data", str(scenes[layout, haze]), "--pipeline.homogeneous-tv-weight", "0.1"]
    )
    assert cfg.pipeline.homogeneous_tv_weight == 0.1 and cfg.pipeline.medium.tv_weight == 0.0
    dm = DataManager(load_scene(cfg.dataset), torch.device("cpu"), seed=0)
    resolved, decisions = cfg.pipeline.resolve(dm, seed=0)
    assert resolved.medium.tv_weight == weight and resolved.homogeneous_tv_weight == 0.0
    assert cfg.pipeline.homogeneous_tv_weight == 0.1 and cfg.pipeline.medium.tv_weight == 0.0
    [d] = decisions
    gate = d.data["homogeneous_tv"]  # the default tri-dehaze has no gate, so no probe and no decision
    assert gate["haze"] == CASES[layout, haze] and gate["tv_weight"] == weight
    assert gate["haze_probe"]["haze"] == CASES[layout, haze] and f"weight {weight:g}" in d.message
    again, none = resolved.resolve(dm, seed=0)
    assert again is resolved and none == []
    off = parse_args(["tri-dehaze", "--data", str(scenes[layout, haze])]).pipeline
    assert off.resolve(dm, seed=0) == (off, [])
