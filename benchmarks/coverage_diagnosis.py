"""Where does a trained run's transmittance error come from: the medium, the depth, or coverage?

For runs on generated scenes (they carry true T and true depth), each test view's medium is
marched again with three end depths, and T is compared with the truth:

- ``rendered``: what training and evaluation use, the rendered depth blended to the far bound by
  the pixel's coverage (``z = alpha * D + (1 - alpha) * far``);
- ``opaque``: the rendered depth D with coverage taken as 1 (every pixel ends at its surface);
- ``true``: the scene's true depth (the medium alone: what is left is the field's own error).

It also prints the coverage (rendered alpha) the run leaves on the test views: a haze-agnostic
3DGS fit covers practically every pixel, so a medium run that leaves surfaces half transparent
lets coverage act as a per-pixel haze knob (a less covered pixel marches further into the haze).

    python benchmarks/coverage_diagnosis.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

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

from pipelines.engine.medium_recovery import REFERENCE_T_KEY, reference_depth, reference_map  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402

QUANTILES = (0.05, 0.25, 0.5)


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    errs: dict[str, list[float]] = {"rendered": [], "opaque": [], "true": []}
    alphas = []
    for idx in dm.test_indices:
        cam = dm.camera(idx)
        out = pipe.render(cam)
        alpha, depth = out["alpha"], out["depth"]  # [H, W, 1]
        alphas.append(alpha.flatten())
        size = tuple(alpha.shape[:2])
        true_t = reference_map(dm, REFERENCE_T_KEY, idx, size)  # type: ignore[arg-type]
        true_z = reference_depth(dm, idx, size)  # type: ignore[arg-type]
        if true_t is None or not pipe.composites_medium:
            continue
        ends = {"rendered": (depth, alpha), "opaque": (depth, torch.ones_like(alpha))}
        if true_z is not None:
            ends["true"] = (true_z, torch.ones_like(alpha))
        for name, (d, a) in ends.items():
            med = pipe.medium_field().render_view(
                pipe.compositor, cam, d, a, pipe.scene_gaussians(), pipe.rasterizer
            )
            errs[name].append(float((med.pixel_transmittance() - true_t).abs().mean()))
    a = torch.cat(alphas)
    return {
        "run": str(config.parent),
        "method": run.config.method_name,
        "scene": Path(str(run.config.dataset.data)).name,
        "t_mae": {k: (float(np.mean(v)) if v else None) for k, v in errs.items()},
        "alpha_quantiles": {f"{q:g}": float(a.quantile(q)) for q in QUANTILES},
        "share_alpha_below_0.95": float((a < 0.95).float().mean()),
    }


def markdown(rows: list[dict]) -> str:
    head = "| scene | method | run | T MAE rendered | T MAE opaque | T MAE true depth | alpha 5/25/50 % | alpha < 0.95 |"
    lines = [head, "|---|---|---|---|---|---|---|---|"]

    def f(v: float | None) -> str:
        return "-" if v is None else f"{v:.3f}"

    for r in rows:
        t, q = r["t_mae"], r["alpha_quantiles"]
        lines.append(
            f"| {r['scene']} | {r['method']} | {Path(r['run']).name} | {f(t['rendered'])} | {f(t['opaque'])} | "
            f"{f(t['true'])} | {' / '.join(f'{v:.2f}' for v in q.values())} | "
            f"{100 * r['share_alpha_below_0.95']:.0f} % |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """T MAE per end depth (bars) and the share of pixels less than 95 % covered (dots), per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(max(6, 0.8 * len(rows)), 4))
    x = np.arange(len(rows))
    for k, name in enumerate(("rendered", "opaque", "true")):
        vals = [r["t_mae"][name] if r["t_mae"][name] is not None else np.nan for r in rows]
        ax.bar(x + (k - 1) * 0.27, vals, 0.27, label=f"T MAE, {name} end depth")
    ax2 = ax.twinx()
    ax2.plot(x, [r["share_alpha_below_0.95"] for r in rows], "ko", label="pixels < 95 % covered")
    ax2.set_ylim(0, 1)
    ax2.set_ylabel("share of test pixels less than 95 % covered")
    ax.set_xticks(x, [f"{r['scene']}\n{r['method']}" for r in rows], fontsize=6, rotation=60)
    ax.set_ylabel("T mean absolute error")
    ax.legend(fontsize=7, loc="upper left")
    ax2.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "Transmittance error by end depth, and coverage",
        "`python benchmarks/coverage_diagnosis.py`", markdown, plot,
    )  # fmt: skip


if __name__ == "__main__":
    main()
