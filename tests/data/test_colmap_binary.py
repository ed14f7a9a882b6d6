"""COLMAP binary files are checked against their size before pycolmap reads them (issue 22: a
truncated ``points3D.bin`` or a count of 2^62 grew memory past 10 GB with no output)."""

from __future__ import annotations

import resource
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pycolmap
import pytest

from components.data.parsers.colmap_binary import check_binary_model
from tests.data.synth import write_colmap
from tridehaze_plugin.errors import DataError

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real"


def binary_model(root: Path, points: int = 40) -> Path:
    """A COLMAP dataset whose sparse/0 is binary (written by pycolmap itself)."""
    rng = np.random.default_rng(0)
    write_colmap(root, n=4, points=rng.uniform(-0.5, 0.5, (points, 3)))
    sparse = root / "sparse" / "0"
    rec = pycolmap.Reconstruction(str(sparse))
    for f in sparse.glob("*.txt"):
        f.unlink()
    rec.write_binary(str(sparse))
    return sparse


def _u64(path: Path, offset: int, value: int) -> None:
    data = bytearray(path.read_bytes())
    struct.pack_into("<Q", data, offset, value)
    path.write_bytes(bytes(data))


def _truncate(path: Path, fraction: float = 0.5) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * fraction)])


def test_valid_models_pass(tmp_path):
    check_binary_model(binary_model(tmp_path / "m"))
    for scene in ("statue", "beer"):
        if (REAL / scene / "sparse" / "0").is_dir():
            check_binary_model(REAL / scene / "sparse" / "0")


# name -> (how to damage the model, expected message)
DAMAGE = {
    "points3D.bin cut in half": (
        lambda s: _truncate(s / "points3D.bin"),
        r"COLMAP points3D.bin is truncated or corrupt \((point \d+ runs past|it announces)",
    ),
    "points count 2^62": (
        lambda s: _u64(s / "points3D.bin", 0, 2**62),
        r"points3D.bin is truncated or corrupt \(it announces 4611686018427387904 points",
    ),
    "first point's track length 2^62": (
        lambda s: _u64(s / "points3D.bin", 8 + 43, 2**62),
        r"points3D.bin is truncated or corrupt \(point 0 announces a track of 4611686018427387904",
    ),
    "images.bin cut at 60 %": (
        lambda s: _truncate(s / "images.bin", 0.6),
        r"COLMAP images.bin is truncated or corrupt",
    ),
    "images count 2^40": (lambda s: _u64(s / "images.bin", 0, 2**40), r"it announces 1099511627776 images"),
    "cameras.bin unknown model id": (
        lambda s: (s / "cameras.bin").write_bytes(struct.pack("<QIiQQ", 1, 1, 99, 40, 30) + b"\0" * 32),
        r"camera 0 has the unknown model id 99",
    ),
    "points3D.bin with trailing bytes": (
        lambda s: (s / "points3D.bin").write_bytes((s / "points3D.bin").read_bytes() + b"junk"),
        r"COLMAP points3D.bin has 4 bytes after its 40 point\(s\)",
    ),
    "empty points3D.bin": (
        lambda s: (s / "points3D.bin").write_bytes(b""),
        r"points3D.bin is truncated or corrupt \(it ends inside a record; the file has 0 bytes\)",
    ),
}


@pytest.mark.parametrize("name", list(DAMAGE))
def test_damaged_models_are_refused(name, tmp_path):
    sparse = binary_model(tmp_path / "m")
    damage, expect = DAMAGE[name]
    damage(sparse)
    with pytest.raises(DataError, match=expect):
        check_binary_model(sparse)


@pytest.mark.parametrize("name", ["points3D.bin cut in half", "points count 2^62", "images count 2^40"])
def test_td_train_fails_in_one_line_under_a_memory_limit(name, tmp_path):
    """The runaway cases as a user meets them, with the address space capped at 4 GB: before the
    check these grew without bound; now they end at once with exit 2 and one line."""
    root = tmp_path / "ds"
    sparse = binary_model(root)
    DAMAGE[name][0](sparse)

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (4 * 2**30, 4 * 2**30))

    res = subprocess.run(
        [sys.executable, "-m", "tridehaze_plugin.cli.train", "vanilla-gs", "--data", str(root),
         "--output-dir", str(tmp_path / "out"), "--max-steps", "1", "--threads", "1"],
        capture_output=True, text=True, timeout=120, preexec_fn=cap,
        cwd=Path(__file__).resolve().parents[2],
    )  # fmt: skip
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2 and len(lines) == 1, res.stderr[-2000:]
    assert lines[0].startswith("error: COLMAP ") and "truncated or corrupt" in lines[0], lines[0]
    assert not (tmp_path / "out").exists()
