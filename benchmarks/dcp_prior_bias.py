"""How far is the dark-channel transmittance from the truth, and on which side?

The Stage I prior pulls the medium's T towards the dark channel's estimate (``--pipeline.dcp-bound
two-sided``) or only keeps T from falling below it (``lower``). Which is right depends on the sign
of the prior's error: on scenes that carry the true T (``td-synth scene`` writes it), this prints
and writes (JSON + markdown + plot) per scene the estimate's mean absolute error, its mean signed
error by true-T bin, and the share of pixels where it is *above* the truth by more than 0.05 (a
lower bound would be violated there).

    python benchmarks/dcp_prior_bias.py --scenes runs/restoration-set/* --output docs/results/dcp_prior_bias
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_output import publish  # noqa: E402

from components.losses.dcp import estimate_dcp  # noqa: E402

T_BINS = ((0.0, 0.2), (0.2, 0.4), (0.4, 0.6), (0.6, 0.8), (0.8, 1.01))
ABOVE = 0.05
"""An estimate more than this above the true T counts as violating the lower bound."""


def scene_errors(scene: Path) -> dict:
    """Signed errors t_dcp - t_true over every view of one generated scene, summarised."""
    tf = json.loads((scene / "transforms.json").read_text())
    diffs, trues = [], []
    for fr in tf["frames"]:
        if "gt_transmittance_file_path" not in fr:
            continue
        img = cv2.cvtColor(cv2.imread(str(scene / fr["file_path"])), cv2.COLOR_BGR2RGB)  # [H, W, 3]
        t_true = np.load(scene / fr["gt_transmittance_file_path"]).reshape(img.shape[:2])  # [H, W]
        diffs.append((estimate_dcp(img).transmittance - t_true).ravel())
        trues.append(t_true.ravel())
    if not diffs:
        raise SystemExit(f"{scene}: no frame has gt_transmittance_file_path (make it with td-synth scene)")
    d, t = np.concatenate(diffs), np.concatenate(trues)
    by_bin = {}
    for lo, hi in T_BINS:
        m = (t >= lo) & (t < hi)
        by_bin[f"{lo:.1f}-{min(hi, 1.0):.1f}"] = {
            "share": float(m.mean()),
            "bias": float(d[m].mean()) if m.any() else None,
        }
    return {
        "scene": scene.name,
        "views": len(diffs),
        "mae": float(np.abs(d).mean()),
        "bias": float(d.mean()),
        "above_share": float((d > ABOVE).mean()),
        "below_share": float((d < -ABOVE).mean()),
        "bias_by_true_t": by_bin,
    }


def markdown(rows: list[dict]) -> str:
    bins = list(rows[0]["bias_by_true_t"])
    head = "| scene | MAE | mean error | above truth by >0.05 | below by >0.05 | " + " | ".join(
        f"error at true T {b}" for b in bins
    )
    lines = [head + " |", "|" + "---|" * (5 + len(bins))]
    for r in rows:
        cells = [
            f"{r['bias_by_true_t'][b]['bias']:+.2f}" if r["bias_by_true_t"][b]["bias"] is not None else "-"
            for b in bins
        ]
        lines.append(
            f"| {r['scene']} | {r['mae']:.3f} | {r['bias']:+.3f} | {100 * r['above_share']:.0f} % "
            f"| {100 * r['below_share']:.0f} % | " + " | ".join(cells) + " |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bins = list(rows[0]["bias_by_true_t"])
    fig, ax = plt.subplots(figsize=(7, 4))
    for r in rows:
        ys = [r["bias_by_true_t"][b]["bias"] for b in bins]
        xs = [i for i, y in enumerate(ys) if y is not None]
        ax.plot(xs, [ys[i] for i in xs], marker="o", label=r["scene"])
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xticks(range(len(bins)), bins)
    ax.set_xlabel("true transmittance")
    ax.set_ylabel("dark-channel T - true T")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=Path, nargs="+", required=True, help="generated scene folders")
    ap.add_argument("--output", type=Path, required=True, help="output stem: writes .json, .md, .png")
    args = ap.parse_args()
    rows = [scene_errors(s) for s in args.scenes if (s / "transforms.json").exists()]
    if not rows:
        raise SystemExit("no scene folder with a transforms.json among --scenes")
    publish(
        args.output, rows, "Dark-channel transmittance against the truth",
        "`python benchmarks/dcp_prior_bias.py` (signed error: estimate minus truth).", markdown(rows), plot,
    )  # fmt: skip


if __name__ == "__main__":
    main()
