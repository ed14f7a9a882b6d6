"""What the light colour fit (``--pipeline.light-colour-fit``) reads on a trained run, against the truth.

For runs on generated scenes. Per run, over the training views: the fixed-effects light of the
seed points' hazy colours (pipelines/tridehaze/light_colour_fit.py) with the model's T and with
the true T, the model's and the true mean light S / (1 - T) over the pixels with at least 30 %
haze, and the chromaticity of each (each colour over its mean). With the true T the fit says
whether the photos hold the light's colour; with the model's T, whether the run's own medium is
good enough to read it. Session 37 of docs/results/medium_recovery.md reads the table.

    python benchmarks/light_colour_fit.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

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

from bench_output import diagnose_runs_main, grouped_bars  # noqa: E402

from pipelines.engine.medium_recovery import REFERENCE_S_KEY, REFERENCE_T_KEY, reference_map  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402
from pipelines.tridehaze.light_colour_fit import (  # noqa: E402
    PointObservations,
    chroma,
    fit_light,
    light_spread,
    ray_light,
)
from pipelines.tridehaze.priors import visible_points  # noqa: E402


def _observations(parts: list[tuple[Tensor, Tensor, Tensor]]) -> PointObservations | None:
    if not parts:
        return None
    return PointObservations(*(torch.cat([p[k] for p in parts]) for k in range(3)))


def _mean(values: list[Tensor]) -> Tensor | None:
    return torch.stack(values).mean(dim=0) if values else None


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    if dm.scene.points is None or len(dm.scene.points) == 0:
        raise SystemExit(f"{config}: the dataset has no seed points")
    pts = dm.scene.points.detach().float().cpu()
    model_obs, true_obs, model_rays, true_rays = [], [], [], []
    for i in dm.train_indices:
        cam = dm.camera(i)
        size = (int(cam.height[0]), int(cam.width[0]))
        true_t, true_s = (reference_map(dm, k, i, size) for k in (REFERENCE_T_KEY, REFERENCE_S_KEY))
        if true_t is None or true_s is None:
            raise SystemExit(f"{config}: the dataset has no true transmittance and scattering maps")
        out = pipe.render(cam)
        T, tt = out["transmittance"][..., 0].cpu(), true_t[..., 0].cpu()  # [H, W]
        model_rays.append(ray_light(T, out["scattering"].cpu()))  # [P, 3]
        true_rays.append(ray_light(tt, true_s.cpu()))
        vis = visible_points(cam, pts)
        ids, colour = vis.mask.nonzero()[:, 0], dm.image(i).cpu()[vis.v, vis.u].float()
        model_obs.append((ids, colour, T[vis.v, vis.u]))
        true_obs.append((ids, colour, tt[vis.v, vis.u]))
    row = {
        "run": str(config.parent),
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
        "light_spread": light_spread(model_rays),
    }
    for key, parts in (("fit_model_t", model_obs), ("fit_true_t", true_obs)):
        obs = _observations(parts)
        fit = fit_light(obs) if obs is not None else None
        row[key] = None if fit is None else fit.light.tolist()
        row[key + "_rel_stderr"] = None if fit is None else fit.rel_stderr
        row[key + "_points"] = None if fit is None else fit.points
    for key, rays in (("light_model", model_rays), ("light_true", true_rays)):
        mean = _mean([x.mean(dim=0) for x in rays if len(x)])  # the mean of the views' means
        row[key] = None if mean is None else mean.tolist()
    return row


def _chroma(rgb: list[float] | None) -> str:
    return (
        "-" if rgb is None else "(" + ", ".join(f"{c:.3f}" for c in chroma(torch.tensor(rgb)).tolist()) + ")"
    )


def _blue_error(row: dict, key: str) -> float | None:
    """The blue chromaticity's error against the true light's (the channel the rooms get wrong)."""
    if row[key] is None or row["light_true"] is None:
        return None
    return float(chroma(torch.tensor(row[key]))[2] - chroma(torch.tensor(row["light_true"]))[2])


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{value:.1%}"


def markdown(rows: list[dict]) -> str:
    lines = [
        "| scene | seed | chromaticity: true light / model light / fit, model T / fit, true T "
        "| blue error: model / fit, model T | fit's standard error (model T) | points | model light's spread |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        chromas = " / ".join(
            _chroma(r[k]) for k in ("light_true", "light_model", "fit_model_t", "fit_true_t")
        )
        errs = " / ".join(
            "-" if (e := _blue_error(r, k)) is None else f"{e:+.3f}" for k in ("light_model", "fit_model_t")
        )
        lines.append(
            f"| {r['scene']} | {r['seed']} | {chromas} | {errs} | {_pct(r['fit_model_t_rel_stderr'])} "
            f"| {r['fit_model_t_points'] or '-'} | {_pct(r['light_spread'])} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """Per run, the blue chromaticity's error of the model's light and of the fit with the model's T."""
    series = [
        ("model's light", [_blue_error(r, "light_model") or 0.0 for r in rows]),
        ("fit, model's T", [_blue_error(r, "fit_model_t") or 0.0 for r in rows]),
    ]
    labels = [f"{r['scene']} s{r['seed']}" for r in rows]
    grouped_bars(path, labels, series, "blue chromaticity - true", zero_line=True)


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "The light colour fit against the truth", "`python benchmarks/light_colour_fit.py`",
        markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
