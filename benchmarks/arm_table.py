"""Several arms of ``td-bench restoration`` in one table and one figure: where the gap lies.

Each arm is a ``td-bench restoration`` output folder (``ARM/seed<N>/results/<scene>/<method>.json``);
typically the default, the ``reference`` medium (the generator's true medium, nothing learnt), the
same with a scene-side change, and an oracle. Per scene and seed: restoration PSNR (whole image and
observable pixels), T MAE at the rendered depth and the hazy test views' reconstruction PSNR (how
well the arm explains photos it did not train on) of every arm; per seed the mean over the scenes
that every arm finished. Writes STEM.{json,md,png}.

    python benchmarks/arm_table.py --arms default=runs/base reference=runs/ref --output docs/results/x
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_output import publish  # noqa: E402
from paired_restoration import arm_folders, load_arm, result_value  # noqa: E402

SHOWN = (
    ("psnr", ("restoration", "psnr")),
    ("observable", ("observable", "psnr")),
    ("t_mae", ("medium", "t_mae")),
    ("reconstruction", ("reconstruction", "psnr")),
)


def rows_of(arms: list[tuple[str, dict]]) -> list[dict]:
    """One row per (scene, seed) that every arm finished: each shown metric per arm."""
    common = set.intersection(*(set(runs) for _, runs in arms))
    return [
        {
            "scene": scene,
            "seed": seed,
            **{n: [result_value(runs[(scene, seed)], k) for _, runs in arms] for n, k in SHOWN},
        }
        for scene, seed in sorted(common)
    ]


def means_of(rows: list[dict], n_arms: int) -> list[dict]:
    out = []
    for seed in sorted({r["seed"] for r in rows}):
        sel = [r for r in rows if r["seed"] == seed]
        m = {"seed": seed, "scenes": len(sel)}
        for name, _ in SHOWN:
            cols = [[r[name][i] for r in sel if r[name][i] is not None] for i in range(n_arms)]
            m[name] = [statistics.fmean(c) if len(c) == len(sel) else None for c in cols]
        out.append(m)
    return out


def _cell(values: list[float | None], digits: int) -> str:
    return " / ".join("-" if v is None else f"{v:.{digits}f}" for v in values)


def table(rows: list[dict], means: list[dict], names: list[str]) -> str:
    arms = " / ".join(names)
    head = f"| scene | seed | restoration ({arms}) | observable | T MAE | hazy reconstruction |"
    lines = [head, "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['seed']} | {_cell(r['psnr'], 2)} | {_cell(r['observable'], 2)} | "
            f"{_cell(r['t_mae'], 3)} | {_cell(r['reconstruction'], 2)} |"
        )
    for m in means:
        lines.append(
            f"| **mean ({m['scenes']} scenes)** | {m['seed']} | {_cell(m['psnr'], 2)} | "
            f"{_cell(m['observable'], 2)} | {_cell(m['t_mae'], 3)} | {_cell(m['reconstruction'], 2)} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = next(r["arms"] for r in rows if "arms" in r)
    rows = [r for r in rows if "scene" in r]
    labels = [f"{r['scene']}\ns{r['seed']}" for r in rows]
    fig, axes = plt.subplots(1, 3, figsize=(max(11, 1.3 * len(rows) + 4), 4.2))
    width = 0.8 / len(names)
    panels = (
        (axes[0], "psnr", "restoration PSNR (dB), whole image"),
        (axes[1], "observable", "restoration PSNR (dB), observable pixels"),
        (axes[2], "reconstruction", "hazy test views' PSNR (dB)"),
    )
    for ax, key, title in panels:
        for i, name in enumerate(names):
            xs = [k + (i - (len(names) - 1) / 2) * width for k in range(len(rows))]
            ax.bar(xs, [r[key][i] or 0.0 for r in rows], width, label=name, color=f"C{i}")
        shown = [v for r in rows for v in r[key] if v is not None]
        if shown:  # differences of a dB or two must show: the bars start near the smallest value
            ax.set_ylim(max(0.0, min(shown) - 3.0), max(shown) + 1.0)
        ax.set_xticks(range(len(rows)), labels, rotation=60, ha="right", fontsize=7)
        ax.set_title(title, fontsize=9)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--arms", nargs="+", required=True, metavar="NAME=FOLDER", help="two or more arms")
    ap.add_argument("--method", default="tri-dehaze", help="the method whose runs are compared")
    ap.add_argument("--output", type=Path, required=True, help="output stem: writes .json, .md, .png")
    ap.add_argument("--title", default="Restoration by arm")
    args = ap.parse_args()
    arms = [(name, load_arm(folder, args.method)) for name, folder in arm_folders(ap, args.arms)]
    if len(arms) < 2:
        ap.error("give at least two arms")
    rows = rows_of(arms)
    if not rows:
        ap.error("no (scene, seed) finished in every arm")
    names = [n for n, _ in arms]
    means = means_of(rows, len(arms))
    how = "`python benchmarks/arm_table.py --arms " + " ".join(args.arms) + f" --output {args.output}`"
    publish(
        args.output,
        rows + [{"arms": names, "seed_means": means}],
        args.title,
        how,
        table(rows, means, names),
        plot,
    )


if __name__ == "__main__":
    main()
