"""Where the restoration error sits: geometry the photos locate against a background they do not.

For runs on a dataset with true depth maps and seed points (a real photo set hazed by `td-synth
haze`, or a generated scene), each test view's pixels are split by the dataset's depth: a pixel is
background where that depth lies beyond ``DEPTH_BEYOND_FACTOR`` times the farthest seed point the
view sees (the check `td-synth haze` records as ``depth_beyond_points``), located elsewhere. No
seed point vouches for a background's depth; a 3D method puts it where its own Gaussians drift,
and the haze the set was made with there depends on a depth no method can check. A view that sees
too few seed points to judge counts as located. Per region: restoration PSNR of the run's clean
render, of the single-image dark channel on the hazy test photo, and the model's and the true
mean T. A region's PSNR is over all its pixels of the test views together.

    python benchmarks/located_split.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

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
from reference_views import reference_views  # noqa: E402
from sky_split import accumulate, arm_of, masked_sums, psnr_of  # noqa: E402

from components.data.cameras import Cameras  # noqa: E402
from components.losses.dcp import dehaze, estimate_dcp  # noqa: E402
from components.synth.haze_existing import DEPTH_BEYOND_FACTOR, farthest_seen_points  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402
from pipelines.experiments.tables import fmt_number  # noqa: E402

REGIONS = ("all", "located", "background")


def background_mask(camera: Cameras, points: Tensor, true_z: Tensor) -> Tensor:
    """[H, W] bool: where the true z-depth ``true_z`` [H, W] lies beyond ``DEPTH_BEYOND_FACTOR``
    times the farthest of ``points`` [M, 3] (same frame) the view sees; all False when it sees
    too few to judge."""
    far = farthest_seen_points(camera, points.double(), [true_z.double().numpy()])[0]
    if far is None:
        return torch.zeros_like(true_z, dtype=torch.bool)
    return true_z > DEPTH_BEYOND_FACTOR * far


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    if dm.scene.points is None or not len(dm.scene.points):
        raise SystemExit(f"{config}: the dataset has no seed points to tell located pixels from background")
    points = dm.scene.points.detach().cpu()  # [M, 3] normalised frame, as the cameras and true depth
    sums = {src: {k: [0.0, 0] for k in REGIONS} for src in ("model", "dcp_2d")}
    t_sum = {"model": 0.0, "true": 0.0}
    n_bg = n_views = 0
    for view in reference_views(dm):
        bg = background_mask(view.camera.to("cpu"), points, view.true_z[..., 0].cpu())  # [H, W]
        masks = {"all": torch.ones_like(bg), "located": ~bg, "background": bg}
        reference = dm.clean_image(view.index)[..., :3].cpu()  # [H, W, 3]
        out = pipe.render(view.camera)
        accumulate(sums["model"], masked_sums(out["clean"].cpu(), reference, masks))
        hazy = dm.image(view.index)[..., :3].cpu().numpy()
        flat = torch.from_numpy(dehaze(hazy, estimate_dcp(hazy)))  # [H, W, 3]
        accumulate(sums["dcp_2d"], masked_sums(flat, reference, masks))
        t_sum["model"] += float(out["transmittance"][..., 0].cpu()[bg].sum())
        t_sum["true"] += float(view.true_t[..., 0].cpu()[bg].sum())
        n_bg += int(bg.sum())
        n_views += 1
    if n_views == 0:
        raise SystemExit(f"{config}: the dataset has no true transmittance and depth maps")
    return {
        "run": str(config.parent),
        "method": config.parent.name,
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
        "background_share": n_bg / sums["model"]["all"][1],
        "psnr": {src: {k: psnr_of(tuple(v)) for k, v in s.items()} for src, s in sums.items()},
        "background_t_model": t_sum["model"] / n_bg if n_bg else None,
        "background_t_true": t_sum["true"] / n_bg if n_bg else None,
    }


def markdown(rows: list[dict]) -> str:
    lines = [
        "| arm | method | scene | seed | background share | PSNR all / located / background | single-image "
        "dark channel, the same | background T model / true |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        cells = [" / ".join(fmt_number(r["psnr"][src][k]) for k in REGIONS) for src in ("model", "dcp_2d")]
        lines.append(
            f"| {arm_of(r['run'])} | {r['method']} | {r['scene']} | {r['seed']} | {100 * r['background_share']:.0f} % | "
            f"{cells[0]} | {cells[1]} | {fmt_number(r['background_t_model'], 3)} / {fmt_number(r['background_t_true'], 3)} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """Located and background PSNR per run, the run's clean render beside the single-image dark channel."""
    series = [
        (f"{k}, {src}", [r["psnr"][src][k] or 0.0 for r in rows])
        for k in ("located", "background")
        for src in ("model", "dcp_2d")
    ]
    labels = [f"{arm_of(r['run'])} {r['method']}\n{r['scene']} s{r['seed']}" for r in rows]
    grouped_bars(path, labels, series, "restoration PSNR (dB)", legend_above=True)


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "Restoration where the photos locate the geometry and on the background",
        "`python benchmarks/located_split.py`", markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
