"""The Tri-DehazeGS pipeline: every ablation override builds and trains, the schedule freezes the
medium, outputs are complete, densification sees uncompensated gradients, runs reload."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from components.medium.compositing import below_horizon
from pipelines.engine.run_loader import load_run
from pipelines.engine.trainer import Trainer, optimization_step
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args

STEPS = 6


@pytest.fixture(scope="module")
def hazy_scene(tmp_path_factory) -> Path:
    return tiny_hazy_scene(
        tmp_path_factory.mktemp("hazy") / "scene", layout="courtyard", haze="patchy", seed=2, num_views=6,
        width=40, height=30, samples=16, num_points=300, test_every=3,
    )  # fmt: skip


def _config(
    scene: Path,
    out: Path,
    device: torch.device,
    *overrides: str,
    method: str = "tri-dehaze",
    steps: int = STEPS,
):
    argv = [
        method, "--data", str(scene), "--output-dir", str(out), "--max-steps", str(steps),
        "--device", str(device),
        "--pipeline.warmup-steps", "3", "--pipeline.freeze-step", "3", "--pipeline.medium-hold-fraction", "0",
        "--pipeline.rasterizer.backend", "torch", "--eval-at-end", "--steps-per-save", "100", *overrides,
    ]  # fmt: skip
    return parse_args(argv)


def _train(cfg) -> Trainer:
    from rich.console import Console

    trainer = Trainer(cfg, console=Console(quiet=True))
    trainer.setup()
    trainer.train()
    return trainer


ABLATIONS = [
    ("triplane",),
    ("--pipeline.medium.backend", "voxel"),
    ("--pipeline.medium.backend", "mlp"),
    ("--pipeline.medium.backend", "fourier"),
    ("--pipeline.medium.backend", "constant"),
    ("--pipeline.medium.backend", "gaussian-bound"),
    ("--pipeline.medium.backend", "none"),
    ("--pipeline.medium.light", "rgb"),
    ("--pipeline.medium.sh-degree", "2"),
    ("--pipeline.gradient-policy", "none"),
    ("--pipeline.gradient-policy", "tgc"),
    ("--pipeline.depth-prior", "dcp"),
    ("--pipeline.depth-prior", "sfm"),
    ("--pipeline.depth-prior", "warmup"),
    ("--pipeline.depth-prior", "none"),
    ("--pipeline.lambda-depth", "0"),
    ("--pipeline.lambda-smooth", "0"),
    ("--pipeline.lambda-dcp", "0"),
    ("--pipeline.densify-grad", "compensated"),
    ("--pipeline.composite.ray-stride", "1"),
    ("--pipeline.seed-colors", "observed"),
    ("--pipeline.medium.light", "axial"),
    ("--pipeline.sky-shell", "500"),
    ("--pipeline.ground-seeds", "200"),
    ("--pipeline.lambda-dcp-isotropic", "0"),
    ("--pipeline.light-seen-share", "0.2"),
    ("--pipeline.medium-ignores-backdrop",),
    ("--pipeline.light-colour-fit",),
    ("--pipeline.point-tracks", "only"),
    ("--pipeline.point-tracks", "union"),
]


@pytest.mark.parametrize("override", ABLATIONS, ids=lambda o: "-".join(o))
def test_every_ablation_override_trains(hazy_scene, tmp_path, device, override):
    args = () if override == ("triplane",) else override
    cfg = _config(hazy_scene, tmp_path, device, *args)
    trainer = _train(cfg)
    metrics = trainer.pipeline.stats()
    assert metrics["stage"] == 2
    out = trainer.pipeline.render(trainer.datamanager.camera(0))
    for name in trainer.pipeline.output_names():
        assert torch.isfinite(out[name]).all(), name
    assert (trainer.run_dir / "eval" / "metrics.json").is_file()


def test_the_light_isotropy_decision_is_logged_and_followed(hazy_scene, tmp_path, device):
    """``--pipeline.lambda-dcp-isotropic``: one decision in Stage I, in logs/decisions.jsonl, and
    the weight it names is the one the dark-channel term gets from then on."""
    cfg = _config(hazy_scene, tmp_path, device, "--pipeline.lambda-dcp-isotropic", "1",
                  "--pipeline.light-decision-fraction", "0.34")  # fmt: skip
    trainer = _train(cfg)
    lines = (trainer.run_dir / "logs" / "decisions.jsonl").read_text().splitlines()
    records = [r for r in map(json.loads, lines) if "light_cv" in r]
    assert len(records) == 1 and records[0]["step"] <= 3  # within Stage I (frozen at step 3)
    cv, weight = records[0]["light_cv"], records[0]["dcp_weight"]
    assert weight == (1.0 if cv is not None and cv < 0.03 else 0.1)
    assert trainer.pipeline.light_isotropy.weight(STEPS) == weight


def test_a_light_decision_due_after_the_freeze_comes_halfway_through_stage_one(hazy_scene, tmp_path, device):
    """The dark-channel term acts in Stage I only: a decision due after the freeze is taken halfway
    between the hold's end and the freeze instead; without a learning medium there is none."""
    from rich.console import Console

    built = {}
    for freeze, hold in ((3, "0"), (2, "0"), (2, "0.5")):  # the decision is due at step 2 of 6
        cfg = _config(hazy_scene, tmp_path / f"{freeze}-{hold}", device, "--pipeline.freeze-step", str(freeze),
                      "--pipeline.medium-hold-fraction", hold, "--pipeline.light-decision-fraction", "0.25")  # fmt: skip
        trainer = Trainer(cfg, console=Console(quiet=True))
        trainer.setup()
        iso = trainer.pipeline.light_isotropy
        built[freeze, hold] = (iso.measures, iso.decision_step)
    assert built[3, "0"] == (True, 2)  # before the freeze: as asked
    assert built[2, "0"] == (True, 1)  # due at the freeze: halfway through steps 0-2
    assert built[2, "0.5"][0] is False  # held to step 3, frozen at 2: the medium never learns


def test_the_late_medium_rate_acts_from_the_verdict_to_the_freeze(hazy_scene, tmp_path, device):
    """``--pipeline.medium-late-lr-scale``: every medium group (and only those) at its base rate
    times the scale from the one-light verdict up to the freeze, at its base rate elsewhere."""
    from rich.console import Console

    from pipelines.engine.trainer import optimization_step

    cfg = _config(hazy_scene, tmp_path, device, "--pipeline.medium-late-lr-scale", "3",
                  "--pipeline.freeze-step", "5", "--pipeline.light-decision-fraction", "0.34")  # fmt: skip
    trainer = Trainer(cfg, console=Console(quiet=True))
    trainer.setup()
    pipe = trainer.pipeline
    decide, freeze = pipe.light_isotropy.decision_step, pipe.freeze_step
    assert 0 < decide < freeze
    medium = set(pipe.medium.param_groups())
    assert medium and set(pipe.lr_scales(decide)) == medium
    assert set(pipe.lr_scales(decide - 1).values()) == {1.0}
    assert set(pipe.lr_scales(decide).values()) == {3.0} == set(pipe.lr_scales(freeze - 1).values())
    assert set(pipe.lr_scales(freeze).values()) == {1.0}
    optimization_step(pipe, trainer.optimizers, decide)  # the trainer's step sets the rates
    lrs = {name: trainer.optimizers.optimizers[name].param_groups[0]["lr"] for name in medium}
    assert lrs == {name: pytest.approx(3 * trainer.optimizers.base_lr[name]) for name in medium}
    default = _config(hazy_scene, tmp_path / "default", device)
    plain = Trainer(default, console=Console(quiet=True))
    plain.setup()
    assert plain.pipeline.lr_scales(decide) == {}


def test_the_late_medium_rate_can_act_on_chosen_groups_and_runs(hazy_scene, tmp_path, device, monkeypatch):
    """``--pipeline.medium-late-lr-groups medium.features``: the grid's features scaled, the heads,
    light and kappa at their base rates; ``--pipeline.medium-late-lr-when one-light``: only once the
    verdict (read the step after it) says one light; a group the medium lacks is refused at setup."""
    from rich.console import Console

    from pipelines.engine.trainer import optimization_step
    from tridehaze_plugin.errors import ConfigError

    late = ("--pipeline.medium-late-lr-scale", "3", "--pipeline.freeze-step", "5",
            "--pipeline.light-decision-fraction", "0.34")  # fmt: skip
    cfg = _config(hazy_scene, tmp_path, device, *late, "--pipeline.medium-late-lr-groups", "medium.features")
    trainer = Trainer(cfg, console=Console(quiet=True))
    trainer.setup()
    pipe = trainer.pipeline
    decide = pipe.light_isotropy.decision_step
    assert pipe.lr_scales(decide) == {"medium.features": 3.0}
    assert pipe.lr_scales(pipe.freeze_step) == {"medium.features": 1.0}
    optimization_step(pipe, trainer.optimizers, decide)
    base = trainer.optimizers.base_lr
    lrs = {
        name: trainer.optimizers.optimizers[name].param_groups[0]["lr"] for name in pipe.medium.param_groups()
    }
    others = set(lrs) - {"medium.features"}
    assert others and all(lrs[name] == pytest.approx(base[name]) for name in others)
    assert lrs["medium.features"] == pytest.approx(3 * base["medium.features"])
    gated = _config(
        hazy_scene, tmp_path / "gated", device, *late, "--pipeline.medium-late-lr-when", "one-light"
    )
    trainer = Trainer(gated, console=Console(quiet=True))
    trainer.setup()
    pipe = trainer.pipeline
    for one_light in (True, False):
        monkeypatch.setattr(pipe.light_isotropy, "judged_one_light", lambda one_light=one_light: one_light)
        scales = {
            pipe.lr_scales(step)["medium.heads.log_kappa"] for step in (decide + 1, pipe.freeze_step - 1)
        }
        assert scales == ({3.0} if one_light else {1.0})
        assert set(pipe.lr_scales(decide).values()) == {1.0}  # the verdict's own step: not yet read
    wrong = _config(
        hazy_scene, tmp_path / "wrong", device, *late, "--pipeline.medium-late-lr-groups", "medium.grid"
    )
    with pytest.raises(ConfigError, match="medium.grid"):
        Trainer(wrong, console=Console(quiet=True)).setup()


@pytest.mark.parametrize("backend", ["triplane", "gaussian-bound"])
def test_the_light_colour_fit_is_made_once_at_the_freeze_and_logged(
    hazy_scene, tmp_path, device, backend, monkeypatch
):
    """``--pipeline.light-colour-fit``: one decision at the freeze (step 3, logged after it) in
    logs/decisions.jsonl; the gain it names is the medium's from then on and is in the checkpoint;
    a medium without a field light says so instead. The tiny scene's few points are let through."""
    import pipelines.tridehaze.light_colour_fit as fit

    monkeypatch.setattr(fit, "MIN_POINTS", 5)
    monkeypatch.setattr(fit, "MIN_VIEWS", 2)
    monkeypatch.setattr(fit, "MAX_REL_STDERR", 1.0)
    monkeypatch.setattr(fit, "MAX_LIGHT_SPREAD", 1.0)
    cfg = _config(
        hazy_scene, tmp_path, device, "--pipeline.light-colour-fit", "--pipeline.medium.backend", backend
    )
    trainer = _train(cfg)
    lines = (trainer.run_dir / "logs" / "decisions.jsonl").read_text().splitlines()
    records = [r for r in map(json.loads, lines) if "light_gain" in r]
    assert len(records) == 1 and records[0]["step"] == 4
    gain = records[0]["light_gain"]
    medium = trainer.pipeline.medium_field()
    if backend == "gaussian-bound":
        assert gain is None and "no light to recolour" in records[0]["message"]
        return
    assert gain is not None and "recoloured by" in records[0]["message"]
    expected = torch.tensor(gain)
    assert not torch.equal(expected, torch.ones(3))
    torch.testing.assert_close(medium.heads.light_gain.cpu(), expected)
    run = load_run(trainer.run_dir / "config.yml", device=device)
    torch.testing.assert_close(run.pipeline.medium_field().heads.light_gain.cpu(), expected)
    assert not run.pipeline.light_colour.due(STEPS)


def test_sky_shell_adds_gaussians_on_the_sphere_around_the_medium(hazy_scene, tmp_path, device):
    """``--pipeline.sky-shell N``: the seed cloud's Gaussians, then the shell's, at the radius of the
    sphere around the medium's box."""
    from rich.console import Console

    built = {}
    for n in (0, 800):
        trainer = Trainer(_config(hazy_scene, tmp_path / str(n), device, "--pipeline.sky-shell", str(n)),
                          console=Console(quiet=True))  # fmt: skip
        trainer.setup()
        built[n] = trainer.pipeline
    plain, shell = built[0].model.means.detach(), built[800].model.means.detach()
    assert 0 < len(shell) - len(plain) < 800
    torch.testing.assert_close(shell[: len(plain)], plain)
    bounds = built[800].medium.bounds
    radius = (shell[len(plain) :] - bounds.center.to(shell)).norm(dim=-1)
    torch.testing.assert_close(radius, torch.full_like(radius, float(bounds.half_size.norm())))


def test_ground_seeds_add_gaussians_beyond_the_seed_cloud(hazy_scene, tmp_path, device):
    """``--pipeline.ground-seeds``: the Gaussians start from the seed cloud plus points on its
    ground plane farther than the cloud reaches; off, from the cloud alone."""
    from rich.console import Console

    starts = {}
    for n in ("0", "200"):
        cfg = _config(hazy_scene, tmp_path / n, device, "--pipeline.ground-seeds", n)
        trainer = Trainer(cfg, console=Console(quiet=True))
        trainer.setup()
        starts[n] = (trainer.pipeline.model.num_gaussians, trainer.datamanager.scene.points)
    base, cloud = starts["0"]
    assert base == len(cloud)
    assert base < starts["200"][0] <= base + 200


def test_farthest_ground_fill_changes_the_clean_render_below_the_horizon_only(hazy_scene, tmp_path, device):
    """The pipeline finds the generated scene's up (world z, through the scene's normalisation)
    from its training cameras, and ``clean-fill farthest-ground`` moves the clean render only on
    rays below that horizon where T is under t0; the composite and T do not change."""
    trainer = _train(_config(hazy_scene, tmp_path, device, "--pipeline.composite.clean-t0", "0.5"))
    pipe = trainer.pipeline
    # the original world's z axis in the normalised frame
    world_up = pipe.datamanager.scene.transform.rotation[:, 2].float()
    assert float(pipe.scene_up @ world_up) > 0.99
    comp = pipe.compositor.config
    seen_ground = False
    for idx in pipe.datamanager.test_indices:
        cam = pipe.datamanager.camera(idx)
        comp.clean_fill = "haze-light"
        ref = pipe.render(cam)
        comp.clean_fill = "farthest-ground"
        out = pipe.render(cam)
        torch.testing.assert_close(out["hazy"], ref["hazy"])
        torch.testing.assert_close(out["transmittance"], ref["transmittance"])
        H, W = out["clean"].shape[:2]
        below = below_horizon(cam, H, W, pipe.scene_up.to(device))  # [H, W]
        moved = (out["clean"] - ref["clean"]).abs().amax(-1) > 1e-6  # [H, W]
        assert not bool((moved & ~below).any())
        assert not bool((moved & (ref["transmittance"][..., 0] >= 0.5)).any())
        seen_ground = seen_ground or bool(moved.any())
    assert seen_ground  # some test view has hazed ground under t0 for the fill to change


def test_outputs_shapes_and_physics(hazy_scene, tmp_path, device):
    trainer = _train(_config(hazy_scene, tmp_path, device))
    cam = trainer.datamanager.camera(1)
    out = trainer.pipeline.render(cam)
    H, W = int(cam.height[0]), int(cam.width[0])
    shapes = {"clean": 3, "hazy": 3, "transmittance": 1, "scattering": 3, "depth": 1, "alpha": 1}
    assert set(trainer.pipeline.output_names()) == set(shapes)
    for name, c in shapes.items():
        assert tuple(out[name].shape) == (H, W, c), name
    T = out["transmittance"]
    assert float(T.min()) > 0 and float(T.max()) <= 1
    # I = J*T + S with the clean render shown; below the dark channel's t0 the shown clean is
    # faded to the haze light (rendering only), so the identity holds with t0 off
    t0 = trainer.pipeline.compositor.config.clean_t0
    assert t0 == 0.15  # tri-dehaze's default
    trainer.pipeline.compositor.config.clean_t0 = 0.0
    raw = trainer.pipeline.render(cam)
    trainer.pipeline.compositor.config.clean_t0 = t0
    expect = (raw["clean"] * T + raw["scattering"]).clamp(0, 1)
    torch.testing.assert_close(out["hazy"], expect, atol=1e-5, rtol=0)
    kept = (T >= t0).expand_as(out["clean"])  # [H, W, 3]
    if device.type == "cuda":  # two renders on CUDA agree to rounding, not bit for bit (seen on an H200)
        torch.testing.assert_close(out["clean"][kept], raw["clean"][kept], atol=1e-5, rtol=0)
    else:
        assert torch.equal(out["clean"][kept], raw["clean"][kept])
    # the medium marched to a given depth (the evaluation's true-depth protocol): none at the camera,
    # less light through farther planes
    at = trainer.pipeline.medium_at_depth
    near = torch.full_like(T, 1e-6)
    plane = torch.full_like(T, float(out["depth"].median()))
    t0, s0 = at(cam, near)
    t1, s1 = at(cam, plane)
    t2, s2 = at(cam, 2 * plane)
    assert tuple(t1.shape) == (H, W, 1) and tuple(s1.shape) == (H, W, 3)
    torch.testing.assert_close(t0, torch.ones_like(t0), atol=1e-4, rtol=0)
    assert float(s0.abs().max()) < 1e-4
    assert bool((t2 <= t1 + 1e-6).all()) and float((t1 - t2).mean()) > 1e-4 and float(t1.mean()) < 1


def test_no_medium_is_plain_gaussians(hazy_scene, tmp_path, device):
    trainer = _train(_config(hazy_scene, tmp_path, device, "--pipeline.medium.backend", "none"))
    out = trainer.pipeline.render(trainer.datamanager.camera(0))
    assert torch.equal(out["hazy"], out["clean"])
    assert torch.equal(out["transmittance"], torch.ones_like(out["transmittance"]))
    assert not list(trainer.pipeline.medium.parameters())
    assert trainer.pipeline.medium_at_depth(trainer.datamanager.camera(0), out["depth"]) is None


def test_medium_frozen_in_stage_two_and_held_at_start(hazy_scene, tmp_path, device):
    cfg = _config(hazy_scene, tmp_path, device, "--pipeline.freeze-step", "4", steps=8)
    cfg.pipeline.medium_hold_fraction = 0.25  # steps 0, 1 hold the medium
    from rich.console import Console

    trainer = Trainer(cfg, console=Console(quiet=True))
    trainer.setup()
    pipe, opt = trainer.pipeline, trainer.optimizers
    snap = []
    for step in range(8):
        snap.append({k: v.detach().clone() for k, v in pipe.medium.state_dict().items()})
        optimization_step(pipe, opt, step)
    snap.append({k: v.detach().clone() for k, v in pipe.medium.state_dict().items()})

    def changed(a, b):
        return any(not torch.equal(a[k], b[k]) for k in a)

    assert not changed(snap[0], snap[2])  # held: steps 0 and 1
    assert changed(snap[2], snap[4])  # Stage I, learning
    assert not changed(snap[4], snap[8])  # Stage II: frozen
    assert int(pipe.stage) == 2


@pytest.mark.parametrize("geometry", ["free", "held"])
def test_stage_two_holds_the_geometry_only_when_asked(hazy_scene, tmp_path, device, geometry):
    """``--pipeline.stage-two-geometry held``: after the freeze only the colours learn, and
    refinement and opacity resets scheduled past it (a reset at step 6 here) are skipped."""
    from components.gaussians.model import GEOMETRY_NAMES

    cfg = _config(hazy_scene, tmp_path, device, "--pipeline.freeze-step", "4",
                  "--pipeline.stage-two-geometry", geometry, "--pipeline.densify.refine-start", "1",
                  "--pipeline.densify.refine-every", "1", "--pipeline.densify.refine-stop", "8",
                  "--pipeline.densify.reset-every", "6", steps=8)  # fmt: skip
    from rich.console import Console

    trainer = Trainer(cfg, console=Console(quiet=True))
    trainer.setup()
    pipe, opt = trainer.pipeline, trainer.optimizers
    snap = []
    for step in range(8):
        snap.append({k: v.detach().clone() for k, v in pipe.model.params.items()})
        optimization_step(pipe, opt, step)
    snap.append({k: v.detach().clone() for k, v in pipe.model.params.items()})
    stage_one = [k for k in GEOMETRY_NAMES if not torch.equal(snap[2][k], snap[4][k])]
    stage_two = [k for k in GEOMETRY_NAMES if not torch.equal(snap[4][k], snap[8][k])]
    assert stage_one == list(GEOMETRY_NAMES)  # Stage I moves every geometry parameter
    assert stage_two == ([] if geometry == "held" else list(GEOMETRY_NAMES))
    assert not torch.equal(snap[4]["sh0"], snap[8]["sh0"])  # the colours learn in Stage II either way
    if geometry == "held":
        assert snap[4]["means"].shape == snap[8]["means"].shape


def test_the_freeze_checkpoint_is_always_written_and_kept(hazy_scene, tmp_path, device):
    """Stage II ablations resume from the freeze (benchmarks/stage_two_arm.py): its checkpoint is
    written though off the save schedule and survives the rotation (two kept by default)."""
    cfg = _config(
        hazy_scene, tmp_path, device, "--pipeline.freeze-step", "3", "--steps-per-save", "2", steps=8
    )
    trainer = _train(cfg)
    assert trainer.pipeline.milestone_steps() == (3,)
    names = sorted(p.name for p in (trainer.run_dir / "checkpoints").iterdir())
    assert names == ["step-0000003.ckpt", "step-0000006.ckpt", "step-0000008.ckpt"]
    none = _config(hazy_scene, tmp_path / "none", device, "--pipeline.medium.backend", "none", steps=8)
    assert _train(none).pipeline.milestone_steps() == ()  # nothing freezes


def test_checkpoint_holds_stage_and_reloads(hazy_scene, tmp_path, device):
    trainer = _train(_config(hazy_scene, tmp_path, device))
    run = load_run(trainer.run_dir / "config.yml", device=device)
    assert int(run.pipeline.stage) == 2
    a = trainer.pipeline.render(trainer.datamanager.camera(0))
    b = run.pipeline.render(run.datamanager.camera(0))
    for name in ("clean", "hazy", "transmittance"):
        torch.testing.assert_close(a[name], b[name], atol=1e-5, rtol=0)


def test_densification_sees_uncompensated_gradient(hazy_scene, tmp_path, device):
    grads = {}
    for mode in ("uncompensated", "compensated"):
        cfg = _config(hazy_scene, tmp_path / mode, device, "--pipeline.gradient-policy", "tgc",
                      "--pipeline.densify-grad", mode)  # fmt: skip
        from rich.console import Console

        trainer = Trainer(cfg, console=Console(quiet=True))
        trainer.setup()
        pipe, opt = trainer.pipeline, trainer.optimizers
        res = pipe.train_loss(0)
        opt.zero_grad()
        res.loss.backward()
        pipe.after_backward(0)
        grads[mode] = pipe.densifier.grad_sum.clone()
        if mode == "uncompensated":
            weight = pipe._dens_weight
            assert (
                weight is not None and float(weight.min()) >= cfg.pipeline.t_min and float(weight.max()) <= 1
            )
    assert torch.all(grads["uncompensated"] <= grads["compensated"] + 1e-12)
    assert float(grads["uncompensated"].sum()) < float(grads["compensated"].sum())


def test_freeze_step_scales_with_run_length(hazy_scene, tmp_path):
    cfg = parse_args(["tri-dehaze", "--data", str(hazy_scene), "--max-steps", "15000"])
    from pipelines.tridehaze.priors import scaled_step

    assert scaled_step(cfg.pipeline.freeze_step, cfg.pipeline.freeze_fraction, 15000) == 11250
    assert scaled_step(None, cfg.pipeline.freeze_fraction, 1000) == 750
    cfg2 = replace(cfg.pipeline, freeze_step=123)
    assert scaled_step(cfg2.freeze_step, cfg2.freeze_fraction, 1000) == 123


def test_auto_depth_prior_prefers_files_then_sfm_then_warmup(device):
    from types import SimpleNamespace

    from pipelines.tridehaze.priors import resolve_depth_prior

    def dm(depths, points):
        return SimpleNamespace(train_indices=[0, 1], scene=SimpleNamespace(depth_paths=depths, points=points))

    pts = torch.zeros(5, 3, device=device)
    assert resolve_depth_prior("auto", dm([Path("a"), Path("b")], pts)) == "files"
    assert resolve_depth_prior("auto", dm([Path("a"), None], pts)) == "sfm"
    assert resolve_depth_prior("auto", dm([None, None], None)) == "warmup"
    assert resolve_depth_prior("dcp", dm([Path("a"), Path("b")], pts)) == "dcp"


@pytest.mark.parametrize(
    "prior,lambda_depth,applied", [("sfm", "0.05", True), ("sfm", "0", True), ("dcp", "0.05", False)]
)
def test_metric_depth_term_only_against_the_sfm_prior(
    hazy_scene, tmp_path, device, prior, lambda_depth, applied
):
    """The log-depth L1 needs a prior in the scene's own scale: the SfM points, not the dark
    channel's relative depth; it does not depend on the Pearson term being on."""
    cfg = _config(hazy_scene, tmp_path, device, "--pipeline.depth-prior", prior, "--pipeline.lambda-depth",
                  lambda_depth, "--pipeline.lambda-depth-metric", "0.1")  # fmt: skip
    from rich.console import Console

    trainer = Trainer(cfg, console=Console(quiet=True))
    trainer.setup()
    result = trainer.pipeline.train_loss(0)
    assert ("depth_log_l1" in result.metrics) is applied
    if applied:
        value = float(result.metrics["depth_log_l1"])
        assert 0.0 < value < 5.0  # a relative error, and the seed Gaussians are not at every point's depth


def test_a_known_airlight_starts_the_medium_and_sets_the_priors(hazy_scene, tmp_path, device):
    """``--pipeline.airlight``: the medium starts at that light, each view's dark-channel T is
    computed with it, and the light anchor's target is it (the view priors' airlight)."""
    from rich.console import Console

    from components.losses.dcp import estimate_dcp

    light = (0.61, 0.66, 0.72)
    runs = {}
    for name, extra in (("estimated", ()), ("given", ("--pipeline.airlight", *map(str, light)))):
        cfg = _config(hazy_scene, tmp_path / name, device, *extra)
        trainer = Trainer(cfg, console=Console(quiet=True))
        trainer.setup()
        runs[name] = trainer.pipeline
    pipe = runs["given"]
    assert pipe.init_info["init_airlight"] == str(list(light))
    expect = torch.tensor(light)
    for i, prior in pipe.priors.items():
        torch.testing.assert_close(prior.airlight.cpu(), expect)
        image = pipe.datamanager.image(i).cpu().numpy()
        ref = estimate_dcp(image, airlight=expect.numpy()).transmittance
        torch.testing.assert_close(prior.t_dcp.cpu(), torch.from_numpy(ref))
    other = runs["estimated"]
    assert other.init_info["init_airlight"] != pipe.init_info["init_airlight"]
    i = next(iter(pipe.priors))
    assert not torch.equal(other.priors[i].t_dcp, pipe.priors[i].t_dcp)


def test_the_medium_can_ignore_the_random_backdrop(hazy_scene, tmp_path, device):
    """Same step, same forward pass: the medium's gradient changes when T is held in the backdrop's
    term, the Gaussians' colour gradients do not."""
    from rich.console import Console

    grads = {}
    for name, extra in (("held", ("--pipeline.medium-ignores-backdrop",)), ("sees", ())):
        cfg = _config(hazy_scene, tmp_path / name, device, *extra)
        trainer = Trainer(cfg, console=Console(quiet=True))
        trainer.setup()
        pipe = trainer.pipeline
        pipe.model.params["opacity_logits"].data.fill_(-2.0)  # the backdrop shows through
        res = pipe.train_loss(1)  # Stage I, the medium trainable (no hold)
        params = [p for p, _ in pipe.medium.param_groups().values()]
        medium = torch.autograd.grad(res.loss, params, retain_graph=True, allow_unused=True)
        colours = torch.autograd.grad(res.loss, pipe.model.sh0)[0]
        grads[name] = ([g for g in medium if g is not None], colours)
    assert len(grads["held"][0]) > 0
    assert any(not torch.allclose(a, b) for a, b in zip(grads["held"][0], grads["sees"][0], strict=True))
    torch.testing.assert_close(grads["held"][1], grads["sees"][1])
