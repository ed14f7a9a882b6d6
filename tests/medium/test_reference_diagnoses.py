"""Three diagnoses on td-synth data that read the generator's answer (never methods):
``--pipeline.medium-start reference`` starts the trainable medium fitted to the true medium (or
``reference-mean``, to its mean over the box; ``reference-extinction`` / ``reference-light``, to
one part of it with the other at its mean),
``--pipeline.march-to true-depth`` ends the training rays' march at the true depth, and
``--pipeline.medium-learns-from true-depth`` lets the medium learn only from pixels whose rendered
depth is right."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch
from rich.console import Console

from components.medium.base import MediumSample
from components.medium.compositing import MediumRender
from components.medium.reference import true_medium
from pipelines.engine.medium_recovery import reference_depth
from pipelines.engine.trainer import Trainer
from pipelines.tridehaze.true_depth_march import march_to_depth, trusted_medium
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args
from tridehaze_plugin.errors import ConfigError


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("patchy") / "scene"
    tiny_hazy_scene(
        root, layout="street", haze="patchy", seed=3, num_views=4, width=40, height=30,
        samples=128, num_points=200, test_every=2,
    )  # fmt: skip
    return root


def _trainer(data: Path, out: Path, *extra: str) -> Trainer:
    argv = [
        "tri-dehaze", "--data", str(data), "--output-dir", str(out), "--max-steps", "2",
        "--device", "cpu", "--pipeline.rasterizer.backend", "torch", "--steps-per-save", "100", *extra,
    ]  # fmt: skip
    trainer = Trainer(parse_args(argv), console=Console(quiet=True))
    trainer.setup()
    return trainer


def _fitted_and_true(
    trainer: Trainer, data: Path, seed: int, n: int = 4096
) -> tuple[MediumSample, MediumSample]:
    """The trainer's medium and the generator's at ``n`` uniform box points and directions."""
    field = trainer.pipeline.medium
    truth = true_medium(field.config, field.bounds, data, trainer.datamanager.scene.transform)
    gen = torch.Generator().manual_seed(seed)
    x = field.bounds_center + (torch.rand(n, 3, generator=gen) * 2 - 1) * field.bounds_half  # [P, 3]
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen), dim=-1)  # [P, 3]
    with torch.no_grad():
        return field(x, d), truth(x, d)


def _log_beta_error(trainer: Trainer, data: Path) -> float:
    got, want = _fitted_and_true(trainer, data, 1, n=2048)
    return float((got.beta.clamp_min(1e-6).log() - want.beta.clamp_min(1e-6).log()).abs().mean())


def test_reference_start_fits_the_true_medium(scene, tmp_path):
    fitted = _trainer(scene, tmp_path / "a", "--pipeline.medium-start", "reference")
    info = fitted.pipeline.init_info
    assert info["reference_start_log_beta_mae"] < 0.1 and info["reference_start_light_mae"] < 0.05
    err = _log_beta_error(fitted, scene)
    dark = _trainer(scene, tmp_path / "b")  # the dark channel's uniform start
    assert err < 0.1 < _log_beta_error(dark, scene)


def test_reference_mean_start_is_uniform_at_the_true_mean(scene, tmp_path):
    fitted = _trainer(scene, tmp_path / "m", "--pipeline.medium-start", "reference-mean")
    got, want = _fitted_and_true(fitted, scene, 2)
    beta = got.beta.clamp_min(1e-9)
    assert float(beta.std() / beta.mean()) < 0.05  # one extinction everywhere
    assert float(want.beta.std() / want.beta.mean()) > 0.2  # the patchy truth is not
    assert abs(float(beta.mean() / want.beta.mean()) - 1.0) < 0.1  # at the true mean
    assert (got.light.mean(0) - want.light.mean(0)).abs().max() < 0.03
    assert float(got.light.std(0).max()) < 0.02


@pytest.mark.parametrize("part", ["extinction", "light"])
def test_reference_part_start_takes_one_part_and_the_others_mean(scene, tmp_path, part):
    fitted = _trainer(scene, tmp_path / part, "--pipeline.medium-start", f"reference-{part}")
    got, want = _fitted_and_true(fitted, scene, 4)
    beta = got.beta.clamp_min(1e-9)
    assert float(want.light.std(0).max()) > 0.05  # the true light depends on direction
    if part == "extinction":
        assert _log_beta_error(fitted, scene) < 0.1  # the layout is the truth's
        assert float(got.light.std(0).max()) < 0.02  # one light
        assert (got.light.mean(0) - want.light.mean(0)).abs().max() < 0.03
    else:
        assert float(beta.std() / beta.mean()) < 0.05  # one extinction
        assert abs(float(beta.mean() / want.beta.mean()) - 1.0) < 0.1
        assert float((got.light - want.light).abs().mean()) < 0.03  # the light is the truth's


def test_march_to_true_depth(scene, tmp_path):
    trainer = _trainer(scene, tmp_path / "c", "--pipeline.march-to", "true-depth")
    pipe, dm = trainer.pipeline, trainer.datamanager
    idx = list(dm.train_indices)[0]
    cam = dm.camera(idx)
    size = (int(cam.height[0]), int(cam.width[0]))
    z = reference_depth(dm, idx, size)  # [H, W, 1]
    med = march_to_depth(pipe.medium, pipe.compositor, cam, z, pipe.model, pipe.rasterizer)
    T, S = pipe.medium_at_depth(cam, z)
    torch.testing.assert_close(med.transmittance, T, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(med.scattering, S, rtol=1e-4, atol=1e-5)
    assert med.transmittance.requires_grad  # the medium learns through it
    rendered, _ = pipe.medium_at_depth(cam, z * 0.5)  # a march that ends elsewhere differs
    assert float((rendered - T).abs().max()) > 1e-3
    trainer.train()  # and trains


def test_march_to_true_depth_needs_the_maps(scene, tmp_path):
    copy = tmp_path / "photos"
    shutil.copytree(scene, copy)
    meta = json.loads((copy / "transforms.json").read_text())
    for frame in meta["frames"]:
        frame.pop("gt_depth_file_path", None)
    (copy / "transforms.json").write_text(json.dumps(meta))
    trainer = _trainer(copy, tmp_path / "d", "--pipeline.march-to", "true-depth")
    with pytest.raises(ConfigError, match="true depth maps"):
        trainer.train()


def test_medium_learns_only_from_pixels_at_the_true_depth(scene, tmp_path):
    T = torch.rand(6, 8, 1, requires_grad=True)  # [H, W, 1]
    S = torch.rand(6, 8, 3, requires_grad=True)  # [H, W, 3]
    end = torch.full((6, 8, 1), 2.0)
    med = MediumRender(transmittance=T, scattering=S, end_depth=end)
    z = torch.full((6, 8, 1), 2.0)
    z[:3] = 3.0  # the top half's rendered depth is a third short
    z[3:, :2] = 2.08  # within 5 %
    trusted, share = trusted_medium(med, z, 0.05)
    torch.testing.assert_close(trusted.transmittance, T)  # the forward pass is unchanged
    torch.testing.assert_close(trusted.scattering, S)
    want = torch.ones(6, 8, 1)
    want[:3] = 0.0
    (grad_t,) = torch.autograd.grad(trusted.transmittance.sum(), T, retain_graph=True)
    torch.testing.assert_close(grad_t, want)  # the gradient passes the trusted pixels only
    (grad_s,) = torch.autograd.grad(trusted.scattering.sum(), S)
    torch.testing.assert_close(grad_s, want.expand_as(grad_s))
    assert float(share) == pytest.approx(0.5)
    trainer = _trainer(scene, tmp_path / "e", "--pipeline.medium-learns-from", "true-depth")
    trainer.train()  # and trains
    shares = [json.loads(line).get("trusted_share") for line in _metrics_lines(trainer)]
    assert any(s is not None and 0.0 <= s <= 1.0 for s in shares)


def _metrics_lines(trainer: Trainer) -> list[str]:
    return (trainer.run_dir / "logs" / "metrics.jsonl").read_text().splitlines()
