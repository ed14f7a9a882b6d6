"""One writer per run folder (issue 22): a second td-train on a run that is being written is refused
with one clear line; a lock left by a killed process does not block a later resume; a start that
fails leaves no half-made run folder."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from rich.console import Console

from pipelines.engine.checkpoint import latest_checkpoint, load_checkpoint
from pipelines.engine.trainer import Trainer
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.train import parse_args
from tridehaze_plugin.errors import UserError

BUSY = "another td-train process is writing this run folder"


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return tiny_hazy_scene(
        tmp_path_factory.mktemp("lock") / "scene", layout="room", haze="homogeneous", seed=4
    )


def _cfg(scene: Path, out: Path, steps: int = 4, *extra: str):
    return parse_args([
        "tri-dehaze", "--data", str(scene), "--output-dir", str(out), "--max-steps", str(steps),
        "--steps-per-save", "2", "--pipeline.rasterizer.backend", "torch", "--no-eval-at-end",
        "--threads", "1", "--device", "cpu", *extra,
    ])  # fmt: skip


def _trainer(cfg, resume=None) -> Trainer:
    return Trainer(cfg, console=Console(quiet=True), resume=resume)


def test_a_second_writer_is_refused_and_the_first_finishes(scene, tmp_path):
    first = _trainer(_cfg(scene, tmp_path, 4))
    first.setup()  # a run in progress: holds its folder
    run = first.run_dir
    with pytest.raises(UserError, match=BUSY):
        _trainer(_cfg(scene, tmp_path, 6), resume=run).setup()  # td-train --resume while it trains
    first.train()
    assert load_checkpoint(latest_checkpoint(run))["step"] == 4  # the refused resume broke nothing
    again = _trainer(_cfg(scene, tmp_path, 6), resume=run)  # finished: the folder is free again
    again.train()
    assert load_checkpoint(latest_checkpoint(run))["step"] == 6
    steps = [line for line in (run / "logs" / "metrics.jsonl").read_text().splitlines() if line.strip()]
    assert len(steps) == len(set(steps))  # no step logged twice


def test_two_resumes_of_one_run_cannot_both_write(scene, tmp_path):
    run = _trainer(_cfg(scene, tmp_path, 2)).train().run_dir
    a = _trainer(_cfg(scene, tmp_path, 4), resume=run)
    a.setup()
    with pytest.raises(UserError, match=BUSY):
        _trainer(_cfg(scene, tmp_path, 4), resume=run).setup()
    a.train()
    assert load_checkpoint(latest_checkpoint(run))["step"] == 4


def test_a_lock_left_by_a_killed_process_does_not_block_resume(scene, tmp_path):
    run = _trainer(_cfg(scene, tmp_path, 2)).train().run_dir
    holder = textwrap.dedent(f"""
        import sys, time
        from pipelines.engine.run_lock import RunLock
        lock = RunLock({str(run)!r}).acquire()
        print("held", flush=True)
        time.sleep(600)
    """)
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.Popen([sys.executable, "-c", holder], stdout=subprocess.PIPE, text=True, cwd=root)
    try:
        assert proc.stdout.readline().strip() == "held"
        with pytest.raises(UserError, match=BUSY):
            _trainer(_cfg(scene, tmp_path, 4), resume=run).setup()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        proc.kill()
    _trainer(_cfg(scene, tmp_path, 4), resume=run).train()  # the kernel dropped the dead holder's lock
    assert load_checkpoint(latest_checkpoint(run))["step"] == 4


def test_a_start_that_fails_leaves_no_run_folder(scene, tmp_path, monkeypatch):
    import pipelines.engine.trainer as trainer_module

    def disk_full(*_a, **_k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(trainer_module, "save_config", disk_full)
    with pytest.raises(OSError, match="No space left"):
        _trainer(_cfg(scene, tmp_path / "out", 2)).setup()
    assert not (tmp_path / "out").exists()  # nor the scene / method folders made for it
    (tmp_path / "kept").mkdir()
    with pytest.raises(OSError, match="No space left"):
        _trainer(_cfg(scene, tmp_path / "kept", 2)).setup()
    assert (tmp_path / "kept").is_dir() and not any((tmp_path / "kept").iterdir())  # existed: stays


def test_checkpoints_on_a_time_budget(scene, tmp_path, monkeypatch):
    """Issue 22: a run killed before its first step-count checkpoint had nothing to resume. With
    ``--minutes-per-save`` a checkpoint also comes when the time since the last one is spent."""
    import json

    import pipelines.engine.trainer as trainer_module

    clock = iter(range(0, 10_000, 7))  # every reading of the clock is 7 s later
    monkeypatch.setattr(trainer_module.time, "perf_counter", lambda: float(next(clock)))
    cfg = _cfg(scene, tmp_path, 6, "--steps-per-save", "1000", "--minutes-per-save", "0.5")
    run = _trainer(cfg).train().run_dir
    saved = [json.loads(line) for line in (run / "logs" / "checkpoints.jsonl").read_text().splitlines()]
    steps = [r["step"] for r in saved]
    assert steps[-1] == 6 and len(steps) >= 3 and steps != [2, 4, 6], (
        steps
    )  # the first after 6 s, then every 30 s, and the end
    assert all(r["bytes"] > 0 and r["seconds"] >= 0 for r in saved)
    assert steps == sorted(set(steps))

    monkeypatch.undo()
    off = _trainer(_cfg(scene, tmp_path / "off", 6, "--steps-per-save", "1000", "--minutes-per-save", "0"))
    run = off.train().run_dir
    written = [json.loads(x)["step"] for x in (run / "logs" / "checkpoints.jsonl").read_text().splitlines()]
    assert off.pipeline.milestone_steps() == (5,)  # tri-dehaze's freeze at three quarters of 6 steps
    assert written == [5, 6]  # no time-based checkpoint: the milestone and the end only


class _FakeMsvcrt:
    """msvcrt.locking's semantics for one process: a byte range locked through one descriptor of a
    file cannot be locked through another until unlocked (Windows is not available here)."""

    LK_NBLCK, LK_UNLCK = 2, 0

    def __init__(self) -> None:
        self.held: dict[tuple[int, int], int] = {}

    def locking(self, fd: int, mode: int, nbytes: int) -> None:
        st = os.fstat(fd)
        key = (st.st_dev, st.st_ino)
        if mode == self.LK_NBLCK:
            if key in self.held and self.held[key] != fd:
                raise OSError(36, "Resource deadlock avoided")
            self.held[key] = fd
        elif self.held.get(key) == fd:
            del self.held[key]


def test_windows_locks_a_file_in_the_run_folder(tmp_path, monkeypatch):
    """Where there is no flock (Windows) the lock is msvcrt.locking on .td-run.lock (simulated)."""
    from pipelines.engine import run_lock

    fake = _FakeMsvcrt()
    monkeypatch.setattr(run_lock, "fcntl", None)
    monkeypatch.setattr(run_lock, "msvcrt", fake)
    run = tmp_path / "run"
    run.mkdir()
    first = run_lock.RunLock(run).acquire()
    assert (run / run_lock.WINDOWS_LOCK_FILE).is_file() and fake.held
    with pytest.raises(UserError, match=BUSY) as err:
        run_lock.RunLock(run).acquire()
    assert str(run) in str(err.value)
    first.release()
    assert not fake.held
    again = run_lock.RunLock(run).acquire()  # free once the first writer let go
    again.release()
