"""The paper's ablation families as data: variants (a method + CLI overrides), families, claims.

A variant is what one ``td-train`` run trains; a family lists variants in the paper's column
order. Variants shared between families (``full`` is in four) are trained once per scene.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Variant:
    """One trained configuration of the ablation."""

    name: str
    method: str
    overrides: tuple[str, ...] = ()
    label: str = ""
    """Row label in the table (default: the name)."""
    max_steps: int | None = None
    """Steps of this variant's run (None: the runner's step budget)."""

    def train_args(self) -> list[str]:
        return [self.method, *self.overrides]


VARIANTS: dict[str, Variant] = {
    v.name: v
    for v in (
        Variant("full", "tri-dehaze", label="Tri-DehazeGS (full)"),
        Variant("constant", "tri-dehaze-constant", label="constant medium"),
        Variant(
            "gaussian-bound",
            "tri-dehaze",
            ("--pipeline.medium.backend", "gaussian-bound"),
            label="Gaussian-bound medium",
        ),
        Variant(
            "triplane-rgb", "tri-dehaze", ("--pipeline.medium.light", "rgb"), label="tri-plane, RGB light"
        ),
        Variant("mlp", "tri-dehaze", ("--pipeline.medium.backend", "mlp"), label="coordinate MLP"),
        Variant("fourier", "tri-dehaze", ("--pipeline.medium.backend", "fourier"), label="Fourier MLP"),
        Variant("voxel", "tri-dehaze", ("--pipeline.medium.backend", "voxel"), label="voxel grid"),
        Variant("no-tgc", "tri-dehaze", ("--pipeline.gradient-policy", "none"), label="no TGC"),
        Variant("tgc-start", "tri-dehaze", ("--pipeline.gradient-policy", "tgc"), label="TGC from the start"),
        Variant(
            "no-depth-corr", "tri-dehaze", ("--pipeline.no-depth-correlation",), label="w/o depth correlation"
        ),
        Variant("no-smooth", "tri-dehaze", ("--pipeline.lambda-smooth", "0"), label="w/o depth smoothness"),
        Variant("no-dcp", "tri-dehaze", ("--pipeline.lambda-dcp", "0"), label="w/o DCP prior"),
        Variant("vanilla-gs", "vanilla-gs", label="vanilla 3DGS"),
        Variant("dcp-gs", "dcp-gs", label="DCP + 3DGS"),
    )  # fmt: skip
}
"""Every variant the families use, by name."""

FAMILIES: dict[str, tuple[str, ...]] = {
    "representation": ("constant", "gaussian-bound", "triplane-rgb", "full"),
    "field": ("mlp", "fourier", "voxel", "full"),
    "schedule": ("no-tgc", "tgc-start", "full"),
    "losses": ("no-depth-corr", "no-smooth", "no-dcp", "full"),
    "baselines": ("vanilla-gs", "dcp-gs", "constant", "full"),
}
"""The paper's ablation tables (plus the baselines), variants in the paper's order."""


@dataclass(frozen=True)
class Claim:
    """An ordering the paper reports: restoration PSNR of ``worse`` < that of ``better``."""

    family: str
    worse: str
    better: str
    paper: tuple[float, float]
    """The paper's PSNRs (RealX3D) of (worse, better)."""


PAPER_PSNR: dict[str, float] = {
    "constant": 13.69, "gaussian-bound": 15.53, "triplane-rgb": 16.43, "full": 17.34,
    "mlp": 15.46, "fourier": 14.98, "voxel": 17.11,
    "no-tgc": 17.21, "tgc-start": 16.17,
    "no-depth-corr": 12.77, "no-smooth": 17.02, "no-dcp": 16.89,
}  # fmt: skip
"""Ablation PSNRs on RealX3D from the paper (../shared/docs/method.md)."""


def paper_claims() -> list[Claim]:
    """Every adjacent pair of each family sorted by the paper's PSNR: the orderings it claims."""
    claims, seen = [], set()
    for family, names in FAMILIES.items():
        ranked = sorted((n for n in names if n in PAPER_PSNR), key=PAPER_PSNR.__getitem__)
        for worse, better in zip(ranked, ranked[1:], strict=False):
            if (worse, better) not in seen:  # the baselines repeat the representation family's pair
                seen.add((worse, better))
                claims.append(Claim(family, worse, better, (PAPER_PSNR[worse], PAPER_PSNR[better])))
    return claims


def plan(families: list[str]) -> list[Variant]:
    """The distinct variants the chosen families need, in first-use order."""
    names: dict[str, None] = {}
    for f in families:
        for n in FAMILIES[f]:
            names[n] = None
    return [VARIANTS[n] for n in names]
