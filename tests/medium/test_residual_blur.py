"""``--pipeline.medium-residual-blur``: why the medium is fitted to a low-passed residual, and that
the split leaves the forward pass and the Gaussians' gradient as they were."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from components.losses.filters import low_pass
from components.losses.reconstruction import ReconstructionLossConfig
from components.medium.compositing import composite
from pipelines.engine.trainer import Trainer
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args


def _fit_transmittance(clean: torch.Tensor, light: torch.Tensor, hazy: torch.Tensor, sigma: float) -> float:
    """The one global T that the photometric loss (L1 + SSIM) prefers for a fixed clean image."""
    loss_fn = ReconstructionLossConfig().setup()
    logit = torch.zeros((), requires_grad=True)
    opt = torch.optim.Adam([logit], lr=0.05)
    for _ in range(150):
        T = torch.sigmoid(logit)
        pred = clean * T + light * (1 - T)  # [H, W, 3]
        loss, _ = loss_fn(low_pass(pred, sigma), low_pass(hazy, sigma)) if sigma > 0 else loss_fn(pred, hazy)
        opt.zero_grad()
        loss.backward()
        opt.step()
    return float(torch.sigmoid(logit.detach()))


def test_the_scenes_error_biases_a_full_resolution_medium_and_a_low_pass_removes_it():
    g = torch.Generator().manual_seed(0)
    true_clean = low_pass(torch.rand(32, 32, 3, generator=g), 2.0)  # [32, 32, 3] smooth texture
    true_clean = (1.5 * (true_clean - true_clean.mean()) + 0.5).clamp(0, 1)
    light, true_t = torch.tensor([0.7, 0.7, 0.75]), 0.4
    hazy = true_clean * true_t + light * (1 - true_t)
    noisy = true_clean + 0.05 * torch.randn(32, 32, 3, generator=g)  # the Gaussians' fitting error
    assert abs(_fit_transmittance(true_clean, light, hazy, 0.0) - true_t) < 0.01  # no error: no bias
    assert _fit_transmittance(noisy, light, hazy, 0.0) < true_t - 0.05  # measured 0.32: too dense
    assert abs(_fit_transmittance(noisy, light, hazy, 2.0) - true_t) < 0.01  # measured 0.397


@pytest.fixture(scope="module")
def hazy_scene(tmp_path_factory) -> Path:
    return tiny_hazy_scene(tmp_path_factory.mktemp("blur") / "scene", layout="street", haze="patchy", seed=3,
                           width=40, height=30, samples=16)  # fmt: skip


def _pipeline(scene: Path, out: Path, device: torch.device, sigma: float):
    from rich.console import Console

    cfg = parse_args([
        "tri-dehaze", "--data", str(scene), "--output-dir", str(out), "--max-steps", "6", "--device", str(device),
        "--pipeline.warmup-steps", "3", "--pipeline.freeze-step", "3", "--pipeline.medium-hold-fraction", "0",
        "--pipeline.rasterizer.backend", "torch", "--pipeline.no-random-background", "--pipeline.lambda-dcp", "0",
        "--pipeline.lambda-depth", "0", "--pipeline.medium-residual-blur", str(sigma),
    ])  # fmt: skip
    trainer = Trainer(cfg, console=Console(quiet=True))
    trainer.setup()
    return trainer.pipeline


def _grads(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: p.grad.clone() for k, p in module.named_parameters() if p.grad is not None}


def test_split_keeps_forward_and_scene_gradient_and_low_passes_the_mediums(hazy_scene, tmp_path, device):
    full, split = (_pipeline(hazy_scene, tmp_path / str(s), device, s) for s in (0.0, 2.0))
    results = {}
    for name, pipe in (("full", full), ("split", split)):
        pipe.zero_grad()
        res = pipe.train_loss(0)  # Stage I, medium trainable
        res.loss.backward()
        results[name] = (res.metrics, _grads(pipe.model), _grads(pipe.medium))
    (m_full, g_full, med_full), (m_split, g_split, med_split) = results["full"], results["split"]
    assert float(m_full["psnr"]) == pytest.approx(float(m_split["psnr"]), abs=1e-5)  # same composite
    assert g_full.keys() == g_split.keys() and g_full
    for k in g_full:
        torch.testing.assert_close(g_split[k], g_full[k], atol=1e-7, rtol=1e-5)
    # the medium's gradient is the low-passed loss's, and not the full-resolution one's
    pipe = split
    cam = pipe.datamanager.camera(pipe.datamanager.train_index(0))
    out = pipe._rasterize(cam, 0, pipe.background)
    med = pipe._medium(cam, out)
    target = pipe.training_target(pipe.datamanager.train_index(0))
    pred = composite(out.rgb[0].detach(), med)  # [H, W, 3]
    loss, _ = pipe.loss_fn(low_pass(pred, 2.0), low_pass(target, 2.0))
    named = [(k, p) for k, p in pipe.medium.named_parameters() if k in med_split]
    expected = torch.autograd.grad(loss, [p for _, p in named])
    for (k, _), e in zip(named, expected, strict=True):
        torch.testing.assert_close(med_split[k], e, atol=1e-7, rtol=1e-4)
    assert any(not torch.allclose(med_split[k], med_full[k], atol=1e-6) for k in med_split)
