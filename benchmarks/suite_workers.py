"""Wall time of the test suite by worker count and thread setting, side by side in one run.

Most of the default suite's time is start-up of the CLI processes the end-to-end tests launch
(importing torch alone takes ~2 s here), so one pytest process leaves a core idle while it waits
on them; pytest-xdist runs tests in parallel worker processes. Each worker's torch (and every CLI
process it starts) then needs one thread, or two workers' threads fight over the two cores. The
settings below are run in turn, ``--rounds`` times interleaved, on the same test selection:

    python benchmarks/suite_workers.py tests/eval tests/medium --rounds 1

Writes ``benchmarks/results/suite_workers.{json,md,png}`` (``--output`` to change the stem).
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from benchmarks.bench_output import publish  # noqa: E402

SETTINGS: dict[str, tuple[list[str], dict[str, str]]] = {
    "1 process, threads as torch picks": (["-p", "no:xdist"], {"TD_TEST_THREADS": "default"}),
    "1 process, 1 thread": (["-p", "no:xdist"], {"TD_TEST_THREADS": "1"}),
    "2 workers, threads as torch picks": (["-n", "2"], {"TD_TEST_THREADS": "default"}),
    "2 workers, 1 thread (make test)": (["-n", "2"], {}),
}
"""Name -> (pytest options, environment). ``TD_TEST_THREADS`` is read by tests/conftest.py."""


def run_once(paths: list[str], opts: list[str], env: dict[str, str]) -> tuple[float, str]:
    """Wall seconds of one pytest run and its summary line (to check the same tests passed)."""
    full = {k: v for k, v in os.environ.items() if k != "OMP_NUM_THREADS"} | env
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *opts, *paths]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=REPO, env=full, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    last = [ln for ln in r.stdout.splitlines() if re.search(r"\d+ (passed|failed)", ln)]
    return wall, (last[-1].strip("= ") if last else f"rc {r.returncode}")


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 2.8))
    ax.barh([r["setting"] for r in rows], [r["median_s"] for r in rows], color="#4a7")
    for i, r in enumerate(rows):
        ax.text(r["median_s"], i, f" {r['ratio']:.2f}x", va="center")
    ax.set_xlabel("wall seconds (median over rounds)")
    ax.invert_yaxis()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("paths", nargs="*", default=["tests"], help="test paths (default: the whole suite)")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--output", type=Path, default=REPO / "benchmarks" / "results" / "suite_workers")
    args = ap.parse_args()
    walls: dict[str, list[float]] = {name: [] for name in SETTINGS}
    summary: dict[str, str] = {}
    for _ in range(args.rounds):
        for name, (opts, env) in SETTINGS.items():
            wall, line = run_once(args.paths, opts, env)
            walls[name].append(wall)
            summary[name] = line
            print(f"{name}: {wall:.1f} s ({line})", flush=True)
    base = statistics.median(walls[next(iter(SETTINGS))])
    rows = [
        {
            "setting": name,
            "median_s": round(statistics.median(w), 1),
            "runs_s": [round(x, 1) for x in w],
            "ratio": round(statistics.median(w) / base, 3),
            "result": summary[name],
        }
        for name, w in walls.items()
    ]
    table = "| setting | wall s (median) | vs first | result |\n|---|---|---|---|\n" + "".join(
        f"| {r['setting']} | {r['median_s']} | {r['ratio']:.2f}x | {r['result']} |\n" for r in rows
    )
    how = (
        f"`python benchmarks/suite_workers.py {' '.join(args.paths)} --rounds {args.rounds}` "
        f"({os.cpu_count()} CPUs)"
    )
    publish(args.output, rows, "Test suite wall time by workers and threads", how, table, plot)


if __name__ == "__main__":
    main()
