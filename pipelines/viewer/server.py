"""The viser server: scene (training cameras, seed points), GUI and one view state per browser.

The viewer talks to the model only through the :class:`~pipelines.engine.contract.Pipeline` contract
(``render``, ``output_names``, ``stats``); the output list in the browser is whatever the
pipeline names. Per browser: the output dropdown, the split view and a status line (each browser
has its own camera anyway); shared by all: the training readouts, pause / resume and the toggles
of the training cameras and seed points (scene state is shared in viser).
"""

from __future__ import annotations

import contextlib
import io
import math
import threading
import time
import warnings
from typing import Any

import numpy as np
import viser
from rich.console import Console

from pipelines.engine.config import ViewerConfig
from pipelines.engine.contract import Pipeline
from pipelines.engine.datamanager import DataManager
from pipelines.engine.live_view import LiveView
from pipelines.viewer.camera_convert import camera_to_viser, image_size, up_direction
from pipelines.viewer.ports import check_port_free, port_in_use
from pipelines.viewer.render_loop import CameraPose, RenderLoop, TicketLock, ViewState

SPLIT_OFF = "off"
READOUT_SECONDS = 0.5
"""Readouts are refreshed at most this often (one websocket message each)."""


class Viewer(LiveView):
    """A live view of a pipeline in the browser, while training (``training=True``) or of a saved run.

    The trainer takes :attr:`lock` around each optimisation step and calls :meth:`update` after it;
    :meth:`update` blocks while the browser has paused training.
    """

    def __init__(
        self,
        cfg: ViewerConfig,
        pipeline: Pipeline,
        datamanager: DataManager,
        *,
        training: bool,
        console: Console | None = None,
        max_steps: int | None = None,
        title: str = "Tri-DehazeGS",
    ) -> None:
        self.cfg = cfg
        self.pipeline = pipeline
        self.datamanager = datamanager
        self.training = training
        self.console = console or Console(soft_wrap=True)
        self.max_steps = max_steps
        self.title = title
        self.lock = TicketLock()
        self.outputs = list(pipeline.output_names())
        self.loop = RenderLoop(pipeline, cfg, self.lock, on_error=self._log_error)
        self.url = ""
        self.server: viser.ViserServer | None = None
        self._resume = threading.Event()
        self._resume.set()
        self._closed = threading.Event()
        self._step = 0
        self._metrics: dict[str, float] = {}
        self._readout_at = -math.inf
        self._logged_errors: set[str] = set()

    # ---------------------------------------------------------------------------- lifecycle
    def start(self) -> str:
        """Start serving; returns the URL. A port in use or a host that cannot be bound is a UserError."""
        check_port_free(self.cfg.host, self.cfg.port)
        # a frame for a browser that just left is dropped; that is expected, not worth a warning
        warnings.filterwarnings("ignore", message="Queued a .* on a closed connection", category=UserWarning)
        with contextlib.redirect_stdout(io.StringIO()):  # viser prints its own banner; we print one line
            server = viser.ViserServer(
                host=self.cfg.host, port=self.cfg.port, label=self.title, verbose=False
            )
        if self.cfg.port and server.get_port() != self.cfg.port:  # taken between our check and viser's bind
            server.stop()
            raise port_in_use(self.cfg.host, self.cfg.port)
        self.server = server
        host = "localhost" if self.cfg.host in ("0.0.0.0", "::") else self.cfg.host
        self.url = f"http://{f'[{host}]' if ':' in host else host}:{server.get_port()}"
        try:
            self._build_scene(server)
            self._build_gui(server)
        except BaseException:
            self.close()
            raise
        server.on_client_connect(self._on_connect)
        server.on_client_disconnect(lambda client: self.loop.remove_view(client.client_id))
        self.loop.limited = self.training
        self.loop.start()
        return self.url

    def close(self) -> None:
        """Stop rendering and serving (idempotent); a paused trainer is released."""
        if self._closed.is_set():
            return
        self._closed.set()
        self._resume.set()
        self.loop.stop()
        if self.server is not None:
            with contextlib.redirect_stdout(io.StringIO()):
                self.server.stop()

    def serve_forever(self) -> None:
        """Block until Ctrl-C (or :meth:`close` from another thread), keeping the readouts current."""
        try:
            while not self._closed.wait(READOUT_SECONDS):
                self._show_readouts()
        except KeyboardInterrupt:
            pass

    # ---------------------------------------------------------------------------- training hooks
    def update(self, step: int, metrics: dict[str, float]) -> None:
        """Training finished ``step`` steps; refresh the readouts; wait here while paused."""
        self._step, self._metrics = step, metrics
        self.loop.step = step
        now = time.perf_counter()
        if now - self._readout_at >= READOUT_SECONDS:
            self._readout_at = now
            self._show_readouts()
        self.loop.poke()
        if not self._resume.is_set():
            self._show_readouts()
            while not self._resume.wait(0.1):
                pass

    def finish(self) -> None:
        """Training ended: lift the render throttle and say so in the readouts."""
        self.training = False
        self.loop.limited = False
        if self.server is not None:
            self._pause.visible = False
            self._show_readouts()

    # ---------------------------------------------------------------------------- scene
    def _build_scene(self, server: viser.ViserServer) -> None:
        dm = self.datamanager
        cams = dm.cameras
        train = dm.train_indices or list(range(len(cams)))
        centers = cams.centers[train].double().cpu().numpy()  # [N, 3]
        middle = centers.mean(0)
        extent = float(np.linalg.norm(centers - middle, axis=1).max()) or 1.0
        up = up_direction(cams[train])
        server.scene.set_up_direction(tuple(up))

        # start a little behind and above the first training view (on it, its own frustum fills the view)
        wxyz, pos, fov, _ = camera_to_viser(cams, train[0])
        forward = _rotation(wxyz)[:, 2]
        server.initial_camera.position = tuple(pos + (0.15 * up - 0.3 * forward) * extent)
        server.initial_camera.look_at = tuple(pos + forward * extent)
        server.initial_camera.up = tuple(up)
        server.initial_camera.fov = fov

        self._frustums = []
        for idx in train:
            wxyz, pos, fov, aspect = camera_to_viser(cams, idx)
            frustum = server.scene.add_camera_frustum(
                f"/training_cameras/{idx}",
                fov=fov,
                aspect=aspect,
                scale=0.08 * extent,
                thickness=0.004 * extent,
                color=(60, 110, 220),
                image=self._thumbnail(idx),
                wxyz=wxyz,
                position=pos,
            )
            frustum.on_click(self._jump_to(idx))
            self._frustums.append(frustum)
        points, colors = dm.scene.points, dm.scene.point_colors
        self._points = None
        if points is not None and len(points):
            keep = np.linspace(0, len(points) - 1, min(len(points), 100_000)).astype(np.int64)
            pts = points[keep].cpu().numpy().astype(np.float32)  # [M, 3]
            cols = (
                (colors[keep].cpu().numpy() * 255).astype(np.uint8)
                if colors is not None
                else np.full((len(keep), 3), 200, np.uint8)
            )
            self._points = server.scene.add_point_cloud(
                "/seed_points", pts, cols, point_size=0.01 * extent, visible=False
            )

    def _thumbnail(self, idx: int) -> np.ndarray | None:
        if self.cfg.thumbnail_size == 0:
            return None
        import cv2

        img = self.datamanager.image(idx)  # [H, W, 3] float
        arr = (img.detach().float().cpu().numpy().clip(0, 1) * 255).astype(np.uint8)
        w, h = image_size(arr.shape[1] / arr.shape[0], self.cfg.thumbnail_size)
        return cv2.resize(arr, (w, h), interpolation=cv2.INTER_AREA)

    def _jump_to(self, idx: int):
        """Clicking a frustum moves that browser's camera onto the training view."""

        def jump(event: Any) -> None:
            wxyz, pos, fov, _ = camera_to_viser(self.datamanager.cameras, idx)
            client = event.client
            if client is None:
                return
            with client.atomic():
                client.camera.wxyz = wxyz
                client.camera.position = pos
                client.camera.fov = fov

        return jump

    # ---------------------------------------------------------------------------- GUI
    def _build_gui(self, server: viser.ViserServer) -> None:
        gui = server.gui
        self._readouts = gui.add_markdown("starting…", order=0)
        self._pause = gui.add_button("Pause training", icon=viser.Icon.PLAYER_PAUSE, order=10)
        self._pause.visible = self.training
        self._pause.on_click(lambda _: self._toggle_pause())
        show_cams = gui.add_checkbox("Training cameras", True, order=11)

        @show_cams.on_update
        def _(_: Any) -> None:
            for f in self._frustums:
                f.visible = show_cams.value

        if self._points is not None:
            show_points = gui.add_checkbox("Seed points", False, order=12)

            @show_points.on_update
            def _(_: Any) -> None:
                self._points.visible = show_points.value

        self._show_readouts()

    def _on_connect(self, client: viser.ClientHandle) -> None:
        """Per-browser controls and view state; the first camera message triggers the first frame."""
        key, gui = client.client_id, client.gui
        names = self.outputs
        output = gui.add_dropdown("Output", names, initial_value=names[0], order=1)
        split = gui.add_dropdown(
            "Split with", [SPLIT_OFF, *names], initial_value=SPLIT_OFF, order=2,
            hint="show a second output right of the split line",
        )  # fmt: skip
        split_at = gui.add_slider("Split at", 0.0, 1.0, 0.01, 0.5, order=3, visible=False)
        status = gui.add_markdown("connected · waiting for the first frame", order=4)

        def send(frame: np.ndarray) -> None:
            client.scene.set_background_image(frame, format="jpeg", jpeg_quality=self.cfg.jpeg_quality)

        def report(text: str) -> None:
            status.content = text

        self.loop.add_view(key, ViewState(send=send, report=report, output=names[0]))

        @output.on_update
        def _(_: Any) -> None:
            self.loop.set_display(key, output=output.value)

        @split.on_update
        def _(_: Any) -> None:
            split_at.visible = split.value != SPLIT_OFF
            self.loop.set_display(key, split_with=None if split.value == SPLIT_OFF else split.value)

        @split_at.on_update
        def _(_: Any) -> None:
            self.loop.set_display(key, split_at=float(split_at.value))

        @client.camera.on_update
        def _(camera: viser.CameraHandle) -> None:
            self.loop.set_camera(key, _pose(camera))

        with contextlib.suppress(AssertionError):  # no camera message yet: on_update will bring it
            self.loop.set_camera(key, _pose(client.camera))

    def _toggle_pause(self) -> None:
        if self._resume.is_set():
            self._resume.clear()
            self._pause.label, self._pause.icon = "Resume training", viser.Icon.PLAYER_PLAY
            self.loop.limited = False
        else:
            self._pause.label, self._pause.icon = "Pause training", viser.Icon.PLAYER_PAUSE
            self.loop.limited = self.training
            self._resume.set()
        self._show_readouts()
        self.loop.poke()

    def _show_readouts(self) -> None:
        if self.server is None:
            return
        m = {**self._metrics}
        state = "paused" if not self._resume.is_set() else ("training" if self.training else "done")
        if not self.training and self.max_steps is None:
            state = "saved run"
        total = f" / {self.max_steps}" if self.max_steps else ""
        lines = [f"**{state}** · step {self._step}{total}"]
        parts = []
        if "stage" in m:
            parts.append(f"stage {_roman(m.pop('stage'))}")
        if "loss" in m:
            parts.append(f"loss {m.pop('loss'):.4f}")
        if "psnr" in m:
            parts.append(f"PSNR {m.pop('psnr'):.2f}")
        if "gaussians" in m:
            parts.append(f"Gaussians {int(m.pop('gaussians')):,}")
        if "its" in m and self.training:
            parts.append(f"{m.pop('its'):.1f} it/s")
        if parts:
            lines.append(" · ".join(parts))
        share = self.loop.throttle.recent_share(time.perf_counter())
        limit = f" (limit {self.cfg.render_share:.0%})" if self.training and self.cfg.render_share < 1 else ""
        lines.append(f"viewer {share:.0%} of time{limit}")
        text = "  \n".join(lines)
        if text != self._readouts.content:  # each change is a websocket message to every browser
            self._readouts.content = text

    def _log_error(self, message: str) -> None:
        first = message.splitlines()[0]
        if first not in self._logged_errors:  # once per distinct error, not once per frame
            self._logged_errors.add(first)
            self.console.print(f"[yellow]viewer[/]: {message}", markup=False, highlight=False)


def _pose(camera: viser.CameraHandle) -> CameraPose:
    return CameraPose(
        wxyz=np.array(camera.wxyz, dtype=np.float64),
        position=np.array(camera.position, dtype=np.float64),
        fov=float(camera.fov),
        canvas_width=int(camera.image_width),
        canvas_height=int(camera.image_height),
    )


def _rotation(wxyz: np.ndarray) -> np.ndarray:
    return viser.transforms.SO3(np.asarray(wxyz)).as_matrix()


def _roman(value: float) -> str:
    n = int(value)
    return {1: "I", 2: "II", 3: "III", 4: "IV"}.get(n, str(n))
