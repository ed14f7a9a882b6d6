"""``td-ablate``: the paper's ablation families on a list of scenes, in parallel and resumable.

    td-ablate --scenes S1 S2 S3 --max-steps 1500 --output-dir ablation [--families ...] [--jobs 2]

Each (scene, variant) is a ``td-train`` run followed by ``td-eval``; finished runs are skipped,
interrupted ones resumed. Writes ``OUT/ablation.md`` (one paper-shaped table per family plus the
paper's claims checked against our numbers), ``OUT/ablation.csv``, ``OUT/ablation.png`` and
``OUT/ablation.json``. See docs/evaluation.md.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import tyro

from components.data.config import DataConfig
from components.data.loader import load_scene
from pipelines.engine.datamanager import DataManager
from pipelines.engine.image_baselines import baseline_images
from pipelines.engine.metrics import psnr
from pipelines.engine.run_config import write_text_atomic
from pipelines.experiments.ablation import FAMILIES, plan
from pipelines.experiments.runner import AblationRunner, Job, RunnerOptions
from pipelines.experiments.sweep import report_failures, run_sweep
from pipelines.experiments.tables import bar_plot, claims_table, csv_text, markdown_table
from tridehaze_plugin.cli.common import run_cli, split_train_args
from tridehaze_plugin.cli.sweep_args import SweepExecutorArgs, sweep_options
from tridehaze_plugin.config import SEED_RANGE, check_numbers
from tridehaze_plugin.errors import ConfigError


@dataclass
class AblateArgs(SweepExecutorArgs):
    """Run the paper's ablations (medium representation, medium field, schedule, losses, baselines)."""

    scenes: list[Path]
    """Dataset folders (each with haze-free test references for the restoration protocol)."""
    max_steps: int = 1500
    """Training steps of every run (the step budget)."""
    output_dir: Path = Path("ablation")
    """Folder for runs/, results/, logs/ and the table, CSV and plot."""
    families: list[Literal["representation", "field", "schedule", "losses", "baselines"]] = field(
        default_factory=lambda: list(FAMILIES)
    )
    """Which ablation families to run (variants shared between families are trained once)."""
    jobs: int = 2
    """Runs in parallel (separate processes)."""
    threads: int = 1
    """CPU threads per run, torch's and the rasterizer kernel's (jobs x threads should not exceed the
    cores)."""
    seed: Annotated[int, SEED_RANGE] = 42
    """Seed of every run."""
    bins: Literal["auto", "model", "reference", "none"] = "reference"
    """Transmittance for the visibility bins (``reference``: the dataset's own, the same pixels for
    every variant; falls back to none where a scene has no gt_transmittance)."""
    lpips: Literal["auto", "on", "off"] = "auto"
    """LPIPS in td-eval (see td-eval --help)."""
    train_args: str = ""
    """Extra td-train arguments for every run, e.g. "--pipeline.rasterizer.backend torch"."""
    noise_db: float = 0.5
    """Differences of mean PSNR up to this are called ``tie`` when checking the paper's orderings:
    the 3-scene mean PSNR of the full method changed by up to 0.48 dB between seeds 42, 1 and 2
    (1500 steps, docs/evaluation.md)."""
    dry_run: bool = False
    """Print the runs (and which are finished) without running anything."""


def _check(args: AblateArgs) -> None:
    check_numbers(args)
    if not args.scenes:
        raise ConfigError("no scenes given", fix="pass --scenes DIR [DIR ...]")
    names = [p.name for p in args.scenes]
    for p in args.scenes:
        if not p.is_dir():
            raise ConfigError("scene folder not found", where=str(p), fix="pass dataset folders to --scenes")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(f"scene folder names must differ (results are keyed by name): {', '.join(dup)}")
    if args.max_steps < 1:
        raise ConfigError(f"--max-steps must be >= 1, got {args.max_steps}")
    if args.jobs < 1 or args.threads < 1:
        raise ConfigError("--jobs and --threads must be >= 1")
    if not args.families:
        raise ConfigError("no families given", fix=f"choose from {', '.join(FAMILIES)}")


def baseline_psnrs(scene: Path) -> dict[str, float]:
    """Mean PSNR over the test views of each single-image baseline (the hazy photo itself, its
    dark-channel dehazing) against the references: what a scene gives with no 3D at all."""
    sc = load_scene(DataConfig(data=scene))
    dm = DataManager(sc, device="cpu")  # type: ignore[arg-type]
    vals: dict[str, list[float]] = {}
    for i in sc.test_indices:
        ref, hazy = dm.clean_image(i), dm.hazy_image(i)
        if ref is not None and hazy is not None:
            for name, image in baseline_images(hazy).items():
                vals.setdefault(name, []).append(float(psnr(image, ref)))
    return {name: sum(v) / len(v) for name, v in vals.items()}


def scene_baselines(scenes: list[Path]) -> dict[str, dict[str, float]]:
    """Single-image baseline -> scene name -> mean PSNR over its test views."""
    out: dict[str, dict[str, float]] = {}
    for scene in scenes:
        for name, value in baseline_psnrs(scene).items():
            out.setdefault(name, {})[scene.name] = value
    return out


def main(argv: list[str] | None = None) -> None:
    args = tyro.cli(AblateArgs, args=sys.argv[1:] if argv is None else argv, prog="td-ablate")
    _check(args)
    families = list(dict.fromkeys(args.families))
    variants = plan(families)
    sweep = sweep_options(args, args.jobs, args.threads)
    jobs = [Job(scene, v) for scene in args.scenes for v in variants]
    opts = RunnerOptions(
        output_dir=args.output_dir, max_steps=args.max_steps, seed=args.seed, threads=args.threads,
        jobs=args.jobs, bins=args.bins, lpips=args.lpips, extra=split_train_args(args.train_args),
    )  # fmt: skip
    runner = AblationRunner(opts)
    if args.dry_run:
        for job in jobs:
            state = runner.state(job)
            print(
                f"{job.scene.name:>16}  {job.variant.name:<16} {state:<10} td-train {' '.join(job.variant.train_args())}"
            )
        return
    baselines = scene_baselines(args.scenes)
    t0 = time.perf_counter()
    counter = {"n": 0}

    def on_done(job: Job, result: dict, skipped: bool) -> None:
        counter["n"] += 1
        what = "finished earlier" if skipped else f"{result.get('wall_seconds', 0):.0f} s"
        score = result.get("restoration") or {}
        ps = (
            f"{score['psnr']:.2f} dB"
            if score.get("psnr") is not None
            else result.get("why", result["status"])
        )
        print(
            f"[{counter['n']}/{len(jobs)}] {job.scene.name} / {job.variant.name}: {ps} ({what})", flush=True
        )

    where = f"{args.jobs} at a time" if sweep.executor == "local" else "as Ray tasks"
    print(f"{len(jobs)} runs ({len(variants)} variants x {len(args.scenes)} scenes), {where}")
    results = run_sweep(runner, jobs, on_done, sweep, "td-ablate")
    scenes = [s.name for s in args.scenes]
    out = args.output_dir
    md = markdown_table(results, scenes, families, baselines)
    claims_md, claims = claims_table(results, scenes, families, args.noise_db)
    header = (
        f"# Ablation: {len(scenes)} scenes, {args.max_steps} steps per run\n\n"
        f"Restoration PSNR (dB) of the clean render against the haze-free test views; means over scenes.\n\n"
    )
    write_text_atomic(out / "ablation.md", header + md + "\n## The paper's claims\n\n" + claims_md)
    write_text_atomic(out / "ablation.csv", csv_text(results))
    write_text_atomic(
        out / "ablation.json",
        json.dumps({"scenes": scenes, "max_steps": args.max_steps, "baseline_psnr": baselines, "results": results,
                    "claims": claims}, indent=2) + "\n",
    )  # fmt: skip
    bar_plot(results, scenes, families, baselines, out / "ablation.png")
    print(header + md + "\n" + claims_md)
    print(f"wrote {out}/ablation.md, .csv, .json, .png in {time.perf_counter() - t0:.0f} s")
    report_failures(results)


def entrypoint() -> None:
    run_cli(main)


if __name__ == "__main__":
    entrypoint()
