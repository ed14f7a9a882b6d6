"""Resume after Ctrl-C continues exactly where the run stopped; non-finite steps are skipped, and
repeated ones stop the run with the last good checkpoint intact."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from rich.console import Console

from pipelines.engine.checkpoint import Elapsed, latest_checkpoint, load_checkpoint
from pipelines.engine.contract import StepResult
from pipelines.engine.trainer import MAX_BAD_STEPS, Trainer, TrainingDiverged
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args, split_resume
from tridehaze_plugin.errors import ConfigError

STEPS = 8


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return tiny_hazy_scene(
        tmp_path_factory.mktemp("resume") / "scene", layout="room", haze="homogeneous", seed=4, test_every=0
    )


def _cfg(scene: Path, out: Path, *extra: str):
    return parse_args([
        "tri-dehaze", "--data", str(scene), "--output-dir", str(out), "--max-steps", str(STEPS),
        "--pipeline.freeze-step", "4", "--pipeline.medium-hold-fraction", "0", "--pipeline.depth-prior", "sfm",
        "--pipeline.rasterizer.backend", "torch", "--no-eval-at-end", "--steps-per-save", "2", "--threads", "1",
        "--device", "cpu",  # bit-exact resume is a CPU claim: CUDA atomics (grid_sample backward) reorder sums
        *extra,
    ])  # fmt: skip


def _trainer(cfg, resume=None) -> Trainer:
    t = Trainer(cfg, console=Console(quiet=True), resume=resume)
    t.setup()
    return t


@pytest.mark.parametrize("extra", [(), ("--pipeline.random-background",)], ids=["black", "random-bg"])
def test_interrupted_then_resumed_equals_uninterrupted(scene, tmp_path, extra):
    full = _trainer(_cfg(scene, tmp_path / "a", *extra))
    full.train()

    part = _trainer(_cfg(scene, tmp_path / "b", *extra))
    real = part.pipeline.train_loss

    def stop_at_5(step):
        if step == 5:
            raise KeyboardInterrupt
        return real(step)

    part.pipeline.train_loss = stop_at_5
    with pytest.raises(KeyboardInterrupt):
        part.train()
    stopped = load_checkpoint(latest_checkpoint(part.run_dir))
    assert stopped["step"] == 5  # written on Ctrl-C

    resume, args = split_resume(["--resume", str(part.run_dir)])
    again = _trainer(parse_args(args), resume=resume)
    assert again.start_step == 5 and again.run_dir == part.run_dir
    again.train()
    a, b = full.pipeline.state_dict(), again.pipeline.state_dict()
    assert a.keys() == b.keys()
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0, msg=k)
    assert int(again.pipeline.stage) == 2
    _cost_spans_the_resume(part.run_dir, Elapsed.from_payload(stopped), again)


def _cost_spans_the_resume(run_dir: Path, before: Elapsed, resumed: Trainer) -> None:
    """A resumed run reports the whole run's time and CPU, not only its last leg's."""
    assert before.train_seconds > 0 and before.cpu_seconds > 0
    assert resumed.spent_before == before
    final = json.loads((run_dir / "eval" / "metrics.json").read_text())
    assert final["train_seconds"] > before.train_seconds and final["cpu_seconds"] > before.cpu_seconds
    times = [
        json.loads(line)["time"] for line in (run_dir / "logs" / "metrics.jsonl").read_text().splitlines()
    ]
    assert times[-1] == pytest.approx(final["train_seconds"], abs=0.5)
    assert times[-1] > before.train_seconds  # the log's clock does not restart at the resume


def test_nonfinite_steps_are_skipped_and_counted(scene, tmp_path):
    t = _trainer(_cfg(scene, tmp_path))
    real = t.pipeline.train_loss

    def sometimes_nan(step):
        res = real(step)
        return StepResult(res.loss * float("nan"), res.metrics) if step in (2, 3) else res

    t.pipeline.train_loss = sometimes_nan
    result = t.train()
    assert result.metrics["skipped_nonfinite_steps"] == 2
    for p in t.pipeline.parameters():
        assert torch.isfinite(p).all()


def test_repeated_nonfinite_steps_stop_with_last_good_checkpoint(scene, tmp_path):
    cfg = _cfg(scene, tmp_path, "--max-steps", str(MAX_BAD_STEPS + 10))
    t = _trainer(cfg)
    real = t.pipeline.train_loss

    def nan_from_4(step):
        res = real(step)
        return StepResult(res.loss * float("nan"), res.metrics) if step >= 4 else res

    t.pipeline.train_loss = nan_from_4
    with pytest.raises(TrainingDiverged, match="non-finite"):
        t.train()
    ckpt = latest_checkpoint(t.run_dir)
    payload = load_checkpoint(ckpt)
    assert payload["step"] == 4
    assert all(torch.isfinite(v).all() for v in payload["pipeline"].values() if v.is_floating_point())


def test_resume_bad_input(tmp_path):
    with pytest.raises(ConfigError, match="no config.yml"):
        split_resume(["--resume", str(tmp_path)])
    with pytest.raises(ConfigError, match="needs a run folder"):
        split_resume(["--resume"])


def test_same_seed_gives_the_same_model_with_the_compiled_kernel(tmp_path):
    """Two runs, one seed, the cpu kernel on 2 threads: bit-identical parameters (its backward sums
    each thread's tiles in a fixed order; first-come scheduling made runs drift apart)."""
    scene = tiny_hazy_scene(tmp_path / "scene", layout="room", haze="homogeneous", seed=4, test_every=0,
                            width=96, height=72, num_points=600)  # fmt: skip
    states = []
    for name in ("a", "b"):
        cfg = parse_args([
            "tri-dehaze", "--data", str(scene), "--output-dir", str(tmp_path / name), "--max-steps", "25",
            "--pipeline.depth-prior", "sfm", "--pipeline.rasterizer.backend", "cpu", "--threads", "2", "--device", "cpu",
            "--no-eval-at-end", "--seed", "3",
        ])  # fmt: skip
        t = _trainer(cfg)
        t.train()
        states.append(t.pipeline.state_dict())
    a, b = states
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k
