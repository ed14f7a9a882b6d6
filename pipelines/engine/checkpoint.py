"""Checkpoints: written atomically, read without executing code from the file."""

from __future__ import annotations

import os
import pickle
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import torch

from components.data.images import default_file_mode
from tridehaze_plugin.errors import UserError

CHECKPOINT_GLOB = "step-*.ckpt"


def checkpoint_path(run_dir: Path, step: int) -> Path:
    return run_dir / "checkpoints" / f"step-{step:07d}.ckpt"


def save_checkpoint(path: Path, payload: dict[str, Any], keep: int = 2) -> Path:
    """Write ``payload`` to ``path`` via a temporary file and rename; keep the newest ``keep`` files."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".ckpt", dir=path.parent)
    try:
        os.fchmod(fd, default_file_mode())
        with os.fdopen(fd, "wb") as fh:
            torch.save(payload, fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    if keep > 0:
        for old in sorted(path.parent.glob(CHECKPOINT_GLOB))[:-keep]:
            old.unlink(missing_ok=True)
    for stale in path.parent.glob(".tmp-*.ckpt"):  # left by a process killed mid-write (SIGKILL)
        stale.unlink(missing_ok=True)
    return path


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
    return payload
