"""How far does training move the medium from its dark-channel start, and where does it end?

For runs on generated scenes (true T and true depth per view), each test view's optical depth
-ln T is compared with the truth's, both marched to the *true* depth so that only the medium is
measured (not the rendered depth or coverage):

- ``start``: the homogeneous extinction the pipeline starts from (``estimate_medium``: the median
  over seed points of -ln T_dcp / distance), recomputed from the run's training views;
- ``trained``: the run's medium after training.

The ratio model / truth of the optical depth, per true-T bin, says whether a run ends with too
much haze (> 1) or too little (< 1), and whether training moved it from its start. Beside it, the
medium's light against the true light (``S / (1 - T)``, summed over the pixels whose true T is
below ``LIGHT_T_MAX``, where the haze light is a large share of the pixel): a light too dim needs
more haze to explain the same in-scattering, a light too bright less, so the two ratios read
together.

    python benchmarks/medium_start.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

Writes OUT.json, OUT.md (one row per run) and OUT.png.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import diagnose_runs_main  # noqa: E402
from reference_views import TRUE_T_BINS as BINS  # noqa: E402
from reference_views import reference_views  # noqa: E402

from components.medium.compositing import pixel_path_lengths  # noqa: E402
from pipelines.engine.medium_recovery import REFERENCE_S_KEY, reference_map  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402
from pipelines.tridehaze.priors import dcp_per_view, estimate_medium  # noqa: E402

LIGHT_T_MAX = 0.6
"""True T below which a pixel counts towards the light ratio."""


def _light_sums(scattering: Tensor, transmittance: Tensor, mask: Tensor) -> Tensor:
    """[4]: sum of S [3] and of 1 - T over the masked pixels; their ratio is the mean light S / (1 - T)
    weighted by 1 - T."""
    return torch.cat([scattering[mask].sum(0), (1.0 - transmittance[mask]).sum()[None]]).cpu()


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    airlight = run.config.pipeline.airlight  # the start the run had, where a known light was given
    est = estimate_medium(dm, dcp_per_view(dm, dm.train_indices, airlight=airlight), dm.scene.points)
    if est.beta is None:
        raise SystemExit(f"{config}: the scene has no seed points, so there is no extinction start")
    true_od, start_od, trained_od = [], [], []
    light_true, light_model = torch.zeros(4), torch.zeros(4)
    for view in reference_views(dm):
        cam, size, true_t, z = view.camera, (view.height, view.width), view.true_t, view.true_z  # [H, W, 1]
        marched = pipe.medium_at_depth(cam, z)
        if marched is None:
            raise SystemExit(f"{config}: the run has no medium to compare with the truth")
        model_t, model_s = marched  # [H, W, 1], [H, W, 3]
        true_od.append(-true_t.clamp(1e-4, 0.9999).log().flatten())
        path = z[..., 0] * pixel_path_lengths(cam, size[0], size[1], z.device, z.dtype)  # [H, W]
        start_od.append((est.beta * path).flatten())
        trained_od.append(-model_t.clamp_min(1e-4).log().flatten())
        true_s = reference_map(dm, REFERENCE_S_KEY, view.index, size)  # [H, W, 3]
        if true_s is not None:
            m = true_t[..., 0] < LIGHT_T_MAX  # [H, W]
            light_true += _light_sums(true_s, true_t[..., 0], m)
            light_model += _light_sums(model_s, model_t[..., 0], m)
    if not true_od:
        raise SystemExit(f"{config}: the dataset has no true transmittance and depth maps")
    od, od0, od1 = (torch.cat(v).cpu().numpy() for v in (true_od, start_od, trained_od))
    t = np.exp(-od)
    bins = []
    for lo, hi in BINS:
        m = (t >= lo) & ((t < hi) if hi < 1.0 else (t <= 1.0))
        if m.sum() < 10:
            continue
        bins.append({
            "true_t": [lo, hi], "share": float(m.mean()),
            "ratio_start": float(np.median(od0[m] / od[m])),
            "ratio_trained": float(np.median(od1[m] / od[m])),
            "t_error_start": float((np.exp(-od0[m]) - t[m]).mean()),
            "t_error_trained": float((np.exp(-od1[m]) - t[m]).mean()),
        })  # fmt: skip
    return {
        "run": str(config.parent),
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
        "beta_start": float(est.beta),
        "t_mae_start": float(np.abs(np.exp(-od0) - t).mean()),
        "t_mae_trained": float(np.abs(np.exp(-od1) - t).mean()),
        "light_start": est.airlight.tolist(),
        "light_ratio_start": _ratio(est.airlight, light_true),
        "light_ratio_trained": _ratio(light_model[:3] / light_model[3].clamp_min(1e-6), light_true),
        "bins": bins,
    }


def _ratio(light: Tensor, true_sums: Tensor) -> float | None:
    """Mean over channels of model / true light (``true_sums`` from :func:`_light_sums`, summed over
    views); None where no pixel had true T below ``LIGHT_T_MAX``."""
    if float(true_sums[3]) <= 0:
        return None
    return float((light.cpu() / (true_sums[:3] / true_sums[3]).clamp_min(1e-6)).mean())


def markdown(rows: list[dict]) -> str:
    head = (
        "| scene | seed | T MAE start / trained (true depth) | light model / true, start -> trained | "
        "optical depth model / true, start -> trained, per true-T bin |"
    )
    lines = [head, "|---|---|---|---|---|"]
    for r in rows:
        cells = "; ".join(
            f"{b['true_t'][0]:.1f}-{b['true_t'][1]:.1f} ({100 * b['share']:.0f} %): "
            f"{b['ratio_start']:.2f} -> {b['ratio_trained']:.2f}"
            for b in r["bins"]
        )
        light = "-" if r.get("light_ratio_start") is None else (
            f"{r['light_ratio_start']:.2f} -> {r['light_ratio_trained']:.2f}"
        )  # fmt: skip
        lines.append(
            f"| {r['scene']} | {r['seed']} | {r['t_mae_start']:.3f} / {r['t_mae_trained']:.3f} | {light} | {cells} |"
        )
    return "\n".join(lines) + "\n"


def _mean_ratio(r: dict) -> float:
    """The trained optical-depth ratio over the run's bins, share-weighted in log."""
    w = np.array([b["share"] for b in r["bins"]])
    v = np.log([b["ratio_trained"] for b in r["bins"]])
    return float(np.exp((w * v).sum() / w.sum()))


def plot(rows: list[dict], path: Path) -> None:
    """Left: optical-depth ratio (model / true) at the start (hollow) and trained (filled), per bin
    and run. Right: trained light ratio against trained optical-depth ratio, one point per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, lx) = plt.subplots(
        1,
        2,
        figsize=(max(6, 0.7 * len(rows)) + 4, 4),
        gridspec_kw={"width_ratios": [max(6, 0.7 * len(rows)), 4]},
    )
    colours = plt.cm.viridis(np.linspace(0, 0.9, len(BINS)))
    for k, (lo, hi) in enumerate(BINS):
        label: str | None = f"true T {lo:.1f}-{hi:.1f}"  # on the bin's first point only
        for x, r in enumerate(rows):
            b = next((b for b in r["bins"] if b["true_t"] == [lo, hi]), None)
            if b is None:
                continue
            dx = x + (k - 1.5) * 0.15
            ax.plot([dx, dx], [b["ratio_start"], b["ratio_trained"]], color=colours[k], lw=1)
            ax.plot(dx, b["ratio_start"], "o", mfc="none", color=colours[k])
            ax.plot(dx, b["ratio_trained"], "o", color=colours[k], label=label)
            label = None
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_yscale("log")
    ax.set_xticks(
        range(len(rows)), [f"{r['scene']}\nseed {r['seed']}" for r in rows], fontsize=6, rotation=60
    )
    ax.set_ylabel("optical depth, model / true")
    ax.set_title("hollow: the dark-channel start, filled: trained (both to the true depth)", fontsize=8)
    ax.legend(fontsize=7)
    lit = [r for r in rows if r.get("light_ratio_trained") is not None and r["bins"]]
    for r in lit:
        x, y = r["light_ratio_trained"], _mean_ratio(r)
        lx.plot(x, y, "o", color="tab:blue")
        lx.annotate(r["scene"], (x, y), fontsize=5, xytext=(2, 2), textcoords="offset points")
    lx.axhline(1.0, color="k", lw=0.8)
    lx.axvline(1.0, color="k", lw=0.8)
    lx.set_yscale("log")
    lx.set_xlabel("light, model / true (trained)")
    lx.set_ylabel("optical depth, model / true (trained)")
    lx.set_title("a light too dim needs more haze", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "The medium's optical depth against the truth, at its start and trained",
        "`python benchmarks/medium_start.py`", markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
