"""Checkpoints: written atomically, read without executing code from the file."""

from __future__ import annotations

import errno
import os
import pickle
import shutil
import tempfile
import zipfile
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from components.data.images import default_file_mode
from tridehaze_plugin.errors import ConfigError, UserError

CHECKPOINT_GLOB = "step-*.ckpt"
ELAPSED_KEYS = ("train_seconds", "cpu_seconds")


@dataclass(frozen=True)
class Elapsed:
    """What training a run has cost so far, carried in its checkpoints so that a run resumed after
    an interruption reports the whole run's cost (work redone after the last checkpoint is not
    counted twice: it is lost with the interrupted process)."""

    train_seconds: float = 0.0
    """Wall time inside the training loop."""
    cpu_seconds: float = 0.0
    """CPU time of the training processes, setup (data, probe) included."""

    def plus(self, train_seconds: float, cpu_seconds: float) -> Elapsed:
        return Elapsed(self.train_seconds + train_seconds, self.cpu_seconds + cpu_seconds)

    def to_dict(self) -> dict[str, float]:
        return {"train_seconds": self.train_seconds, "cpu_seconds": self.cpu_seconds}

    def to_payload(self) -> dict[str, float]:
        return {f"elapsed_{k}": v for k, v in self.to_dict().items()}

    @classmethod
    def from_payload(cls, payload: dict[str, Any]) -> Elapsed:
        """Zero for checkpoints written before the cost was stored."""
        return cls(*(float(payload.get(f"elapsed_{k}", 0.0)) for k in ELAPSED_KEYS))


def checkpoint_path(run_dir: Path, step: int) -> Path:
    return run_dir / "checkpoints" / f"step-{step:07d}.ckpt"


def save_checkpoint(
    path: Path, payload: dict[str, Any], keep: int = 2, protected: Iterable[Path] = ()
) -> Path:
    """Write ``payload`` to ``path`` via a temporary file and rename; keep the newest ``keep`` files
    besides the ``protected`` ones, which are never removed."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".ckpt", dir=path.parent)
    try:
        os.fchmod(fd, default_file_mode())
        with os.fdopen(fd, "wb") as fh:
            torch.save(payload, fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        full = _out_of_space(path.parent, exc)  # before the partial file frees its space again
        Path(tmp).unlink(missing_ok=True)
        if full:
            raise UserError(
                "no space left on the device while writing a checkpoint",
                where=str(path),
                fix="free some space and resume the run (--resume); its earlier checkpoints are intact",
            ) from None
        raise
    if keep > 0:
        kept = {Path(p).name for p in protected}
        rotating = [p for p in sorted(path.parent.glob(CHECKPOINT_GLOB)) if p.name not in kept]
        for old in rotating[:-keep]:
            old.unlink(missing_ok=True)
    for stale in path.parent.glob(".tmp-*.ckpt"):  # left by a process killed mid-write (SIGKILL)
        stale.unlink(missing_ok=True)
    return path


def _out_of_space(folder: Path, exc: BaseException) -> bool:
    """Whether a failed write ran out of disk: torch.save reports that as a RuntimeError about the
    file position, not as ENOSPC, so the free space is looked at too."""
    if isinstance(exc, OSError):
        return exc.errno in (errno.ENOSPC, errno.EDQUOT)
    if not isinstance(exc, RuntimeError):
        return False
    try:
        return shutil.disk_usage(folder).free < 1 << 20
    except OSError:
        return False


def latest_checkpoint(run_dir: Path) -> Path | None:
    found = sorted((run_dir / "checkpoints").glob(CHECKPOINT_GLOB))
    return found[-1] if found else None


def load_checkpoint(path: Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """Load with ``weights_only=True``: tensors and primitives only, no arbitrary objects."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"checkpoint not found: {path}")
    try:
        payload = torch.load(path, map_location=map_location, weights_only=True)
    except (RuntimeError, pickle.UnpicklingError, EOFError, zipfile.BadZipFile, ValueError) as exc:
        first = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
        raise UserError(
            f"checkpoint is corrupt, truncated or not a tridehaze checkpoint ({first})",
            where=str(path),
            fix="use an earlier checkpoint from the same folder or retrain",
        ) from None
    if not isinstance(payload, dict) or "pipeline" not in payload or "step" not in payload:
        raise UserError("file is not a tridehaze checkpoint (missing 'pipeline'/'step')", where=str(path))
    problem = _schema_problem(payload)
    if problem:
        raise UserError(
            f"checkpoint has wrong contents ({problem})",
            where=str(path),
            fix="use an earlier checkpoint from the same folder or retrain",
        )
    return payload


def _schema_problem(payload: dict[str, Any]) -> str | None:
    """What is wrong with a loaded checkpoint's layout (None: nothing): checked before any of it is
    used, so a tampered file gives one line instead of a traceback deep in a model."""
    step = payload["step"]
    if isinstance(step, bool) or not isinstance(step, int) or step < 0:
        return f"step must be a non-negative integer, got {type(step).__name__}"
    state = payload["pipeline"]
    if not isinstance(state, dict) or not all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()
    ):
        return "'pipeline' must map names to tensors"
    bad = [k for k, v in state.items() if v.is_floating_point() and not bool(torch.isfinite(v).all())]
    if bad:
        return f"non-finite values in {', '.join(bad[:3])}"
    if "optimizers" in payload and not isinstance(payload["optimizers"], dict):
        return "'optimizers' must be a mapping"
    for key in (f"elapsed_{k}" for k in ELAPSED_KEYS):
        value = payload.get(key, 0.0)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value < 1e9:
            return f"'{key}' must be a non-negative number of seconds"
    rng = payload.get("torch_rng")
    if rng is not None and not (
        isinstance(rng, torch.Tensor) and rng.dtype == torch.uint8 and rng.dim() == 1
    ):
        return "'torch_rng' must be a 1-D uint8 tensor"
    return None


def state_part(payload: dict[str, Any], prefix: str) -> dict[str, torch.Tensor]:
    """The entries of a checkpoint's pipeline state under ``prefix`` (e.g. ``medium.``), the
    prefix taken off, as one of the pipeline's parts loads them."""
    return {k[len(prefix) :]: v for k, v in payload["pipeline"].items() if k.startswith(prefix)}


def load_part_strictly(
    module: torch.nn.Module, state: dict[str, torch.Tensor], what: str, path: Path, fix: str
) -> None:
    """``module.load_state_dict(state)`` (strict), a mismatch as a ConfigError that says ``what``
    does not fit, with the first line of torch's reason, where (``path``) and ``fix``."""
    try:
        module.load_state_dict(state)
    except RuntimeError as exc:
        first = str(exc).strip().splitlines()[0][:160]
        raise ConfigError(f"{what} ({first})", where=str(path), fix=fix) from None


def load_pipeline_state(pipeline: torch.nn.Module, payload: dict[str, Any], path: Path) -> None:
    """``pipeline.load_state_dict`` with a one-line error when the weights do not fit it."""
    try:
        pipeline.load_state_dict(payload["pipeline"])
    except (RuntimeError, KeyError, ValueError, TypeError) as exc:
        first = str(exc).strip().splitlines()[0][:200]
        raise UserError(f"checkpoint does not match the run's config ({first})", where=str(path)) from None


def load_training_state(optimizers: Any, payload: dict[str, Any], path: Path) -> None:
    """The optimiser state and RNG of a resumed run, with a one-line error when they do not fit."""
    if "optimizers" not in payload:
        raise UserError(
            "checkpoint has no optimiser state, so training cannot resume from it",
            where=str(path),
            fix="it can still be rendered and evaluated; start a new run to train",
        )
    try:
        optimizers.load_state_dict(payload["optimizers"])
        if "torch_rng" in payload:
            torch.set_rng_state(payload["torch_rng"].cpu())
    except (RuntimeError, KeyError, ValueError, TypeError, IndexError, AttributeError) as exc:
        first = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
        raise UserError(
            f"checkpoint's optimiser or RNG state does not fit this run ({first})", where=str(path)
        ) from None
