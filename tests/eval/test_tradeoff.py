"""td-bench tradeoff: the grid, the Pareto front, and a tiny end-to-end sweep."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

from pipelines.experiments.tradeoff import (
    BASE_STEPS,
    COMBOS,
    KNOBS,
    grid,
    pareto_front,
    parse_knobs,
)

ROOT = Path(__file__).resolve().parents[2]


def test_grid_varies_one_knob_at_a_time():
    variants = grid()
    names = [v.name for v in variants]
    assert names[0] == "base" and variants[0].overrides == () and variants[0].max_steps == BASE_STEPS
    assert len(names) == len(set(names)) == 1 + sum(len(k.values) - 1 for k in KNOBS) + 2
    samples = {v.name: v for v in grid(["samples"], combos=False)}
    assert set(samples) == {"base", "samples=4", "samples=8", "samples=32"}
    assert samples["samples=8"].overrides == ("--pipeline.composite.num-samples", "8")
    steps = {v.name: v for v in grid(["steps"], combos=False)}
    assert steps["steps=500"].max_steps == 500 and steps["steps=500"].overrides == ()
    assert {v.name: v.max_steps for v in grid(["steps"], combos=False, base_steps=300)}["steps=3000"] == 600


def test_each_knobs_first_value_is_the_defaults():
    """A knob's first value is left off the command line as the base, so passing it must give
    tri-dehaze's default config; else a variant labelled with it would run the default instead."""
    from tridehaze_plugin.cli.train import parse_args

    default = parse_args(["tri-dehaze"]).pipeline
    checked = 0
    for knob in KNOBS:
        if knob.flag is None or not knob.flag.startswith("--pipeline."):
            continue
        value = knob.values[0]
        if knob.name == "rasterizer" and value == "cpu":
            value = "auto"  # the default, which picks cpu on the CPU machines the bench runs on
        assert parse_args(["tri-dehaze", knob.flag, value]).pipeline == default, knob.name
        checked += 1
    assert checked >= 10


def test_pareto_front():
    pts = [
        {"name": "a", "wall_seconds": 10, "psnr": 15.0},
        {"name": "b", "wall_seconds": 20, "psnr": 18.0},
        {"name": "c", "wall_seconds": 25, "psnr": 17.0},  # slower and worse than b
        {"name": "d", "wall_seconds": 40, "psnr": 18.0},  # as good as b, slower
        {"name": "e", "wall_seconds": 50, "psnr": 19.0},
        {"name": "f", "wall_seconds": None, "psnr": 30.0},  # failed run: not on the front
    ]
    assert pareto_front(pts) == ["a", "b", "e"]
    # a cost-like gain (LPIPS: lower is better) reads the same points the other way round
    lp = [{"name": p["name"], "wall_seconds": p["wall_seconds"], "lpips": -p["psnr"]} for p in pts]
    assert pareto_front(lp, gain="lpips", higher_is_better=False) == ["a", "b", "e"]


def test_td_bench_tradeoff_tiny(eval_scene, tmp_path):
    out = tmp_path / "tt"
    train_args = "--pipeline.warmup-steps 2 --pipeline.model.sh-degree 0"
    r = subprocess.run(
        [sys.executable, "-m", "tridehaze_plugin.cli.bench", "tradeoff", "--scenes", str(eval_scene),
         "--output-dir", str(out), "--knobs", "samples", "--combos", "--base-steps", "3", "--lpips", "off",
         f"--train-args={train_args}"],
        capture_output=True, text=True, cwd=ROOT, env={**os.environ, "OMP_NUM_THREADS": "1"}, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    rows = list(csv.DictReader((out / "tradeoff.csv").open()))
    assert [row["name"] for row in rows] == ["base", "samples=4", "samples=8", "samples=32"]
    for row in rows:
        assert float(row["wall_seconds"]) > 0 and float(row["peak_rss_mb"]) > 50 and float(row["psnr"]) > 5
    assert any(row["pareto"] == "True" for row in rows)
    data = json.loads((out / "tradeoff.json").read_text())
    assert {r["steps"] for r in data["results"]} == {3}  # --base-steps
    assert (out / "tradeoff.png").stat().st_size > 1000 and "Pareto front" in r.stdout


def test_knob_values_can_be_chosen():
    names = [v.name for v in grid(["samples=4,8", "steps=500"], combos=["fast"])]
    assert names == ["base", "steps=500", "samples=4", "samples=8", "fast"]
    for bad in (["samples=5"], ["nope"], ["samples=,"]):
        try:
            parse_knobs(bad)
        except ValueError as e:
            assert "knob" in str(e)
        else:
            raise AssertionError(f"{bad} accepted")


def test_presets_are_the_measured_combinations():
    """The bench measures the registered presets themselves, and every setting a preset changes
    from tri-dehaze is a knob the bench also sweeps alone (so its cost and benefit are measured)."""
    from dataclasses import asdict

    from tridehaze_plugin.registry import REGISTRY, load_all

    load_all()
    base = REGISTRY.get("method", "tri-dehaze").make_config()
    combos = {v.name: v for v in grid([], combos=True, base_steps=BASE_STEPS)}
    knob_fields = {k.flag.removeprefix("--pipeline.").replace("-", "_") for k in KNOBS if k.flag}
    for preset, combo in (("tri-dehaze-fast", "fast"), ("tri-dehaze-quality", "quality")):
        cfg = REGISTRY.get("method", preset).make_config()
        assert COMBOS[combo]().method_name == preset == combos[combo].method
        assert combos[combo].overrides == () and combos[combo].max_steps == cfg.max_steps
        a, b = asdict(base)["pipeline"], asdict(cfg)["pipeline"]
        changed = set()
        for group in a:
            if isinstance(a[group], dict):
                changed |= {f"{group}.{k}" for k in a[group] if a[group][k] != b[group][k]}
            elif a[group] != b[group]:
                changed.add(group)
        assert changed, preset
        assert changed <= knob_fields, (preset, changed - knob_fields)
        assert cfg.max_steps != base.max_steps or preset == "tri-dehaze-quality"


def test_preset_descriptions_point_at_measured_results():
    """Figures in help texts go stale: the speed presets name where their measurements live."""
    import re

    from tridehaze_plugin.registry import REGISTRY, load_all

    load_all()
    table = (ROOT / "docs/results/tradeoff.md").read_text()
    for name, row in (("tri-dehaze-fast", "| fast |"), ("tri-dehaze-quality", "| quality |")):
        text = REGISTRY.get("method", name).description
        assert "docs/results/tradeoff.md" in text, (name, text)
        assert row in table
        assert not re.search(r"\d+(\.\d+)? (s|dB)\b", text), f"{name} quotes a measured figure: {text}"
