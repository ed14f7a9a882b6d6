"""``td-bench probe``: the haze probe on its scene set, its confusion tables and what mistakes cost.

The probe runs on every scene of :mod:`pipelines.experiments.probe_set` (each also with a degraded seed cloud);
tables are split by calibration / held-out part. With restoration results (the runner's JSON per
scene and variant) it adds, per hazy scene, the fast preset against ``tri-dehaze``, and per wrong
verdict its restoration cost: the fast preset with the verdict's medium minus with the right one.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

import torch

from components.data.config import DataConfig
from components.data.loader import load_scene
from pipelines.engine.datamanager import DataManager
from pipelines.experiments.probe_set import ProbeScene, degrade_points
from pipelines.experiments.tables import fmt_number, nested
from pipelines.tridehaze.probe import probe_haze

CLASSES = ("none", "homogeneous", "varying")
VERDICTS = ("none", "homogeneous", "varying", "unsure")
FAST_MAX_GAP_DB = 1.5
"""Issue 17's target: the fast preset's restoration within this of tri-dehaze's..."""
FAST_MAX_TIME_RATIO = 1 / 3
"""...at no more than this share of its CPU time."""


def probe_scene(scene: ProbeScene) -> dict[str, Any]:
    """The probe's verdict and numbers on one scene, with the truth beside them."""
    data = load_scene(DataConfig(data=scene.path))
    points = degrade_points(data.points) if scene.sparse and data.points is not None else data.points
    p = probe_haze(DataManager(data, torch.device("cpu")), data.train_indices, points)
    right = (p.backend == "none") == (scene.truth == "none")
    return {"scene": scene.name, "family": scene.family, "split": scene.split, "truth": scene.truth,
            "sparse": scene.sparse, "points": 0 if points is None else len(points), "backend_right": right,
            **p.to_dict()}  # fmt: skip


def confusion(rows: list[dict[str, Any]]) -> str:
    """Markdown confusion table: true class (rows) by verdict (columns), with the backend's accuracy."""
    lines = [
        "| truth \\ probe | " + " | ".join(VERDICTS) + " | backend right |",
        "|---" * (len(VERDICTS) + 2) + "|",
    ]
    for cls in CLASSES:
        rs = [r for r in rows if r["truth"] == cls]
        if not rs:
            continue
        c = Counter(r["haze"] for r in rs)
        right = sum(r["backend_right"] for r in rs)
        lines.append(f"| {cls} ({len(rs)}) | " + " | ".join(str(c.get(v, 0)) for v in VERDICTS)
                     + f" | {right}/{len(rs)} ({right / len(rs):.0%}) |")  # fmt: skip
    return "\n".join(lines)


def _psnr(results: dict[tuple[str, str], dict], scene: str, variant: str) -> float | None:
    r = results.get((scene, variant))
    return nested(r, "restoration", "psnr") if r and r.get("status") == "ok" else None


def restoration_table(
    rows: list[dict[str, Any]], results: dict[tuple[str, str], dict]
) -> tuple[str, list[dict]]:
    """Per hazy scene: fast preset vs tri-dehaze (PSNR, CPU seconds, their ratio). Rows without both
    runs are listed as pending."""
    out, lines = (
        [],
        [
            "| scene | split | probe | fast dB | tri-dehaze dB | fast - tri-dehaze | CPU s fast / tri-dehaze | time ratio | ok |",
            "|---|---|---|---|---|---|---|---|---|",
        ],
    )
    for r in rows:
        if r["truth"] == "none" or r["sparse"]:
            continue
        fast, full = _psnr(results, r["scene"], "fast"), _psnr(results, r["scene"], "tri-dehaze")
        tf = (results.get((r["scene"], "fast")) or {}).get("cpu_seconds")
        tt = (results.get((r["scene"], "tri-dehaze")) or {}).get("cpu_seconds")
        gap = None if fast is None or full is None else fast - full
        ratio = None if not tf or not tt else tf / tt
        ok = (
            None
            if gap is None or ratio is None
            else (gap >= -FAST_MAX_GAP_DB and ratio <= FAST_MAX_TIME_RATIO)
        )
        out.append({"scene": r["scene"], "split": r["split"], "probe": r["haze"], "fast_psnr": fast,
                    "tri_dehaze_psnr": full, "gap_db": gap, "time_ratio": ratio, "within_target": ok})  # fmt: skip
        lines.append(f"| {r['scene']} | {r['split']} | {r['haze']} | {fmt_number(fast)} | {fmt_number(full)} | {fmt_number(gap)} | "
                     f"{fmt_number(tf, 0)} / {fmt_number(tt, 0)} | {fmt_number(ratio)} | {'pending' if ok is None else ('yes' if ok else 'NO')} |")  # fmt: skip
    return "\n".join(lines), out


def mistake_costs(rows: list[dict[str, Any]], results: dict[tuple[str, str], dict]) -> tuple[str, list[dict]]:
    """Per scene where the verdict's backend is wrong (full seed clouds): restoration PSNR of the fast
    preset with the verdict's medium and with the right one."""
    out, lines = [], ["| scene | truth | probe | with the probe's medium | with the right medium | cost dB |",
                      "|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        if r["backend_right"] or r["sparse"]:
            continue
        right = "fast-none" if r["truth"] == "none" else "fast-triplane"
        got, want = _psnr(results, r["scene"], "fast"), _psnr(results, r["scene"], right)
        cost = None if got is None or want is None else want - got
        out.append({"scene": r["scene"], "truth": r["truth"], "probe": r["haze"], "psnr_probe": got,
                    "psnr_right": want, "cost_db": cost})  # fmt: skip
        lines.append(
            f"| {r['scene']} | {r['truth']} | {r['haze']} | {fmt_number(got)} | {fmt_number(want)} | {fmt_number(cost)} |"
        )
    return "\n".join(lines), out


def load_results(
    results_dir: Path, scenes: list[ProbeScene], variants: list[str]
) -> dict[tuple[str, str], dict]:
    """The runner's finished results (``OUT/results/<scene>/<variant>.json``) that exist."""
    found = {}
    for s in scenes:
        for v in variants:
            path = results_dir / s.path.name / f"{v}.json"
            if path.exists():
                found[s.name, v] = json.loads(path.read_text())
    return found
