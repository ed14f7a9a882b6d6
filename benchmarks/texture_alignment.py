"""How much of the trained medium's fine structure follows the scene's texture (a diagnosis).

Session 50 found the walls' checker and brick pattern in the trained extinction field. Before
building a prior against "medium texture aligned with the image" (which, unlike a smoothness
prior, would leave real patches of haze alone), this measures how much such a prior could
remove. For runs on generated scenes, on each test view's surface pixels (coverage >= 0.5):

- the relative roughness of the mean extinction tau / z: the mean squared difference of
  adjacent pixels' tau / z (over the view's mean; depth edges left out), for the model (its T,
  its rendered depth) and for the truth (the generator's T and depth);
- the same for the trained field marched to the true depth (the field alone, not the depth);
- the share of the model's roughness that a linear fit on the luminance differences explains,
  per 8 x 8 pixel tile (a texture's sign of correlation changes from wall to wall), with the
  true clean image's luminance and with the hazy photo's.

A small share says the texture is not where the image's edges are (the tri-plane smears it
between views), so an image-aligned prior could not remove it.

    python benchmarks/texture_alignment.py --runs RUN_A/config.yml ... --output OUT

Writes OUT.json, OUT.md (one row per run) and OUT.png.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch
from torch import Tensor
from torch.nn import functional as F

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import diagnose_runs_main, grouped_bars  # noqa: E402
from reference_views import reference_views  # noqa: E402
from sky_split import arm_of  # noqa: E402

from components.losses.medium_texture import (  # noqa: E402
    path_extinction_roughness,
    relative_mean_extinction,
    same_surface_pairs,
)
from pipelines.engine.run_loader import load_run  # noqa: E402

TILE = 8
"""Tile side (pixels) of the per-tile linear fit."""
DEPTH_STEP = 0.05
"""Adjacent pixels further apart than this in log depth are a depth edge (as the prior's default)."""
SURFACE = 0.5
"""Coverage from which a pixel's ray ends on the scene."""


def aligned_energy(t: Tensor, z: Tensor, surface: Tensor, image: Tensor, tile: int = TILE) -> Tensor:
    """Per tile, the energy of the adjacent differences of tau / z (relative to the view's mean)
    explained by a linear fit on the image's luminance differences, summed and divided by the
    pairs counted: the part of :func:`path_extinction_roughness` aligned with ``image``'s edges.
    t, z: [H, W]; surface: [H, W] bool; image: [H, W, 3]."""
    rel = relative_mean_extinction(t, z, surface)  # [H, W]
    lum = image.mean(dim=-1)  # [H, W]
    H, W = rel.shape
    th, tw = H // tile, W // tile
    cross, energy, pairs = rel.new_zeros(th, tw), rel.new_zeros(th, tw), rel.new_zeros(())
    for dim, pad in ((0, (0, 0, 0, 1)), (1, (0, 1))):
        same = same_surface_pairs(z, surface, dim, DEPTH_STEP).to(rel.dtype)
        # each pair counted in its first pixel's tile
        d_rel = F.pad(rel.diff(dim=dim) * same, pad)[: th * tile, : tw * tile]
        d_lum = F.pad(lum.diff(dim=dim) * same, pad)[: th * tile, : tw * tile]
        cross = cross + (d_rel * d_lum).reshape(th, tile, tw, tile).sum(dim=(1, 3))
        energy = energy + d_lum.square().reshape(th, tile, tw, tile).sum(dim=(1, 3))
        pairs = pairs + F.pad(same, pad)[: th * tile, : tw * tile].sum()
    return (cross.square() / (energy + 1e-8)).sum() / pairs.clamp_min(1.0)


def diagnose(config: Path) -> dict:
    run = load_run(config)
    pipe, dm = run.pipeline, run.datamanager
    sums = {
        "rough_model": 0.0,
        "rough_model_true_z": 0.0,
        "rough_true": 0.0,
        "aligned_clean": 0.0,
        "aligned_hazy": 0.0,
    }
    n = 0
    for v in reference_views(dm):
        clean = dm.clean_image(v.index)  # [H, W, 3]
        if clean is None:
            continue
        out = pipe.render(v.camera)
        t, z = out["transmittance"][..., 0], out["depth"][..., 0]  # [H, W]
        surface = out["alpha"][..., 0] >= SURFACE
        hazy = dm.image(v.index)  # [H, W, 3]
        sums["rough_model"] += float(path_extinction_roughness(t, z, surface, DEPTH_STEP))
        true_surface = torch.ones_like(surface)  # every true ray ends on something
        sums["rough_true"] += float(
            path_extinction_roughness(
                v.true_t[..., 0].clamp_min(1e-4), v.true_z[..., 0], true_surface, DEPTH_STEP
            )
        )
        t_true_z, _ = pipe.medium_at_depth(v.camera, v.true_z)  # the trained field, the true depth
        sums["rough_model_true_z"] += float(
            path_extinction_roughness(t_true_z[..., 0], v.true_z[..., 0], true_surface, DEPTH_STEP)
        )
        sums["aligned_clean"] += float(aligned_energy(t, z, surface, clean))
        sums["aligned_hazy"] += float(aligned_energy(t, z, surface, hazy))
        n += 1
    row = {k: s / max(n, 1) for k, s in sums.items()}
    rough = max(row["rough_model"], 1e-12)
    row.update(
        scene=dm.scene.root.name,
        seed=run.config.seed,
        arm=arm_of(str(Path(config).parent)),
        views=n,
        share_clean=row["aligned_clean"] / rough,
        share_hazy=row["aligned_hazy"] / rough,
    )
    return row


def table(rows: list[dict]) -> str:
    head = (
        "| arm | scene | seed | roughness of tau / z, model / model at the true depth / truth "
        "| share aligned with the clean image | with the hazy photo |\n|---|---|---|---|---|---|\n"
    )
    return head + "".join(
        f"| {r['arm']} | {r['scene']} | {r['seed']} | {r['rough_model']:.4f} / "
        f"{r['rough_model_true_z']:.4f} / {r['rough_true']:.4f} "
        f"| {100 * r['share_clean']:.0f} % | {100 * r['share_hazy']:.0f} % |\n"
        for r in rows
    )


def plot(rows: list[dict], path: Path) -> None:
    labels = [f"{r['scene']} s{r['seed']}" for r in rows]
    grouped_bars(
        path,
        labels,
        [
            ("model roughness", [r["rough_model"] for r in rows]),
            ("truth roughness", [r["rough_true"] for r in rows]),
            ("aligned with the clean image", [r["aligned_clean"] for r in rows]),
        ],
        "relative roughness of tau / z",
    )


if __name__ == "__main__":
    diagnose_runs_main(
        __doc__,
        diagnose,
        "How much of the trained medium's fine structure follows the scene's texture",
        "python benchmarks/texture_alignment.py",
        table,
        plot,
        order=lambda r: (r["scene"], r["seed"]),
    )
