"""The ablation's outputs: a paper-shaped markdown table, a long-format CSV, a bar plot, claims."""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any

from pipelines.engine.image_baselines import LABELS as BASELINE_LABELS
from pipelines.experiments.ablation import FAMILIES, VARIANTS, paper_claims

CSV_FIELDS = (
    "scene", "variant", "method", "status", "restoration_psnr", "restoration_ssim", "restoration_lpips",
    "reconstruction_psnr", "low_T_psnr", "t_mae", "s_mae", "gaussians", "train_seconds", "wall_seconds",
)  # fmt: skip


def nested(result: dict[str, Any], *keys: str) -> float | None:
    """``result[k1][k2]...`` or None where any level is missing."""
    node: Any = result
    for k in keys:
        if not isinstance(node, dict) or node.get(k) is None:
            return None
        node = node[k]
    return node


def mean_finite(values: list[float | None]) -> float | None:
    """Mean of the finite values (None if there are none)."""
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return sum(vals) / len(vals) if vals else None


def fmt_number(v: float | None, digits: int = 2) -> str:
    """A table cell: ``-`` for a missing number."""
    return "-" if v is None else f"{v:.{digits}f}"


def by_key(results: list[dict[str, Any]]) -> dict[tuple[str, str], dict[str, Any]]:
    return {(r["scene"], r["variant"]): r for r in results}


def variant_means(results: list[dict[str, Any]], scenes: list[str]) -> dict[str, dict[str, float | None]]:
    """Per variant, the means over scenes of its restoration metrics and wall time."""
    table = by_key(results)
    out = {}
    for name in VARIANTS:
        rows = [table[(s, name)] for s in scenes if (s, name) in table and table[(s, name)]["status"] == "ok"]
        if not rows:
            continue
        out[name] = {
            "psnr": mean_finite([nested(r, "restoration", "psnr") for r in rows]),
            "ssim": mean_finite([nested(r, "restoration", "ssim") for r in rows]),
            "lpips": mean_finite([nested(r, "restoration", "lpips") for r in rows]),
            "low_T_psnr": mean_finite([nested(r, "binned", "low", "psnr") for r in rows]),
            "t_mae": mean_finite([nested(r, "medium", "t_mae") for r in rows]),
            "s_mae": mean_finite([nested(r, "medium", "s_mae") for r in rows]),
            "wall_seconds": mean_finite([r.get("wall_seconds") for r in rows]),
            "scenes": len(rows),
        }
    return out


SceneBaselines = dict[str, dict[str, float]]
"""Single-image baseline -> scene -> restoration PSNR (``image_baselines``: hazy input, 2D DCP)."""


def markdown_table(
    results: list[dict[str, Any]], scenes: list[str], families: list[str], baselines: SceneBaselines
) -> str:
    """One table per family: restoration PSNR per scene, then means of PSNR / SSIM / LPIPS / time;
    the baselines family opens with the single-image baselines of the same test views."""
    table = by_key(results)
    means = variant_means(results, scenes)
    head = ["variant", *scenes, "mean PSNR", "SSIM", "LPIPS", "PSNR T<=0.4", "T MAE", "S MAE", "time (s)"]
    lines: list[str] = []
    for fam in families:
        lines += [f"### {fam}", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for key, per_scene_psnr in baselines.items() if fam == "baselines" else ():
            cells = [
                BASELINE_LABELS[key],
                *(fmt_number(per_scene_psnr.get(s)) for s in scenes),
                fmt_number(mean_finite([per_scene_psnr.get(s) for s in scenes])),
            ]
            lines.append("| " + " | ".join(cells + ["-"] * (len(head) - len(cells))) + " |")
        for name in FAMILIES[fam]:
            per_scene = []
            for s in scenes:
                r = table.get((s, name))
                per_scene.append(
                    "failed"
                    if r is not None and r["status"] != "ok"
                    else fmt_number(nested(r or {}, "restoration", "psnr"))
                )
            m = means.get(name, {})
            lines.append(
                "| " + " | ".join([
                    VARIANTS[name].label or name, *per_scene, fmt_number(m.get("psnr")), fmt_number(m.get("ssim"), 3),
                    fmt_number(m.get("lpips"), 3), fmt_number(m.get("low_T_psnr")), fmt_number(m.get("t_mae"), 3),
                    fmt_number(m.get("s_mae"), 3), fmt_number(m.get("wall_seconds"), 0),
                ]) + " |"
            )  # fmt: skip
        lines.append("")
    return "\n".join(lines)


def claims_table(
    results: list[dict[str, Any]], scenes: list[str], families: list[str], noise_db: float = 0.0
) -> tuple[str, list[dict]]:
    """Each ordering the paper reports, and whether our mean restoration PSNRs agree: ``yes`` /
    ``no`` when the difference exceeds ``noise_db`` (seed-to-seed spread), else ``tie``."""
    means = variant_means(results, scenes)
    rows = []
    lines = ["| family | paper claims | paper (dB) | ours (dB) | agrees |", "|---|---|---|---|---|"]
    for c in paper_claims():
        if c.family not in families:
            continue
        w, b = means.get(c.worse, {}).get("psnr"), means.get(c.better, {}).get("psnr")
        diff = None if w is None or b is None else b - w
        if diff is None:
            verdict = None
        elif abs(diff) <= noise_db:
            verdict = "tie"
        else:
            verdict = "yes" if diff > 0 else "no"
        rows.append({"family": c.family, "worse": c.worse, "better": c.better, "paper": list(c.paper),
                     "ours": [w, b], "agrees": verdict})  # fmt: skip
        lines.append(
            f"| {c.family} | {c.worse} < {c.better} | {c.paper[0]:.2f} < {c.paper[1]:.2f} | "
            f"{fmt_number(w)} vs {fmt_number(b)} ({fmt_number(diff)}) | {verdict or '-'} |"
        )
    if noise_db > 0:
        lines.append(f"\n`tie`: the difference is within the seed-to-seed spread ({noise_db:.2f} dB).")
    return "\n".join(lines) + "\n", rows


def csv_text(results: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_FIELDS, extrasaction="ignore")
    writer.writeheader()
    for r in sorted(results, key=lambda r: (r["scene"], r["variant"])):
        writer.writerow({
            "scene": r["scene"], "variant": r["variant"], "method": r.get("method", ""), "status": r["status"],
            "restoration_psnr": nested(r, "restoration", "psnr"), "restoration_ssim": nested(r, "restoration", "ssim"),
            "restoration_lpips": nested(r, "restoration", "lpips"),
            "reconstruction_psnr": nested(r, "reconstruction", "psnr"), "low_T_psnr": nested(r, "binned", "low", "psnr"),
            "t_mae": nested(r, "medium", "t_mae"), "s_mae": nested(r, "medium", "s_mae"),
            "gaussians": r.get("gaussians"), "train_seconds": r.get("train_seconds"),
            "wall_seconds": r.get("wall_seconds"),
        })  # fmt: skip
    return buf.getvalue()


def bar_plot(
    results: list[dict[str, Any]],
    scenes: list[str],
    families: list[str],
    baselines: SceneBaselines,
    path: Path,
) -> None:
    """One panel per family: mean restoration PSNR per variant (bars), each scene (dots), the
    single-image baselines as dashed lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = by_key(results)
    means = variant_means(results, scenes)
    fig, axes = plt.subplots(1, len(families), figsize=(3.2 * len(families), 3.6), sharey=True, squeeze=False)
    for ax, fam in zip(axes[0], families, strict=True):
        names = list(FAMILIES[fam])
        vals = [means.get(n, {}).get("psnr") or 0.0 for n in names]
        colors = ["tab:orange" if n == "full" else "tab:blue" for n in names]
        ax.bar(range(len(names)), vals, color=colors)
        for i, n in enumerate(names):
            pts = [nested(table.get((s, n), {}), "restoration", "psnr") for s in scenes]
            pts = [p for p in pts if p is not None]
            ax.scatter([i] * len(pts), pts, color="black", s=8, zorder=3)
        for (key, per_scene_psnr), color in zip(baselines.items(), ("gray", "tab:green"), strict=False):
            level = mean_finite([per_scene_psnr.get(s) for s in scenes])
            if level is not None:
                ax.axhline(level, color=color, ls="--", lw=1, label=BASELINE_LABELS[key])
        ax.set_xticks(
            range(len(names)), [VARIANTS[n].name for n in names], rotation=40, ha="right", fontsize=8
        )
        ax.set_title(fam)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("restoration PSNR (dB)")
    levels = [v for per_scene_psnr in baselines.values() for v in per_scene_psnr.values()]
    lo = min([v["psnr"] for v in means.values() if v["psnr"] is not None] + levels or [0.0])
    axes[0][0].set_ylim(max(lo - 2.0, 0.0), None)
    if levels:
        axes[0][0].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
