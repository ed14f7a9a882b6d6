"""The render thread's logic: throttle bound, fair lock, resolution schedule, errors, split frames."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import torch

from pipelines.engine.config import ViewerConfig
from pipelines.viewer.frames import compose_frame
from pipelines.viewer.render_loop import CameraPose, RenderLoop, RenderThrottle, TicketLock, ViewState
from tests.viewer.helpers import FakePipeline


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def pose(x: float = 0.0, width: int = 400, height: int = 300) -> CameraPose:
    return CameraPose(np.array([1.0, 0, 0, 0]), np.array([x, 0.0, 0.0]), 0.8, width, height)


def make_loop(**cfg) -> tuple[RenderLoop, Clock, FakePipeline]:
    clock, pipe = Clock(), FakePipeline()
    base = {"max_resolution": 200, "moving_resolution": 40, "rest_seconds": 0.25, "refresh_seconds": 1.0}
    return RenderLoop(pipe, ViewerConfig(**{**base, **cfg}), TicketLock(), clock=clock), clock, pipe


def add_view(loop: RenderLoop, key: int = 1) -> tuple[ViewState, list[np.ndarray], list[str]]:
    frames, lines = [], []
    view = ViewState(send=frames.append, report=lines.append, output="clean")
    loop.add_view(key, view)
    return view, frames, lines


@pytest.mark.parametrize("share", [0.05, 0.2, 0.5])
def test_throttle_bounds_the_render_share(share):
    """Renders of random length back to back: their share of wall time never exceeds ``share``."""
    throttle, now, busy = RenderThrottle(share), 0.0, 0.0
    rng = np.random.default_rng(0)
    for _ in range(500):
        now += throttle.wait_time(now, limited=True)
        took = float(rng.uniform(0.001, 0.3))
        now += took
        busy += took
        throttle.record(took, now)
    now += throttle.wait_time(now, limited=True)  # complete the last cycle (render + its pause)
    assert busy / now <= share + 1e-9
    assert busy / now > 0.9 * share  # and it does not waste the budget either
    assert throttle.wait_time(now, limited=False) == 0.0  # paused or not training: no limit


def test_throttle_reports_the_recent_share():
    throttle = RenderThrottle(0.2, window=10.0)
    throttle.record(1.0, 5.0)
    throttle.record(1.0, 9.0)
    assert throttle.recent_share(10.0) == pytest.approx(0.2)
    assert throttle.recent_share(100.0) == 0.0


def test_ticket_lock_is_fair():
    """A thread that re-takes the lock in a tight loop (the trainer) cannot starve a waiting one."""
    lock, stop, got = TicketLock(), threading.Event(), []

    def trainer():
        while not stop.is_set():
            with lock:
                time.sleep(0.002)

    t = threading.Thread(target=trainer)
    t.start()
    try:
        for _ in range(5):
            start = time.perf_counter()
            with lock:
                got.append(time.perf_counter() - start)
    finally:
        stop.set()
        t.join()
    assert max(got) < 0.5, got


def test_ticket_lock_survives_an_interrupted_waiter():
    """Ctrl-C while the trainer queues for the lock must not leave the renderer waiting forever."""
    lock = TicketLock()
    lock.__enter__()  # the renderer holds it
    real_wait = lock._cond.wait

    def interrupted(*_a, **_k):
        raise KeyboardInterrupt

    lock._cond.wait = interrupted
    with pytest.raises(KeyboardInterrupt):
        lock.__enter__()  # the trainer queues and is interrupted
    lock._cond.wait = real_wait
    lock.__exit__(None, None, None)
    got = threading.Event()

    def later():
        with lock:
            got.set()

    t = threading.Thread(target=later, daemon=True)
    t.start()
    assert got.wait(2), "the queue stalled behind the abandoned ticket"


def test_moving_camera_gets_low_resolution_then_full_at_rest():
    loop, clock, _ = make_loop()
    view, frames, lines = add_view(loop)
    assert loop.next_job(clock()) is None  # no camera message yet
    loop.set_camera(1, pose(0.0))
    key, job_view, full = loop.next_job(clock())
    assert (key, job_view, full) == (1, view, False)
    loop.render_once(key, job_view, full)
    assert frames[-1].shape == (30, 40, 3) and "moving" in lines[-1]
    assert loop.next_job(clock()) is None  # still moving: nothing new to show
    clock.t += 0.3
    key, _, full = loop.next_job(clock())
    assert full
    loop.render_once(key, view, full)
    assert frames[-1].shape == (150, 200, 3) and lines[-1].startswith("showing clean · 200×150 full")
    assert loop.next_job(clock()) is None
    # a repeated identical camera message (viser sends some) is not a move
    loop.set_camera(1, pose(0.0))
    assert loop.next_job(clock()) is None


def test_full_resolution_never_exceeds_the_canvas():
    loop, clock, _ = make_loop(max_resolution=1000)
    view, frames, _ = add_view(loop)
    loop.set_camera(1, pose(0.0, width=120, height=60))
    clock.t += 1
    loop.render_once(*loop.next_job(clock()))
    assert frames[-1].shape == (60, 120, 3)


def test_training_progress_refreshes_a_resting_view_at_most_every_refresh_seconds():
    loop, clock, _ = make_loop()
    view, frames, _ = add_view(loop)
    loop.set_camera(1, pose())
    clock.t += 1
    loop.render_once(*loop.next_job(clock()))
    loop.step = 5
    assert loop.next_job(clock()) is None
    clock.t += 1.0
    assert loop.next_job(clock()) is not None


def test_output_and_split_changes_render_again():
    loop, clock, _ = make_loop()
    view, frames, lines = add_view(loop)
    loop.set_camera(1, pose())
    clock.t += 1
    loop.render_once(*loop.next_job(clock()))
    loop.set_display(1, output="depth")
    loop.render_once(*loop.next_job(clock()))
    assert lines[-1].startswith("showing depth")
    loop.set_display(1, output="clean", split_with="hazy", split_at=0.5)
    loop.render_once(*loop.next_job(clock()))
    assert lines[-1].startswith("showing clean | hazy")
    frame = frames[-1]  # clean is dark on the left, hazy dark on the right: both halves dark at the edges
    assert frame[:, :3].mean() < 20 and frame[:, -3:].mean() < 20


def test_render_errors_are_reported_not_raised():
    errors = []
    loop, clock, pipe = make_loop()
    loop.on_error = errors.append
    view, frames, lines = add_view(loop)
    loop.set_camera(1, pose())
    clock.t += 1
    pipe.fail = RuntimeError("out of memory\nmore detail")
    loop.render_once(*loop.next_job(clock()))
    assert lines[-1] == "render error: RuntimeError: out of memory" and not frames
    assert errors and errors[0].startswith("render error: RuntimeError: out of memory")
    assert loop.next_job(clock()) is None  # no hot loop on a failing render
    pipe.fail = None
    loop.set_camera(1, pose(1.0))
    clock.t += 1
    loop.render_once(*loop.next_job(clock()))
    assert lines[-1].startswith("showing clean") and len(frames) == 1


def test_a_browser_that_disappears_does_not_stop_the_others():
    loop, clock, _ = make_loop()

    def gone(_frame):
        raise ConnectionError("client went away")

    loop.add_view(1, ViewState(send=gone, report=lambda _: None, output="clean"))
    view2, frames2, _ = add_view(loop, key=2)
    loop.set_camera(1, pose())
    loop.set_camera(2, pose())
    clock.t += 1
    for _ in range(2):
        loop.render_once(*loop.next_job(clock()))
    assert len(frames2) == 1  # served in turn despite the failing one
    loop.remove_view(1)
    assert loop.view(1) is None


def test_thread_serves_views_and_respects_the_lock():
    """The real thread: frames arrive; while the trainer holds the lock, nothing renders."""
    loop = RenderLoop(FakePipeline(), ViewerConfig(rest_seconds=0.0, max_resolution=32), TicketLock())
    view, frames, _ = add_view(loop)
    loop.start()
    try:
        with loop.lock:
            loop.set_camera(1, pose())
            time.sleep(0.2)
            assert not frames
        deadline = time.time() + 5
        while not frames and time.time() < deadline:
            time.sleep(0.01)
        assert frames and frames[-1].shape == (24, 32, 3)
    finally:
        loop.stop()


def test_compose_frame_colour_maps_and_splits():
    h, w = 4, 10
    outs = {
        "clean": torch.zeros(h, w, 3),
        "hazy": torch.ones(h, w, 3),
        "transmittance": torch.full((h, w, 1), 0.5),
        "depth": torch.linspace(1, 2, w)[None, :, None].expand(h, w, 1),
    }
    assert compose_frame(outs, "clean").max() == 0
    t = compose_frame(outs, "transmittance")  # fixed [0, 1] range: 0.5 is the middle of turbo
    assert t.shape == (h, w, 3) and len(np.unique(t.reshape(-1, 3), axis=0)) == 1
    assert len(np.unique(compose_frame(outs, "depth").reshape(-1, 3), axis=0)) > 3
    split = compose_frame(outs, "clean", "hazy", 0.3)
    assert (split[:, :2] == 0).all() and (split[:, 3:] == 255).all()  # seam line at column 2
    with pytest.raises(KeyError, match="no output 'scattering'"):
        compose_frame(outs, "scattering")
