"""The haze probe of ``--pipeline.medium.backend auto``: generated scenes without haze, with a
uniform medium and with patchy haze each get their medium; clear real photos get none; the choice
is written into the run's config and logged."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch
import yaml

from components.data.config import DataConfig
from components.data.loader import load_scene
from pipelines.datamanager import DataManager
from pipelines.haze_probe import NONE_OPTICAL_DEPTH, VARYING_EFFECT, VARYING_F, probe_haze
from tests.conftest import require_real
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args

PROBE_SCENE = {"num_views": 8, "width": 64, "height": 48, "samples": 16, "num_points": 1500}
"""Big enough for the probe's statistics (8 views: 28 pairs), a second to generate."""
EXPECTED = {"none": "none", "uniform": "homogeneous", "patchy": "varying"}
"""Haze class per td-synth preset (the backend follows from BACKEND_FOR)."""


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> dict[tuple[str, str], Path]:
    root = tmp_path_factory.mktemp("probe")
    return {
        (layout, haze): tiny_hazy_scene(root / f"{layout}-{haze}", layout=layout, haze=haze, seed=1, **PROBE_SCENE)
        for layout in ("courtyard", "room")
        for haze in EXPECTED
    }  # fmt: skip


def _probe(path: Path, downscale: int = 1):
    scene = load_scene(DataConfig(data=path, downscale=downscale))
    return probe_haze(DataManager(scene, torch.device("cpu")), scene.train_indices, scene.points)


@pytest.mark.parametrize("layout", ["courtyard", "room"])
@pytest.mark.parametrize("haze", list(EXPECTED))
def test_probe_chooses_the_medium_the_scene_has(scenes, layout, haze):
    p = _probe(scenes[layout, haze])
    assert p.haze == EXPECTED[haze], p.message()
    assert p.backend == ("none" if haze == "none" else "triplane")  # measured best per class
    assert p.views == 7 and p.pairs >= 20  # 8 views, one held out for testing
    if haze == "none":
        assert p.optical_depth < NONE_OPTICAL_DEPTH
    else:  # the fitted extinction is a real one, well inside the margins of the decision
        assert p.optical_depth > 2 * NONE_OPTICAL_DEPTH and p.depth_trend > 0.6
    if haze == "uniform":
        assert p.variation_f < VARYING_F / 3 and p.variation_effect < VARYING_EFFECT
    if haze == "patchy":
        assert p.variation_f > 3 * VARYING_F and p.variation_effect > 2 * VARYING_EFFECT
    assert f"{p.haze} haze -> medium backend {p.backend}" in p.message() and math.isfinite(p.beta)
    assert 0 < p.seconds < 30


def test_probe_without_seed_points_keeps_the_field(scenes):
    scene = load_scene(DataConfig(data=scenes["courtyard", "uniform"]))
    p = probe_haze(DataManager(scene, torch.device("cpu")), scene.train_indices, None)
    assert p.haze == "unknown" and p.backend == "triplane" and "no seed points" in p.reason


@pytest.mark.parametrize("name", ["statue", "beer"])
def test_probe_clear_real_photos_get_no_medium(name):
    p = _probe(require_real(name), downscale=8)
    assert p.haze == "none" and p.backend == "none", p.message()


def test_auto_backend_is_resolved_saved_and_logged(scenes, tmp_path):
    from pipelines.trainer import Trainer

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
    [d] = [json.loads(x) for x in (t.run_dir / "logs" / "decisions.jsonl").read_text().splitlines()]
    assert d["step"] == 0 and "varying haze -> medium backend triplane" in d["message"]
