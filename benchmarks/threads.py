"""Thread settings for CPU training, measured side by side in one run.

Each setting trains the same short run in a fresh process (torch's intra-op threads and
``OMP_NUM_THREADS`` / ``OMP_WAIT_POLICY`` only take effect at start-up) and reports seconds
per step. Settings are interleaved over several rounds so that load from other users of a
shared machine hits all of them alike; ratios against the default are the number to quote.

    python benchmarks/threads.py --data ../shared/data/real/statue --downscale 8 --steps 200

Writes ``benchmarks/results/threads.{json,csv,png}``.
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

SETTINGS: dict[str, dict[str, str]] = {
    "default (torch picks, 2)": {},
    "torch 1, OMP 1": {"--threads": "1", "OMP_NUM_THREADS": "1"},
    "torch 2, OMP 2": {"--threads": "2", "OMP_NUM_THREADS": "2"},
    "torch 2, OMP passive": {"--threads": "2", "OMP_WAIT_POLICY": "PASSIVE"},
}


def run_once(setting: dict[str, str], args: argparse.Namespace, out: Path) -> float:
    env = dict(os.environ)
    cli = ["td-train", args.method, "--data", str(args.data), "--downscale", str(args.downscale)]
    cli += ["--max-steps", str(args.steps), "--output-dir", str(out), "--no-eval-at-end"]
    for key, value in setting.items():
        if key.startswith("--"):
            cli += [key, value]
        else:
            env[key] = value
    res = subprocess.run(cli, capture_output=True, text=True, env=env, check=True)
    m = re.search(r"train_seconds ([0-9.]+)", res.stdout)
    if not m:
        raise RuntimeError(f"no timing in output:\n{res.stdout}\n{res.stderr}")
    return float(m.group(1)) / args.steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--method", default="vanilla-gs")
    ap.add_argument("--downscale", type=int, default=8)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = ap.parse_args()

    times: dict[str, list[float]] = {name: [] for name in SETTINGS}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for name, setting in SETTINGS.items():
                times[name].append(run_once(setting, args, Path(tmp)))
                print(
                    f"round {r + 1}/{args.rounds}  {name:28s} {times[name][-1] * 1e3:7.1f} ms/step",
                    flush=True,
                )

    base = statistics.median(times[next(iter(SETTINGS))])
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
    print(f"\n{'setting':28s} {'median ms/step':>15s} {'min':>8s} {'vs default':>11s}")
    for row in rows:
        print(
            f"{row['setting']:28s} {row['median_ms_per_step']:15.1f} {row['min_ms_per_step']:8.1f} "
            f"{row['ratio_vs_default']:10.2f}x"
        )

    args.out.mkdir(parents=True, exist_ok=True)
    meta = {"method": args.method, "data": str(args.data), "downscale": args.downscale, "steps": args.steps}
    (args.out / "threads.json").write_text(json.dumps({"config": meta, "results": rows}, indent=2))
    with (args.out / "threads.csv").open("w", newline="") as fh:
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
    ax.set_title(f"{args.method}, {Path(args.data).name} /{args.downscale}, {args.steps} steps, 2 cores")
    fig.tight_layout()
    fig.savefig(args.out / "threads.png", dpi=120)
    print(f"wrote {args.out}/threads.{{json,csv,png}}")


if __name__ == "__main__":
    main()
