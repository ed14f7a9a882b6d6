"""td-synth from the outside (one line, exit 2 for user mistakes), the gallery and the demo scene."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import pytest

import components.synth.demo as demo
from components.data.config import DataConfig
from components.data.loader import load_scene
from components.synth.medium import PRESETS
from tridehaze_plugin.cli.common import run_cli
from tridehaze_plugin.cli.synth import main


def run_inproc(capsys, *args: str) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of ``td-synth ARGS`` run in this process through ``run_cli``."""
    with pytest.raises(SystemExit) as exc:
        run_cli(lambda: main(list(args)))
        raise SystemExit(0)
    cap = capsys.readouterr()
    return int(exc.value.code or 0), cap.out, cap.err


def failing(capsys, *args: str) -> tuple[int, str]:
    code, _, err = run_inproc(capsys, *args)
    return code, err


def assert_one_line(code: int, err: str, *needles: str) -> None:
    assert code == 2, err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    for n in needles:
        assert n in lines[0], lines[0]


def test_entrypoint_help_and_error_exit_2(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "TRIDEHAZE_PLUGINS"}
    cmd = [sys.executable, "-m", "tridehaze_plugin.cli.synth"]
    res = subprocess.run([*cmd, "--help"], capture_output=True, text=True, timeout=120, env=env)
    assert res.returncode == 0 and all(s in res.stdout for s in ("scene", "haze", "gallery"))
    res = subprocess.run(
        [*cmd, "haze", "--data", str(tmp_path / "nope"), "--output-dir", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert_one_line(res.returncode, res.stderr, "dataset folder not found")


def test_haze_user_errors(capsys, tmp_path, tiny_dataset):
    out = str(tmp_path / "o")
    base = ("haze", "--data", str(tiny_dataset), "--output-dir", out)
    assert_one_line(*failing(capsys, *base, "--beta", "-1"), "--beta")
    assert_one_line(*failing(capsys, *base, "--median-transmittance", "1.2"), "--median-transmittance")
    assert_one_line(*failing(capsys, *base), "no depth map", "--depth-from-run")
    assert_one_line(
        *failing(capsys, *base, "--depth-from-run", str(tmp_path / "x.yml")), "run config not found"
    )
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "f").write_text("x")
    args = ("haze", "--data", str(tiny_dataset), "--output-dir", str(busy), "--beta", "0.1")
    assert_one_line(*failing(capsys, *args), "not empty", "--overwrite")
    assert (busy / "f").read_text() == "x"


def test_scene_cli_and_errors(capsys, tmp_path):
    out = tmp_path / "s"
    small = ("--num-views", "2", "--width", "24", "--height", "18", "--samples", "16", "--supersample", "1")
    code, stdout, _ = run_inproc(capsys, "scene", "--output-dir", str(out), "--layout", "room", *small)
    assert code == 0 and "mean T" in stdout and (out / "transforms.json").is_file()
    assert_one_line(*failing(capsys, "scene", "--output-dir", str(out), *small), "not empty")
    assert_one_line(
        *failing(capsys, "scene", "--output-dir", str(tmp_path / "t"), "--num-views", "0"), "--num-views"
    )


def test_gallery(capsys, tmp_path):
    png = tmp_path / "g.png"
    args = f"gallery --output {png} --layouts room field --width 32 --height 24".split()
    code, stdout, _ = run_inproc(capsys, *args)
    assert code == 0 and "homogeneous" in stdout
    img = cv2.imread(str(png))
    rows = len(PRESETS)  # one row per haze preset
    assert img is not None and img.shape[1] == 92 + 6 * (32 + 2) and img.shape[0] == 30 + rows * (24 + 2)


def test_demo_is_generated_once_and_reused(tmp_path, monkeypatch):
    small = replace(demo.DEMO, num_views=4, width=32, height=24, samples=16, supersample=1, num_points=200)
    monkeypatch.setattr(demo, "DEMO", small)
    path = demo.demo_scene_path(tmp_path)
    assert path.parent == tmp_path / "synth" and demo.is_complete(path)
    stamp = (path / "transforms.json").stat().st_mtime_ns
    assert demo.demo_scene_path(tmp_path) == path
    assert (path / "transforms.json").stat().st_mtime_ns == stamp  # reused, not rewritten
    (path / "images" / "0001.png").unlink()  # a damaged copy is regenerated
    assert demo.demo_scene_path(tmp_path) == path and demo.is_complete(path)
    assert len(load_scene(DataConfig(data=path, cache_dir=tmp_path / "c"))) == 4
    assert sorted(p.name for p in (tmp_path / "synth").iterdir()) == [path.name]  # no temp folders


def test_demo_settings_are_small():
    """The real demo: ~24 views near 128x96, so a first td-train without --data starts in seconds."""
    cfg = demo.DEMO
    assert 16 <= cfg.num_views <= 32 and cfg.width * cfg.height <= 160 * 120
    assert Path(demo.demo_dir(None)).name.startswith("demo-")
