"""Cost of one training checkpoint (``--minutes-per-save``, ``--steps-per-save``) by Gaussian count.

A generated scene with N seed points gives a model of N Gaussians; one training step fills the
optimiser state, then ``Trainer.save`` (state dicts -> torch.save -> fsync -> rename) is timed
several times. The overhead of time-based checkpoints is the save time over the interval.

    python benchmarks/checkpoint_cost.py                 # 10k and 50k Gaussians, vanilla-gs and tri-dehaze
    python benchmarks/checkpoint_cost.py --points 50000 --repeats 9

Writes ``benchmarks/results/checkpoint_cost.{json,csv,png}``.
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch
from rich.console import Console

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from components.synth.generate import SceneConfig, generate_scene  # noqa: E402
from pipelines.engine.trainer import Trainer  # noqa: E402
from tridehaze_plugin.cli.train import parse_args  # noqa: E402

OUT = REPO / "benchmarks" / "results"


def measure(method: str, points: int, repeats: int, work: Path) -> dict:
    data = work / f"scene-{points}"
    if not data.exists():
        generate_scene(SceneConfig(output_dir=data, num_views=5, width=160, height=120, num_points=points))
    cfg = parse_args([
        method, "--data", str(data), "--output-dir", str(work / "runs"), "--max-steps", "1",
        "--pipeline.rasterizer.backend", "torch", "--no-eval-at-end", "--threads", "1", "--device", "cpu",
        "--minutes-per-save", "0", "--steps-per-save", "1000",
    ])  # fmt: skip
    trainer = Trainer(cfg, console=Console(quiet=True))
    trainer.train()  # one step: Adam's moments exist, as in any later checkpoint
    gaussians = int(trainer.pipeline.stats()["gaussians"])
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        path = trainer.save(2 + i)
        times.append(time.perf_counter() - t0)
    return {
        "method": method,
        "gaussians": gaussians,
        "seconds_median": statistics.median(times),
        "seconds_max": max(times),
        "megabytes": path.stat().st_size / 1e6,
        "overhead_at_5_min_percent": 100 * statistics.median(times) / 300,
        "repeats": repeats,
    }


def plot(rows: list[dict]) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for method in dict.fromkeys(r["method"] for r in rows):
        sel = [r for r in rows if r["method"] == method]
        ax.plot([r["gaussians"] for r in sel], [r["seconds_median"] for r in sel], "o-", label=method)
    ax.set_xlabel("Gaussians")
    ax.set_ylabel("seconds per checkpoint (median)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(OUT / "checkpoint_cost.png", dpi=100)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, nargs="+", default=[10_000, 50_000])
    ap.add_argument("--methods", nargs="+", default=["vanilla-gs", "tri-dehaze"])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    torch.set_num_threads(1)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for points in args.points:
            for method in args.methods:
                rows.append(measure(method, points, args.repeats, Path(tmp)))
                r = rows[-1]
                print(
                    f"{r['method']:<12} {r['gaussians']:>7} Gaussians  {r['seconds_median']:.3f} s "
                    f"(max {r['seconds_max']:.3f})  {r['megabytes']:.1f} MB  "
                    f"{r['overhead_at_5_min_percent']:.3f} % of a 5-minute interval",
                    flush=True,
                )
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "checkpoint_cost.json").write_text(json.dumps(rows, indent=2) + "\n")
    with (OUT / "checkpoint_cost.csv").open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    plot(rows)


if __name__ == "__main__":
    main()
