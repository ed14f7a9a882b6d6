"""What Stage II does to the restoration: a trained run scored at its freeze and at its end.

Stage II freezes the medium and lets the Gaussians go on under MD-TGC. The freeze checkpoint is
always written and kept (the pipeline's milestone; runs trained before session 65 kept it only when
no time-based save pushed it out), and both checkpoints are evaluated on the test views: restoration
PSNR, the PSNR of the observable pixels (true T >= 0.05), T MAE at the rendered and at the true
depth. The medium is the same at both; T at the rendered depth moves only with the Gaussians.

    python benchmarks/stage_two_change.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

Writes OUT.json, OUT.md (one row per run) and OUT.png. Runs without a checkpoint at the freeze
step are reported with "-".
"""

from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import diagnose_runs_main, fmt, grouped_bars  # noqa: E402
from sky_split import arm_of, run_label  # noqa: E402

from pipelines.engine.checkpoint import checkpoint_path, latest_checkpoint  # noqa: E402
from pipelines.engine.config import TrainerConfig  # noqa: E402
from pipelines.engine.evaluate import evaluate  # noqa: E402
from pipelines.engine.run_config import load_config  # noqa: E402
from pipelines.engine.run_loader import load_run  # noqa: E402
from pipelines.tridehaze.priors import scaled_step  # noqa: E402

STAGES = ("freeze", "end")


def headline(r: dict) -> dict[str, float | None]:
    """The numbers these comparisons read from an evaluation (``evaluate``'s dict or td-eval's JSON)."""
    medium, observable = r.get("medium") or {}, r.get("observable") or {}
    return {
        "psnr": r["restoration"]["psnr"],
        "observable": observable.get("psnr"),
        "t_mae": medium.get("t_mae"),
        "s_mae": medium.get("s_mae"),
        "t_mae_true_depth": medium.get("t_mae_true_depth"),
    }


def _scores(config: Path, checkpoint: Path) -> dict:
    run = load_run(config, checkpoint=checkpoint)
    return {**headline(evaluate(run.pipeline, run.datamanager, "test")), "step": run.step}


def freeze_step_of(cfg: TrainerConfig) -> int:
    """The step at which a run with config ``cfg`` froze its medium."""
    return scaled_step(cfg.pipeline.freeze_step, cfg.pipeline.freeze_fraction, cfg.max_steps)


def diagnose(config: Path) -> dict:
    cfg = load_config(config)
    freeze = freeze_step_of(cfg)
    row: dict = {"run": str(config.parent), "scene": Path(str(cfg.dataset.data)).name, "seed": cfg.seed}
    row["freeze_step"] = freeze
    found = {"freeze": checkpoint_path(config.parent, freeze), "end": latest_checkpoint(config.parent)}
    for stage in STAGES:
        ckpt = found[stage]
        scores = _scores(config, ckpt) if ckpt is not None and ckpt.is_file() else {}
        for k in ("psnr", "observable", "t_mae", "t_mae_true_depth", "step"):
            row[f"{stage}_{k}"] = scores.get(k)
    return row


def _change(row: dict, key: str) -> str:
    a, b = row[f"freeze_{key}"], row[f"end_{key}"]
    return "-" if a is None or b is None else f"{b - a:+.2f}"


def markdown(rows: list[dict]) -> str:
    lines = [
        "| run | scene | seed | restoration freeze -> end | change | observable freeze -> end | "
        "T MAE freeze -> end | T MAE at the true depth freeze -> end |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {arm_of(r['run'])} | {r['scene']} | {r['seed']} | {fmt(r['freeze_psnr'], 2)} -> {fmt(r['end_psnr'], 2)} | "
            f"{_change(r, 'psnr')} | {fmt(r['freeze_observable'], 2)} -> {fmt(r['end_observable'], 2)} | "
            f"{fmt(r['freeze_t_mae'], 3)} -> {fmt(r['end_t_mae'], 3)} | "
            f"{fmt(r['freeze_t_mae_true_depth'], 3)} -> {fmt(r['end_t_mae_true_depth'], 3)} |"
        )
    both = [r for r in rows if r["freeze_psnr"] is not None and r["end_psnr"] is not None]
    if both:
        n = len(both)
        a, b = sum(r["freeze_psnr"] for r in both) / n, sum(r["end_psnr"] for r in both) / n
        lines.append(f"| **mean ({n} runs)** | | | {a:.2f} -> {b:.2f} | {b - a:+.2f} | | | |")
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    grouped_bars(
        path,
        [run_label(r) for r in rows],
        [(f"at the {s}", [r[f"{s}_psnr"] or 0.0 for r in rows]) for s in STAGES],
        "restoration PSNR (dB)",
    )


def main() -> None:
    diagnose_runs_main(
        __doc__, diagnose, "Restoration at the freeze and at the end of training (what Stage II does)",
        "`python benchmarks/stage_two_change.py`", markdown, plot, order=lambda r: (r["scene"], -r["seed"]),
    )  # fmt: skip


if __name__ == "__main__":
    main()
