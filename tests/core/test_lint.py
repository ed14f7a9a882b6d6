"""The tree passes ruff's lint and format checks (``make lint``), so CI, which runs only the test
suite, also catches what they catch (an import-order error once passed it, session 42)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("args", [["check", "."], ["format", "--check", "."]], ids=["check", "format"])
def test_ruff_passes(args):
    done = subprocess.run(
        [sys.executable, "-m", "ruff", *args], cwd=REPO, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, (
        f"ruff {' '.join(args)} failed (run `make lint`):\n{done.stdout}{done.stderr}"
    )
