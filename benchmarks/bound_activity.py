"""Where the own-light dark-channel bound holds a trained medium, by true transmittance.

For runs on generated scenes (true T and S maps per view), every third training view's pixels are
binned by their true T (dense < 0.3 <= mid < 0.7 <= thin). Per bin: the model's and the true mean
T, the ``lower-own-light`` bound 1 - omega min(I / L) with the model's own light L = S / (1 - T)
at omega 0.95 (He et al.'s margin, the default) and at 1, the same bound with the true light at
omega 1 (never above the truth where T is even over the patch), and the share of pixels whose
model T sits within ``ACTIVE_TOL`` of the omega-0.95 bound (where the bound, not the photos, sets T).

Why: on a black clean patch the omega-0.95 bound lies (1 - omega)(1 - T) above the true T, so
where it is active it holds dense haze too thin (docs/results/medium_recovery.md, session 53).

    python benchmarks/bound_activity.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

Writes OUT.json, OUT.md (one row per run and bin) and OUT.png.
"""

from __future__ import annotations

import sys
from pathlib import Path

from torch import Tensor

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import diagnose_runs_main, fmt, grouped_bars  # noqa: E402
from dcp_bound_split import light_along_rays  # noqa: E402
from sky_split import arm_of, run_label  # noqa: E402

from components.losses.dcp import dark_channel_bound, default_patch  # noqa: E402
from pipelines.engine.medium_recovery import REFERENCE_S_KEY, REFERENCE_T_KEY, reference_map  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402

BINS = {"dense": (0.0, 0.3), "mid": (0.3, 0.7), "thin": (0.7, 1.01)}
"""True-T bins [lo, hi)."""
ACTIVE_TOL = 0.02
"""Model T within this of the omega-0.95 bound (or below it) counts as held by the bound."""
VIEW_STRIDE = 3
"""Every third training view (the bins' means settle well before that)."""
COLUMNS = ("model", "true", "own_095", "own_1", "true_1", "active")


def view_maps(
    image: Tensor, t_model: Tensor, s_model: Tensor, t_true: Tensor, s_true: Tensor
) -> dict[str, Tensor]:
    """Per-pixel maps [H, W] of one view: T model / true, the three bounds, the active mask
    (image, S: [H, W, 3]; T: [H, W, 1])."""
    patch = default_patch(*image.shape[:2])
    own = light_along_rays(s_model, t_model)  # [H, W, 3]
    own_095 = dark_channel_bound(image, own, patch, 0.95)
    return {
        "model": t_model[..., 0],
        "true": t_true[..., 0],
        "own_095": own_095,
        "own_1": dark_channel_bound(image, own, patch, 1.0),
        "true_1": dark_channel_bound(image, light_along_rays(s_true, t_true), patch, 1.0),
        "active": ((t_model[..., 0] - own_095) < ACTIVE_TOL).float(),
    }


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    sums = {b: dict.fromkeys((*COLUMNS, "n"), 0.0) for b in BINS}
    for idx in dm.train_indices[::VIEW_STRIDE]:
        cam = dm.camera(idx)
        size = (int(cam.height[0]), int(cam.width[0]))
        t_true = reference_map(dm, REFERENCE_T_KEY, idx, size)  # [H, W, 1]
        s_true = reference_map(dm, REFERENCE_S_KEY, idx, size)  # [H, W, 3]
        if t_true is None or s_true is None:
            continue
        out = pipe.render(cam)
        maps = view_maps(dm.image(idx).float(), out["transmittance"], out["scattering"], t_true, s_true)
        for b, (lo, hi) in BINS.items():
            m = (maps["true"] >= lo) & (maps["true"] < hi)  # [H, W]
            sums[b]["n"] += float(m.sum())
            for k in COLUMNS:
                sums[b][k] += float(maps[k][m].sum())
    if not any(s["n"] for s in sums.values()):
        raise SystemExit(f"{config}: the dataset has no true transmittance and scattering maps")
    row: dict = {
        "run": str(config.parent),
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
    }
    total = sum(s["n"] for s in sums.values())
    for b, s in sums.items():
        row[f"{b}_share"] = s["n"] / total
        for k in COLUMNS:
            row[f"{b}_{k}"] = s[k] / s["n"] if s["n"] else None
    return row


def markdown(rows: list[dict]) -> str:
    lines = [
        "| run | scene | seed | true-T bin (share) | T model / true | own bound 0.95 / 1 | true-light bound 1 | "
        "held by the 0.95 bound |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        for b in BINS:
            if not r[f"{b}_share"]:
                continue
            lines.append(
                f"| {arm_of(r['run'])} | {r['scene']} | {r['seed']} | {b} ({100 * r[f'{b}_share']:.0f} %) | "
                f"{fmt(r[f'{b}_model'])} / {fmt(r[f'{b}_true'])} | {fmt(r[f'{b}_own_095'])} / {fmt(r[f'{b}_own_1'])} | "
                f"{fmt(r[f'{b}_true_1'])} | {100 * (r[f'{b}_active'] or 0.0):.0f} % |"
            )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """Dense pixels: the model's T, the truth and the omega-0.95 bound per run."""
    grouped_bars(
        path,
        [run_label(r) for r in rows],
        [
            (label, [r[f"dense_{k}"] or 0.0 for r in rows])
            for label, k in (("model T", "model"), ("true T", "true"), ("own bound, omega 0.95", "own_095"))
        ],
        "mean T on pixels with true T < 0.3",
    )


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "Where the own-light dark-channel bound holds the medium, by true transmittance",
        "`python benchmarks/bound_activity.py`", markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
