"""Which runs read their medium's light as one light, and what that did to them.

``tri-dehaze`` raises the dark channel's weight at a quarter of the run where the spread of the
medium's per-ray light is under ``--pipeline.light-isotropy-cv`` (docs/medium.md). This lists,
for trained runs, the spread each one logged (logs/decisions.jsonl), the weight it chose, and its
restoration and T error where td-eval has written them (eval/test.json), and the share of the
verdict window's pixels that rendered as opaque haze (T under ``--pipeline.light-seen-level``;
above ``--pipeline.light-seen-share`` a one-light run keeps the weak weight):

    python benchmarks/light_isotropy_split.py --runs RUN_A/config.yml RUN_B/config.yml --output OUT

Writes OUT.json, OUT.md (one row per run) and OUT.png (the spreads against the threshold).
No model is loaded.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bench_output import diagnose_runs_main  # noqa: E402

from pipelines.engine.run_config import load_config  # noqa: E402
from pipelines.experiments.tables import fmt_number  # noqa: E402
from pipelines.tridehaze.methods import tri_dehaze  # noqa: E402


def diagnose(config: Path) -> dict:
    run_dir = config.parent
    cfg = load_config(config)
    records = []
    log = run_dir / "logs" / "decisions.jsonl"
    if log.is_file():
        records = [r for r in map(json.loads, log.read_text().splitlines()) if "light_cv" in r]
    row = {
        "scene": Path(str(cfg.dataset.data)).name,
        "data": str(Path(str(cfg.dataset.data)).parent.name),
        "run": str(run_dir),
        "seed": cfg.seed,
        "threshold": cfg.pipeline.light_isotropy_cv,
        "light_cv": records[-1]["light_cv"] if records else None,
        "dcp_weight": records[-1]["dcp_weight"] if records else None,
        "seen_level": cfg.pipeline.light_seen_level,
        "seen_share": cfg.pipeline.light_seen_share,
        "opaque_share": records[-1].get(f"opaque_{cfg.pipeline.light_seen_level:g}") if records else None,
        "decision_step": records[-1]["step"] if records else None,
        "restoration_psnr": None,
        "t_mae": None,
    }
    test = run_dir / "eval" / "test.json"
    if test.is_file():
        result = json.loads(test.read_text())
        row["restoration_psnr"] = (result.get("restoration") or {}).get("psnr")
        row["t_mae"] = (result.get("medium") or {}).get("t_mae")
    return row


def table(rows: list[dict]) -> str:
    lines = [
        "| scene | set | seed | light spread (cv) | threshold | opaque share (T under) | seen share | "
        "dark-channel weight | restoration PSNR | T MAE |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        opaque = "-" if r["opaque_share"] is None else f"{r['opaque_share']:.3f} ({r['seen_level']:g})"
        cells = [r["scene"], r["data"], str(r["seed"]), fmt_number(r["light_cv"], 3), fmt_number(r["threshold"], 3),
                 opaque, fmt_number(r["seen_share"], 2),
                 "no decision" if r["dcp_weight"] is None else f"{r['dcp_weight']:g}",
                 fmt_number(r["restoration_psnr"], 2), fmt_number(r["t_mae"], 3)]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = [r for r in rows if r["light_cv"] is not None]
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(max(6, 0.45 * len(shown)), 6.5), sharex=True)
    for x, r in enumerate(shown):
        strong = r["dcp_weight"] is not None and r["dcp_weight"] >= 1.0
        ax.bar(x, r["light_cv"], color="C2" if strong else "C0")
        ax2.bar(x, r["opaque_share"] or 0.0, color="C2" if strong else "C0")
    for t in sorted({r["threshold"] for r in shown}):
        ax.axhline(t, color="k", ls="--", lw=0.8)
    preset = tri_dehaze().pipeline.light_seen_share
    if preset < 1.0:  # 1.0: the preset never gates (session 41)
        ax2.axhline(preset, color="k", ls="--", lw=0.8)
    for t in sorted({r["seen_share"] for r in shown if r["seen_share"] is not None} - {preset, 1.0}):
        ax2.axhline(t, color="0.5", ls=":", lw=0.8)
    ax2.set_xticks(range(len(shown)), [f"{r['data']}/{r['scene']} s{r['seed']}" for r in shown], fontsize=6, rotation=60,
                   ha="right")  # fmt: skip
    ax.set_ylabel("spread of the medium's per-ray light (cv)", fontsize=8)
    ax2.set_ylabel("share of pixels behind opaque haze", fontsize=8)
    ax.set_title("green: dark-channel weight raised; blue: kept; dashed: tri-dehaze's thresholds (dotted: a run's "
                 "own seen share)", fontsize=8)  # fmt: skip
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    diagnose_runs_main(
        __doc__,
        diagnose,
        "The medium's light: one light or not, per run",
        "`python benchmarks/light_isotropy_split.py --runs RUN/config.yml ... --output OUT`",
        table,
        plot,
        order=lambda r: (r["light_cv"] is None, r["light_cv"] or 0.0),
    )
