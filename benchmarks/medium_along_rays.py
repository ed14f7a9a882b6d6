"""Where along the rays does the trained medium put its extinction, against the true medium?

For runs on generated scenes, every test pixel whose true surface lies inside the medium's box is
marched to its true depth through both the trained field and the generator's own medium
(``ReferenceField``), at 32 points. The optical depth of each quarter of the path (camera end
first) is summed over the pixels, trained over true; so is the mean light of the samples. A ratio
above 1 in the first quarter and below 1 in the last says the trained medium has moved haze from
the surfaces towards the cameras, which changes T little on rays of the length it was fitted on
and too much on short ones (near surfaces look too hazy).

    python benchmarks/medium_along_rays.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

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
from reference_views import march_samples, reference_views, true_medium_field  # noqa: E402

from components.medium.compositing import pixel_rays  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402

SAMPLES = 32
"""Points per ray (a multiple of 4: the quarters)."""


def _march(field, origin, dirs, z) -> tuple[np.ndarray, torch.Tensor]:
    """Optical depth per quarter of the path [4] and the samples' mean light [3] of rays
    origin + t * dirs (dirs [P, 3] with unit camera z) to camera z-depths z [P]."""
    tau, light = march_samples(field, origin, dirs, z, SAMPLES)  # [P, K], [P, K, 3]
    quarters = tau.reshape(len(z), 4, SAMPLES // 4).sum(dim=(0, 2))  # [4]
    return quarters.double().cpu().numpy(), light.reshape(-1, 3).mean(0)


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    trained = pipe.medium_field()
    truth = true_medium_field(pipe, dm)
    od = {"trained": np.zeros(4), "true": np.zeros(4)}
    light = {"trained": [], "true": []}
    pixels = 0
    for view in reference_views(dm):
        dirs, origin = pixel_rays(view.camera, view.height, view.width, view.true_z.device, view.true_z.dtype)
        z = view.true_z[..., 0]  # [H, W]
        inside = trained.bounds.inside(origin + dirs * z[..., None])  # [H, W]: the surface is in the box
        if not bool(inside.any()):
            continue
        dirs, z = dirs[inside], z[inside]  # [P, 3], [P]
        pixels += len(z)
        for name, field in (("trained", trained), ("true", truth)):
            q, mean_light = _march(field, origin, dirs, z)
            od[name] += q
            light[name].append(mean_light)
    if pixels == 0:
        raise SystemExit(f"{config}: no test pixel with a true surface inside the medium's box")
    ratio = od["trained"] / np.maximum(od["true"], 1e-12)
    lt, lr = (torch.stack(light[k]).mean(0).cpu().numpy() for k in ("trained", "true"))
    return {
        "run": str(config.parent),
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
        "pixels": pixels,
        "optical_depth_ratio_by_quarter": [float(x) for x in ratio],
        "optical_depth_ratio": float(od["trained"].sum() / max(od["true"].sum(), 1e-12)),
        "light_trained": [float(x) for x in lt],
        "light_true": [float(x) for x in lr],
        "light_ratio": float(lt.mean() / max(lr.mean(), 1e-12)),
    }


def markdown(rows: list[dict]) -> str:
    lines = [
        "| scene | seed | optical depth, trained / true, by quarter of the path (camera first) | whole path "
        "| light trained (RGB) | light true (RGB) | light ratio |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        q = " / ".join(f"{x:.2f}" for x in r["optical_depth_ratio_by_quarter"])
        lt, lr = (" ".join(f"{x:.2f}" for x in r[k]) for k in ("light_trained", "light_true"))
        lines.append(
            f"| {r['scene']} | {r['seed']} | {q} | {r['optical_depth_ratio']:.2f} | {lt} | {lr} | {r['light_ratio']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """Trained / true optical depth per quarter of the path, one line per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    colours = plt.cm.tab10(np.linspace(0, 1, 10))
    scenes = sorted({r["scene"] for r in rows})
    for r in rows:
        c = colours[scenes.index(r["scene"]) % 10]
        ax.plot(range(1, 5), r["optical_depth_ratio_by_quarter"], "-o", color=c, ms=3, lw=1,
                label=f"{r['scene']} s{r['seed']}")  # fmt: skip
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_yscale("log")
    ax.set_yticks([0.5, 0.7, 1.0, 1.4, 2.0, 3.0], ["0.5", "0.7", "1", "1.4", "2", "3"])
    ax.minorticks_off()
    ax.set_xticks(range(1, 5), ["camera", "2nd", "3rd", "surface"])
    ax.set_xlabel("quarter of the path to the true surface")
    ax.set_ylabel("optical depth, trained / true")
    ax.legend(fontsize=5, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "Where the trained medium puts its extinction along the rays",
        "`python benchmarks/medium_along_rays.py`", markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
