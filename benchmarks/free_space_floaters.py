"""How much of a trained run's scene floats in free space in front of the true surfaces (a diagnosis).

Session 57 found that on the default's runs the farthest surfaces' pixels take a quarter to a half
of their alpha from Gaussians well in front of the true surface, and that these Gaussians are
brighter, greyer and more transparent than the ones on the surfaces: part of the haze lives in the
scene instead of the medium. For runs on generated scenes (they carry true depth maps):

- floaters: Gaussians whose centre lies more than ``MARGIN`` in front of the true surface in more
  than half of the training views that see it on a surface pixel (components/gaussians/free_space.py);
  their share, mean opacity, mean colour (SH degree 0) and saturation, against the other Gaussians';
- on the test views' surface pixels (sky left out), the share of the rendered alpha that comes from
  the test view's own free-space Gaussians, by true T bin (benchmarks/reference_views.py);
- the same rule on the model's own rendered depth (coverage >= 0.5) instead of the true one: how
  many of the true floaters it finds (precision, and recall weighted by opacity).

    python benchmarks/free_space_floaters.py --runs RUN_A/config.yml ... --output OUT

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

from bench_output import diagnose_runs_main, fmt, grouped_bars  # noqa: E402
from reference_views import TRUE_T_BINS, reference_views  # noqa: E402
from sky_split import _far_bound_m, arm_of, run_label  # noqa: E402

from components.gaussians.free_space import floaters, in_front_counts  # noqa: E402
from components.gaussians.sh import C0  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402
from pipelines.tridehaze.floater_pruning import rendered_surface, true_surface  # noqa: E402

MARGIN = 0.15
"""Relative distance in front of the surface from which a centre is in free space."""


def _far_z(run) -> float:
    """The generator's far bound in the run's frame (its sky lies at it)."""
    return _far_bound_m(run) * run.datamanager.scene.transform.scale


def _group(mask: Tensor, opacity: Tensor, rgb: Tensor) -> dict:
    """Share, mean opacity, opacity-weighted colour and saturation of the Gaussians in ``mask``."""
    w = opacity[mask]
    if w.numel() == 0:
        return {"count": 0, "opacity": None, "rgb": None, "saturation": None}
    c = rgb[mask]
    sat = c.max(dim=-1).values - c.min(dim=-1).values
    return {
        "count": int(mask.sum()),
        "opacity": float(w.mean()),
        "rgb": [float(x) for x in (c * w[:, None]).sum(0) / w.sum()],
        "saturation": float((sat * w).sum() / w.sum()),
    }


def _alpha_share_by_true_t(pipe, dm, far_z: float) -> list[float | None]:
    """Per true-T bin, the mean share of the test views' surface pixels' alpha from Gaussians that
    are in free space in that view."""
    g = pipe.model
    sums = [[0.0, 0] for _ in TRUE_T_BINS]
    for v in reference_views(dm):
        surface = true_surface(v.true_z, far_z)
        view = [(v.camera.viewmats()[0], v.camera.Ks()[0], surface)]
        in_front, _ = in_front_counts(g.means, view, MARGIN)
        share = g.render_values(pipe.rasterizer, v.camera, (in_front > 0).to(g.means)[:, None])[0, ..., 0]
        t = v.true_t[..., 0]
        for b, (lo, hi) in enumerate(TRUE_T_BINS):
            m = torch.isfinite(surface) & (t >= lo) & ((t < hi) if hi < 1.0 else (t <= hi))
            sums[b][0] += float(share[m].sum())
            sums[b][1] += int(m.sum())
    return [s / n if n else None for s, n in sums]


def diagnose(config: Path) -> dict:
    run = load_run(config)
    dm, pipe = run.datamanager, run.pipeline
    far_z = _far_z(run)
    g = pipe.model
    true_views, own_views = [], []
    for v in reference_views(dm, list(dm.train_indices)):
        out = pipe.render(v.camera)
        true_views.append((v.camera.viewmats()[0], v.camera.Ks()[0], true_surface(v.true_z, far_z)))
        own_views.append(
            (v.camera.viewmats()[0], v.camera.Ks()[0], rendered_surface(out["depth"], out["alpha"]))
        )
    truth = floaters(*in_front_counts(g.means, true_views, MARGIN), share=0.5)
    own = floaters(*in_front_counts(g.means, own_views, MARGIN), share=0.5)
    opacity = g.opacities.reshape(-1)
    rgb = (0.5 + C0 * g.sh0.reshape(-1, 3)).clamp(0, 1)  # [N, 3]
    hit = own & truth
    return {
        "run": str(config.parent),
        "scene": Path(str(run.config.dataset.data)).name,
        "seed": run.config.seed,
        "gaussians": g.num_gaussians,
        "floaters": _group(truth, opacity, rgb),
        "others": _group(~truth, opacity, rgb),
        "alpha_share_by_true_t": _alpha_share_by_true_t(pipe, dm, far_z),
        "rendered_rule": {
            "found": int(own.sum()),
            "precision": float(hit.sum()) / max(int(own.sum()), 1),
            "recall_by_opacity": float(opacity[hit].sum() / opacity[truth].sum().clamp_min(1e-12)),
        },
    }


def markdown(rows: list[dict]) -> str:
    bins = " / ".join(f"{lo:g}-{hi:g}" for lo, hi in TRUE_T_BINS)
    lines = [
        f"| run | scene | seed | floaters (share) | opacity floaters / others | colour floaters | colour others "
        f"| alpha share from floaters by true T ({bins}) | rendered rule: precision, recall by opacity |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        f, o, rule = r["floaters"], r["others"], r["rendered_rule"]
        colour = lambda g: " ".join(fmt(x, 2) for x in g["rgb"]) if g["rgb"] else "-"  # noqa: E731
        lines.append(
            f"| {arm_of(r['run'])} | {r['scene']} | {r['seed']} | {f['count']} ({100 * f['count'] / r['gaussians']:.0f} %) "
            f"| {fmt(f['opacity'], 2)} / {fmt(o['opacity'], 2)} | {colour(f)} | {colour(o)} "
            f"| {' / '.join(fmt(x, 2) for x in r['alpha_share_by_true_t'])} "
            f"| {fmt(rule['precision'], 2)}, {fmt(rule['recall_by_opacity'], 2)} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    """The alpha share from floaters per true-T bin, per run."""
    series = [
        (f"true T {lo:g}-{hi:g}", [r["alpha_share_by_true_t"][b] or 0.0 for r in rows])
        for b, (lo, hi) in enumerate(TRUE_T_BINS)
    ]
    grouped_bars(path, [run_label(r) for r in rows], series, "share of alpha from free-space Gaussians")


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "Gaussians in free space in front of the true surfaces",
        "`python benchmarks/free_space_floaters.py`", markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
