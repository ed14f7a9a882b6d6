"""The viewer's render thread: which view to render next, at which resolution, and when.

Renders run in their own thread under the pipeline lock that the training loop also takes around
each optimisation step, so a render never sees half-updated parameters (densification changes
tensor sizes). The lock is FIFO (:class:`TicketLock`): with a plain lock the training thread,
which releases and re-takes it at once, would starve the renderer.

Costs are bounded by :class:`RenderThrottle`: while training runs, renders may use at most
``render_share`` of wall time, whatever the number of browsers (one thread serves them in turn).
A moving camera is rendered at ``moving_resolution``; once it has rested ``rest_seconds`` it gets
one ``max_resolution`` render. Rendering errors are reported to the browser, never raised.
"""

from __future__ import annotations

import math
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from pipelines.engine.config import ViewerConfig
from pipelines.engine.contract import Pipeline
from pipelines.viewer.camera_convert import image_size, viser_to_camera
from pipelines.viewer.frames import compose_frame


class TicketLock:
    """A first-come first-served lock (a context manager), fair between the trainer and the renderer.

    A waiter interrupted while queueing (Ctrl-C in the training thread) gives up its turn, so the
    queue behind it never stalls.
    """

    def __init__(self) -> None:
        self._cond = threading.Condition(threading.Lock())
        self._next_ticket = 0
        self._serving = 0
        self._abandoned: set[int] = set()

    def __enter__(self) -> TicketLock:
        with self._cond:
            ticket = self._next_ticket
            self._next_ticket += 1
            try:
                while self._serving != ticket:
                    self._cond.wait()
            except BaseException:
                self._abandoned.add(ticket)
                self._advance(0)
                raise
        return self

    def __exit__(self, *exc: object) -> None:
        with self._cond:
            self._advance(1)

    def _advance(self, by: int) -> None:
        self._serving += by
        while self._serving in self._abandoned:
            self._abandoned.discard(self._serving)
            self._serving += 1
        self._cond.notify_all()


class RenderThrottle:
    """Keeps renders to at most ``share`` of wall time: after a render of d seconds the next one may
    start d * (1 - share) / share seconds later, so busy / (busy + idle) <= share in every cycle."""

    def __init__(self, share: float, window: float = 10.0) -> None:
        self.share = share
        self.window = window
        self._next_start = -math.inf
        self._busy: deque[tuple[float, float]] = deque()  # (end time, seconds) of recent renders

    def wait_time(self, now: float, limited: bool) -> float:
        """Seconds to wait before the next render may start (0 when not ``limited``, e.g. paused)."""
        return max(0.0, self._next_start - now) if limited and self.share < 1 else 0.0

    def record(self, seconds: float, now: float) -> None:
        """A render that took ``seconds`` ended at ``now``."""
        self._next_start = now + seconds * (1.0 - self.share) / self.share
        self._busy.append((now, seconds))
        while self._busy and self._busy[0][0] < now - self.window:
            self._busy.popleft()

    def recent_share(self, now: float) -> float:
        """Fraction of the last ``window`` seconds spent rendering."""
        return sum(s for end, s in self._busy if end >= now - self.window) / self.window


@dataclass
class CameraPose:
    """A browser camera as viser reports it (OpenCV axes; see :mod:`camera_convert`)."""

    wxyz: np.ndarray  # [4]
    position: np.ndarray  # [3]
    fov: float
    """Vertical field of view, radians."""
    canvas_width: int
    canvas_height: int

    def same_as(self, other: CameraPose | None) -> bool:
        return (
            other is not None
            and np.allclose(self.wxyz, other.wxyz, atol=1e-7)
            and np.allclose(self.position, other.position, atol=1e-7)
            and math.isclose(self.fov, other.fov, abs_tol=1e-7)
            and (self.canvas_width, self.canvas_height) == (other.canvas_width, other.canvas_height)
        )


@dataclass
class ViewState:
    """What one browser wants to see and what it was last sent."""

    send: Callable[[np.ndarray], None]
    """Delivers a uint8 RGB frame [H, W, 3] to the browser."""
    report: Callable[[str], None]
    """Shows a one-line status (or an error) in the browser."""
    output: str
    split_with: str | None = None
    split_at: float = 0.5
    camera: CameraPose | None = None
    version: int = 0
    """Bumped whenever the camera or a display setting changes."""
    last_move: float = -math.inf
    shown_version: int = -1
    shown_full: bool = False
    shown_step: int = -1
    shown_at: float = -math.inf
    frames: int = 0
    last_error: str | None = None


class RenderLoop:
    """Serves every registered :class:`ViewState` from one background thread."""

    def __init__(
        self,
        pipeline: Pipeline,
        cfg: ViewerConfig,
        lock: TicketLock,
        clock: Callable[[], float] = time.perf_counter,
        on_error: Callable[[str], None] | None = None,
    ) -> None:
        self.pipeline = pipeline
        self.cfg = cfg
        self.lock = lock
        self.clock = clock
        self.on_error = on_error
        self.throttle = RenderThrottle(cfg.render_share)
        self.step = 0
        """Training step of the parameters on show (views are refreshed as it advances)."""
        self.limited = False
        """True while training runs: renders are throttled."""
        self.last_render_seconds = 0.0
        self.total_frames = 0
        self.total_seconds = 0.0
        """Frames rendered and the seconds they took (render + encode + send), for benchmarks."""
        self._views: dict[int, ViewState] = {}
        self._mutex = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ---------------------------------------------------------------------------- views
    def add_view(self, key: int, view: ViewState) -> None:
        with self._mutex:
            self._views[key] = view
        self._wake.set()

    def remove_view(self, key: int) -> None:
        with self._mutex:
            self._views.pop(key, None)

    def view(self, key: int) -> ViewState | None:
        with self._mutex:
            return self._views.get(key)

    def set_camera(self, key: int, pose: CameraPose) -> None:
        """A camera message; identical repeats (viser sends some) do not restart the rest timer."""
        with self._mutex:
            view = self._views.get(key)
            if view is None or pose.same_as(view.camera):
                return
            view.camera = pose
            view.version += 1
            view.last_move = self.clock()
        self._wake.set()

    def set_display(self, key: int, **settings: object) -> None:
        """Change ``output``, ``split_with`` or ``split_at`` of a view."""
        with self._mutex:
            view = self._views.get(key)
            if view is None:
                return
            for name, value in settings.items():
                setattr(view, name, value)
            view.version += 1
        self._wake.set()

    def poke(self) -> None:
        """Something changed (training advanced, paused, resumed): reconsider what to render."""
        self._wake.set()

    # ---------------------------------------------------------------------------- scheduling
    def next_job(self, now: float) -> tuple[int, ViewState, bool] | None:
        """(key, view, full resolution?) of the view that waited longest among those needing a frame."""
        best = None
        with self._mutex:
            for key, view in self._views.items():
                if view.camera is None:
                    continue
                moving = now - view.last_move < self.cfg.rest_seconds
                changed = view.version != view.shown_version
                sharpen = not view.shown_full and not moving
                refresh = self.step != view.shown_step and now - view.shown_at >= self.cfg.refresh_seconds
                if (changed or sharpen or refresh) and (best is None or view.shown_at < best[1].shown_at):
                    best = (key, view, not moving)
        return best

    def render_once(self, key: int, view: ViewState, full: bool) -> None:
        """Render ``view`` now (under the pipeline lock), send the frame, update the throttle."""
        with self._mutex:
            pose, version = view.camera, view.version
            output, split_with, split_at = view.output, view.split_with, view.split_at
        assert pose is not None
        side = self.cfg.max_resolution if full else self.cfg.moving_resolution
        side = max(8, min(side, max(pose.canvas_width, pose.canvas_height)))
        width, height = image_size(pose.canvas_width / max(pose.canvas_height, 1), side)
        camera = viser_to_camera(pose.wxyz, pose.position, pose.fov, width, height)
        start = None
        try:
            with self.lock:
                start = self.clock()
                step = self.step
                with torch.no_grad():
                    outputs = self.pipeline.render(camera.to(self.pipeline.device))
            frame = compose_frame(outputs, output, split_with, split_at)
            view.send(frame)
            took = self.clock() - start
            shown = f"{output} | {split_with}" if split_with else output
            view.report(
                f"showing {shown} · {width}×{height} {'full' if full else 'moving'} · "
                f"{took * 1000:.0f} ms · step {step}"
            )
        except Exception as exc:  # noqa: BLE001 - a failed render is shown, never fatal
            step = self.step
            message = f"render error: {_one_line(exc)}"
            view.last_error = message
            try:
                view.report(message)
            except Exception:  # noqa: BLE001 - the browser may be gone already
                pass
            if self.on_error is not None:
                self.on_error(message + "\n" + traceback.format_exc(limit=4))
        end = self.clock()
        took = end - start if start is not None else 0.0
        self.last_render_seconds = took
        self.total_frames += 1
        self.total_seconds += took
        self.throttle.record(took, end)
        with self._mutex:
            view.shown_version, view.shown_full, view.shown_step, view.shown_at = version, full, step, end
            view.frames += 1

    # ---------------------------------------------------------------------------- thread
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="viewer-render", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def _run(self) -> None:
        while not self._stop.is_set():
            now = self.clock()
            job = self.next_job(now)
            if job is None:
                self._wake.wait(0.05)
                self._wake.clear()
                continue
            wait = self.throttle.wait_time(now, self.limited)
            if wait > 0:  # sleep in short slices: the camera may move again meanwhile
                self._stop.wait(min(wait, 0.05))
                continue
            self.render_once(*job)


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text.splitlines()[0][:300]}" if text else type(exc).__name__
