"""td-render --path interpolate|orbit: MP4s and PNG frames per output, side-by-side, errors."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest

from components.data.images import read_image
from tridehaze_plugin.cli.render import main as render_main
from tridehaze_plugin.errors import UserError

W, H = 40, 30


def _video(path: Path) -> tuple[int, int, int]:
    cap = cv2.VideoCapture(str(path))
    n = 0
    size = (0, 0)
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        n += 1
        size = frame.shape[1], frame.shape[0]
    cap.release()
    return n, *size


def test_orbit_writes_videos_and_frames(tri_run, tmp_path, capsys):
    out = tmp_path / "orbit"
    render_main(
        ["--load-config", str(tri_run), "--path", "orbit", "--num-frames", "5", "--fps", "10",
         "--outputs", "clean,transmittance,side-by-side", "--output-dir", str(out)]
    )  # fmt: skip
    assert "wrote 5 frames" in capsys.readouterr().out
    assert _video(out / "clean.mp4") == (5, W, H)
    assert _video(out / "transmittance.mp4") == (5, W, H)
    assert _video(out / "side-by-side.mp4") == (5, 2 * W, H)
    frames = sorted(p.name for p in (out / "clean").iterdir())
    assert frames == [f"frame_{i:05d}.png" for i in range(5)]
    assert read_image(out / "side-by-side" / "frame_00002.png").shape == (H, 2 * W, 3)
    meta = json.loads((out / "camera_path.json").read_text())
    assert len(meta["camtoworlds"]) == 5 and meta["fps"] == 10 and meta["intrinsics"]["w"] == W
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no staging left behind


def test_interpolate_without_frames_replaces_old_output(tri_run, tmp_path):
    out = tmp_path / "interp"
    (out / "hazy").mkdir(parents=True)
    (out / "hazy" / "frame_00099.png").write_bytes(b"old")
    render_main(
        ["--load-config", str(tri_run), "--path", "interpolate", "--num-frames", "4", "--outputs", "hazy",
         "--output-dir", str(out), "--split", "all"]
    )  # fmt: skip
    assert _video(out / "hazy.mp4") == (4, W, H)
    assert sorted(p.name for p in (out / "hazy").iterdir()) == [f"frame_{i:05d}.png" for i in range(4)]
    render_main(
        ["--load-config", str(tri_run), "--path", "interpolate", "--num-frames", "3", "--outputs", "clean",
         "--output-dir", str(out), "--no-frames"]
    )  # fmt: skip
    assert _video(out / "clean.mp4") == (3, W, H) and not (out / "clean").exists()


def test_views_side_by_side_and_errors(tri_run, tmp_path):
    out = tmp_path / "views"
    render_main(["--load-config", str(tri_run), "--outputs", "side-by-side", "--output-dir", str(out)])
    pngs = sorted((out / "side-by-side").glob("*.png"))
    assert pngs and read_image(pngs[0]).shape == (H, 2 * W, 3)
    with pytest.raises(UserError, match="num-frames must be at least 2"):
        render_main(["--load-config", str(tri_run), "--path", "orbit", "--num-frames", "1"])
    with pytest.raises(UserError, match="also side-by-side"):
        render_main(["--load-config", str(tri_run), "--path", "orbit", "--outputs", "fog"])
    with pytest.raises(UserError, match=r"fps must be in \(0, 1000\]"):
        render_main(["--load-config", str(tri_run), "--path", "orbit", "--fps", "0"])
