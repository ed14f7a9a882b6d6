"""The viewer in a real browser: headless Chromium (playwright-core) watches a tiny training run.

Checks: the page connects and shows a rendered frame (not blank, not one colour), switching the
output dropdown changes the image, a second browser and a reconnect are served, and training
advances throughout and still stops cleanly on Ctrl-C. Skipped locally when the tools are
missing, a failure under CI (see docs/viewer.md for the install lines).
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading

import cv2
import numpy as np

from tests.tiny_scenes import tiny_hazy_scene
from tests.viewer.helpers import BROWSER_CHECK, REPO, TRAIN_FLAGS, require_browser

OUTPUTS = ("clean", "hazy", "transmittance")


def start_training(scene, out) -> tuple[subprocess.Popen, str, list[str]]:
    """td-train with the viewer on a free port; returns the process, the viewer URL and its output."""
    cmd = [sys.executable, "-m", "tridehaze_plugin.cli.train", "tri-dehaze", "--data", str(scene),
           "--output-dir", str(out), "--max-steps", "100000", "--threads", "1", "--steps-per-save", "100000",
           "--vis", "viewer", "--viewer.port", "0", "--viewer.max-resolution", "96",
           "--viewer.moving-resolution", "48", "--viewer.thumbnail-size", "16", "--viewer.refresh-seconds", "0.5",
           *TRAIN_FLAGS]  # fmt: skip
    # Ctrl-C must reach td-train as in a terminal even when the suite itself was started in the
    # background (a shell without job control starts it with SIGINT ignored, which children inherit)
    proc = subprocess.Popen(
        cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    lines: list[str] = []
    url: list[str] = []
    found = threading.Event()

    def read() -> None:
        for line in proc.stdout:
            lines.append(line)
            m = re.search(r"viewer: (http://\S+)", line)
            if m and not url:
                url.append(m.group(1))
                found.set()
        found.set()

    threading.Thread(target=read, daemon=True).start()
    found.wait(120)
    assert url, "td-train printed no viewer URL:\n" + "".join(lines)
    return proc, url[0], lines


def crop(img: np.ndarray) -> np.ndarray:
    """The part of the page left of viser's control panel and above its axes gizmo."""
    h, w = img.shape[:2]
    return img[int(0.1 * h) : int(0.85 * h), int(0.1 * w) : int(0.6 * w)]


def test_viewer_in_a_real_browser(tmp_path):
    node, chromium = require_browser()
    scene = tiny_hazy_scene(tmp_path / "scene", width=40, height=30, test_every=0)
    proc, url, lines = start_training(scene, tmp_path / "out")
    shots = tmp_path / "shots"
    run = None
    try:
        run = subprocess.run(
            [node, str(BROWSER_CHECK), "--url", url, "--out", str(shots), "--outputs", ",".join(OUTPUTS),
             "--hide-cameras", "--second-page", "--reconnect"],
            capture_output=True, text=True, timeout=150, env={**os.environ, "CHROMIUM": chromium},
        )  # fmt: skip
        assert run.returncode == 0, run.stdout + run.stderr + "".join(lines)
        assert proc.poll() is None, "training stopped while browsers came and went:\n" + "".join(lines)
    finally:
        proc.send_signal(signal.SIGINT)  # Ctrl-C: checkpoint and exit, viewer or not
        try:
            code = proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
            browser = (run.stdout + run.stderr) if run is not None else "(browser check did not finish)"
            raise AssertionError(
                "td-train did not exit within 60 s of Ctrl-C\n--- browser check ---\n"
                f"{browser}\n--- td-train ---\n{''.join(lines)}"
            ) from None
    assert code == 130, "".join(lines)
    assert any("interrupted at step" in line for line in lines), "".join(lines)

    result = json.loads((shots / "result.json").read_text())
    images = {name: cv2.imread(result["shots"][name])[..., ::-1] for name in OUTPUTS}
    for name, img in images.items():  # a rendered frame, not viser's empty (white) scene or one colour
        part = crop(img).reshape(-1, 3)
        white = (part > 245).all(axis=1).mean()
        assert len(np.unique(part, axis=0)) > 10 and white < 0.5, (name, len(np.unique(part, axis=0)), white)
    clean = crop(images["clean"]).reshape(-1, 3).astype(float)
    assert clean.std(axis=0).max() > 3, "the clean view has no structure"
    for a, b in (("clean", "hazy"), ("hazy", "transmittance")):  # switching the output changes the image
        diff = np.abs(crop(images[a]).astype(float) - crop(images[b]).astype(float)).mean()
        assert diff > 3, f"{a} -> {b}: the image did not change (mean difference {diff:.2f})"

    steps = [int(re.search(r"step (\d+)", result[key]).group(1)) for key in ("text_before", "text_after")]
    assert steps[1] > steps[0], f"training did not advance while watched: {steps}"
    assert result["second_page"] and result["reconnected"]
