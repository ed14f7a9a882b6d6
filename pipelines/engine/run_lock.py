"""One writer per run folder: an exclusive advisory lock on the folder itself while td-train runs.

The lock is ``flock`` on the run folder's own file descriptor: nothing is written into the folder,
and the kernel drops the lock when the process ends however it ends (Ctrl-C, SIGKILL, a crash), so
a stale lock never blocks a later ``--resume``. Where ``flock`` does not exist (Windows) runs are
not locked.
"""

from __future__ import annotations

import os
from pathlib import Path

from tridehaze_plugin.errors import UserError

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None  # type: ignore[assignment]


class RunLock:
    """Held from :meth:`acquire` until :meth:`release` (or the end of the process)."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = Path(run_dir)
        self._fd: int | None = None

    def acquire(self) -> RunLock:
        if fcntl is None or self._fd is not None:
            return self
        try:
            fd = os.open(self.run_dir, os.O_RDONLY)
        except OSError as exc:
            raise UserError(
                f"cannot open the run folder ({exc.strerror or exc})", where=str(self.run_dir)
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise UserError(
                "another td-train process is writing this run folder",
                where=str(self.run_dir),
                fix="wait for it to finish or stop it, then resume; two writers would corrupt its checkpoints",
            ) from None
        self._fd = fd
        return self

    def __del__(self) -> None:  # a trainer dropped without finishing must not keep its folder locked
        self.release()

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the lock
            self._fd = None
