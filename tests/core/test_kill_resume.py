"""A run killed with SIGKILL at random moments always leaves a loadable checkpoint and resumes to
completion (checkpoints are written to a temporary file and renamed)."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time

import pytest

from pipelines.engine.checkpoint import latest_checkpoint, load_checkpoint
from tests.tiny_scenes import tiny_hazy_scene

STEPS = 60


def _cmd(*args: str) -> list[str]:
    return [sys.executable, "-c", "from tridehaze_plugin.cli.train import entrypoint; entrypoint()", *args]


@pytest.mark.skipif(os.name != "posix", reason="SIGKILL is POSIX")
def test_sigkill_at_random_points_then_resume(tmp_path):
    scene = tiny_hazy_scene(
        tmp_path / "scene",
        layout="room",
        haze="homogeneous",
        seed=5,
        num_views=4,
        num_points=150,
        test_every=0,
    )
    out = tmp_path / "out"
    args = [
        "tri-dehaze", "--data", str(scene), "--output-dir", str(out), "--timestamp", "run",
        "--max-steps", str(STEPS), "--steps-per-save", "1", "--threads", "1", "--no-eval-at-end",
        "--pipeline.rasterizer.backend", "torch", "--pipeline.depth-prior", "sfm",
    ]  # fmt: skip
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    run_dir = out / "scene" / "tri-dehaze" / "run"
    rng = random.Random(7)
    steps_seen = []
    cmd = _cmd(*args)
    for _attempt in range(3):
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
        # wait until training has written at least one new checkpoint, then kill at a random moment
        start = time.time()
        base = steps_seen[-1] if steps_seen else 0
        while time.time() - start < 120 and proc.poll() is None:
            ckpt = latest_checkpoint(run_dir) if run_dir.exists() else None
            if ckpt is not None and int(ckpt.stem.split("-")[1]) > base:
                break
            time.sleep(0.05)
        time.sleep(rng.uniform(0.0, 0.4))
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        ckpt = latest_checkpoint(run_dir)
        assert ckpt is not None
        payload = load_checkpoint(ckpt)  # never truncated: atomic rename
        steps_seen.append(int(payload["step"]))
        cmd = _cmd("--resume", str(run_dir))
    assert steps_seen == sorted(steps_seen) and steps_seen[0] > 0
    done = subprocess.run(
        _cmd("--resume", str(run_dir)), capture_output=True, text=True, env=env, timeout=300
    )
    assert done.returncode == 0, done.stderr[-1500:]
    assert load_checkpoint(latest_checkpoint(run_dir))["step"] == STEPS
    assert json.loads((run_dir / "eval" / "metrics.json").read_text())["steps"] == STEPS
    assert not list(run_dir.glob("checkpoints/.tmp-*"))  # stale temporaries cleaned up
