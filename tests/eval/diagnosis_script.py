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
    """Import ``benchmarks/<name>.py`` (its sibling modules on the path for this test only). The
    module is in ``sys.modules`` while it runs, as an import puts it: its dataclasses resolve their
    string annotations there (it passed only where an earlier test had imported the module)."""
    monkeypatch.syspath_prepend(str(REPO / "benchmarks"))
    spec = importlib.util.spec_from_file_location(name, REPO / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, name, mod)
    spec.loader.exec_module(mod)
    return mod


def tiny_field_run(tmp_path: Path) -> tuple[Path, Path, float]:
    """A tiny generated field under height fog (sky and ground in every view), a 4-step run on it,
    and its test views' true sky share (true depth at 0.75 of the far bound or beyond)."""
    import numpy as np

    from tests.export.tiny_run import train_tiny
    from tests.tiny_scenes import tiny_hazy_scene

    scene = tiny_hazy_scene(
        tmp_path / "scene", layout="field", haze="height", seed=2, num_views=6, width=40, height=30,
        samples=16, num_points=300, test_every=3,
    )  # fmt: skip
    config = train_tiny(scene, tmp_path / "runs", "--device", "cpu", steps=4)
    meta = json.loads((scene / "synth_meta.json").read_text())
    frames = json.loads((scene / "transforms.json").read_text())
    test = [f for f in frames["frames"] if f["file_path"] in frames["test_filenames"]]
    depth = np.stack([np.load(scene / f["gt_depth_file_path"]) for f in test])
    return scene, config, float((depth >= 0.75 * meta["far_bound_m"]).mean())
