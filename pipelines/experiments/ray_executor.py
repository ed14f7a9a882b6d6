"""Sweeps on a Ray cluster: every (scene, variant) run is one Ray task.

A task runs the same ``td-train`` + ``td-eval`` pair as a local sweep (:class:`AblationRunner`),
on whichever node Ray gives it, with ``threads`` CPUs (and a GPU where the cluster has them).
Where the head's output folder is visible to the worker at the same path (a shared file system,
probed with a token file), the run writes in place. Otherwise the worker trains in a scratch
folder, and the run folder (checkpoints only on request) comes back through Ray's object store, or
goes straight to a storage path; scenes a worker lacks travel to it the same way. Ray retries a
task whose worker or node dies (``max_retries``); a retry on the same node resumes from the run's
last checkpoint, which stays in that node's scratch folder.

Plain Ray tasks, not Ray Tune: a sweep point is a whole subprocess run whose result file is the
bookkeeping (finished runs are skipped on a rerun, as locally), and the trade-off grid needs every
point's time and quality, so stopping "hopeless" configurations early would remove the very
measurements the Pareto front is made of. Tune would add its trial store and pyarrow/pandas on
every node for nothing the runner does not already do.

Ray is optional (``pip install -e '.[cluster]'``): it is imported only when a sweep asks for it.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import secrets
import shutil
import socket
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

from pipelines.engine.run_config import write_text_atomic
from pipelines.experiments.run_archive import (
    copy_to_storage,
    folder_fingerprint,
    pack_folder,
    run_folder_filter,
    unpack_folder,
)
from pipelines.experiments.runner import AblationRunner, Job
from tridehaze_plugin.errors import ConfigError

TOKEN_FILE = ".td-sweep-token"
"""File in the head's output folder whose content a worker compares to tell a shared file system."""
SCRATCH_ENV = "TD_SWEEP_SCRATCH"
"""Where workers keep scratch run folders and scene copies (default: the system's temp folder)."""


@dataclass(frozen=True)
class RayOptions:
    """How a sweep uses Ray (the ``--ray-*`` flags of td-ablate and td-bench tradeoff)."""

    address: str | None = None
    """A running cluster (``HOST:PORT`` of its head); None: an embedded single-node Ray on 127.0.0.1."""
    shared_fs: Literal["auto", "yes", "no"] = "auto"
    """Whether workers see the head's output folder: probed per task (auto), assumed, or ruled out."""
    storage_path: str | None = None
    """Run folders go here (a path or a pyarrow URI such as s3://bucket/sweeps) instead of OUT/runs."""
    keep_checkpoints: bool = False
    """Return the run folders' checkpoints too (without a shared file system)."""
    max_retries: int = 2
    """Retries of a run whose worker process or node dies."""
    gpus_per_run: float | None = None
    """GPUs per run; None: 1 where the cluster has GPUs, else 0."""
    local_cpus: int | None = None
    """CPUs of the embedded Ray (None: all); ignored with an address."""


@dataclass(frozen=True)
class TaskPlan:
    """What every task of one sweep needs besides its job."""

    head_output_dir: str
    token: str | None
    shared_fs: str
    storage_path: str | None
    keep_checkpoints: bool
    scratch_key: str


def job_key(job: Job) -> str:
    return f"{job.scene.name}/{job.variant.name}"


def scratch_root() -> Path:
    return Path(os.environ.get(SCRATCH_ENV) or tempfile.gettempdir()) / "tridehaze-sweep"


# ----------------------------------------------------------------------------------------- workers
class SweepBoard:
    """A tiny actor on the cluster where tasks say when (and where) each attempt starts: the head's
    progress line counts running runs from it, and a key started twice was retried."""

    def __init__(self) -> None:
        self.starts: dict[str, list[dict[str, Any]]] = {}

    def started(self, key: str, node: str, pid: int) -> None:
        self.starts.setdefault(key, []).append({"node": node, "pid": pid, "time": time.time()})

    def snapshot(self) -> dict[str, list[dict[str, Any]]]:
        return self.starts


_FINGERPRINTS: dict[str, str] = {}


def _sees_head_folder(plan: TaskPlan) -> bool:
    if plan.shared_fs != "auto":
        return plan.shared_fs == "yes"
    try:
        return (Path(plan.head_output_dir) / TOKEN_FILE).read_text() == plan.token
    except OSError:
        return False


def _local_scene(scene: Path, fingerprint: str, archive: bytes | None, trust_path: bool) -> Path:
    """The scene at the head's path when this node has that very dataset there, else a copy
    unpacked from the object store (once per node)."""
    if trust_path:
        return scene
    if scene.is_dir():
        key = str(scene.resolve())
        if key not in _FINGERPRINTS:
            _FINGERPRINTS[key] = folder_fingerprint(scene)
        if _FINGERPRINTS[key] == fingerprint:
            return scene
    dest = scratch_root() / "scenes" / fingerprint / scene.name
    if not dest.is_dir() and archive is not None:
        with contextlib.suppress(FileExistsError, OSError):  # another task on this node unpacked it
            unpack_folder(archive, dest, replace=False)
    if not dest.is_dir():
        raise RuntimeError(f"could not unpack scene {scene.name} into {dest}")
    return dest


def run_task(
    job: Job, opts, plan: TaskPlan, fingerprint: str, archive: bytes | None, board
) -> dict[str, Any]:
    """One run on a worker (a Ray task): train + evaluate, then hand the run back to the head.

    Never ``ray.get`` in here: a task blocked in ``ray.get`` lends its CPUs to the next task, which
    then runs beside it (two trainings on one CPU). The scene archive is therefore an argument
    (Ray fetches it before the task starts) and the start notice is sent without waiting."""
    import ray

    node = ray.util.get_node_ip_address()
    board.started.remote(job_key(job), node, os.getpid())
    shared = _sees_head_folder(plan)
    scene = _local_scene(job.scene, fingerprint, archive, trust_path=plan.shared_fs == "yes")
    workdir = Path(plan.head_output_dir) if shared else scratch_root() / "runs" / plan.scratch_key
    runner = AblationRunner(replace(opts, output_dir=workdir, jobs=1, die_with_parent=True))
    local_job = Job(scene, job.variant)
    result = runner.run_one(local_job)
    out: dict[str, Any] = {
        "result": result,
        "node": node,
        "shared": shared,
        "archive": None,
        "stored_at": None,
        "scene_used": str(scene),
    }
    log = runner.log_path(local_job)
    out["log"] = None if shared or not log.is_file() else log.read_text(errors="replace")
    if result.get("status") == "ok":
        rd = runner.run_dir(local_job)
        keep = run_folder_filter(plan.keep_checkpoints)
        rel = rd.relative_to(workdir / "runs").as_posix()
        if plan.storage_path:
            out["stored_at"] = copy_to_storage(rd, plan.storage_path, rel, keep)
        elif not shared:
            out["archive"] = pack_folder(rd, keep)
        if not shared:  # the scratch copy was only kept for a retry on this node to resume
            shutil.rmtree(rd, ignore_errors=True)
    return out


# -------------------------------------------------------------------------------------------- head
def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """A ``HOST:PORT`` nobody listens on fails in seconds (``ray.init`` would retry for minutes)."""
    host, _, port = address.rpartition(":")
    if "://" in address or not host or not port.isdigit():
        return  # "auto", ray:// client addresses: Ray's own resolution and errors
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as e:
        raise ConfigError(
            f"cannot connect to the Ray cluster ({e.strerror or e})", where=address,
            fix="start it with `ray start --head --port PORT`, then pass --ray-address HOST:PORT",
        ) from None  # fmt: skip


def _point_config_at(config: Path, scene: Path) -> None:
    """A run trained on a worker's copy of the scene: its config names the head's dataset instead,
    so ``td-eval`` / ``td-render --load-config`` work on the landed run (with --keep-checkpoints)."""
    import yaml

    if not config.is_file():
        return
    cfg = yaml.safe_load(config.read_text())
    if isinstance(cfg, dict) and isinstance(cfg.get("dataset"), dict):
        cfg["dataset"]["data"] = str(scene)
        write_text_atomic(config, yaml.safe_dump(cfg, sort_keys=False))


class RayExecutor:
    """Runs a sweep's unfinished jobs as Ray tasks and lands their results like a local sweep."""

    def __init__(self, runner: AblationRunner, opts: RayOptions) -> None:
        self.runner = runner
        self.opts = opts
        self.attempts: dict[str, int] = {}
        self.submitted: dict[str, dict[str, Any]] = {}  # job key -> its signature when submitted

    def _init_ray(self):
        # no usage statistics leave the machine; an embedded Ray binds to 127.0.0.1 only (Ray maps
        # 127.0.0.1 to the host's outward address while multi-node mode is on: off for one node)
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
        if self.opts.address is None:
            os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
        try:
            import ray
        except ImportError:
            raise ConfigError(
                "--executor ray needs Ray, which is not installed", fix="pip install -e '.[cluster]'"
            ) from None
        kw: dict[str, Any] = {"log_to_driver": False, "logging_level": "WARNING", "configure_logging": True}
        if self.opts.address is None:
            ray.init(num_cpus=self.opts.local_cpus, include_dashboard=False, **kw)
        else:
            _check_reachable(self.opts.address)
            try:
                ray.init(address=self.opts.address, **kw)
            except (ConnectionError, RuntimeError, ValueError) as e:
                raise ConfigError(
                    f"cannot connect to the Ray cluster ({e})", where=self.opts.address,
                    fix="start it with `ray start --head --port PORT`, then pass --ray-address HOST:PORT",
                ) from None  # fmt: skip
        return ray

    def _resources(self, ray) -> tuple[float, float]:
        cpus = float(self.runner.opts.threads)
        nodes = [n.get("Resources", {}) for n in ray.nodes() if n.get("Alive")]
        most = max((n.get("CPU", 0.0) for n in nodes), default=0.0)
        if most < cpus:
            raise ConfigError(
                f"no node of the Ray cluster has {cpus:g} CPUs for one run (the largest has {most:g})",
                fix="lower --threads, or add CPUs to the cluster",
            )
        gpus = self.opts.gpus_per_run
        if gpus is None:
            gpus = 1.0 if any(n.get("GPU", 0.0) >= 1 for n in nodes) else 0.0
        return cpus, gpus

    def _plan(self) -> TaskPlan:
        out = self.runner.opts.output_dir.resolve()
        out.mkdir(parents=True, exist_ok=True)
        token = None
        if self.opts.shared_fs == "auto":
            token = secrets.token_hex(16)
            write_text_atomic(out / TOKEN_FILE, token)
        key = hashlib.sha256(f"{socket.gethostname()}:{out}".encode()).hexdigest()[:16]
        return TaskPlan(str(out), token, self.opts.shared_fs, self.opts.storage_path,
                        self.opts.keep_checkpoints, key)  # fmt: skip

    def run(self, jobs: list[Job], on_done, on_start=None) -> list[dict[str, Any]]:
        """Like :meth:`AblationRunner.run`, on the cluster."""
        results, todo = self.runner.split_finished(jobs, on_done)
        if not todo:
            return results
        ray = self._init_ray()
        try:
            return results + self._run(ray, todo, on_done, on_start)
        finally:
            ray.shutdown()

    def _run(self, ray, todo: list[Job], on_done, on_start) -> list[dict[str, Any]]:
        cpus, gpus = self._resources(ray)
        plan = self._plan()
        opts = replace(self.runner.opts, output_dir=Path(plan.head_output_dir))
        scenes: dict[Path, tuple[str, Any]] = {}
        for job in todo:
            if job.scene not in scenes:  # one copy in the object store per scene, not per run
                ship = None if self.opts.shared_fs == "yes" else ray.put(pack_folder(job.scene))
                scenes[job.scene] = (folder_fingerprint(job.scene), ship)
        board = ray.remote(SweepBoard).options(num_cpus=0).remote()
        # the board must be up before any task starts: a start notice sent to an actor that is
        # still being created waits in the sender's worker and dies with it, so a first attempt
        # killed early went unrecorded and its retry counted as attempt 1
        ray.get(board.snapshot.remote())
        task = ray.remote(run_task)
        refs = {}
        for job in todo:
            fp, box = scenes[job.scene]
            ref = task.options(
                num_cpus=cpus, num_gpus=gpus, max_retries=self.opts.max_retries, retry_exceptions=False,
                name=f"td-run {job_key(job)}",
            ).remote(job, opts, plan, fp, box, board)  # fmt: skip
            refs[ref] = job
            self.submitted[job_key(job)] = self.runner.signature(job)  # the code it was sent with
        results: list[dict[str, Any]] = []
        pending = list(refs)
        try:
            while pending:
                ready, pending = ray.wait(pending, num_returns=1, timeout=1.0)
                self._note_starts(ray, board, on_start, refs)
                for ref in ready:
                    job = refs[ref]
                    res = self._land(ray, ref, job)
                    results.append(res)
                    on_done(job, res, False)
        except KeyboardInterrupt:
            # force: a polite cancel does not reach a task waiting on its td-train. The worker dies,
            # its td-train with it (PDEATHSIG); a rerun resumes from the run's last periodic checkpoint
            for ref in pending:
                with contextlib.suppress(Exception):
                    ray.cancel(ref, force=True)
            raise
        return results

    def _note_starts(self, ray, board, on_start, refs) -> None:
        starts = ray.get(board.snapshot.remote())
        keys = {job_key(j): j for j in refs.values()}
        for key, attempts in starts.items():
            if len(attempts) > self.attempts.get(key, 0):
                self.attempts[key] = len(attempts)
                if on_start is not None and key in keys:
                    on_start(keys[key])

    def _land(self, ray, ref, job: Job) -> dict[str, Any]:
        """The task's result, written to the head's output folder as a local run would be."""
        import ray.exceptions as rex

        runner, key = self.runner, job_key(job)
        try:
            out = ray.get(ref)
        except rex.RayTaskError as e:  # our code raised on the worker: not retried (it would again)
            return self._failure(job, f"the run's task raised {type(e.cause).__name__}: {e.cause}")
        except rex.RayError as e:  # the worker or its node died on every attempt
            n = self.attempts.get(key, 0)
            return self._failure(
                job, f"{type(e).__name__} after {n} attempt(s): {str(e).splitlines()[0][:200]}"
            )
        result = out["result"]
        result["attempts"] = max(self.attempts.get(key, 1), 1)
        result["node"] = out["node"]
        if out["log"] is not None:
            write_text_atomic(runner.log_path(job), out["log"])
            if "log" in result:
                result["log"] = str(runner.log_path(job))
        if result.get("status") != "ok":
            return result
        result["signature"] = self.submitted.get(key) or runner.signature(job)
        if out["stored_at"] is not None:
            result["run"] = out["stored_at"]
        elif out["archive"] is not None:
            rd = unpack_folder(out["archive"], runner.run_dir(job))
            result["run"] = str(rd)
            if out["scene_used"] != str(job.scene):
                _point_config_at(rd / "config.yml", job.scene)
        write_text_atomic(runner.result_path(job), json.dumps(result, indent=2) + "\n")
        return result

    def _failure(self, job: Job, why: str) -> dict[str, Any]:
        return {"status": "failed", "scene": job.scene.name, "variant": job.variant.name, "why": why,
                "attempts": self.attempts.get(job_key(job), 0), "log": str(self.runner.log_path(job))}  # fmt: skip
