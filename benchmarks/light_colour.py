"""The haze light's colour: the dark channel's airlight, the truth and a trained run's, and what the
clean render's colour cast costs.

For runs on generated scenes. Per run: the dark-channel airlight (mean over the training views),
the true and the model's mean light S / (1 - T) over the test pixels with at least 30 % haze
(each by its own T), their chromaticity (each colour over its mean), the clean render's mean
signed error per channel over the test views (its colour cast), and the restoration PSNR with that
one cast taken out (an oracle: what a right light colour could be worth at most, if the cast is
the light's). Session 36 of docs/results/medium_recovery.md reads the table.

    python benchmarks/light_colour.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

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

from bench_output import diagnose_runs_main, grouped_bars, psnr_of_mse  # noqa: E402
from reference_views import reference_views  # noqa: E402

from pipelines.engine.medium_recovery import REFERENCE_S_KEY, reference_map  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402
from pipelines.experiments.tables import fmt_number  # noqa: E402
from pipelines.tridehaze.light_colour_fit import mean_ray_light  # noqa: E402
from pipelines.tridehaze.priors import dcp_per_view  # noqa: E402


def _mean(values: list[Tensor]) -> list[float] | None:
    return torch.stack(values).mean(dim=0).tolist() if values else None


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    dcp = dcp_per_view(dm, dm.train_indices)  # the estimate the pipeline's medium start reads
    airlight = torch.stack([torch.from_numpy(d.airlight) for d in dcp.values()]).mean(dim=0)  # [3]
    true_l, model_l, errors = [], [], []
    for view in reference_views(dm):
        out = pipe.render(view.camera)
        errors.append(out["clean"] - dm.clean_image(view.index))  # [H, W, 3]
        true_s = reference_map(dm, REFERENCE_S_KEY, view.index, (view.height, view.width))
        if true_s is not None and (light := mean_ray_light(view.true_t[..., 0], true_s)) is not None:
            true_l.append(light)
        if (light := mean_ray_light(out["transmittance"][..., 0], out["scattering"])) is not None:
            model_l.append(light)
    if not errors:
        raise SystemExit(f"{config}: the dataset has no true transmittance and depth maps")
    cast = torch.stack([e.reshape(-1, 3).mean(dim=0) for e in errors]).mean(dim=0)  # [3]
    psnr = sum(psnr_of_mse(float((e**2).mean())) for e in errors) / len(errors)
    without = sum(psnr_of_mse(float(((e - cast) ** 2).mean())) for e in errors) / len(errors)
    return {
        "run": str(config.parent),
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
        "airlight_dcp": airlight.tolist(),
        "light_true": _mean(true_l),
        "light_model": _mean(model_l),
        "cast": cast.tolist(),
        "psnr": psnr,
        "psnr_without_cast": without,
    }


def _chroma(rgb: list[float] | None) -> str:
    if rgb is None:
        return "-"
    mean = sum(rgb) / 3.0
    return "(" + ", ".join(f"{c / mean:.3f}" for c in rgb) + ")"


def _rgb(rgb: list[float] | None) -> str:
    return "-" if rgb is None else "(" + ", ".join(f"{c:.3f}" for c in rgb) + ")"


def markdown(rows: list[dict]) -> str:
    lines = [
        "| scene | seed | light: dark channel / true / model | chromaticity: dark channel / true / model "
        "| clean colour cast (RGB) | PSNR | without the cast |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lights = " / ".join(_rgb(r[k]) for k in ("airlight_dcp", "light_true", "light_model"))
        chroma = " / ".join(_chroma(r[k]) for k in ("airlight_dcp", "light_true", "light_model"))
        lines.append(
            f"| {r['scene']} | {r['seed']} | {lights} | {chroma} | {_rgb(r['cast'])} | "
            f"{fmt_number(r['psnr'])} | {fmt_number(r['psnr_without_cast'])} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """Per run, the restoration PSNR and the same without the clean render's colour cast."""
    series = [
        ("PSNR", [r["psnr"] for r in rows]),
        ("without the cast", [r["psnr_without_cast"] for r in rows]),
    ]
    grouped_bars(path, [f"{r['scene']} s{r['seed']}" for r in rows], series, "restoration PSNR (dB)")


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "The haze light's colour", "`python benchmarks/light_colour.py`",
        markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
