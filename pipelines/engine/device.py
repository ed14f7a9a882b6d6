"""The one place a ``--device`` value becomes a torch device."""

from __future__ import annotations

import re

import torch

from tridehaze_plugin.cuda_probe import cuda_status
from tridehaze_plugin.errors import ConfigError


def check_device_name(name: str, flag: str = "--device") -> None:
    """Reject anything but auto, cpu, cuda and cuda:N (right after parsing, before any work)."""
    if name not in ("auto", "cpu") and not re.fullmatch(r"cuda(:\d+)?", name):
        raise ConfigError(f"{flag} must be auto, cpu, cuda or cuda:N, got {name!r}")


def resolve_device(name: str, flag: str = "--device", cuda_available: bool | None = None) -> torch.device:
    """``auto`` -> cuda when available, else cpu; CUDA asked for without a GPU is a ConfigError (not a
    confusing failure later, e.g. while loading a checkpoint)."""
    check_device_name(name, flag)
    cuda, failure = cuda_status() if cuda_available is None else (cuda_available, None)
    if name == "auto":
        return torch.device("cuda" if cuda else "cpu")
    if name.startswith("cuda") and not cuda:
        why = f" (CUDA failed to start: {failure})" if failure else ""
        raise ConfigError(
            f"{flag} {name} was asked for but CUDA is not available{why}", fix=f"use {flag} cpu"
        )
    return torch.device(name)
