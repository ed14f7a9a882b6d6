"""Does the medium's learnt direction dependence of the light cost the test views? (no training)

For each trained run: the test views' hazy photos inverted with the model's own T and S,
J = (I - S) / T, once with the light as learnt and once with every ray given the light's mean over
the training pixels (``flatten_light``, what ``--pipeline.flatten-one-light`` does at the freeze),
against the clean reference; and the clean render's mean colour offset per view. A light whose
direction dependence is spurious gives each view its own in-scattering error, which shows as a
per-view colour offset of the clean render and as a gain when the light is flattened.

    python benchmarks/flat_light_inversion.py --runs RUN/config.yml ... --output STEM
"""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import diagnose_runs_main, fmt, grouped_bars, mean_or_none  # noqa: E402
from sky_split import arm_of, run_label  # noqa: E402

from pipelines.engine.metrics import psnr  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402
from pipelines.tridehaze.light_colour_fit import light_spread, mean_view_light, ray_light  # noqa: E402

T_FLOOR = 0.05
"""The inversion divides by T clamped here (as the medium-recovery protocol's J inversion)."""


def _test_views(pipe, dm) -> tuple[list[float], list[list[float]]]:
    """Per test view: the PSNR of (I - S) / T against the clean reference, and the clean render's
    mean colour minus the reference's [3]."""
    scores, offsets = [], []
    for idx in dm.test_indices:
        out = pipe.render(dm.camera(idx))
        hazy, clean = dm.hazy_image(idx), dm.clean_image(idx)  # [H, W, 3]
        J = ((hazy - out["scattering"]) / out["transmittance"].clamp_min(T_FLOOR)).clamp(0.0, 1.0)
        scores.append(float(psnr(J, clean)))
        offsets.append((out["clean"] - clean).reshape(-1, 3).mean(dim=0).tolist())
    return scores, offsets


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    lights = []
    for idx in dm.train_indices:
        out = pipe.render(dm.camera(idx))
        lights.append(ray_light(out["transmittance"][..., 0], out["scattering"]))  # [P, 3]
    mean = mean_view_light(lights)
    learnt, offsets = _test_views(pipe, dm)
    flat = None
    if mean is not None and pipe.medium.recolours_light:
        pipe.medium.flatten_light(mean)
        flat, _ = _test_views(pipe, dm)
    iso = pipe.light_isotropy
    return {
        "run": str(config.parent),
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
        "one_light": iso.judged_one_light(),
        "seen_share": iso.seen_light_share(),
        "light_spread": light_spread(lights),
        "inverted_learnt": learnt,
        "inverted_flat": flat,
        "clean_offset": offsets,
    }


def markdown(rows: list[dict]) -> str:
    lines = [
        "| run | scene | seed | judged one light | opaque share | light spread (training pixels) "
        "| inverted PSNR, learnt light -> flat, per test view | mean | clean render's colour offset per view (RGB) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        flat = r["inverted_flat"] or [None] * len(r["inverted_learnt"])
        views = ", ".join(f"{fmt(a)} -> {fmt(b)}" for a, b in zip(r["inverted_learnt"], flat, strict=True))
        offsets = "; ".join(" ".join(f"{x:+.3f}" for x in o) for o in r["clean_offset"])
        lines.append(
            f"| {arm_of(r['run'])} | {r['scene']} | {r['seed']} | {'yes' if r['one_light'] else 'no'} "
            f"| {fmt(r['seen_share'], 3)} | {fmt(r['light_spread'], 3)} | {views} "
            f"| {fmt(mean_or_none(r['inverted_learnt']))} -> {fmt(mean_or_none(r['inverted_flat']))} | {offsets} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    series = [
        ("learnt light", [mean_or_none(r["inverted_learnt"]) or 0.0 for r in rows]),
        ("flat light", [mean_or_none(r["inverted_flat"]) or 0.0 for r in rows]),
    ]
    grouped_bars(path, [run_label(r) for r in rows], series, "PSNR of (I - S) / T on the test views (dB)")


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "The test views inverted with the learnt and with a flat medium light",
        "`python benchmarks/flat_light_inversion.py`", markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
