"""Adaptive density control: clone, split, prune, reset, the cap, and Adam state surgery."""

from __future__ import annotations

import math

import torch

from components.gaussians import GaussianModel, GaussianModelConfig
from components.gaussians.densify import Densifier, DensifyConfig
from components.rasterizers.base import RasterizeOutput


def _model(scales, opacities) -> GaussianModel:
    n = len(scales)
    cfg = GaussianModelConfig(sh_degree=1)
    params = {
        "means": torch.arange(n * 3, dtype=torch.float32).reshape(n, 3) * 0.1,
        "quats": torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        "log_scales": torch.log(torch.tensor(scales, dtype=torch.float32))[:, None].repeat(1, 3),
        "opacity_logits": torch.logit(torch.tensor(opacities, dtype=torch.float32)),
        "sh0": torch.rand(n, 1, 3),
        "shN": torch.rand(n, 3, 3),
    }
    return GaussianModel(cfg, params, scene_extent=1.0)


def _optimizers(model):
    opts = {name: torch.optim.Adam([p], lr=1e-3) for name, (p, _) in model.param_groups().items()}
    loss = sum(p.square().sum() for p in model.parameters())
    loss.backward()
    for o in opts.values():
        o.step()  # creates Adam moments to be carried over
    return opts


def _fake_output(grad_px: torch.Tensor, w=100, h=80) -> RasterizeOutput:
    n = grad_px.shape[0]
    means2d = torch.zeros(1, n, 2, requires_grad=True)
    means2d.grad = grad_px[None].clone()
    z = torch.zeros(1, h, w, 1)
    return RasterizeOutput(
        rgb=torch.zeros(1, h, w, 3),
        depth=z,
        alpha=z,
        means2d=means2d,
        radii=torch.ones(1, n, dtype=torch.int32),
        visible=torch.ones(1, n, dtype=torch.bool),
    )


def _check_optimizer_consistency(model, opts):
    for name, opt in opts.items():
        p = model.params[name]
        assert opt.param_groups[0]["params"][0] is p
        st = opt.state[p]
        assert st["exp_avg"].shape == p.shape and st["exp_avg_sq"].shape == p.shape


def test_clone_small_and_split_big_with_state_surgery():
    # G0 small + high grad -> clone; G1 big + high grad -> split; G2 low grad -> untouched
    model = _model([0.001, 0.5, 0.001], [0.5, 0.5, 0.5])
    opts = _optimizers(model)
    d = Densifier(DensifyConfig(refine_start=1, refine_every=1, prune_opacity=0.01), 1.0, max_steps=100)
    d.collect(_fake_output(torch.tensor([[0.01, 0.0], [0.01, 0.0], [1e-7, 0.0]])))
    big_mean = model.means[1].detach().clone()
    log = d.step(0, model, opts)
    assert log["cloned"] == 1 and log["split"] == 1 and log["pruned"] == 0
    assert model.num_gaussians == 3 + 1 + 1  # clone adds one, split turns one into two
    # the split children are 1.6x smaller and centred around the parent
    scales = model.scales.max(dim=-1).values
    children = torch.isclose(scales, torch.tensor(0.5 / 1.6), rtol=5e-3)  # Adam moved it by ~1e-3
    assert int(children.sum()) == 2
    assert (model.means[children] - big_mean).norm(dim=-1).max() < 4 * 0.5
    _check_optimizer_consistency(model, opts)
    # new rows start with zero moments
    st = opts["means"].state[model.params["means"]]
    assert torch.all(st["exp_avg"][-2:] == 0)
    # training continues after surgery
    loss = model.means.square().sum() + model.opacities.sum()
    loss.backward()
    for o in opts.values():
        o.step()


def test_prune_transparent_and_reset_opacity():
    model = _model([0.01, 0.01, 0.01], [0.001, 0.9, 0.5])
    opts = _optimizers(model)
    cfg = DensifyConfig(refine_start=1, refine_every=1, reset_every=2, prune_opacity=0.005)
    d = Densifier(cfg, 1.0, max_steps=100)
    d.collect(_fake_output(torch.zeros(3, 2)))
    assert d.step(0, model, opts)["pruned"] == 1
    assert model.num_gaussians == 2
    _check_optimizer_consistency(model, opts)
    d.collect(_fake_output(torch.zeros(2, 2)))
    log = d.step(1, model, opts)  # step 2: reset
    assert log["opacity_reset"] == 1
    assert model.opacities.max() <= 2 * cfg.prune_opacity + 1e-6
    assert torch.all(opts["opacity_logits"].state[model.params["opacity_logits"]]["exp_avg"] == 0)


def test_cap_keeps_highest_gradients_and_schedule_window():
    model = _model([0.001] * 4, [0.5] * 4)
    opts = _optimizers(model)
    cfg = DensifyConfig(refine_start=10, refine_every=10, max_gaussians=6)
    d = Densifier(cfg, 1.0, max_steps=40)  # refine_stop defaults to 20
    grads = torch.tensor([[0.01, 0], [0.03, 0], [0.02, 0], [0.001, 0]])
    d.collect(_fake_output(grads))
    assert d.step(5, model, opts) == {}  # before refine_start: nothing
    log = d.step(9, model, opts)
    assert log["cloned"] == 2 and model.num_gaussians == 6  # capped at 6: the two highest grads cloned
    clones = model.means[-2:]
    torch.testing.assert_close(clones, model.means[[1, 2]])
    d.collect(_fake_output(torch.full((6, 2), 0.05)))
    assert "cloned" not in d.step(29, model, opts)  # after refine_stop (20): no refinement
    assert math.isclose(d.refine_stop, 20)


def _grow_run(losses: list[float], cfg: DensifyConfig, n_steps: int) -> tuple[Densifier, list[int]]:
    """Feed one loss per step and high gradients everywhere; returns the count after each refinement."""
    model = _model([0.001] * 4, [0.5] * 4)
    opts = _optimizers(model)
    d = Densifier(cfg, 1.0, max_steps=10 * n_steps)
    counts = []
    for step in range(n_steps):
        d.collect(_fake_output(torch.full((model.num_gaussians, 2), 0.05)))
        d.observe_loss(torch.tensor(losses[step]))
        log = d.step(step, model, opts)
        if "cloned" in log:
            counts.append(model.num_gaussians)
    return d, counts


def test_plateau_growth_stops_when_the_loss_stops_improving():
    cfg = DensifyConfig(refine_start=20, refine_every=10, growth="plateau", plateau_min_improvement=0.02)
    # the loss falls 10 % per 10-step window, then is flat from step 40 on
    losses = [0.9 ** min(s // 10, 4) for s in range(80)]
    d, counts = _grow_run(losses, cfg, 80)
    # refinements after 20, 30, 40, 50 steps grow (each window 10 % below the one before); after 60
    # the window equals the previous one: growth stops for good, pruning-only refinements follow
    assert counts == [8, 16, 32, 64, 64, 64, 64]
    assert d.growth_stopped_at == 60 and float(d.plateau[0]) == 60
    assert len(d.decisions) == 1 and "step 60" in d.decisions[0] and "+0.0 %" in d.decisions[0]
    # a 1 % gain is below the 2 % threshold too
    d, _ = _grow_run([0.99 ** (s // 10) for s in range(40)], cfg, 40)
    assert d.growth_stopped_at == 20
    # the schedule mode keeps growing on the same losses
    _, counts = _grow_run(losses, DensifyConfig(refine_start=20, refine_every=10), 80)
    assert counts == [8, 16, 32, 64, 128, 256, 512]


def test_prune_by_mask_keeps_the_rest_and_their_statistics():
    model = _model([0.01, 0.01, 0.01, 0.01], [0.5, 0.5, 0.5, 0.5])
    opts = _optimizers(model)
    d = Densifier(DensifyConfig(refine_start=1, refine_every=1), 1.0, max_steps=100)
    d.collect(_fake_output(torch.tensor([[1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [4.0, 0.0]])))
    kept_means = model.means[[0, 2, 3]].detach().clone()
    moments = opts["means"].state[model.params["means"]]["exp_avg"][[0, 2, 3]].clone()
    stats = d.grad_sum[[0, 2, 3]].clone()
    assert d.prune(model, opts, torch.tensor([False, True, False, False])) == 1
    assert model.num_gaussians == 3
    torch.testing.assert_close(model.means.detach(), kept_means, rtol=0, atol=0)
    torch.testing.assert_close(opts["means"].state[model.params["means"]]["exp_avg"], moments, rtol=0, atol=0)
    torch.testing.assert_close(d.grad_sum, stats, rtol=0, atol=0)
    _check_optimizer_consistency(model, opts)
    # nothing, or everything, selected: the model is left alone
    assert d.prune(model, opts, torch.zeros(3, dtype=torch.bool)) == 0
    assert d.prune(model, opts, torch.ones(3, dtype=torch.bool)) == 0
    assert model.num_gaussians == 3
