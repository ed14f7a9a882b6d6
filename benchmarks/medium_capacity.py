"""Can the run's medium field hold the true medium at all? Capacity against identifiability.

For runs on generated scenes, a copy of the trained medium field (same backend, resolution and
heads, warm-started from the trained values) is fitted directly to the generator's own extinction:
the L1 error of each training ray's transmittance, marched to its true surface (16 samples, the
rays whose surface lies in the medium's box), Adam for ``STEPS`` steps of ``BATCH`` rays. The test
views' rays then say how far that field gets from the truth when it is told the answer, next to
how far the trained one is. A fitted error near zero says the representation is not what keeps
the trained medium from the truth; the photometric fit and its priors are.

    python benchmarks/medium_capacity.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

Writes OUT.json, OUT.md (one row per run) and OUT.png.
"""

from __future__ import annotations

import copy
import sys
from pathlib import Path

import torch
from torch import Tensor

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import diagnose_runs_main, grouped_bars  # noqa: E402
from reference_views import march_samples, reference_views, true_medium_field  # noqa: E402

from components.medium.compositing import pixel_rays  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402

SAMPLES = 16
"""Points per ray (the default march's count)."""
STEPS = 1500
"""Adam steps of the fit to the truth (the trained medium's own Stage I length at 3000 steps)."""
BATCH = 4096
"""Rays per step."""
LR = 0.01
"""The medium's default learning rate."""


def _rays(dm, indices, bounds) -> tuple[Tensor, Tensor, Tensor] | None:
    """Origins [P, 3], directions [P, 3] (unit camera z) and true z-depths [P] of the views' pixels
    whose true surface is inside the medium's box."""
    parts = []
    for view in reference_views(dm, indices):
        z = view.true_z[..., 0]  # [H, W]
        dirs, origin = pixel_rays(view.camera, view.height, view.width, z.device, z.dtype)  # [H, W, 3], [3]
        inside = bounds.inside(origin + dirs * z[..., None])  # [H, W]
        n = int(inside.sum())
        if n:
            parts.append((origin.reshape(1, 3).expand(n, 3), dirs[inside], z[inside]))
    if not parts:
        return None
    return tuple(torch.cat([p[k] for p in parts]) for k in range(3))  # type: ignore[return-value]


def transmittance(field, origin: Tensor, dirs: Tensor, z: Tensor) -> Tensor:
    """exp(-optical depth) [P] of rays origin + t * dirs to camera z-depths z, midpoint rule."""
    tau, _ = march_samples(field, origin, dirs, z, SAMPLES)  # [P, K]
    return torch.exp(-tau.sum(dim=-1))


def fit_to_truth(field, rays: tuple[Tensor, Tensor, Tensor], target: Tensor, steps: int) -> None:
    """Fit ``field`` (in place) to the target transmittance [P] of ``rays``."""
    params = list(field.parameters())
    for p in params:
        p.requires_grad_(True)
    opt = torch.optim.Adam(params, lr=LR)
    gen = torch.Generator().manual_seed(0)
    with torch.enable_grad():
        for _ in range(steps):
            idx = torch.randint(0, len(target), (BATCH,), generator=gen)
            loss = (transmittance(field, *(r[idx] for r in rays)) - target[idx]).abs().mean()
            opt.zero_grad()
            loss.backward()
            opt.step()


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    trained = pipe.medium_field()
    truth = true_medium_field(pipe, dm)
    train, test = (_rays(dm, idx, trained.bounds) for idx in (dm.train_indices, dm.test_indices))
    if train is None or test is None:
        raise SystemExit(
            f"{config}: no pixel with a true depth inside the medium's box in the train or test views"
        )
    with torch.no_grad():
        true_train, true_test = transmittance(truth, *train), transmittance(truth, *test)  # [P]
    fitted = copy.deepcopy(trained)
    fit_to_truth(fitted, train, true_train, STEPS)
    with torch.no_grad():
        mae = {
            name: float((transmittance(f, *rays) - target).abs().mean())
            for name, f, rays, target in (
                ("trained_test", trained, test, true_test),
                ("fitted_train", fitted, train, true_train),
                ("fitted_test", fitted, test, true_test),
            )
        }
    return {
        "run": str(config.parent),
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
        "backend": pipe.config.medium.backend,
        "train_rays": len(true_train),
        "test_rays": len(true_test),
        "t_mae_trained": mae["trained_test"],
        "t_mae_fitted": mae["fitted_test"],
        "t_mae_fitted_train_rays": mae["fitted_train"],
    }


def markdown(rows: list[dict]) -> str:
    lines = [
        "| scene | seed | backend | test rays | T MAE, trained | T MAE, the same field fitted to the truth "
        "(test rays / training rays) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['seed']} | {r['backend']} | {r['test_rays']} | {r['t_mae_trained']:.3f} | "
            f"{r['t_mae_fitted']:.3f} / {r['t_mae_fitted_train_rays']:.3f} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    labels = [f"{r['scene']} s{r['seed']}" for r in rows]
    series = [
        ("trained", [r["t_mae_trained"] for r in rows]),
        ("fitted to the truth", [r["t_mae_fitted"] for r in rows]),
    ]
    grouped_bars(path, labels, series, "T MAE on the test rays (true depth)")


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "Can the medium field hold the true medium? Trained against fitted to the truth",
        "`python benchmarks/medium_capacity.py`", markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
