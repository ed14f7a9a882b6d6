"""Thread settings for CPU training, measured side by side in one run.

Each setting trains the same short run in a fresh process (torch's intra-op threads and
``OMP_NUM_THREADS`` / ``OMP_WAIT_POLICY`` only take effect at start-up) and reports seconds
per step. Settings are interleaved over several rounds so that load from other users of a
shared machine hits all of them alike; ratios against the default are the number to quote.

    python benchmarks/threads.py --data ../shared/data/real/statue --downscale 8 --steps 200

With ``--concurrent N`` each setting runs N identical trainings at once, as ``td-bench`` and
``td-ablate`` run their jobs (``--threads 1`` each), and compares where the CPU rasterizer's kernel
threads come from: every core (the default before session 26) or torch's threads (now):

    python benchmarks/threads.py --data SCENE --downscale 1 --method tri-dehaze --concurrent 2

Writes ``benchmarks/results/threads.{json,csv,png}`` (``threads_concurrent<N>.*`` with
``--concurrent``).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from components.rasterizers.cpu_rasterizer import THREADS_ENV_VAR, available_cores  # noqa: E402

SETTINGS: dict[str, dict[str, str]] = {
    "default (torch picks, 2)": {},
    "torch 1, OMP 1": {"--threads": "1", "OMP_NUM_THREADS": "1"},
    "torch 2, OMP 2": {"--threads": "2", "OMP_NUM_THREADS": "2"},
    "torch 2, OMP passive": {"--threads": "2", "OMP_WAIT_POLICY": "PASSIVE"},
}
CORES = available_cores()
SWEEP_SETTINGS: dict[str, dict[str, str]] = {
    "torch 1, kernel 1 (follows --threads)": {"--threads": "1", "OMP_NUM_THREADS": "1"},
    f"torch 1, kernel {CORES} (every core, before)": {
        "--threads": "1",
        "OMP_NUM_THREADS": "1",
        THREADS_ENV_VAR: str(CORES),
    },
}
"""Settings of ``--concurrent``: each of a sweep's runs is given ``--threads 1``."""


def run_once(setting: dict[str, str], args: argparse.Namespace, out: Path) -> float:
    """Seconds per step of one training in ``setting``; with ``--concurrent N``, the median over N
    identical trainings started together."""
    env = dict(os.environ)
    cli = ["td-train", args.method, "--data", str(args.data), "--downscale", str(args.downscale)]
    cli += ["--max-steps", str(args.steps), "--no-eval-at-end"]
    for key, value in setting.items():
        if key.startswith("--"):
            cli += [key, value]
        else:
            env[key] = value
    # each run logs to a file: a pipe left unread while another run is waited on could fill and
    # stall that run's training, inflating the very time being measured
    logs = [out / f"run{i}.log" for i in range(args.concurrent)]
    procs = []
    for i, log in enumerate(logs):
        with log.open("w") as fh:
            cmd = [*cli, "--output-dir", str(out / str(i))]
            procs.append(subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, text=True, env=env))
    per_step = []
    for proc, log in zip(procs, logs, strict=True):
        proc.wait()
        text = log.read_text()
        m = re.search(r"train_seconds ([0-9.]+)", text)
        if proc.returncode != 0 or not m:
            raise RuntimeError(f"no timing in output:\n{text}")
        per_step.append(float(m.group(1)) / args.steps)
    return statistics.median(per_step)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--method", default="vanilla-gs")
    ap.add_argument("--downscale", type=int, default=8)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    ap.add_argument("--concurrent", type=int, default=1, help="trainings run at once per setting")
    args = ap.parse_args()

    settings = SETTINGS if args.concurrent == 1 else SWEEP_SETTINGS
    stem = "threads" if args.concurrent == 1 else f"threads_concurrent{args.concurrent}"
    times: dict[str, list[float]] = {name: [] for name in settings}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for name, setting in settings.items():
                times[name].append(run_once(setting, args, Path(tmp)))
                print(
                    f"round {r + 1}/{args.rounds}  {name:40s} {times[name][-1] * 1e3:7.1f} ms/step",
                    flush=True,
                )

    base = statistics.median(times[next(iter(settings))])
    rows = [
        {
            "setting": name,
            "median_ms_per_step": statistics.median(t) * 1e3,
            "min_ms_per_step": min(t) * 1e3,
            "ratio_vs_default": statistics.median(t) / base,
            "rounds": len(t),
        }
        for name, t in times.items()
    ]
    print(f"\n{'setting':40s} {'median ms/step':>15s} {'min':>8s} {'vs default':>11s}")
    for row in rows:
        print(
            f"{row['setting']:40s} {row['median_ms_per_step']:15.1f} {row['min_ms_per_step']:8.1f} "
            f"{row['ratio_vs_default']:10.2f}x"
        )

    write_outputs(rows, args, stem)


def write_outputs(rows: list[dict], args: argparse.Namespace, stem: str) -> None:
    """The table as JSON and CSV, and a bar plot where matplotlib is installed."""
    args.out.mkdir(parents=True, exist_ok=True)
    meta = {"method": args.method, "data": str(args.data), "downscale": args.downscale, "steps": args.steps,
            "concurrent": args.concurrent, "cores": CORES}  # fmt: skip
    (args.out / f"{stem}.json").write_text(json.dumps({"config": meta, "results": rows}, indent=2))
    with (args.out / f"{stem}.csv").open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed (pip install -e '.[bench]'): no plot written", file=sys.stderr)
        return
    fig, ax = plt.subplots(figsize=(7, 3))
    ax.barh([r["setting"] for r in rows], [r["median_ms_per_step"] for r in rows], color="#4a7fb5")
    ax.set_xlabel("ms per training step (median)")
    runs = f", {args.concurrent} at once" if args.concurrent > 1 else ""
    ax.set_title(
        f"{args.method}, {Path(args.data).name} /{args.downscale}, {args.steps} steps{runs}, {CORES} cores",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(args.out / f"{stem}.png", dpi=120)
    print(f"wrote {args.out}/{stem}.{{json,csv,png}}")


if __name__ == "__main__":
    main()
