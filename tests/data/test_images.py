from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.data.images import image_size, read_depth, read_image, write_image_atomic
from components.data.ply import read_ply_points, write_ply_points
from tridehaze_plugin.errors import DataError

from .synth import make_image, write_rgb


def test_read_image_rgb_order_and_unicode_path(tmp_path):
    img = make_image(20, 10, 3)
    path = write_image_atomic_and_return(tmp_path / "ünïcödé 图" / "a.png", img)
    out = read_image(path)
    assert out.dtype == np.uint8 and out.shape == (10, 20, 3)
    np.testing.assert_array_equal(out, img)


def write_image_atomic_and_return(path, img):
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image_atomic(path, img)
    assert not [p for p in path.parent.iterdir() if p.name.endswith(".tmp")]  # no temp file left behind
    return path


def test_read_image_gray_16bit_and_alpha_on_white(tmp_path):
    gray = np.arange(12, dtype=np.uint8).reshape(3, 4) * 20
    cv2.imwrite(str(tmp_path / "g.png"), gray)
    np.testing.assert_array_equal(read_image(tmp_path / "g.png"), np.repeat(gray[:, :, None], 3, axis=2))

    deep = np.full((3, 4, 3), 65535, np.uint16)
    cv2.imwrite(str(tmp_path / "d.png"), deep)
    assert (read_image(tmp_path / "d.png") == 255).all()

    rgba = np.zeros((2, 2, 4), np.uint8)  # BGRA: black, alpha 0 / 255 / 128
    rgba[0, 0, 3], rgba[0, 1, 3], rgba[1, 0, 3] = 0, 255, 128
    cv2.imwrite(str(tmp_path / "a.png"), rgba)
    out = read_image(tmp_path / "a.png")
    assert out[0, 0].tolist() == [255, 255, 255]  # transparent -> white background
    assert out[0, 1].tolist() == [0, 0, 0]
    assert abs(int(out[1, 0, 0]) - 127) <= 1


@pytest.mark.parametrize("content", [b"", b"definitely not an image" * 4])
def test_read_image_corrupt_or_empty(tmp_path, content):
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(content)
    with pytest.raises(DataError, match="bad.jpg"):
        read_image(bad)
    with pytest.raises(DataError, match="bad.jpg"):
        image_size(bad)


def test_read_image_missing(tmp_path):
    with pytest.raises(DataError, match="not found"):
        read_image(tmp_path / "nope.png")


@pytest.mark.parametrize("ext", [".png", ".jpg", ".bmp"])
def test_image_size_matches_decode(tmp_path, ext):
    path = write_rgb(tmp_path / f"x{ext}", make_image(37, 23))
    assert image_size(path) == (37, 23)


def test_read_depth_npy_and_png(tmp_path):
    d = np.random.default_rng(0).random((5, 6)).astype(np.float32)
    np.save(tmp_path / "d.npy", d[:, :, None])
    np.testing.assert_array_equal(read_depth(tmp_path / "d.npy"), d)
    mm = np.array([[1000, 2500]], np.uint16)
    cv2.imwrite(str(tmp_path / "d.png"), mm)
    np.testing.assert_allclose(read_depth(tmp_path / "d.png"), [[1.0, 2.5]])
    with pytest.raises(DataError, match="unsupported depth format"):
        read_depth(tmp_path / "d.exr")


@settings(max_examples=20, deadline=None)
@given(n=st.integers(0, 30), binary=st.booleans(), colors=st.booleans(), seed=st.integers(0, 9))
def test_ply_round_trip(tmp_path_factory, n, binary, colors, seed):
    rng = np.random.default_rng(seed)
    xyz = rng.normal(size=(n, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, size=(n, 3), dtype=np.uint8) if colors else None
    path = tmp_path_factory.mktemp("ply") / "p.ply"
    write_ply_points(path, xyz, rgb, binary=binary)
    got, got_rgb = read_ply_points(path)
    np.testing.assert_allclose(got, xyz, rtol=1e-6)
    if colors:
        np.testing.assert_array_equal(got_rgb, rgb)
    else:
        assert got_rgb is None


def test_ply_binary_with_extra_properties_and_faces(tmp_path):
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment made by hand\nelement vertex 2\n"
        "property double x\nproperty double y\nproperty double z\nproperty float nx\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    dt = np.dtype(
        [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("nx", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")]
    )
    v = np.array([(1, 2, 3, 0, 10, 20, 30), (4, 5, 6, 0, 40, 50, 60)], dtype=dt)
    face = bytes([3]) + np.array([0, 1, 1], "<i4").tobytes()
    (tmp_path / "m.ply").write_bytes(header.encode() + v.tobytes() + face)
    xyz, rgb = read_ply_points(tmp_path / "m.ply")
    np.testing.assert_array_equal(xyz, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(rgb, [[10, 20, 30], [40, 50, 60]])


def test_ply_garbage(tmp_path):
    (tmp_path / "x.ply").write_bytes(
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n"
    )
    with pytest.raises(DataError, match="x.ply"):
        read_ply_points(tmp_path / "x.ply")
