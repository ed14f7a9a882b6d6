"""Where a run's restoration dB are lost: what each region of the picture would be worth if perfect.

For runs on generated scenes, each test view's pixels are split by the generator's truth into the
sky (true depth at the far bound, as ``sky_split.py``), hidden surfaces (true T under 0.05) and
three bins of the true T of the seen surfaces. Per region: its share of the pixels, the gain in
restoration PSNR (the mean over views, as ``td-bench restoration`` reports it) if the clean render
were exact there and unchanged elsewhere, the model's and the true mean T, the model's rendered
depth over the true depth (median of the per-pixel ratio), and the clean render's mean signed
error (positive: brighter than the reference, haze left in). Session 33 of
docs/results/medium_recovery.md reads the table.

    python benchmarks/error_by_region.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

Writes OUT.json, OUT.md (one row per run and region) and OUT.png.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch
from torch import Tensor

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import diagnose_runs_main, grouped_bars, psnr_of_mse  # noqa: E402
from reference_views import reference_views  # noqa: E402
from sky_split import SKY_FAR_SHARE, _far_bound_m  # noqa: E402

from pipelines.engine.medium_recovery import OBSERVABLE_T  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402
from pipelines.experiments.tables import fmt_number  # noqa: E402

REGIONS = ("sky", "hidden", "T<0.3", "T<0.7", "T>=0.7")


def region_masks(true_t: Tensor, sky: Tensor) -> dict[str, Tensor]:
    """[H, W] bool per region from the true T [H, W] and the sky [H, W]; they partition the view."""
    seen = ~sky & (true_t >= OBSERVABLE_T)
    return {
        "sky": sky,
        "hidden": ~sky & (true_t < OBSERVABLE_T),
        "T<0.3": seen & (true_t < 0.3),
        "T<0.7": seen & (true_t >= 0.3) & (true_t < 0.7),
        "T>=0.7": seen & (true_t >= 0.7),
    }


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    far_z = SKY_FAR_SHARE * _far_bound_m(run) * dm.scene.transform.scale  # normalised frame
    base: list[float] = []
    perfect: dict[str, list[float]] = {r: [] for r in REGIONS}
    sums = {r: {"n": 0, "t_model": 0.0, "t_true": 0.0, "signed": 0.0, "ratios": []} for r in REGIONS}
    for view in reference_views(dm):
        reference = dm.clean_image(view.index)  # [H, W, 3]
        out = pipe.render(view.camera)
        err = out["clean"] - reference  # [H, W, 3]
        se = (err**2).sum(-1)  # [H, W]
        masks = region_masks(view.true_t[..., 0], view.true_z[..., 0] >= far_z)
        base.append(psnr_of_mse(float(se.sum()) / (3 * se.numel())))
        for name, m in masks.items():
            perfect[name].append(psnr_of_mse(float(se[~m].sum()) / (3 * se.numel())))
            s = sums[name]
            s["n"] += int(m.sum())
            s["t_model"] += float(out["transmittance"][..., 0][m].sum())
            s["t_true"] += float(view.true_t[..., 0][m].sum())
            s["signed"] += float(err[m].mean(-1).sum())
            s["ratios"].append(out["depth"][..., 0][m] / view.true_z[..., 0][m].clamp_min(1e-6))
    if not base:
        raise SystemExit(f"{config}: the dataset has no true transmittance and depth maps")
    mean_base = sum(base) / len(base)
    total = sum(s["n"] for s in sums.values())
    regions = {}
    for name, s in sums.items():
        n = max(s["n"], 1)
        ratios = torch.cat(s["ratios"])
        regions[name] = {
            "share": s["n"] / total,
            "gain_if_perfect": sum(perfect[name]) / len(perfect[name]) - mean_base,
            "t_model": s["t_model"] / n if s["n"] else None,
            "t_true": s["t_true"] / n if s["n"] else None,
            "depth_ratio": float(ratios.median()) if len(ratios) else None,
            "signed_error": s["signed"] / n if s["n"] else None,
        }
    return {
        "run": str(config.parent),
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
        "psnr": mean_base,
        "regions": regions,
    }


def markdown(rows: list[dict]) -> str:
    lines = [
        "| scene | seed | PSNR | region | share | gain if perfect (dB) | T model / true | depth model / true "
        "| signed error |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        for name in REGIONS:
            g = r["regions"][name]
            if g["share"] == 0:
                continue
            lines.append(
                f"| {r['scene']} | {r['seed']} | {fmt_number(r['psnr'])} | {name} | {100 * g['share']:.0f} % | "
                f"{g['gain_if_perfect']:+.2f} | {fmt_number(g['t_model'], 2)} / {fmt_number(g['t_true'], 2)} | "
                f"{fmt_number(g['depth_ratio'], 2)} | {fmt_number(g['signed_error'], 3)} |"
            )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """Per run, the gain if each region were perfect."""
    series = [(name, [r["regions"][name]["gain_if_perfect"] for r in rows]) for name in REGIONS]
    grouped_bars(path, [f"{r['scene']} s{r['seed']}" for r in rows], series, "gain if perfect (dB)")


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "Where the restoration error sits, by region", "`python benchmarks/error_by_region.py`",
        markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
