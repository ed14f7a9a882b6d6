"""Runs ablation variants on scenes as ``td-train`` + ``td-eval`` subprocesses, resumably.

Each (scene, variant) trains into ``OUT/runs/<scene>/<method>/<variant>/`` and its numbers land in
``OUT/results/<scene>/<variant>.json`` (written last, atomically): a result file whose signature
(method, overrides, steps, seed, extra arguments, and the fingerprint of the framework's source)
matches is a finished run and is skipped; a run folder with a checkpoint but no result (killed,
Ctrl-C) is continued with ``td-train --resume``. Runs made by other code are run again.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pipelines.engine.checkpoint import latest_checkpoint
from pipelines.engine.run_config import write_text_atomic
from pipelines.experiments.ablation import Variant
from pipelines.experiments.code_version import code_fingerprint

RUNNER_FLAGS = ("--data", "--output-dir", "--timestamp", "--max-steps", "--seed", "--threads")
"""Flags the runner sets itself after a variant's overrides (a variant setting one would be
silently overruled): steps go in ``Variant.max_steps``, the seed in ``RunnerOptions.seed``."""


@dataclass(frozen=True)
class Job:
    scene: Path
    variant: Variant

    def __post_init__(self) -> None:
        taken = [flag for flag in (a.split("=")[0] for a in self.variant.overrides) if flag in RUNNER_FLAGS]
        if taken:
            raise ValueError(
                f"variant {self.variant.name!r}: {', '.join(taken)} in its overrides would be overruled "
                "by the runner; use Variant.max_steps / RunnerOptions (seed, threads) instead"
            )


@dataclass
class RunnerOptions:
    output_dir: Path
    max_steps: int
    seed: int = 42
    threads: int = 1
    jobs: int = 2
    bins: str = "auto"
    lpips: str = "auto"
    extra: tuple[str, ...] = ()
    die_with_parent: bool = False
    """Children get SIGKILL when the process that started them dies (Linux): a sweep worker that a
    cluster kills must not leave a td-train behind that still writes the run folder its retry uses."""


def _die_with_parent() -> None:
    """``preexec_fn``: ask the kernel to kill this child when its parent thread ends (Linux only)."""
    import ctypes

    pr_set_pdeathsig = 1
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(pr_set_pdeathsig, signal.SIGKILL)


class AblationRunner:
    """Trains and evaluates jobs, ``jobs`` at a time; Ctrl-C interrupts children (they checkpoint)."""

    def __init__(self, opts: RunnerOptions) -> None:
        self.opts = opts
        self._procs: set[subprocess.Popen] = set()
        self._lock = threading.Lock()
        self._stopping = False
        self._on_start = None
        self.peak_rss_mb: dict[int, float] = {}
        """Peak resident memory of the current job's processes, per worker thread."""
        self.cpu_seconds: dict[int, float] = {}
        """Per worker thread: CPU time (user + system) of the children of the current job, which
        unlike wall time hardly changes when other work shares the cores."""

    # ------------------------------------------------------------------------------- paths
    def run_dir(self, job: Job) -> Path:
        return self.opts.output_dir / "runs" / job.scene.name / job.variant.method / job.variant.name

    def result_path(self, job: Job) -> Path:
        return self.opts.output_dir / "results" / job.scene.name / f"{job.variant.name}.json"

    def log_path(self, job: Job) -> Path:
        return self.opts.output_dir / "logs" / f"{job.scene.name}__{job.variant.name}.log"

    def steps(self, job: Job) -> int:
        return job.variant.max_steps or self.opts.max_steps

    def signature(self, job: Job) -> dict[str, Any]:
        o = self.opts
        return {
            "scene": str(job.scene.resolve()),
            "method": job.variant.method,
            "overrides": list(job.variant.overrides),
            "max_steps": self.steps(job),
            "seed": o.seed,
            "extra": self.extra_args(job),
            "code": code_fingerprint(),
        }

    def finished(self, job: Job) -> dict[str, Any] | None:
        """The stored result when it exists and was made with the same settings and code, else None."""
        result = _read_json(self.result_path(job))
        return result if result.get("signature") == self.signature(job) else None

    def state(self, job: Job) -> str:
        """``done``, ``other code`` (a stored result of these settings made by other code: it is run
        again) or ``to run``, for dry runs."""
        ours = self.signature(job)
        stored = _read_json(self.result_path(job)).get("signature") or {}
        if stored == ours:
            return "done"
        same_settings = {k: v for k, v in stored.items() if k != "code"} == {
            k: v for k, v in ours.items() if k != "code"
        }
        return "other code" if stored and same_settings else "to run"

    # ------------------------------------------------------------------------------ running
    def _call(self, cmd: list[str], log) -> int:
        env = {**os.environ, "OMP_NUM_THREADS": str(self.opts.threads)}
        log.write(f"$ {' '.join(cmd)}\n")
        log.flush()
        preexec = _die_with_parent if self.opts.die_with_parent and sys.platform == "linux" else None
        proc = subprocess.Popen(
            cmd, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True, preexec_fn=preexec
        )
        with self._lock:
            self._procs.add(proc)
        try:
            try:
                _, status, usage = os.wait4(proc.pid, 0)  # the child's own peak memory, unlike getrusage
            except KeyboardInterrupt:  # a cancelled sweep task: Ctrl-C the child, which checkpoints
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGINT)
                try:
                    proc.wait(timeout=60.0)
                except subprocess.TimeoutExpired:
                    with contextlib.suppress(ProcessLookupError):
                        os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
                raise
            proc.returncode = os.waitstatus_to_exitcode(status)
            me = threading.get_ident()
            self.peak_rss_mb[me] = max(self.peak_rss_mb.get(me, 0.0), usage.ru_maxrss / 1024.0)  # KiB -> MiB
            self.cpu_seconds[me] = self.cpu_seconds.get(me, 0.0) + usage.ru_utime + usage.ru_stime
            return proc.returncode
        finally:
            with self._lock:
                self._procs.discard(proc)

    def run_one(self, job: Job) -> dict[str, Any]:
        rd = self.run_dir(job)
        log_path = self.log_path(job)
        log_path.parent.mkdir(parents=True, exist_ok=True)
        self.peak_rss_mb[threading.get_ident()] = 0.0
        self.cpu_seconds[threading.get_ident()] = 0.0
        out_json = rd / "eval" / "test.json"
        t0 = time.perf_counter()
        with log_path.open("a", encoding="utf-8") as log:
            code = self._call(self._train_command(job, rd), log)
            train_s = time.perf_counter() - t0
            train_cpu = self.cpu_seconds[threading.get_ident()]
            if code != 0 or self._stopping:
                return self._failed(job, f"td-train exited with {code}", log_path)
            o = self.opts
            code = self._call(
                [sys.executable, "-m", "tridehaze_plugin.cli.eval", "--load-config", str(rd / "config.yml"),
                 "--output-path", str(out_json), "--bins", o.bins, "--lpips", o.lpips, "--no-images"],
                log,
            )  # fmt: skip
            if code != 0:
                return self._failed(job, f"td-eval exited with {code}", log_path)
        result = self._result(
            job, rd, json.loads(out_json.read_text()), train_s, time.perf_counter() - t0, train_cpu
        )
        write_text_atomic(self.result_path(job), json.dumps(result, indent=2) + "\n")
        return result

    def _train_command(self, job: Job, rd: Path) -> list[str]:
        """Continue the run folder when it has a checkpoint of the same settings, else start afresh."""
        o, v, steps = self.opts, job.variant, self.steps(job)
        train = [sys.executable, "-m", "tridehaze_plugin.cli.train"]
        if rd.exists() and latest_checkpoint(rd) is not None and self._same_config(job):
            return [*train, "--resume", str(rd), "--max-steps", str(steps)]
        if rd.exists():
            shutil.rmtree(rd)  # ours, unfinished and unusable (no checkpoint or other settings)
        self.state_path(job).parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(self.state_path(job), json.dumps(self.signature(job)))
        return [
            *train, *v.train_args(), "--data", str(job.scene),
            "--output-dir", str(o.output_dir / "runs"), "--timestamp", v.name,
            "--max-steps", str(steps), "--seed", str(o.seed), "--threads", str(o.threads),
            "--no-eval-at-end", "--steps-per-save", str(max(steps // 4, 1)), *self.extra_args(job),
        ]  # fmt: skip

    def extra_args(self, job: Job) -> list[str]:
        """The extra td-train arguments of ``job``, with ``{scene}`` and ``{seed}`` filled in (so one
        sweep can give each run, say, its own checkpoint of an earlier sweep)."""
        return [
            a.replace("{scene}", job.scene.name).replace("{seed}", str(self.opts.seed))
            for a in self.opts.extra
        ]

    def _result(
        self, job: Job, rd: Path, report: dict, train_s: float, wall_s: float, train_cpu: float
    ) -> dict[str, Any]:
        """The result record of a finished run (the table's row): its numbers and how it was made.
        Training time and CPU come from the run (summed over resumes) where it records them, else
        from this call's child process."""
        train_info = _read_json(rd / "eval" / "metrics.json")
        eval_cpu = self.cpu_seconds[threading.get_ident()] - train_cpu
        return {
            "signature": self.launch_signature(job),
            "status": "ok",
            "scene": job.scene.name,
            "variant": job.variant.name,
            "method": job.variant.method,
            "run": str(rd),
            "train_seconds": train_info.get("train_seconds", train_s),
            "wall_seconds": wall_s,
            "gaussians": train_info.get("gaussians"),
            "steps": self.steps(job),
            "peak_rss_mb": self.peak_rss_mb.get(threading.get_ident()),
            "cpu_seconds": train_info.get("cpu_seconds", train_cpu) + eval_cpu,
            "restoration": report.get("restoration"),
            "reconstruction": report.get("reconstruction"),
            "binned": report.get("binned"),
            "medium": report.get("medium"),
            "observable": report.get("observable"),
            "baselines": report.get("baselines"),
        }

    def launch_signature(self, job: Job) -> dict[str, Any]:
        """The settings and code the run folder's training started with (its state file, written at
        a fresh start and matched at each resume), so a result trained before an edit of the code is
        never stored as the edited code's; the current signature where there is no state file."""
        return _read_json(self.state_path(job)) or self.signature(job)

    def state_path(self, job: Job) -> Path:
        """The settings a run folder was started with (kept outside it: td-train makes the folder)."""
        return self.opts.output_dir / "state" / f"{job.scene.name}__{job.variant.name}.json"

    def _same_config(self, job: Job) -> bool:
        """A run folder may be resumed only if it was started with this job's settings."""
        return _read_json(self.state_path(job)) == self.signature(job)

    def _failed(self, job: Job, why: str, log_path: Path) -> dict[str, Any]:
        tail = ""
        if log_path.is_file():
            lines = [ln for ln in log_path.read_text(errors="replace").splitlines() if ln.strip()]
            tail = lines[-1][:300] if lines else ""
        return {"status": "failed", "scene": job.scene.name, "variant": job.variant.name, "why": why,
                "last_line": tail, "log": str(log_path)}  # fmt: skip

    def split_finished(self, jobs: list[Job], on_done) -> tuple[list[dict[str, Any]], list[Job]]:
        """The stored results of finished jobs (``on_done(job, result, True)`` for each) and the rest."""
        results: list[dict[str, Any]] = []
        todo = []
        for job in jobs:
            done = self.finished(job)
            if done is not None:
                results.append(done)
                on_done(job, done, True)
            else:
                todo.append(job)
        return results, todo

    def run(self, jobs: list[Job], on_done, on_start=None) -> list[dict[str, Any]]:
        """Run every unfinished job in local processes; ``on_start(job)`` as each starts,
        ``on_done(job, result, skipped)`` after each."""
        results, todo = self.split_finished(jobs, on_done)
        self._on_start = on_start
        pool = ThreadPoolExecutor(max_workers=max(self.opts.jobs, 1))
        try:
            futures = {pool.submit(self._guarded, job): job for job in todo}
            for fut in as_completed(futures):
                res = fut.result()
                results.append(res)
                on_done(futures[fut], res, False)
        except KeyboardInterrupt:
            self._stopping = True
            self.interrupt()
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        pool.shutdown(wait=True)
        return results

    def _guarded(self, job: Job) -> dict[str, Any]:
        if self._stopping:
            return {"status": "skipped", "scene": job.scene.name, "variant": job.variant.name}
        if self._on_start is not None:
            self._on_start(job)
        return self.run_one(job)

    def interrupt(self) -> None:
        """Ctrl-C for every child: td-train writes a checkpoint, so the next call resumes."""
        with self._lock:
            procs = list(self._procs)
        for p in procs:
            try:
                os.killpg(p.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + 60.0  # the worker threads reap them (os.wait4)
        while time.monotonic() < deadline:
            with self._lock:
                if not self._procs:
                    return
            time.sleep(0.2)
        with self._lock:
            for p in self._procs:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.pid, signal.SIGKILL)


def _read_json(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return {}
