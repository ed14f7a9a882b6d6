"""Where a trained medium's T is wrong: pixels where the dark-channel bound is tight, and the rest.

For runs on generated scenes (true T and S maps per view), every training view's pixels with at
least ``MIN_HAZE`` haze are split by whether the dark channel's lower bound on T, computed with
the *true* light along each ray (S / (1 - T)), lies within ``TIGHT_TOL`` of the true T: "tight"
where the clean patch has a dark pixel (the bound is the truth there), "loose" elsewhere (bright or
haze-coloured surfaces, where the bound says little). Per region: the model's mean T error
(bias; negative means too much haze) and mean absolute error. Per run also: the mean violation of
the bound with the true light and with the model's own light (the ``lower-own-light`` loss's
target), and the median ratio of the model's light along the rays to the true one.

Why: with the model's own light and T even over a patch, the bound T >= 1 - omega min(I / L)
reduces to S <= omega I at the patch's pixels; it holds the in-scattering, not the split of the
haze into T and light (docs/results/medium_recovery.md, session 27).

    python benchmarks/dcp_bound_split.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

Writes OUT.json, OUT.md (one row per run) and OUT.png.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch
from torch import Tensor

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import diagnose_runs_main, fmt, grouped_bars  # noqa: E402
from sky_split import arm_of, run_label  # noqa: E402

from components.losses.dcp import dark_channel_bound, default_patch  # noqa: E402
from pipelines.engine.medium_recovery import REFERENCE_S_KEY, REFERENCE_T_KEY, reference_map  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402

MIN_HAZE = 0.05
"""Pixels with less haze (1 - true T) are left out: the light S / (1 - T) is undefined there, as in
the training loss's mask."""
TIGHT_TOL = 0.03
"""The true-light bound within this of the true T counts as tight."""
REGIONS = ("tight", "loose")


def light_along_rays(scattering: Tensor, transmittance: Tensor) -> Tensor:
    """S / (1 - T) [H, W, 3], the haze's mean light along each ray; scattering [H, W, 3], T [H, W, 1]."""
    return scattering / (1.0 - transmittance).clamp_min(MIN_HAZE)


def split_sums(
    image: Tensor, t_model: Tensor, s_model: Tensor, t_true: Tensor, s_true: Tensor, patch: int
) -> dict[str, float]:
    """Sums over one view (image, S: [H, W, 3]; T: [H, W, 1]): per region the T error's sum, its
    absolute sum and the pixel count; the bound violations' sums; the light ratios' list."""
    true_bound = dark_channel_bound(image, light_along_rays(s_true, t_true), patch)  # [H, W]
    own_bound = dark_channel_bound(image, light_along_rays(s_model, t_model), patch)  # [H, W]
    tm, tt = t_model[..., 0], t_true[..., 0]  # [H, W]
    hazy = (1.0 - tt) >= MIN_HAZE
    tight = (true_bound - tt).abs() < TIGHT_TOL
    err = tm - tt
    out: dict[str, float] = {}
    for name, m in (("tight", hazy & tight), ("loose", hazy & ~tight)):
        out[f"{name}_err"] = float(err[m].sum())
        out[f"{name}_abs"] = float(err[m].abs().sum())
        out[f"{name}_n"] = float(m.sum())
    out["viol_true"] = float((true_bound - tm).clamp_min(0.0)[hazy].sum())
    out["viol_own"] = float((own_bound - tm).clamp_min(0.0)[hazy].sum())
    return out


def light_ratio(t_model: Tensor, s_model: Tensor, t_true: Tensor, s_true: Tensor) -> Tensor:
    """Model light / true light (channel means) on pixels with at least 30 % true haze: [P]."""
    m = (1.0 - t_true[..., 0]) >= 0.3
    lm = light_along_rays(s_model, t_model).mean(-1)
    lt = light_along_rays(s_true, t_true).mean(-1)
    return (lm / lt.clamp_min(1e-3))[m]


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    totals: dict[str, float] = {}
    ratios = []
    for idx in dm.train_indices:
        cam = dm.camera(idx)
        size = (int(cam.height[0]), int(cam.width[0]))
        t_true = reference_map(dm, REFERENCE_T_KEY, idx, size)  # [H, W, 1]
        s_true = reference_map(dm, REFERENCE_S_KEY, idx, size)  # [H, W, 3]
        if t_true is None or s_true is None:
            continue
        out = pipe.render(cam)
        t_model, s_model = out["transmittance"], out["scattering"]
        sums = split_sums(dm.image(idx).float(), t_model, s_model, t_true, s_true, default_patch(*size))
        for k, v in sums.items():
            totals[k] = totals.get(k, 0.0) + v
        ratios.append(light_ratio(t_model, s_model, t_true, s_true))
    if not totals:
        raise SystemExit(f"{config}: the dataset has no true transmittance and scattering maps")
    n = totals["tight_n"] + totals["loose_n"]
    row: dict = {"run": str(config.parent), "scene": Path(str(run.config.dataset.data)).name}
    row["seed"] = run.config.seed
    row["tight_share"] = totals["tight_n"] / n if n else None
    for r in REGIONS:
        count = totals[f"{r}_n"]
        row[f"{r}_bias"] = totals[f"{r}_err"] / count if count else None
        row[f"{r}_mae"] = totals[f"{r}_abs"] / count if count else None
    row["bias"] = (totals["tight_err"] + totals["loose_err"]) / n if n else None
    row["violation_true_light"] = totals["viol_true"] / n if n else None
    row["violation_own_light"] = totals["viol_own"] / n if n else None
    r = torch.cat(ratios)
    row["light_ratio"] = float(r.median()) if r.numel() else None
    return row


def markdown(rows: list[dict]) -> str:
    lines = [
        "| run | scene | seed | tight share | T bias all / tight / loose | T MAE tight / loose | "
        "bound violation, true / own light | light / true light |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        bias = " / ".join(fmt(r[k], sign=True) for k in ("bias", "tight_bias", "loose_bias"))
        mae = " / ".join(fmt(r[k]) for k in ("tight_mae", "loose_mae"))
        viol = f"{fmt(r['violation_true_light'])} / {fmt(r['violation_own_light'])}"
        lines.append(
            f"| {arm_of(r['run'])} | {r['scene']} | {r['seed']} | {100 * (r['tight_share'] or 0):.0f} % | "
            f"{bias} | {mae} | {viol} | {fmt(r['light_ratio'], 2)} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """T bias on tight and loose pixels per run."""
    grouped_bars(
        path,
        [run_label(r) for r in rows],
        [(f"{region} pixels", [r[f"{region}_bias"] or 0.0 for r in rows]) for region in REGIONS],
        "T error, model - true\n(< 0: too much haze)",
        zero_line=True,
    )


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "The medium's T error where the dark-channel bound is tight and where it is loose",
        "`python benchmarks/dcp_bound_split.py`", markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
