"""Pair a Stage II change against finished runs by continuing each from its freeze checkpoint.

A change that acts only after the freeze (Stage II) need not retrain Stage I: every run of a
``td-bench restoration`` output folder is copied, its checkpoints after the freeze dropped, and
continued with ``td-train --resume COPY ARGS`` to its end, then evaluated. A continued run with no
ARGS reproduces its original to the last digit (docs/results/medium_recovery.md, session 53), so
the pairs differ by the change alone, at a quarter of the cost of a full arm.

    python benchmarks/stage_two_arm.py --base BENCH_OUT --output OUT --train-args="--pipeline.X" [--jobs 2]

Prints one row per run (restoration, observable pixels, T / S MAE: base -> continued) and the
per-seed means; writes OUT/pairs.json. Runs already evaluated under OUT are kept.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import fmt  # noqa: E402
from stage_two_change import freeze_step_of, headline  # noqa: E402

from pipelines.engine.checkpoint import CHECKPOINT_GLOB, checkpoint_path  # noqa: E402
from pipelines.engine.run_config import load_config  # noqa: E402


def pair_line(row: dict) -> str:
    """One printed pair: restoration, T and S MAE before -> after (``-`` where a dataset has no true
    map: real photos carry no scattering)."""
    b, c = row["base"], row["continued"]
    cells = [
        f"{row['seed']:7s} {row['scene']:20s} {b['psnr']:.2f} -> {c['psnr']:.2f} ({c['psnr'] - b['psnr']:+.2f})"
    ]
    cells += [f"{name} {fmt(b[k])} -> {fmt(c[k])}" for name, k in (("T MAE", "t_mae"), ("S MAE", "s_mae"))]
    return "  ".join(cells)


def base_runs(base: Path) -> list[tuple[str, str, Path]]:
    """(seed folder, scene, run folder) of every run under a td-bench output folder."""
    found = []
    for config in sorted(base.glob("seed*/runs/*/*/*/config.yml")):
        run = config.parent
        found.append((run.parents[3].name, run.parents[1].name, run))
    return found


def freeze_step(run: Path) -> int:
    """The run's freeze step, whose checkpoint must exist (checked for every run before any is
    continued)."""
    freeze = freeze_step_of(load_config(run / "config.yml"))
    if not checkpoint_path(run, freeze).is_file():
        raise SystemExit(
            f"{run}: no checkpoint at the freeze (step {freeze}); runs trained before session 65 may "
            "have rotated it away: retrain, or leave the run out"
        )
    return freeze


def continue_run(run: Path, freeze: int, dest: Path, args: list[str]) -> Path:
    """Copy ``run`` to ``dest`` from its freeze checkpoint, continue it with ``args``, evaluate it."""
    result = dest / "eval.json"
    if result.is_file():
        return result
    shutil.rmtree(dest, ignore_errors=True)
    shutil.copytree(run, dest, ignore=shutil.ignore_patterns("eval"))
    keep = checkpoint_path(dest, freeze)
    for ckpt in (dest / "checkpoints").glob(CHECKPOINT_GLOB):
        if ckpt != keep:  # the freeze checkpoint becomes the newest
            ckpt.unlink()
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    with dest.with_suffix(".log").open("w") as log:
        subprocess.run([sys.executable, "-m", "tridehaze_plugin.cli.train", "--resume", str(dest), *args],
                       check=True, env=env, stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
        subprocess.run([sys.executable, "-m", "tridehaze_plugin.cli.eval", "--load-config",
                        str(dest / "config.yml"), "--output-path", str(result), "--lpips", "off", "--no-images"],
                       check=True, env=env, stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
    return result


def scores(path: Path) -> dict[str, float | None]:
    return headline(json.loads(path.read_text()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", type=Path, required=True, help="a td-bench restoration output folder")
    ap.add_argument("--output", type=Path, required=True, help="where the continued runs go")
    ap.add_argument("--train-args", default="", help="td-train options for Stage II, one string")
    ap.add_argument("--jobs", type=int, default=2, help="runs continued in parallel")
    args = ap.parse_args()
    runs = base_runs(args.base)
    extra = shlex.split(args.train_args)
    freezes = [freeze_step(run) for _, _, run in runs]
    with ThreadPoolExecutor(args.jobs) as pool:
        jobs = [(r, f, args.output / r[0] / r[1]) for r, f in zip(runs, freezes, strict=True)]
        done = list(pool.map(lambda j: continue_run(j[0][2], j[1], j[2], extra), jobs))
    rows = []
    for (seed, scene, run), result in zip(runs, done, strict=True):
        before = scores(run / "eval" / "test.json") if (run / "eval" / "test.json").is_file() else None
        if before is None:  # td-bench keeps its evaluation beside the runs
            before = scores(args.base / seed / "results" / scene / f"{run.parent.name}.json")
        rows.append({"seed": seed, "scene": scene, "base": before, "continued": scores(result)})
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / "pairs.json").write_text(json.dumps(rows, indent=2))
    for r in rows:
        print(pair_line(r))
    for seed in sorted({r["seed"] for r in rows}):
        d = [r["continued"]["psnr"] - r["base"]["psnr"] for r in rows if r["seed"] == seed]
        print(f"{seed}: mean change {sum(d) / len(d):+.3f} dB over {len(d)} runs")


if __name__ == "__main__":
    main()
