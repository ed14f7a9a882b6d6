"""Checkpoints that load safely but hold wrong contents give one clear line, never a traceback
(issue 22), whether resumed by td-train or reloaded by td-eval / td-render / td-export / td-viewer
(all of which go through ``load_run``)."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
from rich.console import Console

from pipelines.engine.checkpoint import latest_checkpoint
from pipelines.engine.run_loader import load_run
from pipelines.engine.trainer import Trainer
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args
from tridehaze_plugin.errors import UserError


def _cfg(scene: Path, out: Path, steps: int):
    return parse_args([
        "tri-dehaze", "--data", str(scene), "--output-dir", str(out), "--max-steps", str(steps),
        "--steps-per-save", "2", "--pipeline.rasterizer.backend", "torch", "--no-eval-at-end",
        "--threads", "1", "--device", "cpu",
    ])  # fmt: skip


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("schema")
    scene = tiny_hazy_scene(root / "scene", layout="room", haze="homogeneous", seed=4)
    return Trainer(_cfg(scene, root / "out", 2), console=Console(quiet=True)).train().run_dir


def _means(p: dict) -> torch.Tensor:
    return p["pipeline"]["model.params.means"]


def _first_moment(payload: dict) -> dict:
    """The Adam state of the means (the first parameter of their optimiser)."""
    return payload["optimizers"]["means"]["state"][0]


def _set(key: str, value) -> Callable[[dict], None]:  # noqa: ANN001 - any payload value
    return lambda p: p.__setitem__(key, value)


# case -> (tamper with the payload, message on resume, message on reload (None: reloads fine))
CASES = {
    "step is a string": (_set("step", "5"), "step must be a non-negative integer", "step must be"),
    "step is negative": (_set("step", -3), "step must be a non-negative integer", "step must be"),
    "a parameter is not a tensor": (
        lambda p: p["pipeline"].__setitem__("background", [0.0, 0.0, 0.0]),
        "'pipeline' must map names to tensors",
        "'pipeline' must map names to tensors",
    ),
    "means of the wrong shape": (
        lambda p: p["pipeline"].__setitem__("model.params.means", _means(p)[:, :2].clone()),
        "checkpoint does not match the run's config (stored Gaussian parameters do not fit",
        "checkpoint does not match the run's config",
    ),
    "Gaussian counts disagree": (
        lambda p: p["pipeline"].__setitem__("model.params.means", _means(p)[:-1].clone()),
        "checkpoint does not match the run's config (stored Gaussian parameters do not fit",
        "checkpoint does not match the run's config",
    ),
    "a NaN in the means": (
        lambda p: _means(p).__setitem__((0, 0), float("nan")),
        "checkpoint has wrong contents (non-finite values in model.params.means",
        "non-finite values in model.params.means",
    ),
    "no optimiser state": (
        lambda p: p.pop("optimizers"),
        "checkpoint has no optimiser state",
        None,  # rendering and evaluation need no optimiser
    ),
    "optimiser state of another kind": (
        _set("optimizers", {"means": "adam"}),
        "checkpoint's optimiser or RNG state does not fit this run",
        None,
    ),
    "optimiser moments of the wrong shape": (
        lambda p: _first_moment(p).__setitem__("exp_avg", torch.zeros(3, 1)),
        "checkpoint's optimiser or RNG state does not fit this run (optimiser state 'exp_avg' of",
        None,
    ),
    "broken RNG state": (
        _set("torch_rng", torch.zeros(3)),
        "'torch_rng' must be a 1-D uint8 tensor",
        "torch_rng",
    ),
    "negative elapsed time": (
        _set("elapsed_cpu_seconds", -1.0),
        "'elapsed_cpu_seconds' must be a non-negative number of seconds",
        "elapsed_cpu_seconds",
    ),
    "truncated RNG state": (
        _set("torch_rng", torch.zeros(7, dtype=torch.uint8)),
        "checkpoint's optimiser or RNG state does not fit this run",
        None,
    ),
}


@pytest.mark.parametrize("name", list(CASES))
def test_wrong_contents_are_one_line(name, run, tmp_path):
    tamper, on_resume, on_reload = CASES[name]
    copy = Path(shutil.copytree(run, tmp_path / "run"))
    ckpt = latest_checkpoint(copy)
    payload = torch.load(ckpt, weights_only=True)
    tamper(payload)
    torch.save(payload, ckpt)
    cfg = _cfg(Path(parse_args(["--load-config", str(copy / "config.yml")]).dataset.data), tmp_path, 4)
    with pytest.raises(UserError, match=_escape(on_resume)):
        Trainer(cfg, console=Console(quiet=True), resume=copy).setup()
    if on_reload is None:
        assert load_run(copy / "config.yml").step == 2
    else:
        with pytest.raises(UserError, match=_escape(on_reload)):
            load_run(copy / "config.yml")


def _escape(text: str) -> str:
    import re

    return re.escape(text)
