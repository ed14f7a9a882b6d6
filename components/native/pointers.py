"""Tensor -> ctypes pointer for the kernels' C entry points (kept apart from ``build``, which must
not import torch)."""

from __future__ import annotations

import ctypes

from torch import Tensor


def tensor_ptr(t: Tensor | None) -> ctypes.c_void_p | None:
    """The tensor's data pointer (NULL for an empty tensor), or None (NULL) for an absent one.
    The caller keeps ``t`` alive until the call returns: a temporary would be freed first."""
    if t is None:
        return None
    return ctypes.c_void_p(t.data_ptr() if t.numel() else 0)
