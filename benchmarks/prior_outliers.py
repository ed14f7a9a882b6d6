"""Are the SfM depth prior's outliers the pixels a trimmed depth correlation leaves out?

For trained runs on generated scenes (true depth per view), each training view's sparse ``sfm``
prior (built as the run built it: tracks, ``union``) is compared with the true z-depth: a prior
pixel is an *outlier* when it is more than 30 % off. The run's final rendered depth and the prior
are standardised over the prior's pixels, as the Pearson loss does, and the share ``trim`` of
pixels with the largest squared difference is what ``--pipeline.depth-trim`` would leave out at
that state. A trim is worth trying when that set is rich in outliers (far above their base rate)
and holds most of them.

    python benchmarks/prior_outliers.py --runs RUN_A/config.yml ... --output OUT

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

from bench_output import diagnose_runs_main, grouped_bars  # noqa: E402
from reference_views import reference_views  # noqa: E402

from components.losses.depth import untrimmed_pixels  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402
from pipelines.tridehaze.priors import build_view_priors, resolve_depth_prior  # noqa: E402

TRIM = 0.2
"""The share of the prior's pixels looked at as the trimmed set."""
OUTLIER = 0.3
"""Relative depth error beyond which a prior (or rendered) pixel counts as an outlier."""


def _view_shares(prior, true_z: torch.Tensor, depth: torch.Tensor) -> dict | None:
    """One view's outlier shares; ``true_z``, ``depth`` [H, W]."""
    valid = prior.depth_valid & torch.isfinite(prior.depth)  # [H, W]
    n = int(valid.sum())
    if n < 10:
        return None
    q = prior.depth.nan_to_num(0.0)
    outlier = valid & ((q - true_z).abs() > OUTLIER * true_z)
    render_off = valid & ((depth - true_z).abs() > OUTLIER * true_z)
    top = valid & ~untrimmed_pixels(depth, prior.depth, prior.depth_valid, TRIM)  # what the trim drops
    k = max(int(top.sum()), 1)
    return {
        "outliers": float(outlier.sum()) / n,
        "outliers_in_trim": float((outlier & top).sum()) / k,
        "outliers_caught": float((outlier & top).sum()) / max(int(outlier.sum()), 1),
        "render_off": float(render_off.sum()) / n,
        "render_off_in_trim": float((render_off & top).sum()) / k,
    }


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe, cfg = run.datamanager, run.pipeline, run.pipeline.config
    source = resolve_depth_prior(cfg.depth_prior, dm)
    if source != "sfm":
        raise SystemExit(f"{config}: the run's depth prior is {source!r}; this diagnosis is for 'sfm'")
    tracks = dm.scene.point_tracks if cfg.point_tracks != "off" else None
    priors = build_view_priors(
        dm, dm.train_indices, {}, source, dm.scene.points, None, tracks, union=cfg.point_tracks == "union"
    )  # fmt: skip
    views = []
    for view in reference_views(dm, dm.train_indices):
        depth = pipe.render(view.camera)["depth"][..., 0]  # [H, W]
        shares = _view_shares(priors[view.index], view.true_z[..., 0], depth)
        if shares is not None:
            views.append(shares)
    if not views:
        raise SystemExit(f"{config}: no training view has a true depth map and prior pixels")
    out = {
        "run": str(config.parent),
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
    }
    out.update({k: float(np.mean([v[k] for v in views])) for k in views[0]})
    out["views"] = len(views)
    return out


def markdown(rows: list[dict]) -> str:
    lines = [
        f"| scene | seed | prior pixels > {OUTLIER:.0%} off | share of the trimmed {TRIM:.0%} that are | "
        f"outliers the trim catches | render > {OUTLIER:.0%} off: all / in the trimmed set |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['seed']} | {r['outliers']:.3f} | {r['outliers_in_trim']:.3f} | "
            f"{r['outliers_caught']:.3f} | {r['render_off']:.3f} / {r['render_off_in_trim']:.3f} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    labels = [f"{r['scene']}\n{r['seed']}" for r in rows]
    series = [
        ("prior outliers (base rate)", [r["outliers"] for r in rows]),
        ("outliers in the trimmed set", [r["outliers_in_trim"] for r in rows]),
        ("outliers caught by the trim", [r["outliers_caught"] for r in rows]),
    ]
    grouped_bars(path, labels, series, "share", legend_above=True)


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "The SfM depth prior's outliers and a trimmed depth correlation",
        "`python benchmarks/prior_outliers.py`", markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
