"""What the clean render's fade below t0 should go to: the haze light or the farthest seen surfaces.

For each trained run, every test view with a haze-free reference is rendered with
``--pipeline.composite.clean-fill`` ``haze-light``, ``farthest-seen`` and ``farthest-ground``
(rendering only: the Gaussians, the medium and the composite are the run's), at the run's own
``clean-t0``; ``auto`` is whichever the run's one-light verdict picks
(``--pipeline.lambda-dcp-isotropic``).
Restoration PSNR of the whole picture as ``td-bench restoration`` reports it (the mean over the
test views of each view's PSNR) and, where the dataset has true transmittance maps, over the
pixels whose clean colour does not reach the camera (true T under 0.05: sky, or walls behind
dense haze; all test views' such pixels together), where the fill is all there is.

    python benchmarks/clean_fill.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

Writes OUT.json, OUT.md (one row per run) and OUT.png.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import diagnose_runs_main, grouped_bars  # noqa: E402
from sky_split import accumulate, arm_of, masked_sums, psnr_of  # noqa: E402

from pipelines.engine.medium_recovery import OBSERVABLE_T, REFERENCE_T_KEY, reference_map  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402
from pipelines.experiments.tables import fmt_number  # noqa: E402

FILLS = ("haze-light", "farthest-seen", "farthest-ground")
REGIONS = ("all", "unobserved")


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    composite = pipe.compositor.config
    one_light = pipe.light_isotropy.judged_one_light()
    sums = {fill: {k: [0.0, 0] for k in REGIONS} for fill in FILLS}
    views: dict[str, list[float]] = {fill: [] for fill in FILLS}  # each view's whole-picture PSNR
    for idx in dm.test_indices:
        reference = dm.clean_image(idx)  # [H, W, 3]
        if reference is None:
            continue
        H, W = reference.shape[:2]
        true_t = reference_map(dm, REFERENCE_T_KEY, idx, (H, W))  # [H, W, 1] or None
        everything = torch.ones(H, W, dtype=torch.bool, device=reference.device)
        hidden = true_t[..., 0] < OBSERVABLE_T if true_t is not None else ~everything  # [H, W]
        for fill in FILLS:
            composite.clean_fill = fill
            clean = pipe.render(dm.camera(idx))["clean"]  # [H, W, 3]
            view = masked_sums(clean, reference, {"all": everything, "unobserved": hidden})
            accumulate(sums[fill], view)
            views[fill].append(psnr_of(view["all"]))
    if not views[FILLS[0]]:
        raise SystemExit(f"{config}: no test view has a haze-free reference")
    psnr = {
        fill: {
            "all": sum(views[fill]) / len(views[fill]),
            "unobserved": psnr_of(tuple(sums[fill]["unobserved"])),
        }
        for fill in FILLS
    }
    composite.clean_fill = "auto"
    psnr["auto"] = psnr[pipe.compositor.fill(one_light)]
    return {
        "run": str(config.parent),
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
        "clean_t0": composite.clean_t0,
        "one_light": one_light,
        "light_cv": pipe.light_isotropy.measured_cv(),
        "unobserved_share": sums[FILLS[0]]["unobserved"][1] / sums[FILLS[0]]["all"][1],
        "psnr": psnr,
    }


def markdown(rows: list[dict]) -> str:
    lines = [
        "| run | scene | seed | light spread | one light | unobserved share | PSNR haze-light / farthest-seen "
        "/ farthest-ground (unobserved pixels) | auto | auto - haze-light |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        p = r["psnr"]
        cells = " / ".join(f"{fmt_number(p[f]['all'])} ({fmt_number(p[f]['unobserved'])})" for f in FILLS)
        gain = p["auto"]["all"] - p["haze-light"]["all"]
        lines.append(
            f"| {arm_of(r['run'])} | {r['scene']} | {r['seed']} | {fmt_number(r['light_cv'], 3)} | "
            f"{'yes' if r['one_light'] else 'no'} | {100 * r['unobserved_share']:.0f} % | {cells} | "
            f"{fmt_number(p['auto']['all'])} | {gain:+.2f} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """Whole-picture PSNR per run for each fill and for the run's ``auto`` choice."""
    series = [(fill, [r["psnr"][fill]["all"] for r in rows]) for fill in (*FILLS, "auto")]
    labels = [f"{r['scene']} s{r['seed']}{' (one light)' if r['one_light'] else ''}" for r in rows]
    grouped_bars(path, labels, series, "restoration PSNR (dB)", legend_above=True)


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "The clean render's fade: haze light or farthest seen surfaces",
        "`python benchmarks/clean_fill.py`", markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
