"""Growth that stops on a loss plateau and early stopping on the held-out loss: each decision is
taken at the step the rule says, logged, kept in the checkpoint, and ends the run cleanly."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from rich.console import Console

from pipelines.engine.checkpoint import latest_checkpoint, load_checkpoint
from pipelines.engine.trainer import Trainer
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args
from tridehaze_plugin.errors import ConfigError


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return tiny_hazy_scene(
        tmp_path_factory.mktemp("adaptive") / "scene", layout="room", haze="homogeneous", seed=4, test_every=3
    )


def _train(scene: Path, out: Path, steps: int, *extra: str, resume: Path | None = None) -> Trainer:
    cfg = parse_args([
        "tri-dehaze", "--data", str(scene), "--output-dir", str(out), "--max-steps", str(steps),
        "--pipeline.depth-prior", "sfm", "--pipeline.rasterizer.backend", "torch", "--threads", "1",
        "--pipeline.densify.refine-start", "20", "--pipeline.densify.refine-every", "10",
        "--pipeline.densify.grow-grad2d", "1e-9", "--steps-per-save", "10",
        # nothing reads the light's verdict, so it is not taken, and the light colour fit is off
        # (both decisions are tested in tests/medium)
        "--pipeline.lambda-dcp-isotropic", "0", "--pipeline.composite.clean-fill", "haze-light",
        "--pipeline.no-light-colour-fit",
        *extra,
    ])  # fmt: skip
    t = Trainer(cfg, console=Console(quiet=True), resume=resume)
    t.setup()
    t.train()
    return t


def _decisions(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "logs" / "decisions.jsonl").read_text().splitlines()]


def test_plateau_growth_stops_logs_and_resumes(scene, tmp_path):
    # an improvement threshold of 100 % can never be met: growth stops at the first refinement (20)
    plateau = ("--pipeline.densify.growth", "plateau", "--pipeline.densify.plateau-min-improvement", "1.0")
    t = _train(scene, tmp_path, 40, *plateau, "--no-eval-at-end")
    [d] = _decisions(t.run_dir)
    assert d["step"] == 20 and "stops growing" in d["message"]
    counts = {}
    for line in (t.run_dir / "logs" / "metrics.jsonl").read_text().splitlines():
        row = json.loads(line)
        counts[row["step"]] = row["gaussians"]
        if row["step"] >= 20:
            assert row["growth_stopped_at"] == 20
    after = [counts[s] for s in sorted(counts) if s >= 20]
    assert after == sorted(after, reverse=True)  # pruning only from then on
    assert float(load_checkpoint(latest_checkpoint(t.run_dir))["pipeline"]["densify_plateau"][0]) == 20
    # the schedule grows on the same run (so the test above measures the rule, not a scene without growth)
    grown = _train(scene, tmp_path / "s", 40, "--no-eval-at-end")
    assert grown.pipeline.stats()["gaussians"] > t.pipeline.stats()["gaussians"]
    assert not (grown.run_dir / "logs" / "decisions.jsonl").exists()
    # resuming a stopped run keeps the decision: no growth at the refinements after the resume point
    r = _train(scene, tmp_path, 60, *plateau, "--no-eval-at-end", resume=t.run_dir)
    assert r.pipeline.densifier.growth_stopped_at == 20
    assert r.pipeline.stats()["gaussians"] <= t.pipeline.stats()["gaussians"]
    # moving the pipeline (new buffer tensors) keeps the densifier on the checkpointed state
    r.pipeline.half()
    assert r.pipeline.densifier.plateau is r.pipeline.densify_plateau
    assert r.pipeline.densifier.growth_stopped_at == 20


def test_early_stop_on_heldout_plateau(scene, tmp_path):
    stop = ("--early-stop.enabled", "--early-stop.every", "5", "--early-stop.patience", "2",
            "--early-stop.min-improvement", "1.0", "--early-stop.start-fraction", "0.25")  # fmt: skip
    t = _train(scene, tmp_path, 60, *stop)
    # checks at 15 (first: the best so far), 20 and 25 (no 100 % improvement): stop after 25 steps
    held = [json.loads(x) for x in (t.run_dir / "logs" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in held if "heldout_l1" in r] == [15, 20, 25]
    assert all(0 < r["heldout_l1"] < 1 for r in held if "heldout_l1" in r)
    [d] = _decisions(t.run_dir)
    assert d["step"] == 25 and "early stop" in d["message"]
    metrics = json.loads((t.run_dir / "eval" / "metrics.json").read_text())
    assert metrics["stopped_early_at"] == 25 and metrics["steps"] == 25 and "psnr" in json.dumps(metrics)
    assert load_checkpoint(latest_checkpoint(t.run_dir))["step"] == 25
    # a threshold that is met keeps training to the end
    t2 = _train(scene, tmp_path / "b", 30, "--early-stop.enabled", "--early-stop.every", "5",
                "--early-stop.min-improvement", "0", "--early-stop.patience", "100")  # fmt: skip
    assert "stopped_early_at" not in json.loads((t2.run_dir / "eval" / "metrics.json").read_text())


def test_early_stop_needs_heldout_views(tmp_path):
    no_test = tiny_hazy_scene(tmp_path / "s", layout="room", haze="homogeneous", seed=4, test_every=0)
    with pytest.raises(ConfigError, match="held-out views"):
        _train(no_test, tmp_path, 10, "--early-stop.enabled")
