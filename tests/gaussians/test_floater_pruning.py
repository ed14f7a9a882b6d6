"""``--pipeline.prune-floaters``: Gaussians in free space in front of the training views' surfaces
are pruned during training, from td-synth's true depth (a diagnosis) or the model's own depth."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from rich.console import Console

from components.gaussians.free_space import in_front_counts
from pipelines.engine.medium_recovery import reference_depth
from pipelines.engine.trainer import Trainer
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("floaters") / "scene"
    tiny_hazy_scene(
        root, layout="street", haze="homogeneous", seed=5, num_views=6, width=40, height=30,
        samples=64, num_points=200, test_every=3,
    )  # fmt: skip
    return root


def _trainer(data: Path, out: Path, mode: str) -> Trainer:
    argv = [
        "tri-dehaze", "--data", str(data), "--output-dir", str(out), "--max-steps", "4",
        "--device", "cpu", "--pipeline.rasterizer.backend", "torch", "--steps-per-save", "100",
        "--pipeline.prune-floaters", mode, "--pipeline.densify.no-enabled",
        "--pipeline.densify.refine-start", "2", "--pipeline.densify.refine-every", "2",
    ]  # fmt: skip
    trainer = Trainer(parse_args(argv), console=Console(quiet=True))
    trainer.setup()
    return trainer


def _true_surfaces(trainer: Trainer) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    """(viewmat, K, true depth [H, W], NaN on the sky) of each training view."""
    dm = trainer.datamanager
    far = trainer.pipeline.compositor.far_bound(trainer.pipeline.medium)
    out = []
    for idx in dm.train_indices:
        cam = dm.camera(idx)
        z = reference_depth(dm, idx, (int(cam.height[0]), int(cam.width[0])))[..., 0]  # [H, W]
        out.append((cam.viewmats()[0], cam.Ks()[0], torch.where(z < 0.9 * far, z, torch.nan)))
    return out


def _plant_floaters(trainer: Trainer, count: int) -> torch.Tensor:
    """Move the first ``count`` Gaussians to 60 % of the way from the first training camera to the
    surface its rays see, at points at least two training views see against a surface; returns
    their new centres [count, 3]."""
    views = _true_surfaces(trainer)
    viewmat, K, z = views[0]
    rows, cols = torch.nonzero(torch.isfinite(z), as_tuple=True)
    near = 0.6 * z[rows, cols]  # [P]
    local = torch.stack(
        [(cols + 0.5 - K[0, 2]) / K[0, 0] * near, (rows + 0.5 - K[1, 2]) / K[1, 1] * near, near], -1
    )  # [P, 3] camera frame
    c2w = torch.linalg.inv(viewmat)
    world = local @ c2w[:3, :3].T + c2w[:3, 3]  # [P, 3]
    _, seen = in_front_counts(world, views, margin=0.15)
    both = world[seen >= 2]
    assert both.shape[0] >= count, "the tiny scene's views must overlap"
    picked = both[torch.linspace(0, both.shape[0] - 1, count).long()]
    with torch.no_grad():
        trainer.pipeline.model.params["means"][:count] = picked.to(trainer.pipeline.model.means)
    return picked


def test_true_depth_prunes_the_gaussians_planted_in_free_space(scene, tmp_path):
    trainer = _trainer(scene, tmp_path / "a", "true-depth")
    pipe = trainer.pipeline
    planted = _plant_floaters(trainer, 6)
    before = pipe.model.num_gaussians
    assert not pipe.floater_pruning.due(0)  # step 1: before refine-start
    pipe.after_optimizer_step(1, trainer.optimizers.optimizers)  # step 2: due
    assert pipe.last_refine["floaters"] >= 6
    assert pipe.model.num_gaussians == before - pipe.last_refine["floaters"]
    left = torch.cdist(planted.to(pipe.model.means), pipe.model.means.detach()).min(dim=1).values
    assert float(left.min()) > 1e-6  # every planted Gaussian is gone
    assert pipe.model.num_gaussians > 0.8 * before  # the seed cloud lies on the surfaces: most stay
    trainer.train()  # and training goes on with the pruned set


def test_rendered_depth_mode_trains(scene, tmp_path):
    trainer = _trainer(scene, tmp_path / "b", "rendered")
    before = trainer.pipeline.model.num_gaussians
    trainer.train()
    assert trainer.pipeline.model.num_gaussians <= before


def test_off_prunes_nothing(scene, tmp_path):
    trainer = _trainer(scene, tmp_path / "c", "off")
    _plant_floaters(trainer, 6)
    before = trainer.pipeline.model.num_gaussians
    trainer.pipeline.after_optimizer_step(1, trainer.optimizers.optimizers)
    assert "floaters" not in trainer.pipeline.last_refine and trainer.pipeline.model.num_gaussians == before
