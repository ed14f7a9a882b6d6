"""The machine's limits (disk full, a name too long, no permission) end a tool with one line and
exit 2, and a checkpoint that cannot be written leaves the earlier ones intact."""

from __future__ import annotations

import errno
from collections import namedtuple
from pathlib import Path

import pytest
import torch

from pipelines.engine import checkpoint as ckpt_module
from pipelines.engine.checkpoint import checkpoint_path, load_checkpoint, save_checkpoint
from tridehaze_plugin.cli.common import run_cli
from tridehaze_plugin.errors import UserError

PAYLOAD = {"step": 1, "pipeline": {"w": torch.ones(3)}}
Usage = namedtuple("Usage", "total used free")


def _full_disk(monkeypatch, exc: BaseException, free: int) -> None:
    def failing_save(obj, fh) -> None:  # noqa: ANN001 - torch.save's signature
        fh.write(b"partial")
        raise exc

    monkeypatch.setattr(ckpt_module.torch, "save", failing_save)
    monkeypatch.setattr(ckpt_module.shutil, "disk_usage", lambda _: Usage(10**9, 10**9 - free, free))


@pytest.mark.parametrize(
    "exc",
    [OSError(errno.ENOSPC, "No space left on device"), RuntimeError("unexpected pos 596928 vs 596816")],
    ids=["ENOSPC", "torch's position error"],
)
def test_a_full_disk_keeps_the_earlier_checkpoint(tmp_path, monkeypatch, exc):
    run = tmp_path / "run"
    first = save_checkpoint(checkpoint_path(run, 1), PAYLOAD)
    before = first.read_bytes()
    _full_disk(monkeypatch, exc, free=0)
    with pytest.raises(UserError, match="no space left on the device while writing a checkpoint"):
        save_checkpoint(checkpoint_path(run, 2), {**PAYLOAD, "step": 2})
    assert first.read_bytes() == before and load_checkpoint(first)["step"] == 1
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == [first.name]  # no partial file


def test_other_write_failures_are_not_called_a_full_disk(tmp_path, monkeypatch):
    _full_disk(monkeypatch, RuntimeError("some other torch failure"), free=10**9)
    with pytest.raises(RuntimeError, match="some other torch failure"):
        save_checkpoint(checkpoint_path(tmp_path, 1), PAYLOAD)
    assert list((tmp_path / "checkpoints").iterdir()) == []


@pytest.mark.parametrize(
    ("code", "expect"),
    [
        (errno.ENOSPC, "error: No space left on device (/out/x); free some space"),
        (errno.ENAMETOOLONG, "error: File name too long (/out/x); use a shorter path"),
        (errno.EACCES, "error: Permission denied (/out/x); choose a folder you may write to"),
        (errno.EROFS, "error: Read-only file system (/out/x); choose a folder on a writable"),
    ],
)
def test_system_limits_are_one_line_and_exit_2(capsys, code, expect):
    def main() -> None:
        raise OSError(code, __import__("os").strerror(code), "/out/x")

    with pytest.raises(SystemExit) as info:
        run_cli(main)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(expect), err


def test_other_os_errors_keep_their_traceback():
    def main() -> None:
        raise OSError(errno.EIO, "Input/output error", "/dev/sdz")

    with pytest.raises(OSError, match="Input/output error"):
        run_cli(main)


def test_a_real_full_disk_when_this_machine_can_mount_one(tmp_path):
    """The same through the real kernel where a small tmpfs can be mounted (root in a container);
    elsewhere it is skipped (and says so) and the monkeypatched cases above stand for it."""
    import subprocess

    mnt = tmp_path / "full"
    mnt.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {res.stderr.decode(errors='replace').strip()[:100]}")
    try:
        with pytest.raises(UserError, match="no space left on the device"):
            save_checkpoint(checkpoint_path(Path(mnt), 1), {"step": 1, "pipeline": {"w": torch.ones(65536)}})
        assert not [p for p in (mnt / "checkpoints").iterdir()]
    finally:
        subprocess.run(["umount", str(mnt)], check=False)
