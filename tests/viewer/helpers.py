"""Shared pieces of the viewer tests: a tiny pipeline, a fake pipeline and the browser tooling."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest
import torch

from components.data.cameras import Cameras
from components.data.loader import load_scene
from pipelines.engine.contract import Pipeline, StepResult
from pipelines.engine.datamanager import DataManager
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args

REPO = Path(__file__).resolve().parents[2]
BROWSER_CHECK = Path(__file__).with_name("browser_check.mjs")
CHROMIUM = Path(os.environ.get("CHROMIUM", "/usr/bin/chromium"))

TRAIN_FLAGS = (
    "--pipeline.warmup-steps", "3", "--pipeline.freeze-step", "3", "--pipeline.medium-hold-fraction", "0",
    "--pipeline.rasterizer.backend", "torch", "--no-eval-at-end", "--pipeline.model.sh-degree", "1",
)  # fmt: skip
"""Settings of the tiny tri-dehaze runs (as in tests/export/tiny_run.py)."""


def tiny_pipeline(root: Path, training: bool = False) -> tuple[Pipeline, DataManager]:
    """An (untrained) tri-dehaze pipeline on a tiny generated hazy scene: renders the seed points."""
    scene = tiny_hazy_scene(root / "scene", test_every=0)
    cfg = parse_args(["tri-dehaze", "--data", str(scene), "--output-dir", str(root / "out"), *TRAIN_FLAGS])
    dm = DataManager(load_scene(cfg.dataset), torch.device("cpu"), seed=cfg.seed)
    return cfg.pipeline.setup(dm, seed=cfg.seed, max_steps=10, training=training), dm


class FakePipeline(Pipeline):
    """Renders a colour that encodes the camera position; can be told to fail."""

    def __init__(self) -> None:
        super().__init__()
        self.w = torch.nn.Parameter(torch.zeros(1))
        self.fail: Exception | None = None
        self.renders = 0

    def train_loss(self, step: int) -> StepResult:
        return StepResult(loss=(self.w**2).sum())

    def param_groups(self):
        return {"w": (self.w, 0.1)}

    def render(self, camera: Cameras, step: int | None = None) -> dict[str, torch.Tensor]:
        self.renders += 1
        if self.fail is not None:
            raise self.fail
        h, w = int(camera.height[0]), int(camera.width[0])
        x = torch.linspace(0, 1, w)[None, :, None].expand(h, w, 1)  # [H, W, 1]
        return {"clean": x.expand(h, w, 3).clone(), "hazy": (1 - x).expand(h, w, 3).clone(), "depth": x + 1}

    def output_names(self) -> list[str]:
        return ["clean", "hazy", "depth"]


def browser_tools() -> tuple[str, str] | str:
    """(node, chromium) when the browser test can run, else why not."""
    node = shutil.which("node")
    if node is None:
        return "node is not installed"
    if not CHROMIUM.exists():
        return f"chromium is not installed at {CHROMIUM}"
    probe = (
        "const {createRequire}=require('module');const r=createRequire(process.argv[1]);"
        "for (const c of [process.env.PLAYWRIGHT_CORE, process.argv[2], 'playwright-core'].filter(Boolean))"
        "{try{r.resolve(c);process.exit(0)}catch{}}process.exit(1)"
    )
    where = str(REPO / ".cache" / "node" / "node_modules" / "playwright-core")
    found = subprocess.run([node, "-e", probe, str(BROWSER_CHECK), where], capture_output=True, timeout=30)
    if found.returncode != 0:
        return "playwright-core is not installed (npm install --prefix .cache/node playwright-core)"
    return node, str(CHROMIUM)


def require_browser() -> tuple[str, str]:
    """The browser tooling; skipped locally when missing, but a failure under CI (it must be there)."""
    tools = browser_tools()
    if isinstance(tools, str):
        if os.environ.get("CI"):
            pytest.fail(f"browser test cannot run in CI: {tools} (see docs/viewer.md for the install lines)")
        pytest.skip(tools)
    return tools
