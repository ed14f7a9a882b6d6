"""Running a ``benchmarks/`` diagnosis of trained runs (``--runs ... --output STEM``) in a test."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType

REPO = Path(__file__).resolve().parents[2]


def run_diagnosis(script: str, configs: list[Path], out: Path) -> dict:
    """Run ``benchmarks/<script>`` on the runs' config.yml files; its first row (the JSON's rows
    carry ``scene``). Fails the test with the script's stderr when it exits non-zero."""
    cmd = [
        sys.executable,
        str(REPO / "benchmarks" / script),
        "--runs",
        *map(str, configs),
        "--output",
        str(out),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return next(r for r in json.loads(out.with_suffix(".json").read_text()) if "scene" in r)


def load_benchmark(monkeypatch, name: str) -> ModuleType:
    """Import ``benchmarks/<name>.py`` (its sibling modules on the path for this test only)."""
    monkeypatch.syspath_prepend(str(REPO / "benchmarks"))
    spec = importlib.util.spec_from_file_location(name, REPO / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
