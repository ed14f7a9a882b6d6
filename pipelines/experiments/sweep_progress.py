"""One live progress line per sweep: runs done / running / failed of the total, and an ETA.

Runs finished in an earlier call are counted as done at the start but left out of the ETA (they
took no time now). The per-run lines the commands print go above the live line.
"""

from __future__ import annotations

import threading
import time

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn


class SweepProgress:
    """``with SweepProgress(total, "td-ablate") as p: p.started(key); p.finished(key, ok)``."""

    def __init__(self, total: int, label: str, console: Console | None = None) -> None:
        self.total = total
        self.label = label
        self.console = console or Console(stderr=True)
        self.done = self.failed = self.skipped = 0
        self.running: set[str] = set()
        self._lock = threading.Lock()
        self._t0 = time.monotonic()
        self._progress = Progress(
            TextColumn("{task.description}"), BarColumn(bar_width=24), TextColumn("{task.fields[state]}"),
            TimeElapsedColumn(), TextColumn("ETA {task.fields[eta]}"),
            console=self.console, transient=False, refresh_per_second=2,
        )  # fmt: skip
        self._task = self._progress.add_task(label, total=total, state=self._state(), eta="-")

    def __enter__(self) -> SweepProgress:
        self._progress.start()
        return self

    def __exit__(self, *exc) -> None:
        self._refresh()
        self._progress.stop()

    def print(self, line: str) -> None:
        """A line above the live one (stdout keeps the per-run lines scripts and tests read)."""
        self._progress.console.print(line, markup=False, highlight=False, soft_wrap=True)

    def skip(self, n: int = 1) -> None:
        with self._lock:
            self.skipped += n
            self.done += n
        self._refresh()

    def started(self, key: str) -> None:
        with self._lock:
            self.running.add(key)
        self._refresh()

    def finished(self, key: str, ok: bool) -> None:
        with self._lock:
            self.running.discard(key)
            if ok:
                self.done += 1
            else:
                self.failed += 1
        self._refresh()

    def eta_seconds(self) -> float | None:
        """Remaining runs times the mean time per run finished in this call (None before the first)."""
        finished_now = self.done + self.failed - self.skipped
        left = self.total - self.done - self.failed
        if finished_now <= 0:
            return None
        return (time.monotonic() - self._t0) / finished_now * left

    def _state(self) -> str:
        return f"done {self.done} / running {len(self.running)} / failed {self.failed} of {self.total}"

    def _refresh(self) -> None:
        eta = self.eta_seconds()
        shown = "-" if eta is None else time.strftime("%H:%M:%S", time.gmtime(eta))
        self._progress.update(self._task, completed=self.done + self.failed, state=self._state(), eta=shown)
