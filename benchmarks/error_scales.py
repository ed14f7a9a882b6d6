"""At what spatial scale the clean render is wrong (no training).

For each trained run, the test views' restoration error e = J - J_ref is split by a Gaussian
low-pass of ``sigma`` pixels: the PSNR the render would reach with the error's low-pass removed
(what is left is the error finer than ``sigma``). A medium whose T or S is wrong in broad patches
leaves a smooth error that removing the low-pass takes away; floaters, blur and wrong texture leave
a fine one. Alongside: the PSNR over the pixels the photos see (true T >= 0.05) and over those they
do not (where any method only guesses), the PSNR after one affine colour map per view and channel
fitted to the reference (an oracle for a per-view colour cast), the PSNR with the run's one mean
colour error over all its test views taken out (an oracle for a cast shared by every view), and
the model's mean signed T error on the seen pixels (positive: the medium too thin).

    python benchmarks/error_scales.py --runs RUN/config.yml ... --output STEM
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import diagnose_runs_main, fmt, grouped_bars, mean_or_none, psnr_of_mse  # noqa: E402
from sky_split import arm_of, run_label  # noqa: E402

from pipelines.engine.medium_recovery import OBSERVABLE_T, REFERENCE_T_KEY, reference_map  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402

SIGMAS = (4, 8, 16)
"""Low-pass widths (pixels) whose share of the error is removed, finest first."""


def _psnr(err: np.ndarray, mask: np.ndarray | None = None) -> float | None:
    """PSNR of an error image [H, W, 3] (over ``mask`` [H, W] where given; None for no pixels)."""
    sq = np.square(err).mean(axis=-1)  # [H, W]
    if mask is not None:
        if not mask.any():
            return None
        sq = sq[mask]
    return psnr_of_mse(float(sq.mean()))


def _affine_error(pred: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """The error [H, W, 3] left after the least-squares gain and offset per channel."""
    out = np.empty_like(pred)
    for c in range(3):
        x = np.stack([pred[..., c].ravel(), np.ones(pred[..., c].size)], axis=1)  # [P, 2]
        coef = np.linalg.lstsq(x, ref[..., c].ravel(), rcond=None)[0]
        out[..., c] = (x @ coef).reshape(pred.shape[:2]) - ref[..., c]
    return out


def view_scores(pred: np.ndarray, ref: np.ndarray, true_t: np.ndarray | None, model_t: np.ndarray) -> dict:
    """One view's scores; pred, ref [H, W, 3], true_t, model_t [H, W] (true_t None: no true map)."""
    err = (pred - ref).astype(np.float32)  # [H, W, 3]
    row: dict = {"psnr": _psnr(err), "affine": _psnr(_affine_error(pred, ref))}
    for s in SIGMAS:
        row[f"fine_{s}"] = _psnr(err - cv2.GaussianBlur(err, (0, 0), s, borderType=cv2.BORDER_REFLECT))
    seen = None if true_t is None else true_t >= OBSERVABLE_T  # [H, W]
    row["seen"] = None if seen is None else _psnr(err, seen)
    row["hidden"] = None if seen is None else _psnr(err, ~seen)
    row["hidden_share"] = None if seen is None else float((~seen).mean())
    row["t_bias_seen"] = None if seen is None or not seen.any() else float((model_t - true_t)[seen].mean())
    return row


def cast_removed(errors: list[np.ndarray]) -> list[float | None]:
    """Each view's PSNR with the mean colour error of all the views [3] taken out; errors [H, W, 3]."""
    if not errors:
        return []
    cast = np.concatenate([e.reshape(-1, 3) for e in errors]).mean(axis=0)  # [3]
    return [_psnr(e - cast) for e in errors]


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    views, errors = [], []
    for idx in dm.test_indices:
        clean = dm.clean_image(idx)
        if clean is None:
            continue
        ref = clean.cpu().numpy()  # [H, W, 3]
        out = pipe.render(dm.camera(idx))
        pred = out["clean"].clamp(0.0, 1.0).cpu().numpy()  # [H, W, 3]
        size = tuple(pred.shape[:2])
        true_t = reference_map(dm, REFERENCE_T_KEY, idx, size)  # [H, W, 1] or None
        true_t = None if true_t is None else true_t[..., 0].cpu().numpy()
        model_t = out["transmittance"][..., 0].cpu().numpy()
        views.append(view_scores(pred, ref, true_t, model_t))
        errors.append(pred - ref)  # [H, W, 3]
    for view, score in zip(views, cast_removed(errors), strict=True):
        view["run_cast"] = score
    return {
        "run": str(config.parent),
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
        "views": views,
        "mean": {k: mean_or_none([v[k] for v in views]) for k in (views[0] if views else {})},
    }


def markdown(rows: list[dict]) -> str:
    fine = " / ".join(f"{s} px" for s in SIGMAS)
    lines = [
        f"| run | scene | seed | PSNR | seen / hidden (hidden share) | error finer than {fine} "
        "| per-view affine colour (oracle) | run's mean colour error out (oracle) | T bias, seen pixels |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        m = r["mean"]
        fine_cells = " / ".join(fmt(m.get(f"fine_{s}"), 2) for s in SIGMAS)
        lines.append(
            f"| {arm_of(r['run'])} | {r['scene']} | {r['seed']} | {fmt(m.get('psnr'), 2)} "
            f"| {fmt(m.get('seen'), 2)} / {fmt(m.get('hidden'), 2)} ({fmt(m.get('hidden_share'), 2)}) "
            f"| {fine_cells} | {fmt(m.get('affine'), 2)} | {fmt(m.get('run_cast'), 2)} "
            f"| {fmt(m.get('t_bias_seen'), 3, sign=True)} |"
        )
    note = (
        "\nPSNR in dB, means over the test views. 'error finer than s px': the PSNR with the error's "
        "Gaussian low-pass of s pixels removed (what a smooth correction could at best recover).\n"
    )
    return "\n".join(lines) + "\n" + note


def plot(rows: list[dict], path: Path) -> None:
    keys = [("whole image", "psnr")] + [(f"error finer than {s} px", f"fine_{s}") for s in SIGMAS]
    series = [(name, [r["mean"].get(k) or 0.0 for r in rows]) for name, k in keys]
    grouped_bars(path, [run_label(r) for r in rows], series, "restoration PSNR (dB)", legend_above=True)


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "At what spatial scale the clean render is wrong",
        "`python benchmarks/error_scales.py`", markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
