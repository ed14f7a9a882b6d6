from __future__ import annotations

from pathlib import Path

import pytest

from components.data.config import DataConfig


@pytest.fixture
def make_cfg(tmp_path: Path):
    """DataConfig factory whose cache lives in this test's tmp_path (never ~/.cache)."""

    def _make(root: Path, **kw) -> DataConfig:
        kw.setdefault("cache_dir", tmp_path / "cache")
        return DataConfig(data=root, **kw)

    return _make
