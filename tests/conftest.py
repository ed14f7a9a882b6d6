"""Suite-wide test settings."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("TRIDEHAZE_SHARED", REPO.parent / "shared"))
"""The team's shared folder (real scenes); CI clones the repo with ``shared/`` beside it."""
REAL_DATA = SHARED / "data" / "real"


def require_real(scene: str) -> Path:
    """Path of a real scene; skipped locally when absent, but a failure in CI (it must be there)."""
    path = REAL_DATA / scene
    if not path.is_dir():
        if os.environ.get("CI"):
            pytest.fail(f"real scene {path} is missing in CI (expected ../shared beside the clone)")
        pytest.skip(f"real scene {path} not available")
    return path
