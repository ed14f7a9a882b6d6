"""Two arms of ``td-bench restoration`` side by side: does a knob beat the seed spread?

Each arm is the output folder of one ``td-bench restoration`` run (``ARM/seed<N>/results/<scene>/
<method>.json``), the two run together on one machine so that the pair shares code, load and CPU
(the machine alone moves single runs by up to 2 dB: docs/results/medium_recovery.md, session 12).
For every scene and seed the table gives the second arm's change against the first in whole-image
and observable-pixel restoration PSNR, T and S MAE and reconstruction PSNR; a scene counts as
better (worse) only where it is better (worse) at every seed. Writes STEM.{json,md,png}.

    python benchmarks/paired_restoration.py --arms base=restoration-base lr=restoration-lr \\
        --output docs/results/medium_lr
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_output import publish  # noqa: E402

METRICS: tuple[tuple[str, tuple[str, ...], int], ...] = (
    ("psnr", ("restoration", "psnr"), +1),
    ("observable", ("observable", "psnr"), +1),
    ("ssim", ("restoration", "ssim"), +1),
    ("t_mae", ("medium", "t_mae"), -1),
    ("s_mae", ("medium", "s_mae"), -1),
    ("t_mae_true_z", ("medium", "t_mae_true_depth"), -1),
    ("recon", ("reconstruction", "psnr"), +1),
    ("train_s", ("train_seconds",), 0),
)
"""(name, keys into a run's result, +1 if higher is better / -1 if lower / 0 neither)."""


def result_value(result: dict, keys: tuple[str, ...]) -> float | None:
    """The number at ``keys`` in a run's result, or None where a key is missing."""
    for k in keys:
        if not isinstance(result, dict) or result.get(k) is None:
            return None
        result = result[k]
    return float(result)


def load_arm(folder: Path, method: str) -> dict[tuple[str, int], dict]:
    """(scene, seed) -> the run's result, for the finished runs of one arm."""
    out = {}
    for path in sorted(folder.glob(f"seed*/results/*/{method}.json")):
        result = json.loads(path.read_text())
        if result.get("status") == "ok":
            out[(path.parent.name, int(path.parents[2].name.removeprefix("seed")))] = result
    return out


def arm_folders(ap: argparse.ArgumentParser, specs: list[str]) -> list[tuple[str, Path]]:
    """``NAME=FOLDER`` arguments as (name, folder); a usage error for a missing folder."""
    arms = []
    for spec in specs:
        name, sep, folder = spec.partition("=")
        if not sep or not Path(folder).is_dir():
            ap.error(f"--arms takes NAME=FOLDER with an existing folder, got {spec!r}")
        arms.append((name, Path(folder)))
    return arms


def paired_rows(a: dict[tuple[str, int], dict], b: dict[tuple[str, int], dict]) -> list[dict]:
    """One row per (scene, seed) both arms finished: each metric in both arms."""
    rows = []
    for scene, seed in sorted(set(a) & set(b)):
        row: dict = {"scene": scene, "seed": seed}
        for name, keys, _ in METRICS:
            row[name] = [result_value(a[(scene, seed)], keys), result_value(b[(scene, seed)], keys)]
        rows.append(row)
    return rows


def _delta(row: dict, name: str) -> float | None:
    x, y = row[name]
    return None if x is None or y is None else y - x


def scene_verdicts(rows: list[dict]) -> dict[str, str]:
    """``better`` / ``worse`` where restoration moves the same way at every seed of a scene
    (and that scene has at least two seeds), else ``mixed`` (or ``one seed``)."""
    out = {}
    for scene in sorted({r["scene"] for r in rows}):
        deltas = [_delta(r, "psnr") for r in rows if r["scene"] == scene]
        deltas = [d for d in deltas if d is not None]
        if len(deltas) < 2:
            out[scene] = "one seed"
        elif all(d > 0 for d in deltas):
            out[scene] = "better"
        elif all(d < 0 for d in deltas):
            out[scene] = "worse"
        else:
            out[scene] = "mixed"
    return out


def seed_means(rows: list[dict]) -> list[dict]:
    """Per seed: the mean of each metric over the scenes both arms finished at that seed."""
    out = []
    for seed in sorted({r["seed"] for r in rows}):
        sel = [r for r in rows if r["seed"] == seed]
        m: dict = {"seed": seed, "scenes": len(sel)}
        for name, _, _ in METRICS:
            pairs = [r[name] for r in sel if None not in r[name]]
            m[name] = (
                [statistics.fmean(p[0] for p in pairs), statistics.fmean(p[1] for p in pairs)]
                if pairs
                else None
            )
        out.append(m)
    return out


def _fmt(v: float | None, digits: int) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def table(rows: list[dict], means: list[dict], verdicts: dict[str, str], names: tuple[str, str]) -> str:
    a, b = names
    shown = [
        (n, 2 if n in ("psnr", "observable", "recon") else (0 if n == "train_s" else 3))
        for n, _, _ in METRICS
    ]
    head = "| scene | seed | " + " | ".join(f"{n} {a} -> {b}" for n, _ in shown) + " | restoration change |"
    lines = [head, "|" + "---|" * (len(shown) + 3)]
    for r in rows:
        cells = [f"{_fmt(r[n][0], d)} -> {_fmt(r[n][1], d)}" for n, d in shown]
        lines.append(
            f"| {r['scene']} | {r['seed']} | " + " | ".join(cells) + f" | {_fmt(_delta(r, 'psnr'), 2)} |"
        )
    for m in means:
        cells = [f"{_fmt(m[n][0], d)} -> {_fmt(m[n][1], d)}" if m[n] else "-" for n, d in shown]
        change = m["psnr"][1] - m["psnr"][0] if m["psnr"] else None
        lines.append(
            f"| **mean ({m['scenes']} scenes)** | {m['seed']} | "
            + " | ".join(cells)
            + f" | {_fmt(change, 2)} |"
        )
    summary = ", ".join(
        f"{v}: {sum(1 for x in verdicts.values() if x == v)}"
        for v in ("better", "worse", "mixed", "one seed")
    )
    detail = "; ".join(f"{s} {v}" for s, v in verdicts.items())
    return (
        "\n".join(lines)
        + f"\n\nScenes by restoration at every seed ({b} against {a}): {summary} ({detail}).\n"
    )


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    scenes = sorted({r["scene"] for r in rows})
    seeds = sorted({r["seed"] for r in rows})
    for ax, name, label in (
        (axes[0], "psnr", "restoration PSNR change (dB)"),
        (axes[1], "t_mae", "T MAE change"),
    ):
        for k, seed in enumerate(seeds):
            pts = [(scenes.index(r["scene"]), _delta(r, name)) for r in rows if r["seed"] == seed]
            pts = [(x, d) for x, d in pts if d is not None]
            ax.scatter([x for x, _ in pts], [d for _, d in pts], color=f"C{k}", s=25, label=f"seed {seed}")
        ax.axhline(0, color="grey", lw=0.8)
        ax.set_xticks(range(len(scenes)), scenes, rotation=45, ha="right", fontsize=8)
        ax.set_ylabel(label)
    axes[1].legend(fontsize=8)
    axes[0].set_title("second arm minus first, one dot per seed")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--arms", nargs=2, required=True, metavar="NAME=FOLDER", help="first arm (reference), second arm"
    )
    ap.add_argument("--method", default="tri-dehaze", help="the method whose runs are compared")
    ap.add_argument("--output", type=Path, required=True, help="output stem: writes .json, .md, .png")
    ap.add_argument("--title", default="Paired restoration benchmark")
    args = ap.parse_args()
    (na, fa), (nb, fb) = arm_folders(ap, args.arms)
    rows = paired_rows(load_arm(fa, args.method), load_arm(fb, args.method))
    if not rows:
        ap.error(f"no (scene, seed) finished in both {fa} and {fb}")
    means, verdicts = seed_means(rows), scene_verdicts(rows)
    how = f"`python benchmarks/paired_restoration.py --arms {na}={fa} {nb}={fb} --output {args.output}`"
    text = table(rows, means, verdicts, (na, nb))
    publish(
        args.output, rows + [{"seed_means": means, "verdicts": verdicts}], args.title, how, text, plot_rows
    )


def plot_rows(rows: list[dict], path: Path) -> None:
    plot([r for r in rows if "scene" in r], path)


if __name__ == "__main__":
    main()
