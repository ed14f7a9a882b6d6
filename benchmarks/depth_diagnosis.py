"""How much of the medium's T error is the depth it is marched to?

For runs on generated scenes (true T and true depth per view), each test view's rendered end
depth (``alpha D + (1 - alpha) far``, what the compositor marches the medium to) is compared with
the true z-depth, and the *true* medium is marched to it: along each pixel's ray the true mean
extinction ``-ln T_true / path_true`` times the rendered path. That T minus the true T is the error
that the depth alone causes, with a perfect medium; the model's own T error is beside it.

    python benchmarks/depth_diagnosis.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

Writes OUT.json, OUT.md (one row per run) and OUT.png.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import diagnose_runs_main  # noqa: E402
from reference_views import TRUE_T_BINS as BINS  # noqa: E402
from reference_views import reference_views  # noqa: E402

from components.medium.compositing import pixel_path_lengths  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    ratio, t_true, err_depth, err_model, alpha = [], [], [], [], []
    for view in reference_views(dm):
        cam, H, W = view.camera, view.height, view.width
        true_t, true_z = view.true_t[..., 0], view.true_z[..., 0]  # [H, W], z in the normalised frame
        out = pipe.render(cam)
        far = pipe.compositor.far_bound(pipe.medium_field())
        z = pipe.compositor.end_depth(out["depth"], out["alpha"], far)[..., 0]  # [H, W] as marched
        length = pixel_path_lengths(cam, H, W, z.device, z.dtype)  # [H, W] path per unit z
        beta = -true_t.clamp(1e-4, 0.9999).log() / (true_z * length).clamp_min(
            1e-9
        )  # [H, W] true mean extinction
        ratio.append((z / true_z.clamp_min(1e-9)).flatten())
        t_true.append(true_t.flatten())
        err_depth.append((torch.exp(-beta * z * length) - true_t).flatten())
        err_model.append((out["transmittance"][..., 0] - true_t).flatten())
        alpha.append(out["alpha"][..., 0].flatten())
    if not ratio:
        raise SystemExit(f"{config}: the dataset has no true transmittance and depth maps")
    r, t, ed, em, a = (torch.cat(v).cpu().numpy() for v in (ratio, t_true, err_depth, err_model, alpha))
    bins = []
    for lo, hi in BINS:
        m = (t >= lo) & ((t < hi) if hi < 1.0 else (t <= 1.0))
        if m.sum() < 10:
            continue
        bins.append({
            "true_t": [lo, hi], "share": float(m.mean()), "depth_ratio": float(np.median(r[m])),
            "t_bias_depth_only": float(ed[m].mean()), "t_bias_model": float(em[m].mean()),
        })  # fmt: skip
    return {
        "run": str(config.parent),
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
        "depth_ratio_median": float(np.median(r)),
        "depth_ratio_p10": float(np.percentile(r, 10)),
        "depth_ratio_p90": float(np.percentile(r, 90)),
        "t_mae_depth_only": float(np.abs(ed).mean()),
        "t_mae_model": float(np.abs(em).mean()),
        "covered_below_095": float((a < 0.95).mean()),
        "bins": bins,
    }


def markdown(rows: list[dict]) -> str:
    head = (
        "| scene | seed | end depth / true, median (p10-p90) | T MAE: true medium to the rendered depth / "
        "model | per true-T bin: depth ratio, T bias depth only / model |"
    )
    lines = [head, "|---|---|---|---|---|"]
    for r in rows:
        cells = "; ".join(
            f"{b['true_t'][0]:.1f}-{b['true_t'][1]:.1f} ({100 * b['share']:.0f} %): {b['depth_ratio']:.2f}, "
            f"{b['t_bias_depth_only']:+.3f} / {b['t_bias_model']:+.3f}"
            for b in r["bins"]
        )
        lines.append(
            f"| {r['scene']} | {r['seed']} | {r['depth_ratio_median']:.2f} ({r['depth_ratio_p10']:.2f}-"
            f"{r['depth_ratio_p90']:.2f}) | {r['t_mae_depth_only']:.3f} / {r['t_mae_model']:.3f} | {cells} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """Median end-depth ratio per true-T bin and run (1 = the true depth)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(max(6, 0.7 * len(rows)), 4))
    colours = plt.cm.viridis(np.linspace(0, 0.9, len(BINS)))
    for k, (lo, hi) in enumerate(BINS):
        xs, ys = [], []
        for x, r in enumerate(rows):
            b = next((b for b in r["bins"] if b["true_t"] == [lo, hi]), None)
            if b is not None:
                xs.append(x + (k - 1.5) * 0.15)
                ys.append(b["depth_ratio"])
        ax.plot(xs, ys, "o", color=colours[k], label=f"true T {lo:.1f}-{hi:.1f}")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_xticks(
        range(len(rows)), [f"{r['scene']}\nseed {r['seed']}" for r in rows], fontsize=6, rotation=60
    )
    ax.set_ylabel("rendered end depth / true depth (median)")
    ax.set_title("below 1: the medium is marched too short a way", fontsize=8)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "The depth the medium is marched to, against the true depth",
        "`python benchmarks/depth_diagnosis.py`", markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
