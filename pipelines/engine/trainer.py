"""The training engine: run folder, optimisation loop, logging, checkpoints, final evaluation.

It knows only the :class:`~pipelines.engine.contract.Pipeline` contract, never a concrete model.
"""

from __future__ import annotations

import contextlib
import json
import math
import random
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import torch
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

from components.data.loader import load_scene
from pipelines.engine.checkpoint import (
    Elapsed,
    checkpoint_path,
    latest_checkpoint,
    load_checkpoint,
    load_pipeline_state,
    load_training_state,
    save_checkpoint,
)
from pipelines.engine.config import TrainerConfig
from pipelines.engine.contract import Decision, Pipeline, StepResult
from pipelines.engine.datamanager import DataManager
from pipelines.engine.device import resolve_device
from pipelines.engine.early_stop import EarlyStopper, heldout_l1
from pipelines.engine.evaluate import evaluate_split
from pipelines.engine.live_view import LiveView, LiveViewProvider
from pipelines.engine.optimizers import Optimizers
from pipelines.engine.run_config import save_config, write_text_atomic
from pipelines.engine.run_lock import RunLock
from tridehaze_plugin.errors import ConfigError, UserError


@dataclass
class TrainResult:
    run_dir: Path
    steps: int
    seconds: float
    metrics: dict[str, Any]


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def make_run_dir(cfg: TrainerConfig, scene_name: str) -> tuple[Path, Path]:
    """OUTPUT/<scene>/<method>/<timestamp>/, never reusing an existing folder.

    Returns the run folder and the outermost folder this call created (what to remove if the
    start fails)."""
    stamp = cfg.timestamp or datetime.now().strftime("%Y-%m-%d_%H%M%S")
    base = cfg.output_dir / scene_name / cfg.method_name / stamp
    run_dir, n = base, 1
    while run_dir.exists():
        run_dir = base.with_name(f"{stamp}-{n}")
        n += 1
    created = run_dir
    while not created.parent.exists():
        created = created.parent
    try:
        run_dir.mkdir(parents=True)
    except OSError:  # e.g. a name too long: take back the parents this call made
        if created != run_dir:
            shutil.rmtree(created, ignore_errors=True)
        raise
    return run_dir, created


def optimization_step(
    pipeline: Pipeline,
    optimizers: Optimizers,
    step: int,
    accept: Callable[[torch.Tensor], bool] | None = None,
) -> tuple[StepResult, bool]:
    """One training step: loss, backward, hooks and update, in the order every caller needs.

    ``accept(loss)`` returning False (e.g. a non-finite gradient) skips the hooks and the update.
    """
    optimizers.schedule(step, pipeline.lr_scales(step))
    result = pipeline.train_loss(step)
    optimizers.zero_grad()
    if result.loss.requires_grad:  # a step where everything is held (e.g. ``scene-from``) learns nothing
        result.loss.backward()
    if accept is not None and not accept(result.loss):
        return result, False
    pipeline.after_backward(step)
    optimizers.step()
    pipeline.after_optimizer_step(step, optimizers.optimizers)
    return result, True


def scalars(values: dict[str, float | torch.Tensor]) -> dict[str, float]:
    """Floats of a step's diagnostics, with all tensor values read back in one transfer."""
    keys = [k for k, v in values.items() if isinstance(v, torch.Tensor)]
    if not keys:
        return {k: float(v) for k, v in values.items()}
    dev = values[keys[0]].device
    read = torch.stack([values[k].reshape(()).to(dev, torch.float64) for k in keys]).tolist()
    return {k: (read[keys.index(k)] if k in keys else float(v)) for k, v in values.items()}


MAX_BAD_STEPS = 25
"""Consecutive steps with a non-finite loss or gradient after which training stops."""


class TrainingDiverged(UserError):
    pass


class Trainer:
    """Builds the pieces from a config and runs the optimisation loop.

    ``resume``: an existing run folder to continue from its newest checkpoint (same optimizer
    state, stage and RNG state; the view order is a function of (seed, step) alone).
    ``live_view``: what shows the run while it trains (td-train passes the browser viewer).
    """

    def __init__(
        self,
        config: TrainerConfig,
        console: Console | None = None,
        resume: Path | None = None,
        live_view: LiveViewProvider | None = None,
    ) -> None:
        self.config = config
        # soft_wrap: paths and metric lines stay on one line in logs and pipes
        self.console = console or Console(soft_wrap=True)
        self.resume = Path(resume) if resume is not None else None
        self.start_step = 0
        self.spent_before = Elapsed()
        """Training time spent on this run by earlier processes (read from the resumed checkpoint)."""
        self.bad_steps = 0
        self.skipped_steps = 0
        self.live_view = live_view
        self.viewer: LiveView | None = None
        """The live viewer (``--vis``): it renders under ``viewer.lock`` and sees every step via
        ``viewer.update``, which blocks while paused from the browser."""
        self.run_lock: RunLock | None = None
        """Held while this trainer may write its run folder (one writer per run)."""
        self._made_run_dir: Path | None = None

    def setup(self) -> None:
        """Build everything; on failure release the run folder and remove one this call made
        (a start that fails leaves no half-made run folder behind)."""
        try:
            self._setup()
        except BaseException:
            self._release_run()
            if self._made_run_dir is not None:
                shutil.rmtree(self._made_run_dir, ignore_errors=True)
            raise

    def _release_run(self) -> None:
        if self.run_lock is not None:
            self.run_lock.release()
            self.run_lock = None

    def _setup(self) -> None:
        cfg = self.config
        if self.resume is not None:  # before reading its checkpoint: another writer may be mid-save
            self.run_lock = RunLock(self.resume).acquire()
        if self.live_view is not None:
            self.live_view.preflight(cfg)
        if cfg.threads is not None:
            torch.set_num_threads(cfg.threads)
        self.device = resolve_device(cfg.device)
        seed_everything(cfg.seed)
        if cfg.dataset.data is not None:  # config.yml must reload from any working directory
            cfg.dataset.data = cfg.dataset.data.expanduser().resolve()
        scene = load_scene(cfg.dataset)
        if not scene.train_indices:
            raise ConfigError("the dataset has no training views", where=str(scene.root))
        self.datamanager = DataManager(scene, self.device, seed=cfg.seed)
        cfg.pipeline, decisions = cfg.pipeline.resolve(self.datamanager, cfg.seed)
        self.pipeline: Pipeline = cfg.pipeline.setup(self.datamanager, seed=cfg.seed, max_steps=cfg.max_steps)
        if self.resume is not None:
            self.run_dir = self.resume
            self._restore()
        self.optimizers = Optimizers(
            self.pipeline.param_groups(), cfg.optimizer, cfg.max_steps, eps=self.pipeline.adam_eps()
        )
        self.stopper = (
            EarlyStopper(cfg.early_stop, self.datamanager, cfg.max_steps) if cfg.early_stop.enabled else None
        )
        if self.resume is not None:
            load_training_state(self.optimizers, self._payload, self._payload_path)  # optimiser + RNG
            del self._payload
        else:
            self.run_dir, self._made_run_dir = make_run_dir(cfg, scene.name)
            self.run_lock = RunLock(self.run_dir).acquire()
        save_config(cfg, self.run_dir / "config.yml")
        write_text_atomic(
            self.run_dir / "dataparser_transforms.json", json.dumps(scene.transform.to_dict(), indent=2)
        )
        self.console.print(
            f"[bold]{cfg.method_name}[/] on [bold]{scene.name}[/]: {len(scene.train_indices)} train / "
            f"{len(scene.test_indices)} test views, {int(self.pipeline.stats().get('gaussians', 0))} Gaussians, "
            f"device {self.device}, {torch.get_num_threads()} threads"
        )
        if self.pipeline.describe():
            self.console.print(self.pipeline.describe())
        self._log_decisions(self.start_step, decisions)
        self.console.print(f"run folder: {self.run_dir}")
        if self.start_step:
            self.console.print(f"resuming at step {self.start_step}/{cfg.max_steps}")
        if self.live_view is not None:
            self.viewer = self.live_view.start(cfg, self.pipeline, self.datamanager, self.console)
        self._made_run_dir = None  # started: from here on the folder holds a run

    def _restore(self) -> None:
        """Load the newest checkpoint of the run being resumed into the freshly built pipeline."""
        ckpt = latest_checkpoint(self.run_dir)
        if ckpt is None:
            raise UserError(
                "nothing to resume: the run has no checkpoint",
                where=str(self.run_dir / "checkpoints"),
                fix="start a new run instead",
            )
        payload = load_checkpoint(ckpt, map_location=self.device)
        load_pipeline_state(self.pipeline, payload, ckpt)
        self.start_step = payload["step"]
        self.spent_before = Elapsed.from_payload(payload)
        self._payload, self._payload_path = payload, ckpt

    # ------------------------------------------------------------------------------- loop
    def train(self) -> TrainResult:
        if not hasattr(self, "pipeline"):
            self.setup()
        try:
            result = self._train()
            if self.viewer is not None:
                self.viewer.finish()
                if self.config.vis == "viewer" and self.config.viewer.wait_at_end:
                    self.console.print(f"viewer still serving {self.viewer.url}; Ctrl-C to exit")
                    self.viewer.serve_forever()
            return result
        finally:
            if self.viewer is not None:
                self.viewer.close()
            self._release_run()

    def _train(self) -> TrainResult:
        cfg = self.config
        log_path = self.run_dir / "logs" / "metrics.jsonl"
        log_path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = self.viewer.lock if self.viewer is not None else contextlib.nullcontext()
        self._its = 0.0
        self._metrics: dict[str, float] = {}
        self._start = self._last_save = time.perf_counter()
        self._save_interval = 60.0 * cfg.minutes_per_save / 5  # the first soon after the start
        self._milestones = set(self.pipeline.milestone_steps())
        done = self.start_step
        progress = self._progress_bar()
        with progress, log_path.open("a", encoding="utf-8") as log:
            task = progress.add_task(
                "train", total=cfg.max_steps, completed=self.start_step, loss=math.nan, psnr=math.nan, its=0.0
            )
            try:
                for step in range(self.start_step, cfg.max_steps):
                    ok = self._step(step)
                    done = step + 1
                    progress.update(task, advance=1, **(self._bar_fields() if ok else {}))
                    if ok:
                        self._record(done, log)
                    if ok and self._stop_early(done, log):
                        break
                    due = ok and (done % cfg.steps_per_save == 0 or self._save_due())
                    if done == cfg.max_steps or done in self._milestones or due:
                        self.save(done)
            except KeyboardInterrupt:
                progress.stop()
                path = self.save(done)
                self.console.print(
                    f"interrupted at step {done}; checkpoint written to {path}\n"
                    f"continue with: td-train --resume {self.run_dir}"
                )
                raise
        return self._finish(done)

    def _progress_bar(self) -> Progress:
        return Progress(
            TextColumn("[bold]train[/]"),
            BarColumn(),
            TextColumn("step {task.completed}/{task.total}"),
            TextColumn("loss {task.fields[loss]:.4f}"),
            TextColumn("PSNR {task.fields[psnr]:.2f}"),
            TextColumn("{task.fields[its]:.2f} it/s"),
            TimeRemainingColumn(),
            console=self.console,
            disable=not self.console.is_terminal,
        )

    def _step(self, step: int) -> bool:
        """One optimisation step under the viewer's lock; False when it was skipped (non-finite)."""
        t0 = time.perf_counter()
        with self._lock:
            result, ok = optimization_step(self.pipeline, self.optimizers, step, accept=self._finite)
        if not ok:
            self._skip_bad_step(step)
            return False
        self.bad_steps = 0
        self._log_decisions(step + 1)
        dt = time.perf_counter() - t0
        self._its = 1.0 / dt if self._its == 0 else 0.9 * self._its + 0.1 / dt
        self._metrics = scalars({"loss": result.loss.detach(), **result.metrics})
        return True

    def _bar_fields(self) -> dict[str, float]:
        return {"loss": self._metrics["loss"], "psnr": self._metrics.get("psnr", math.nan), "its": self._its}

    def _record(self, done: int, log) -> None:  # noqa: ANN001 - an open text file
        """Show the step in the viewer; every ``steps_per_log`` steps, a metrics row (and a line when
        the console is not a terminal, every tenth of the run)."""
        cfg, stats = self.config, self.pipeline.stats()
        if self.viewer is not None:
            self.viewer.update(done, {**self._metrics, "its": self._its, **stats})
        if done % cfg.steps_per_log != 0 and done != cfg.max_steps:
            return
        row = {
            "step": done,
            "time": self._elapsed().train_seconds,
            "its": self._its,
            **self._metrics,
            **stats,
        }
        log.write(json.dumps(row) + "\n")
        log.flush()
        if not self.console.is_terminal and (
            done % max(cfg.max_steps // 10, 1) == 0 or done == cfg.max_steps
        ):
            self.console.print(
                f"step {done}/{cfg.max_steps}  loss {self._metrics['loss']:.4f}  "
                f"PSNR {self._metrics.get('psnr', math.nan):.2f}  {self._its:.2f} it/s"
            )

    def _stop_early(self, done: int, log) -> bool:  # noqa: ANN001 - an open text file
        """Held-out loss check when due; True (after a checkpoint) when it has plateaued."""
        if self.stopper is None or not self.stopper.due(done) or done >= self.config.max_steps:
            return False
        with self._lock:
            held = heldout_l1(self.pipeline, self.datamanager, self.stopper.views)
        log.write(json.dumps({"step": done, "heldout_l1": held}) + "\n")
        if not self.stopper.update(done, held):
            return False
        self._log_decisions(done, self.stopper.decisions)
        self.save(done)
        return True

    def _finish(self, done: int) -> TrainResult:
        """Final metrics (and the test split's evaluation) into eval/metrics.json and the console."""
        cfg = self.config
        spent = self._elapsed()
        seconds = spent.train_seconds
        final: dict[str, Any] = {**spent.to_dict(), "steps": done, **self.pipeline.stats()}
        if done < cfg.max_steps:
            final["stopped_early_at"] = done
        if self.skipped_steps:
            final["skipped_nonfinite_steps"] = self.skipped_steps
        if self.device.type == "cuda":  # the figure a user sizes a GPU by
            final["peak_gpu_memory_gib"] = torch.cuda.max_memory_allocated(self.device) / 2**30
        final.update({f"train_{k}": v for k, v in self._metrics.items()})
        if cfg.eval_at_end and self.datamanager.test_indices:
            with self._lock:
                final.update(evaluate_split(self.pipeline, self.datamanager, "test"))
        write_text_atomic(self.run_dir / "eval" / "metrics.json", json.dumps(final, indent=2))
        self._print_summary(final)
        return TrainResult(self.run_dir, done, seconds, final)

    def _log_decisions(self, step: int, extra: list[str | Decision] | None = None) -> None:
        """Print the pipeline's own choices (and ``extra`` ones) and append them to
        ``logs/decisions.jsonl``."""
        decisions = self.pipeline.pop_decisions() + list(extra or [])
        if not decisions:
            return
        path = self.run_dir / "logs" / "decisions.jsonl"
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("a", encoding="utf-8") as f:
            for d in decisions:
                record = {"message": d} if isinstance(d, str) else {"message": d.message, **d.data}
                self.console.print(f"[cyan]decision[/]: {record['message']}")
                f.write(json.dumps({"step": step, **record}) + "\n")

    def _finite(self, loss: torch.Tensor) -> bool:
        """Loss and every gradient finite, decided on the device and read back once."""
        flags = [torch.isfinite(loss.detach())]
        flags += [torch.isfinite(p.grad).all() for p in self.pipeline.parameters() if p.grad is not None]
        return bool(torch.stack(flags).all())

    def _skip_bad_step(self, step: int) -> None:
        """Drop a step whose loss or gradient is not finite; stop after too many in a row."""
        self.optimizers.zero_grad()
        self.skipped_steps += 1
        self.bad_steps += 1
        if self.bad_steps >= MAX_BAD_STEPS:
            last = latest_checkpoint(self.run_dir)
            fix = "lower the learning rates or check the data, then "
            fix = (
                f"the last good checkpoint is kept; {fix}resume with td-train --resume RUN"
                if last
                else f"no checkpoint was written before it; {fix}start a new run"
            )
            raise TrainingDiverged(
                f"training diverged: {self.bad_steps} consecutive steps (up to step {step + 1}) had a "
                "non-finite loss or gradient",
                where=str(last) if last else str(self.run_dir),
                fix=fix,
            )

    def _elapsed(self) -> Elapsed:
        """Time spent on the run so far, summed over the processes that trained it (a resumed run
        reports the whole run's cost, not the last leg's)."""
        return self.spent_before.plus(time.perf_counter() - self._start, time.process_time())

    def _save_due(self) -> bool:
        """Whether the time budget since the last checkpoint is spent (``--minutes-per-save``)."""
        return self._save_interval > 0 and time.perf_counter() - self._last_save >= self._save_interval

    def save(self, step: int) -> Path:
        t0 = time.perf_counter()
        payload = {
            "step": step,
            "method": self.config.method_name,
            "pipeline": self.pipeline.state_dict(),
            "optimizers": self.optimizers.state_dict(),
            "torch_rng": torch.get_rng_state(),
            **self._elapsed().to_payload(),
        }
        path = save_checkpoint(
            checkpoint_path(self.run_dir, step),
            payload,
            keep=self.config.checkpoints_to_keep,
            protected=[checkpoint_path(self.run_dir, s) for s in self._milestones],
        )
        self._last_save, self._save_interval = time.perf_counter(), 60.0 * self.config.minutes_per_save
        record = {"step": step, "seconds": round(self._last_save - t0, 4), "bytes": path.stat().st_size}
        (self.run_dir / "logs").mkdir(exist_ok=True)
        with (self.run_dir / "logs" / "checkpoints.jsonl").open("a", encoding="utf-8") as log:
            log.write(json.dumps(record) + "\n")
        return path

    def _print_summary(self, final: dict[str, Any]) -> None:
        shown = {k: v for k, v in final.items() if isinstance(v, (int, float))}
        parts = [f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in shown.items()]
        self.console.print("[bold green]done[/]: " + ", ".join(parts))
        self.console.print(f"outputs: {self.run_dir}")
