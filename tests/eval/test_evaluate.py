"""The evaluation protocols on a scripted pipeline whose errors are known exactly."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch import Tensor, nn

from components.data.config import DataConfig
from components.data.images import read_depth
from components.data.loader import load_scene
from components.losses.dcp import dehaze, estimate_dcp
from pipelines.engine.contract import Pipeline, StepResult
from pipelines.engine.datamanager import DataManager
from pipelines.engine.evaluate import evaluate, evaluate_split
from pipelines.engine.medium_recovery import (
    OBSERVABLE_T,
    REFERENCE_DEPTH_KEY,
    REFERENCE_S_KEY,
    REFERENCE_T_KEY,
    T_BINS,
    observable_scores,
    reference_map,
)

DELTA = 0.1
"""Error added to the clean render inside the low-visibility third of each view."""


class ScriptedPipeline(Pipeline):
    """Renders the references themselves, plus DELTA in the right third; T = 0.9 | 0.5 | 0.2 by thirds."""

    def __init__(self, dm: DataManager, medium: bool = True) -> None:
        super().__init__()
        self.dm = dm
        self.medium = medium
        self.dummy = nn.Parameter(torch.zeros(1))

    def train_loss(self, step: int) -> StepResult:
        raise NotImplementedError

    def param_groups(self):
        return {}

    def output_names(self) -> list[str]:
        return ["clean", "hazy", "transmittance"]

    @property
    def composites_medium(self) -> bool:
        return self.medium

    def _index(self, camera) -> int:
        return int(torch.argmin((self.dm.cameras.camtoworlds - camera.camtoworlds).abs().sum((1, 2))))

    def render(self, camera, step=None):
        idx = self._index(camera)
        ref = self.dm.clean_image(idx)  # [H, W, 3]
        H, W = ref.shape[:2]
        third = W // 3
        T = torch.full((H, W, 1), 0.9)
        T[:, third : 2 * third] = 0.5
        T[:, 2 * third :] = 0.2
        clean = ref.clone()
        clean[:, 2 * third :] = (clean[:, 2 * third :] + DELTA).clamp(max=1.0)
        return {
            "clean": clean,
            "hazy": self.dm.image(idx),
            "transmittance": T,
            "scattering": torch.zeros(H, W, 3),
        }


class OraclePipeline(ScriptedPipeline):
    """Renders the dataset's true T and S, T shifted down by ``t_shift`` and S up by ``s_shift``."""

    def __init__(self, dm: DataManager, t_shift: float = 0.0, s_shift: float = 0.0) -> None:
        super().__init__(dm)
        self.t_shift, self.s_shift = t_shift, s_shift

    def render(self, camera, step=None):
        out = super().render(camera, step)
        idx = self._index(camera)
        size = tuple(out["clean"].shape[:2])
        out["transmittance"] = reference_map(self.dm, REFERENCE_T_KEY, idx, size) - self.t_shift
        out["scattering"] = reference_map(self.dm, REFERENCE_S_KEY, idx, size) + self.s_shift
        return out


class DepthMarchedPipeline(OraclePipeline):
    """A homogeneous medium of known extinction and light marched to whatever depth it is given;
    records the depths the evaluation asks for."""

    BETA, LIGHT = 0.3, 0.7

    def __init__(self, dm: DataManager) -> None:
        super().__init__(dm)
        self.asked: list[Tensor] = []

    def medium_at_depth(self, camera, depth):
        self.asked.append(depth)
        T = torch.exp(-self.BETA * depth)  # [H, W, 1]
        return T, self.LIGHT * (1.0 - T).expand(*T.shape[:2], 3)


@pytest.fixture(scope="module")
def dm(eval_scene) -> DataManager:
    return DataManager(load_scene(DataConfig(data=eval_scene)), torch.device("cpu"))


def test_stable_keys_and_perfect_protocols(dm):
    report = evaluate(ScriptedPipeline(dm), dm, "test")
    assert set(report) >= {"split", "views", "restoration", "reconstruction", "binned", "medium", "per_view"}
    assert report["views"] == len(dm.scene.test_indices) == len(report["per_view"]) >= 2
    assert set(report["restoration"]) >= {"psnr", "ssim", "lpips"}
    rec = report["reconstruction"]
    assert rec["psnr"] == 100.0 and rec["ssim"] == pytest.approx(1.0, abs=1e-6) and rec["composite"] is True
    names = dm.scene.names()
    assert [r["name"] for r in report["per_view"]] == [names[i] for i in dm.scene.test_indices]


def test_binned_metrics_pool_pixels_per_bin(dm):
    report = evaluate(ScriptedPipeline(dm), dm, "test", bins="model")
    binned = report["binned"]
    assert binned["source"] == "model"
    W = dm.image(dm.scene.test_indices[0]).shape[1]
    assert binned["high"]["fraction"] == pytest.approx((W // 3) / W)
    assert binned["high"]["psnr"] == 100.0 and binned["mid"]["psnr"] == 100.0
    # the low bin's error: DELTA except where the reference is already near 1 (clamped), pooled
    sq, n = 0.0, 0
    for i in dm.scene.test_indices:
        ref = dm.clean_image(i)[:, 2 * (W // 3) :]
        sq += float((((ref + DELTA).clamp(max=1.0) - ref) ** 2).mean(-1).sum())
        n += ref.shape[0] * ref.shape[1]
    assert binned["low"]["psnr"] == pytest.approx(-10 * math.log10(sq / n), abs=1e-3)
    assert binned["low"]["ssim"] < binned["high"]["ssim"]
    assert report["restoration"]["psnr"] < 100.0


def test_reference_bins_and_no_medium(dm):
    report = evaluate(ScriptedPipeline(dm, medium=False), dm, "test")  # auto: no medium -> reference maps
    binned = report["binned"]
    assert binned["source"] == "reference" and report["reconstruction"]["composite"] is False
    t = np.concatenate(
        [read_depth(dm.scene.extra_paths[REFERENCE_T_KEY][i]).ravel() for i in dm.scene.test_indices]
    )
    assert binned["low"]["fraction"] == pytest.approx(float((t <= 0.4).mean()), abs=1e-6)
    assert evaluate(ScriptedPipeline(dm, medium=False), dm, "test", bins="model")["binned"] is None
    assert evaluate(ScriptedPipeline(dm), dm, "test", bins="none")["binned"] is None


def test_lpips_is_zero_for_a_perfect_render(dm, need_lpips):
    from components.metrics.lpips import load_lpips

    net = load_lpips("alex")
    report = evaluate(ScriptedPipeline(dm), dm, "test", lpips_fn=net)
    assert report["reconstruction"]["lpips"] == 0.0  # hazy render == input
    assert 0.0 < report["restoration"]["lpips"] < 1.0


def test_quick_numbers_match_the_full_protocol(dm):
    quick = evaluate_split(ScriptedPipeline(dm), dm, "test")
    full = evaluate(ScriptedPipeline(dm), dm, "test")
    assert quick["restoration_psnr"] == pytest.approx(full["restoration"]["psnr"])
    assert quick["reconstruction_ssim"] == pytest.approx(full["reconstruction"]["ssim"])


def test_medium_recovery_of_the_true_maps_is_exact(dm):
    med = evaluate(OraclePipeline(dm), dm, "test")["medium"]
    assert med["views"] == len(dm.scene.test_indices)
    assert med["t_mae"] == 0.0 and med["s_mae"] == 0.0
    assert all(v in (0.0, None) for v in med["t_mae_by_true_t"].values())
    assert med["inverted_psnr"] == med["true_inverted_psnr"] > 30.0  # the data allow a near-perfect answer


def test_medium_recovery_measures_known_errors(dm):
    report = evaluate(OraclePipeline(dm, t_shift=0.05, s_shift=0.02), dm, "test")
    med = report["medium"]
    assert med["t_mae"] == pytest.approx(0.05, abs=1e-5) and med["s_mae"] == pytest.approx(0.02, abs=1e-5)
    assert [k for k, v in med["t_mae_by_true_t"].items() if v is not None]  # some bin has pixels
    for v in med["t_mae_by_true_t"].values():
        assert v is None or v == pytest.approx(0.05, abs=1e-5)
    assert med["inverted_psnr"] < med["true_inverted_psnr"]
    assert set(report["per_view"][0]["medium"]) >= {"t_mae", "s_mae", "inverted_psnr", "true_inverted_psnr"}
    assert [b[0] for b in T_BINS] == list(med["t_mae_by_true_t"])


def test_medium_marched_to_the_true_depth_is_scored_apart(dm):
    """The medium is marched to the dataset's true depth in the run's frame, and scored there."""
    pipe = DepthMarchedPipeline(dm)
    report = evaluate(pipe, dm, "test")
    med = report["medium"]
    size = tuple(dm.clean_image(dm.test_indices[0]).shape[:2])
    t_err, s_err = [], []
    for k, idx in enumerate(dm.test_indices):
        z = reference_map(dm, REFERENCE_DEPTH_KEY, idx, size) * dm.scene.transform.scale  # [H, W, 1]
        assert torch.equal(pipe.asked[k], z)
        T = torch.exp(-pipe.BETA * z)
        true_t = reference_map(dm, REFERENCE_T_KEY, idx, size)
        true_s = reference_map(dm, REFERENCE_S_KEY, idx, size)
        t_err.append(float((T - true_t).abs().mean()))
        s_err.append(float((pipe.LIGHT * (1 - T) - true_s).abs().mean()))
        row = report["per_view"][k]["medium"]
        assert row["t_mae_true_depth"] == pytest.approx(t_err[-1], abs=1e-6)
    assert (
        med["t_mae_true_depth"] == pytest.approx(np.mean(t_err), abs=1e-6) and med["t_mae_true_depth"] > 0.01
    )
    assert med["s_mae_true_depth"] == pytest.approx(np.mean(s_err), abs=1e-6)
    assert med["t_mae"] == 0.0  # the rendered maps are the truth; only the marched ones are off


def test_no_true_depth_or_no_march_means_no_true_depth_numbers(dm):
    assert evaluate(OraclePipeline(dm), dm, "test")["medium"]["t_mae_true_depth"] is None  # base: no march
    bare = DataManager(load_scene(DataConfig(data=dm.scene.root)), torch.device("cpu"))
    bare.scene.extra_paths.pop(REFERENCE_DEPTH_KEY)
    med = evaluate(DepthMarchedPipeline(bare), bare, "test")["medium"]
    assert med["t_mae"] == 0.0 and med["t_mae_true_depth"] is None and med["s_mae_true_depth"] is None


def test_no_medium_or_no_true_maps_means_no_medium_numbers(dm):
    assert evaluate(ScriptedPipeline(dm, medium=False), dm, "test")["medium"] is None
    bare = DataManager(load_scene(DataConfig(data=dm.scene.root)), torch.device("cpu"))
    bare.scene.extra_paths.pop(REFERENCE_T_KEY)
    assert evaluate(ScriptedPipeline(bare), bare, "test")["medium"] is None


def test_single_image_baselines_score_the_test_photos_themselves(dm):
    report = evaluate(ScriptedPipeline(dm, medium=False), dm, "test")
    base = report["baselines"]
    assert list(base) == ["hazy_input", "dcp_2d"] and base["dcp_2d"]["views"] == len(dm.scene.test_indices)
    hazy_psnr, dcp_psnr = [], []
    for i in dm.scene.test_indices:  # recomputed here from the photos, independently of the protocol
        hazy, ref = dm.hazy_image(i).numpy(), dm.clean_image(i).numpy()
        dcp = dehaze(hazy, estimate_dcp(hazy))
        hazy_psnr.append(-10 * math.log10(float(((hazy - ref) ** 2).mean())))
        dcp_psnr.append(-10 * math.log10(float(((dcp - ref) ** 2).mean())))
    assert base["hazy_input"]["psnr"] == pytest.approx(np.mean(hazy_psnr), abs=1e-3)
    assert base["dcp_2d"]["psnr"] == pytest.approx(np.mean(dcp_psnr), abs=1e-3)
    assert base["dcp_2d"]["psnr"] != pytest.approx(
        base["hazy_input"]["psnr"], abs=0.1
    )  # DCP changed the photos
    assert set(report["per_view"][0]["baselines"]) == {"hazy_input", "dcp_2d"}
    # the method-independent baselines are the same whatever is evaluated
    assert evaluate(ScriptedPipeline(dm), dm, "test")["baselines"] == base


def test_no_clean_references_means_no_baselines(dm):
    bare = DataManager(load_scene(DataConfig(data=dm.scene.root)), torch.device("cpu"))
    bare.clean_image = lambda idx: None  # type: ignore[method-assign]
    report = evaluate(ScriptedPipeline(dm, medium=False), bare, "test")  # renders from dm, scored on bare
    assert report["baselines"] is None and report["restoration"] is None


def test_observable_scores_leave_out_what_the_haze_hides():
    ref = 0.8 * torch.rand(4, 6, 3, generator=torch.Generator().manual_seed(0))  # + 0.1 stays below 1
    true_t = torch.full((4, 6, 1), 0.5)
    true_t[:, :3] = OBSERVABLE_T / 2  # the left half is behind nearly opaque haze
    pred = ref.clone()
    pred[:, :3] = 1.0 - pred[:, :3]  # wrong only where the photo cannot show the answer
    out = observable_scores(pred, ref, true_t)
    assert out["share"] == 0.5 and out["psnr"] == 100.0
    pred[:, 3:] += 0.1  # now also wrong where it is observed: 0.1 everywhere there -> 20 dB
    assert observable_scores(pred, ref, true_t)["psnr"] == pytest.approx(20.0, abs=0.05)
    assert observable_scores(pred, ref, torch.zeros(4, 6, 1)) == {"psnr": None, "share": 0.0}


@pytest.mark.parametrize("medium", [True, False])
def test_observable_protocol_for_every_method(dm, medium):
    report = evaluate(ScriptedPipeline(dm, medium=medium), dm, "test")
    psnrs, shares = [], []
    for i in dm.scene.test_indices:  # recomputed from the maps, independently of the protocol
        pipe = ScriptedPipeline(dm)
        clean = pipe.render(dm.camera(i))["clean"].numpy()
        ref = dm.clean_image(i).numpy()
        t = reference_map(dm, REFERENCE_T_KEY, i, ref.shape[:2])[..., 0].numpy()
        m = t >= OBSERVABLE_T
        shares.append(m.mean())
        psnrs.append(-10 * math.log10(float(((clean - ref) ** 2).mean(-1)[m].mean())))
    obs = report["observable"]
    assert obs["views"] == len(dm.scene.test_indices) and obs["t_floor"] == OBSERVABLE_T
    assert obs["psnr"] == pytest.approx(np.mean(psnrs), abs=1e-3)
    assert obs["share"] == pytest.approx(np.mean(shares), abs=1e-6)
    assert set(report["per_view"][0]["observable"]) == {"psnr", "share"}
    bare = DataManager(load_scene(DataConfig(data=dm.scene.root)), torch.device("cpu"))
    bare.scene.extra_paths.pop(REFERENCE_T_KEY)
    assert evaluate(ScriptedPipeline(bare, medium=medium), bare, "test")["observable"] is None
