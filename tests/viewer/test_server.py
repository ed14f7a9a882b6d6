"""The viser server around a pipeline: ports, errors, and a training run that viewers cannot stop."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
import urllib.request

import pytest
import viser
from rich.console import Console
from websockets.sync.client import connect

from pipelines.engine.config import ViewerConfig
from pipelines.engine.trainer import Trainer
from pipelines.viewer import TrainingViewer, wants_viewer
from pipelines.viewer.ports import check_port_free
from pipelines.viewer.server import Viewer
from tests.tiny_scenes import tiny_hazy_scene
from tests.viewer.helpers import TRAIN_FLAGS, tiny_pipeline
from tridehaze_plugin.cli.train import parse_args
from tridehaze_plugin.cli.viewer import main as viewer_main
from tridehaze_plugin.errors import ConfigError, UserError


@pytest.fixture(scope="module")
def pipe(tmp_path_factory):
    return tiny_pipeline(tmp_path_factory.mktemp("viewer"))


@contextlib.contextmanager
def listening_port():
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        yield sock.getsockname()[1]


def test_viewer_serves_the_client_on_a_free_port(pipe):
    viewer = Viewer(ViewerConfig(port=0), *pipe, training=False)
    try:
        url = viewer.start()
        assert url.startswith("http://127.0.0.1:") and not url.endswith(":0")
        with urllib.request.urlopen(url, timeout=10) as resp:
            assert resp.status == 200 and b"<html" in resp.read().lower()
        assert viewer.outputs == pipe[0].output_names()  # the dropdown lists what the pipeline renders
    finally:
        viewer.close()
    viewer.close()  # idempotent


def test_port_in_use_is_a_user_error(pipe):
    with listening_port() as port:
        with pytest.raises(UserError, match=f"port {port} on 127.0.0.1 is already in use"):
            Viewer(ViewerConfig(port=port), *pipe, training=False).start()


def test_td_train_checks_the_port_before_any_work(tmp_path):
    with listening_port() as port:
        cfg = parse_args(["vanilla-gs", "--data", str(tmp_path / "absent"), "--output-dir", str(tmp_path / "out"),
                          "--vis", "viewer", "--viewer.port", str(port)])  # fmt: skip
        with pytest.raises(UserError, match="already in use"):
            Trainer(cfg, console=Console(quiet=True), live_view=TrainingViewer()).setup()
    assert not (tmp_path / "out").exists()  # failed before loading data or making a run folder


def test_bad_host_is_a_user_error():
    with pytest.raises(UserError, match="cannot serve the viewer"):
        check_port_free("no-such-host.invalid", 7007)


def test_vis_auto_is_off_under_tests_and_ci(monkeypatch):
    assert not wants_viewer("auto")  # pytest (and CI) never open a server unless asked
    assert wants_viewer("viewer") and not wants_viewer("none")


def test_viewer_options_are_checked(tmp_path):
    with pytest.raises(ConfigError, match="--viewer.port must be in 0..65535"):
        parse_args(["vanilla-gs", "--data", str(tmp_path), "--viewer.port", "70000"])
    with pytest.raises(ConfigError, match="--viewer.render-share"):
        parse_args(["vanilla-gs", "--data", str(tmp_path), "--viewer.render-share", "0"])


def test_td_viewer_errors_are_one_line(tmp_path, capsys):
    from tridehaze_plugin.cli.common import run_cli

    with pytest.raises(SystemExit) as exc:
        run_cli(lambda: viewer_main(["--load-config", str(tmp_path / "nope" / "config.yml")]))
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: no such config file") and "\n" not in err
    with pytest.raises(SystemExit) as exc:
        run_cli(lambda: viewer_main(["--load-config", str(tmp_path), "--port", "-1"]))
    assert exc.value.code == 2 and "--port must be in 0..65535" in capsys.readouterr().err


def test_training_survives_viewers_that_come_and_go_and_pauses(tmp_path):
    """Abrupt websocket connects/drops during training; pause holds the loop; it then finishes."""
    scene = tiny_hazy_scene(tmp_path / "scene", test_every=0)
    argv = ["tri-dehaze", "--data", str(scene), "--output-dir", str(tmp_path / "out"), "--max-steps", "40",
            "--vis", "viewer", "--viewer.port", "0", "--viewer.no-wait-at-end", "--steps-per-save", "1000",
            *TRAIN_FLAGS]  # fmt: skip
    trainer = Trainer(parse_args(argv), console=Console(quiet=True), live_view=TrainingViewer())
    trainer.setup()
    viewer = trainer.viewer
    assert viewer is not None and viewer.training
    ws_url = viewer.url.replace("http", "ws")
    seen: dict[str, object] = {}

    def visitors() -> None:
        try:
            while viewer.loop.step < 5:
                time.sleep(0.01)
            for _ in range(3):  # connect, then vanish without a close handshake
                ws = connect(ws_url, subprotocols=[f"viser-v{viser.__version__}"], open_timeout=10)
                ws.socket.shutdown(socket.SHUT_RDWR)
                ws.socket.close()
            viewer._toggle_pause()
            time.sleep(0.3)  # let a step in flight finish
            before = viewer.loop.step
            time.sleep(0.7)
            seen["paused_steps"] = viewer.loop.step - before
            seen["readout"] = viewer._readouts.content
            viewer._toggle_pause()
        except Exception as exc:  # noqa: BLE001 - reported below
            seen["error"] = exc

    t = threading.Thread(target=visitors)
    t.start()
    result = trainer.train()
    t.join()
    assert "error" not in seen, seen.get("error")
    assert seen["paused_steps"] == 0 and str(seen["readout"]).startswith("**paused**")
    assert result.steps == 40 and viewer.loop.step == 40
    assert viewer._closed.is_set()
    with pytest.raises(OSError):  # the server is gone
        urllib.request.urlopen(viewer.url, timeout=2)
