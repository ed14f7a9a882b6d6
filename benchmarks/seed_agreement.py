"""Whether the clean render's error is bias or seed noise (no training).

Runs of one scene trained with different seeds are rendered on the test views. If their errors
were seed noise, averaging the renders would remove much of them (two independent errors of equal
size: +3 dB); if the errors are a shared bias, the average is as wrong as each run. Per scene: each
run's restoration PSNR, the PSNR of the averaged clean render, the correlation of the runs' errors
(mean over views and run pairs) and the T MAE of each run's and of the averaged transmittance.

    python benchmarks/seed_agreement.py --runs ARM/seed*/runs/*/tri-dehaze/tri-dehaze/config.yml --output STEM

Runs are grouped by scene (the dataset's folder name); a scene with a single run is left out.
"""

from __future__ import annotations

import argparse
import os
import sys
from itertools import combinations
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import fmt, grouped_bars, mean_or_none, psnr_of_mse, publish  # noqa: E402

from pipelines.engine.medium_recovery import REFERENCE_T_KEY, reference_map  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402


def view_agreement(preds: list[np.ndarray], ref: np.ndarray) -> dict:
    """One test view: preds (one clean render [H, W, 3] per run), ref [H, W, 3]."""
    errors = [(p - ref).astype(np.float64).ravel() for p in preds]
    corr = [float(np.corrcoef(a, b)[0, 1]) for a, b in combinations(errors, 2)]
    return {
        "psnr": [psnr_of_mse(float(np.square(p - ref).mean())) for p in preds],
        "ensemble": psnr_of_mse(float(np.square(np.mean(preds, axis=0) - ref).mean())),
        "error_corr": float(np.mean(corr)),
    }


def t_errors(ts: list[np.ndarray], true_t: np.ndarray | None) -> dict:
    """T MAE of each run's transmittance [H, W] and of their mean (None without a true map)."""
    if true_t is None:
        return {"t_mae": [None] * len(ts), "t_mae_ensemble": None}
    return {
        "t_mae": [float(np.abs(t - true_t).mean()) for t in ts],
        "t_mae_ensemble": float(np.abs(np.mean(ts, axis=0) - true_t).mean()),
    }


def _renders(config: Path) -> tuple[object, dict[int, tuple[np.ndarray, np.ndarray]]]:
    """A run and its test views' (clean [H, W, 3], T [H, W]) by view index."""
    run = load_run(config)
    out = {}
    for idx in run.datamanager.test_indices:
        o = run.pipeline.render(run.datamanager.camera(idx))
        out[idx] = (o["clean"].clamp(0.0, 1.0).cpu().numpy(), o["transmittance"][..., 0].cpu().numpy())
    return run, out


def diagnose(configs: list[Path]) -> dict:
    """One scene's row from its runs' config.yml files (two or more seeds)."""
    loaded = [_renders(c) for c in configs]
    dm = loaded[0][0].datamanager
    views = []
    for idx in dm.test_indices:
        clean = dm.clean_image(idx)
        if clean is None:
            continue
        ref = clean.cpu().numpy()  # [H, W, 3]
        true_t = reference_map(dm, REFERENCE_T_KEY, idx, tuple(ref.shape[:2]))  # [H, W, 1] or None
        true_t = None if true_t is None else true_t[..., 0].cpu().numpy()
        row = view_agreement([r[idx][0] for _, r in loaded], ref)
        row.update(t_errors([r[idx][1] for _, r in loaded], true_t))
        views.append(row)
    return {
        "scene": Path(str(loaded[0][0].config.dataset.data)).name,
        "runs": [str(c.parent) for c in configs],
        "seeds": [run.config.seed for run, _ in loaded],
        "views": views,
        "mean": _means(views, len(configs)),
    }


def _means(views: list[dict], n_runs: int) -> dict:
    return {
        "psnr": [mean_or_none([v["psnr"][k] for v in views]) for k in range(n_runs)],
        "ensemble": mean_or_none([v["ensemble"] for v in views]),
        "error_corr": mean_or_none([v["error_corr"] for v in views]),
        "t_mae": [mean_or_none([v["t_mae"][k] for v in views]) for k in range(n_runs)],
        "t_mae_ensemble": mean_or_none([v["t_mae_ensemble"] for v in views]),
    }


def group_by_scene(configs: list[Path]) -> dict[str, list[Path]]:
    """Configs keyed by their run's scene: the folder above ``<method>/<method>/config.yml`` in a
    ``td-bench restoration`` layout (``runs/<scene>/...``), else the run folder's parent."""
    groups: dict[str, list[Path]] = {}
    for c in configs:
        parts = c.resolve().parts
        scene = parts[-4] if len(parts) >= 5 and parts[-5] == "runs" else c.parent.parent.name
        groups.setdefault(scene, []).append(c)
    return groups


def markdown(rows: list[dict]) -> str:
    lines = [
        "| scene | seeds | PSNR per run | mean of runs | averaged render | gain | error correlation "
        "| T MAE per run | T MAE averaged |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        m = r["mean"]
        mean_run = float(np.mean(m["psnr"]))
        lines.append(
            f"| {r['scene']} | {', '.join(map(str, r['seeds']))} | {' / '.join(fmt(p, 2) for p in m['psnr'])} "
            f"| {mean_run:.2f} | {fmt(m['ensemble'], 2)} | {m['ensemble'] - mean_run:+.2f} "
            f"| {fmt(m['error_corr'], 2)} | {' / '.join(fmt(t, 3) for t in m['t_mae'])} "
            f"| {fmt(m['t_mae_ensemble'], 3)} |"
        )
    if rows:
        gain = np.mean([r["mean"]["ensemble"] - np.mean(r["mean"]["psnr"]) for r in rows])
        lines.append(f"\nMean gain of the averaged render over the mean of the runs: {gain:+.2f} dB.")
    note = (
        "\nPSNR in dB, means over the test views. Error correlation: Pearson correlation of two runs' "
        "per-pixel errors (1: the same error, a bias; 0: independent noise, which averaging two runs "
        "would cut by 3 dB).\n"
    )
    return "\n".join(lines) + "\n" + note


def plot(rows: list[dict], path: Path) -> None:
    series = [
        ("mean of the runs", [float(np.mean(r["mean"]["psnr"])) for r in rows]),
        ("averaged render", [r["mean"]["ensemble"] for r in rows]),
    ]
    grouped_bars(path, [r["scene"] for r in rows], series, "restoration PSNR (dB)")


def main() -> None:
    import torch

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=Path, nargs="+", required=True, help="config.yml of trained runs")
    ap.add_argument("--output", type=Path, required=True, help="output stem: writes .json, .md, .png")
    args = ap.parse_args()
    torch.set_grad_enabled(False)
    groups = {k: v for k, v in group_by_scene(args.runs).items() if len(v) >= 2}
    if not groups:
        raise SystemExit(
            "seed_agreement: no scene has two runs among --runs; give each scene's runs of several seeds"
        )
    rows = [diagnose(groups[k]) for k in sorted(groups)]
    common = os.path.commonpath([str(c.resolve()) for c in args.runs])
    how = (
        f"`python benchmarks/seed_agreement.py --runs <{len(args.runs)} config.yml files under {common}> "
        f"--output {args.output}`"
    )
    publish(
        args.output,
        rows,
        "Bias or seed noise: the clean render of several seeds, averaged",
        how,
        markdown(rows),
        plot,
    )


if __name__ == "__main__":
    main()
