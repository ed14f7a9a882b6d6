"""Several Stage II arms side by side: how a change's effect grows with its setting, per scene set.

Each arm is the ``pairs.json`` of one ``benchmarks/stage_two_arm.py`` run (every run continued from
its freeze with the change, against its own end), named ``SET:VALUE`` on the command line. Per set,
value and seed the table gives the mean change in restoration PSNR, how many runs moved up or down
by more than ``--tie`` dB, the largest gain and loss with their scenes, and the mean without the
largest gain (whether one scene carries the mean). Writes STEM.{json,md,png}.

    python benchmarks/stage_two_dose.py --arms benchmark:0.3=OUT_A/pairs.json \\
        holdout:0.3=OUT_B/pairs.json --output docs/results/stage_two_tmin_dose
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_output import fmt, grouped_bars, publish  # noqa: E402


def summarise(set_name: str, value: str, pairs: list[dict], tie: float) -> list[dict]:
    """One row per seed of an arm's pairs: the mean change and where it comes from."""
    rows = []
    for seed in dict.fromkeys(p["seed"] for p in pairs):  # in the order the arm ran them
        deltas = sorted(
            (p["continued"]["psnr"] - p["base"]["psnr"], p["scene"]) for p in pairs if p["seed"] == seed
        )
        values = [d for d, _ in deltas]
        n = len(values)
        rows.append(
            {
                "set": set_name,
                "value": value,
                "seed": seed,
                "runs": n,
                "mean_change": sum(values) / n,
                "up": sum(d > tie for d in values),
                "down": sum(d < -tie for d in values),
                "best": deltas[-1][0],
                "best_scene": deltas[-1][1],
                "worst": deltas[0][0],
                "worst_scene": deltas[0][1],
                "mean_without_best": sum(values[:-1]) / (n - 1) if n > 1 else None,
            }
        )
    return rows


def markdown(rows: list[dict], tie: float) -> str:
    lines = [
        f"| set | value | seed | runs | mean change (dB) | up / down (> {tie:g} dB) | largest gain | "
        "largest loss | mean without the largest gain |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['set']} | {r['value']} | {r['seed']} | {r['runs']} | {fmt(r['mean_change'], 2, sign=True)} | "
            f"{r['up']} / {r['down']} | {fmt(r['best'], 2, sign=True)} ({r['best_scene']}) | "
            f"{fmt(r['worst'], 2, sign=True)} ({r['worst_scene']}) | {fmt(r['mean_without_best'], 2, sign=True)} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path, name: str = "value") -> None:
    """Mean change per set and seed, one bar per value, both in the order of the table."""
    groups = list(dict.fromkeys((r["set"], r["seed"]) for r in rows))
    values = list(dict.fromkeys(r["value"] for r in rows))
    by = {(r["set"], r["seed"], r["value"]): r["mean_change"] for r in rows}
    grouped_bars(
        path,
        [f"{s}\n{seed}" for s, seed in groups],
        [(f"{name} {v}", [by.get((s, seed, v), 0.0) for s, seed in groups]) for v in values],
        "mean restoration change (dB)",
        zero_line=True,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--arms", nargs="+", required=True, help="SET:VALUE=PAIRS_JSON, one per arm")
    ap.add_argument("--output", type=Path, required=True, help="output stem: writes .json, .md, .png")
    ap.add_argument("--name", default="value", help="what VALUE sets, for the plot's legend (t_min)")
    ap.add_argument("--tie", type=float, default=0.02, help="changes within this many dB count as ties")
    args = ap.parse_args()
    rows = []
    for arm in args.arms:
        name, sep, path = arm.partition("=")
        set_name, colon, value = name.partition(":")
        if not sep or not colon or not path:
            raise SystemExit(f"--arms {arm!r}: expected SET:VALUE=PAIRS_JSON")
        if not Path(path).is_file():
            raise SystemExit(f"--arms {arm!r}: no file {path} (stage_two_arm.py writes OUT/pairs.json)")
        rows += summarise(set_name, value, json.loads(Path(path).read_text()), args.tie)
    how = (
        "`python benchmarks/stage_two_dose.py --arms "
        + " ".join(args.arms)
        + f" --name {args.name} --output {args.output}`"
    )
    publish(
        args.output,
        rows,
        "Stage II arms by setting",
        how,
        markdown(rows, args.tie),
        lambda r, p: plot(r, p, args.name),
    )


if __name__ == "__main__":
    main()
