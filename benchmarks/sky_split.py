"""Where the restoration error sits: the sky against the rest of the picture.

For runs on generated scenes, each test view's pixels are split by the true depth: the sky is
where the generator's rays ended at its far bound (true depth at least ``SKY_FAR_SHARE`` of
``far_bound_m`` in synth_meta.json: no surface, the clean image shows the sky), the rest is
surface. Per region: restoration PSNR of the clean render with the dark channel's t0 off and at
``T0`` (``--pipeline.composite.clean-t0``, rendering only), the model's and the true mean T.
A region's PSNR is over all its pixels of the test views together.

    python benchmarks/sky_split.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

Writes OUT.json, OUT.md (one row per run) and OUT.png.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import torch
from torch import Tensor

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import diagnose_runs_main, grouped_bars  # noqa: E402
from reference_views import reference_views  # noqa: E402

from pipelines.engine.run_loader import load_run  # noqa: E402
from pipelines.experiments.tables import fmt_number  # noqa: E402

SKY_FAR_SHARE = 0.75
"""A pixel is sky where its true z-depth is at least this share of the generator's far bound: the
far plane's z is the bound times the cosine of the ray's angle (above 0.8 at a 60 degree field of
view), and the generated scenes' surfaces end well before it (at most half of it)."""
T0 = 0.1
"""The dark channel's t0 (He et al.), which ``tri-dehaze`` rendered with from session 19 to 26 (0.15
since session 27); the sessions' sky splits were made with it."""
REGIONS = ("all", "sky", "surface")


def masked_sums(image: Tensor, reference: Tensor, masks: dict[str, Tensor]) -> dict[str, tuple[float, int]]:
    """Per mask [H, W]: the sum of squared errors of ``image`` against ``reference`` ([H, W, 3])
    over its pixels and channels, and its pixel count."""
    se = ((image - reference) ** 2).sum(-1)  # [H, W]
    return {k: (float(se[m].sum()), int(m.sum())) for k, m in masks.items()}


def accumulate(total: dict[str, list[float]], sums: dict[str, tuple[float, int]]) -> None:
    """Add :func:`masked_sums`' (squared error, pixels) per region into ``total``'s running sums."""
    for k, (se, n) in sums.items():
        total[k][0] += se
        total[k][1] += n


def region_sums(clean: Tensor, reference: Tensor, sky: Tensor) -> dict[str, tuple[float, int]]:
    """:func:`masked_sums` over the whole picture, the sky and the surfaces. clean, reference:
    [H, W, 3]; sky: [H, W] bool."""
    return masked_sums(clean, reference, {"all": torch.ones_like(sky), "sky": sky, "surface": ~sky})


def psnr_of(sums: tuple[float, int]) -> float | None:
    """PSNR (dB) of accumulated (squared error, pixels) over 3 channels; None for no pixels."""
    se, n = sums
    if n == 0:
        return None
    return -10.0 * math.log10(max(se / (3 * n), 1e-12))


def _far_bound_m(run) -> float:
    meta = Path(str(run.config.dataset.data)) / "synth_meta.json"
    if not meta.is_file():
        raise SystemExit(f"{meta}: not found; the sky split needs a td-synth scene (its far bound)")
    return float(json.loads(meta.read_text())["far_bound_m"])


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    far_z = SKY_FAR_SHARE * _far_bound_m(run) * dm.scene.transform.scale  # normalised frame
    composite = pipe.compositor.config
    sums = {t0: {k: [0.0, 0] for k in REGIONS} for t0 in (0.0, T0)}
    t_sum = {"model": 0.0, "true": 0.0}
    n_views = 0
    for view in reference_views(dm):
        sky = view.true_z[..., 0] >= far_z  # [H, W]
        reference = dm.clean_image(view.index)  # [H, W, 3]
        for t0 in sums:
            composite.clean_t0 = t0
            out = pipe.render(view.camera)
            accumulate(sums[t0], region_sums(out["clean"], reference, sky))
        t_sum["model"] += float(out["transmittance"][..., 0][sky].sum())
        t_sum["true"] += float(view.true_t[..., 0][sky].sum())
        n_views += 1
    if n_views == 0:
        raise SystemExit(f"{config}: the dataset has no true transmittance and depth maps")
    n_sky, n_all = sums[0.0]["sky"][1], sums[0.0]["all"][1]
    return {
        "run": str(config.parent),
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
        "sky_share": n_sky / n_all,
        "psnr": {f"t0={t0:g}": {k: psnr_of(tuple(v)) for k, v in s.items()} for t0, s in sums.items()},
        "sky_t_model": t_sum["model"] / n_sky if n_sky else None,
        "sky_t_true": t_sum["true"] / n_sky if n_sky else None,
    }


def arm_of(run: str) -> str:
    """The arm folder of a ``td-bench restoration`` run (``ARM/seed<N>/runs/<scene>/<method>/<method>``),
    else the run folder's own name."""
    parts = Path(run).parts
    if len(parts) >= 6 and parts[-4] == "runs" and parts[-5].startswith("seed"):
        return parts[-6]
    return Path(run).name


def run_label(row: dict) -> str:
    """A plot's bar-group label for one diagnosed run: its arm, scene and seed."""
    return f"{arm_of(row['run'])}\n{row['scene']} s{row['seed']}"


def markdown(rows: list[dict]) -> str:
    lines = [
        "| run | scene | seed | sky share | PSNR all / sky / surface, t0 off | the same, t0 "
        f"{T0:g} | sky T model / true |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        cells = [" / ".join(fmt_number(r["psnr"][key][k]) for k in REGIONS) for key in ("t0=0", f"t0={T0:g}")]
        lines.append(
            f"| {arm_of(r['run'])} | {r['scene']} | {r['seed']} | {100 * r['sky_share']:.0f} % | "
            f"{cells[0]} | {cells[1]} | {fmt_number(r['sky_t_model'], 3)} / {fmt_number(r['sky_t_true'], 3)} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """Sky and surface PSNR per run, without and with t0."""
    series = [
        (f"{k}, {t0}", [r["psnr"][t0][k] or 0.0 for r in rows])
        for k in ("sky", "surface")
        for t0 in ("t0=0", f"t0={T0:g}")
    ]
    labels = [run_label(r) for r in rows]
    grouped_bars(path, labels, series, "restoration PSNR (dB)")


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "Restoration of the sky and of the surfaces",
        "`python benchmarks/sky_split.py`", markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
