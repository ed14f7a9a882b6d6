"""The executor flags of the sweep commands (td-ablate, td-bench tradeoff): local processes or Ray."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from pipelines.experiments.ray_executor import RayOptions
from pipelines.experiments.sweep import SweepOptions
from tridehaze_plugin.config import Range
from tridehaze_plugin.errors import ConfigError


@dataclass(kw_only=True)
class SweepExecutorArgs:
    """Where a sweep's runs execute (shared by td-ablate and td-bench tradeoff; docs/cluster.md)."""

    executor: Literal["local", "ray"] = "local"
    """``local``: --jobs runs at a time as processes on this machine. ``ray``: one Ray task per run
    (needs ``pip install -e '.[cluster]'``), on the cluster at --ray-address, or without one on an
    embedded single-node Ray on 127.0.0.1 with --jobs x --threads CPUs."""
    ray_address: str | None = None
    """``HOST:PORT`` of a running Ray cluster's head (``ray start --head``); with --executor ray."""
    ray_shared_fs: Literal["auto", "yes", "no"] = "auto"
    """Do workers see --output-dir at the same path? ``auto`` probes it per run (a token file):
    where they do, runs write in place; elsewhere run folders come back through Ray."""
    storage_path: str | None = None
    """Put run folders here instead of OUTPUT_DIR/runs: a path, or a URI pyarrow accepts like Ray's
    storage_path (s3://bucket/prefix, gs://..., file:///...), written by the workers themselves.
    Results, tables and logs stay in --output-dir."""
    keep_checkpoints: bool = False
    """Bring checkpoints back with run folders that travel (they are left out by default)."""
    max_retries: Annotated[int, Range(0, 100)] = 2
    """Retries of a run whose Ray worker or node dies (a retry on the same node resumes from the
    run's last checkpoint)."""
    gpus_per_run: Annotated[float | None, Range(0, 64)] = None
    """GPUs each Ray run asks for (default: 1 where the cluster has GPUs, else 0)."""


def sweep_options(args: SweepExecutorArgs, jobs: int, threads: int) -> SweepOptions:
    """The pipeline-side options; Ray-only flags with the local executor are a mistake, not ignored."""
    if args.executor == "local":
        given = [flag for flag, value, default in (
            ("--ray-address", args.ray_address, None), ("--ray-shared-fs", args.ray_shared_fs, "auto"),
            ("--storage-path", args.storage_path, None), ("--keep-checkpoints", args.keep_checkpoints, False),
            ("--max-retries", args.max_retries, 2), ("--gpus-per-run", args.gpus_per_run, None),
        ) if value != default]  # fmt: skip
        if given:
            raise ConfigError(f"{', '.join(given)} only apply to --executor ray", fix="add --executor ray")
        return SweepOptions()
    if args.ray_address is not None and not args.ray_address.strip():
        raise ConfigError(
            "--ray-address is empty", fix="pass HOST:PORT of the cluster's head, or leave it out"
        )
    return SweepOptions(
        "ray",
        RayOptions(
            address=args.ray_address, shared_fs=args.ray_shared_fs, storage_path=args.storage_path,
            keep_checkpoints=args.keep_checkpoints, max_retries=args.max_retries,
            gpus_per_run=args.gpus_per_run, local_cpus=None if args.ray_address else jobs * threads,
        ),
    )  # fmt: skip
