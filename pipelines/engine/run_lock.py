"""One writer per run folder: an exclusive lock held while td-train runs.

POSIX: ``flock`` on the run folder's own file descriptor, so nothing is written into the folder.
Windows (no ``flock``, and a folder cannot be opened as a file): ``msvcrt.locking`` on the first
byte of ``.td-run.lock`` inside the folder. Either way the operating system drops the lock when
the process ends however it ends (Ctrl-C, a kill, a crash), so a stale lock never blocks a later
``--resume``.
"""

from __future__ import annotations

import os
from pathlib import Path

from tridehaze_plugin.errors import UserError

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None  # type: ignore[assignment]
try:
    import msvcrt
except ImportError:  # not Windows
    msvcrt = None  # type: ignore[assignment]

WINDOWS_LOCK_FILE = ".td-run.lock"
"""The file whose first byte carries the lock where folders cannot be locked (Windows)."""
BUSY = "another td-train process is writing this run folder"
BUSY_FIX = "wait for it to finish or stop it, then resume; two writers would corrupt its checkpoints"


class RunLock:
    """Held from :meth:`acquire` until :meth:`release` (or the end of the process)."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = Path(run_dir)
        self._fd: int | None = None

    def acquire(self) -> RunLock:
        if self._fd is not None:
            return self
        if fcntl is not None:
            self._fd = self._flock()
        elif msvcrt is not None:
            self._fd = self._msvcrt_lock()
        return self

    def _flock(self) -> int:
        fd = self._open(self.run_dir, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise self._busy() from None
        return fd

    def _msvcrt_lock(self) -> int:
        fd = self._open(self.run_dir / WINDOWS_LOCK_FILE, os.O_RDWR | os.O_CREAT)
        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            os.close(fd)
            raise self._busy() from None
        return fd

    def _open(self, path: Path, flags: int) -> int:
        try:
            return os.open(path, flags)
        except OSError as exc:
            raise UserError(
                f"cannot open the run folder ({exc.strerror or exc})", where=str(self.run_dir)
            ) from None

    def _busy(self) -> UserError:
        return UserError(BUSY, where=str(self.run_dir), fix=BUSY_FIX)

    def __del__(self) -> None:  # a trainer dropped without finishing must not keep its folder locked
        self.release()

    def release(self) -> None:
        if self._fd is None:
            return
        if fcntl is None:  # the lock was msvcrt's (acquire takes flock wherever it exists)
            try:
                os.lseek(self._fd, 0, os.SEEK_SET)
                msvcrt.locking(self._fd, msvcrt.LK_UNLCK, 1)
            except OSError:
                pass  # closing the handle below drops it as well
        os.close(self._fd)  # closing the descriptor drops the lock
        self._fd = None
