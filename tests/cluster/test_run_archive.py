"""Run folders and scenes as archives (sweeps without a shared file system), storage copies, and the
executor flags' checks. No Ray needed."""

from __future__ import annotations

import io
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest

from pipelines.experiments.run_archive import (
    copy_to_storage,
    folder_fingerprint,
    pack_folder,
    run_folder_filter,
    unpack_folder,
)
from pipelines.experiments.sweep_progress import SweepProgress


def _run_folder(root: Path) -> Path:
    (root / "checkpoints").mkdir(parents=True)
    (root / "checkpoints" / "step-0000010.ckpt").write_bytes(b"\0" * 100)
    (root / "eval").mkdir()
    (root / "eval" / "test.json").write_text('{"psnr": 20}')
    (root / "config.yml").write_text("method_name: tri-dehaze\n")
    return root


def test_round_trip_leaves_checkpoints_out_unless_asked(tmp_path):
    run = _run_folder(tmp_path / "run")
    dest = unpack_folder(pack_folder(run, run_folder_filter(False)), tmp_path / "back")
    assert sorted(p.relative_to(dest).as_posix() for p in dest.rglob("*") if p.is_file()) == [
        "config.yml", "eval/test.json"]  # fmt: skip
    assert (dest / "eval" / "test.json").read_text() == '{"psnr": 20}'
    dest = unpack_folder(pack_folder(run, run_folder_filter(True)), tmp_path / "back")  # replaces
    assert (dest / "checkpoints" / "step-0000010.ckpt").read_bytes() == b"\0" * 100
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".back")]  # no temp folders left
    with pytest.raises(FileExistsError):
        unpack_folder(pack_folder(run), dest, replace=False)


def test_an_archive_cannot_write_outside_its_folder(tmp_path):
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        info = tarfile.TarInfo("../escaped.txt")
        info.size = 2
        tar.addfile(info, io.BytesIO(b"hi"))
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "keep.txt").write_text("x")
    with pytest.raises(tarfile.TarError):
        unpack_folder(buf.getvalue(), tmp_path / "old")
    assert not (tmp_path / "escaped.txt").exists()
    assert (tmp_path / "old" / "keep.txt").read_text() == "x"  # the earlier folder is untouched


def test_fingerprint_follows_content_not_location(tmp_path):
    a = _run_folder(tmp_path / "a")
    b = unpack_folder(pack_folder(a), tmp_path / "b")
    assert folder_fingerprint(a) == folder_fingerprint(b)
    (b / "eval" / "test.json").write_text('{"psnr": 21}')
    assert folder_fingerprint(a) != folder_fingerprint(b)


@pytest.mark.parametrize("as_uri", [False, True])
def test_copy_to_storage_path_and_uri(tmp_path, as_uri):
    run = _run_folder(tmp_path / "run")
    location = (tmp_path / "store").as_uri() if as_uri else str(tmp_path / "store")
    where = copy_to_storage(run, location, "sA/tri-dehaze/full", run_folder_filter(False))
    landed = tmp_path / "store" / "sA" / "tri-dehaze" / "full"
    assert where == (f"{location}/sA/tri-dehaze/full" if as_uri else str(landed))
    assert (landed / "eval" / "test.json").read_text() == '{"psnr": 20}'
    assert (landed / "config.yml").is_file() and not (landed / "checkpoints").exists()


def test_progress_counts_and_eta():
    p = SweepProgress(4, "t")
    p.skip()
    assert p.eta_seconds() is None  # a run skipped now took no time: no rate yet
    p.started("a")
    p.started("b")
    assert len(p.running) == 2 and "running 2" in p._state()
    p.finished("a", ok=True)
    p.finished("b", ok=False)
    assert (p.done, p.failed, len(p.running)) == (2, 1, 0)
    assert p.eta_seconds() is not None and p.eta_seconds() >= 0
    assert p._state() == "done 2 / running 0 / failed 1 of 4"


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize(
    "module, flag",
    [
        ("tridehaze_plugin.cli.ablate", "--ray-address=127.0.0.1:6379"),
        ("tridehaze_plugin.cli.bench", "--keep-checkpoints"),
    ],
)
def test_ray_flags_need_the_ray_executor(tmp_path, module, flag):
    args = ["tradeoff"] if module.endswith("bench") else []
    r = _cli(module, *args, "--scenes", str(tmp_path), flag)
    assert r.returncode == 2 and "only apply to --executor ray" in r.stderr and "Traceback" not in r.stderr


def test_an_unreachable_cluster_is_a_clear_error(tmp_path):
    from tests.export.tiny_run import make_scene

    scene = make_scene(tmp_path / "s")
    r = _cli("tridehaze_plugin.cli.ablate", "--scenes", str(scene), "--executor", "ray",
             "--ray-address", "127.0.0.2:1", "--families", "schedule", "--lpips", "off")  # fmt: skip
    assert r.returncode == 2, r.stdout + r.stderr
    assert "cannot connect to the Ray cluster" in r.stderr and "Traceback" not in r.stderr
