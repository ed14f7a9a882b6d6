"""Where a sweep's runs execute: local processes (default) or a Ray cluster, with one progress line.

td-ablate and td-bench tradeoff build their jobs and tables the same way either way; only
:func:`run_sweep` knows the executors.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Any, Literal

from pipelines.experiments.ray_executor import RayExecutor, RayOptions, job_key
from pipelines.experiments.runner import AblationRunner, Job
from pipelines.experiments.sweep_progress import SweepProgress


@dataclass(frozen=True)
class SweepOptions:
    executor: Literal["local", "ray"] = "local"
    """``local``: ``jobs`` runs at a time in processes on this machine; ``ray``: one Ray task per run."""
    ray: RayOptions = field(default_factory=RayOptions)
    """Ray settings (used with ``executor="ray"``)."""


def run_sweep(
    runner: AblationRunner, jobs: list[Job], on_done, options: SweepOptions, label: str = "sweep"
) -> list[dict[str, Any]]:
    """Run the unfinished jobs (finished ones are skipped) and return every job's result;
    ``on_done(job, result, skipped)`` after each, while one live line shows the sweep's state."""
    with SweepProgress(len(jobs), label) as progress:

        def done(job: Job, result: dict[str, Any], skipped: bool) -> None:
            if skipped:
                progress.skip()
            else:
                progress.finished(job_key(job), result.get("status") == "ok")
            on_done(job, result, skipped)

        def started(job: Job) -> None:
            progress.started(job_key(job))

        if options.executor == "ray":
            return RayExecutor(runner, options.ray).run(jobs, done, started)
        return runner.run(jobs, done, started)


def report_failures(results: list[dict[str, Any]]) -> None:
    """Name the retried runs (stdout) and the failed ones with why (stderr, then exit 1): the table
    above is complete except for the failed runs."""
    for r in results:
        if r.get("status") == "ok" and (r.get("attempts") or 1) > 1:
            print(
                f"retried: {r['scene']} / {r['variant']}: ok after {r['attempts']} attempts (node {r.get('node')})"
            )
    failed = [r for r in results if r.get("status") != "ok"]
    for r in failed:
        print(f"failed: {r['scene']} / {r['variant']}: {r.get('why')} ({r.get('log')})", file=sys.stderr)
    if failed:
        raise SystemExit(1)
