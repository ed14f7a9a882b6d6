"""One test per bad input: each raises DataError whose one-line message names the culprit."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from components.data.loader import DataWarning, load_scene
from tridehaze_plugin.errors import DataError

from .synth import make_image, write_colmap, write_nerfstudio, write_rgb


def _edit_frames(root, fn):
    meta = json.loads((root / "transforms.json").read_text())
    fn(meta)
    (root / "transforms.json").write_text(json.dumps(meta))


def test_no_dataset_given(make_cfg):
    with pytest.raises(DataError, match="no dataset given.*--data"):
        load_scene(make_cfg(None))


def test_missing_folder(tmp_path, make_cfg):
    with pytest.raises(DataError, match="dataset folder not found") as e:
        load_scene(make_cfg(tmp_path / "nowhere"))
    assert "nowhere" in str(e.value)


def test_data_is_a_file(tmp_path, make_cfg):
    (tmp_path / "f.txt").write_text("x")
    with pytest.raises(DataError, match="must be a folder.*f.txt"):
        load_scene(make_cfg(tmp_path / "f.txt"))


def test_unknown_format_lists_what_was_looked_for(tmp_path, make_cfg):
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="transforms.json.*transforms_train.json.*sparse") as e:
        load_scene(make_cfg(tmp_path / "empty"))
    assert "empty" in str(e.value)


def test_invalid_json(tmp_path, make_cfg):
    (tmp_path / "transforms.json").write_text('{"frames": [}')
    with pytest.raises(DataError, match="invalid JSON at line 1.*transforms.json"):
        load_scene(make_cfg(tmp_path))


def test_no_images(tmp_path, make_cfg):
    (tmp_path / "transforms.json").write_text(json.dumps({"fl_x": 10, "w": 8, "h": 8, "frames": []}))
    with pytest.raises(DataError, match="no images") as e:
        load_scene(make_cfg(tmp_path))
    assert str(tmp_path) in str(e.value)


def test_corrupt_image(tmp_path, make_cfg):
    write_nerfstudio(tmp_path, n=3)
    (tmp_path / "images" / "frame_001.png").write_bytes(b"\x89PNG but not really" * 3)
    with pytest.raises(DataError, match="corrupt.*frame_001.png"):
        load_scene(make_cfg(tmp_path))


@pytest.mark.parametrize("model", ["FOV", "THIN_PRISM_FISHEYE"])
def test_unsupported_camera_model(tmp_path, make_cfg, model):
    n_params = {"FOV": 5, "THIN_PRISM_FISHEYE": 12}[model]
    write_colmap(tmp_path, n=2, model=model, params=[30.0, 30.0, 20.0, 15.0] + [0.01] * (n_params - 4))
    with pytest.raises(DataError, match=f"model {model}.*not supported.*sparse.*PINHOLE, SIMPLE_PINHOLE"):
        load_scene(make_cfg(tmp_path))


def test_listed_images_missing(tmp_path, make_cfg):
    write_nerfstudio(tmp_path, n=4)
    (tmp_path / "images" / "frame_002.png").unlink()
    with pytest.raises(
        DataError, match=r"1 of 4 listed image\(s\) are missing: images/frame_002.png.*skip-missing"
    ):
        load_scene(make_cfg(tmp_path))


def test_listed_images_missing_skipped_with_warning(tmp_path, make_cfg):
    write_nerfstudio(
        tmp_path, n=4, extra_global={"test_filenames": ["images/frame_002.png", "images/frame_003.png"]}
    )
    (tmp_path / "images" / "frame_002.png").unlink()
    with pytest.warns(DataWarning, match="frame_002.png"):
        scene = load_scene(make_cfg(tmp_path, skip_missing_images=True))
    assert len(scene) == 3 and "images/frame_002.png" not in scene.names()
    assert scene.test_indices == [2]  # the split still names the dropped view: it is just left out


def test_all_images_missing_even_when_skipping(tmp_path, make_cfg):
    write_nerfstudio(tmp_path, n=2)
    for p in (tmp_path / "images").iterdir():
        p.unlink()
    with warnings.catch_warnings(), pytest.raises(DataError, match="all listed images are missing"):
        warnings.simplefilter("ignore")
        load_scene(make_cfg(tmp_path, skip_missing_images=True))


def test_nan_pose(tmp_path, make_cfg):
    write_nerfstudio(tmp_path, n=3)
    _edit_frames(tmp_path, lambda m: m["frames"][1]["transform_matrix"][0].__setitem__(3, float("nan")))
    with pytest.raises(DataError, match="pose of frame images/frame_001.png contains NaN"):
        load_scene(make_cfg(tmp_path))


def test_non_rigid_pose(tmp_path, make_cfg):
    write_nerfstudio(tmp_path, n=3)

    def scale(meta):
        m = np.array(meta["frames"][2]["transform_matrix"])
        m[:3, :3] *= 1.1
        meta["frames"][2]["transform_matrix"] = m.tolist()

    _edit_frames(tmp_path, scale)
    with pytest.raises(DataError, match="pose of frame images/frame_002.png is not a rigid rotation"):
        load_scene(make_cfg(tmp_path))


def test_non_positive_focal(tmp_path, make_cfg):
    write_nerfstudio(tmp_path, n=2, extra_global={"fl_x": -5.0})
    with pytest.raises(DataError, match="non-positive or invalid fx.*frame_000.png"):
        load_scene(make_cfg(tmp_path))


def test_image_size_differs_from_camera(tmp_path, make_cfg):
    write_colmap(tmp_path, n=2)
    write_rgb(tmp_path / "images" / "0001.png", make_image(20, 15))
    with pytest.raises(DataError, match="image is 20x15 but its camera says 40x30.*0001.png"):
        load_scene(make_cfg(tmp_path))


def test_mismatched_clean_and_hazy_names(tmp_path, make_cfg):
    write_colmap(tmp_path, n=3)
    for i in range(3):
        write_rgb(tmp_path / "clean" / f"{i:04d}_clean.png", make_image(40, 30))
    with pytest.raises(DataError, match="clean/ and images/ names do not match.*0000_clean.png.*clean"):
        load_scene(make_cfg(tmp_path))


def test_clean_size_differs_from_hazy(tmp_path, make_cfg):
    write_nerfstudio(tmp_path, n=2, clean=True)
    write_rgb(tmp_path / "clean" / "frame_001.png", make_image(20, 15))
    with pytest.raises(DataError, match="clean image is 20x15 but hazy image images/frame_001.png is 40x30"):
        load_scene(make_cfg(tmp_path))


@pytest.mark.parametrize(
    ("opt", "flag"), [({"downscale": 0}, "--downscale"), ({"test_every": -1}, "--test-every")]
)
def test_bad_options(tmp_path, make_cfg, opt, flag):
    write_nerfstudio(tmp_path, n=2)
    with pytest.raises(DataError, match=flag):
        load_scene(make_cfg(tmp_path, **opt))


def test_test_every_one_leaves_no_training_views(tmp_path, make_cfg):
    write_nerfstudio(tmp_path, n=3)
    with pytest.raises(DataError, match="test_every=1 leaves no training views"):
        load_scene(make_cfg(tmp_path, test_every=1))


def test_split_names_unknown_image(tmp_path, make_cfg):
    write_nerfstudio(
        tmp_path, n=3, extra_global={"train_filenames": ["images/frame_000.png", "images/nope.png"]}
    )
    with pytest.raises(DataError, match="train split names 'images/nope.png'.*matches no image"):
        load_scene(make_cfg(tmp_path))


def test_non_finite_and_absurd_seed_points_are_dropped_with_a_count(tmp_path, make_cfg):
    """Issue 22: NaN / inf / 1e30 seed points were accepted and every training step was skipped."""
    nan, inf = float("nan"), float("inf")
    pts = np.array([[0.0, 0.0, 0.0], [nan, 0.0, 0.0], [0.1, inf, 0.2], [1e30, 0.0, 0.0], [0.3, -0.2, 0.1]])
    _colmap_binary_with_points(tmp_path, pts)
    with pytest.warns(DataWarning, match=r"dropped 2 non-finite and 1 absurdly far seed point\(s\) of 5"):
        scene = load_scene(make_cfg(tmp_path, center_poses=False, scale_poses=False))
    np.testing.assert_allclose(scene.points.numpy(), pts[[0, 4]], atol=1e-6)
    assert scene.point_colors.shape == (2, 3)


@pytest.mark.parametrize("bad", [float("nan"), float("-inf"), 1e30])
def test_only_unusable_seed_points_is_an_error(bad, tmp_path, make_cfg):
    _colmap_binary_with_points(tmp_path, np.array([[bad, 0.0, 0.0], [0.0, bad, 1.0]]))
    with pytest.raises(DataError, match="none of the 2 seed points is usable"):
        load_scene(make_cfg(tmp_path))


def _colmap_binary_with_points(root, pts: np.ndarray) -> None:
    """A binary COLMAP model holding exactly ``pts`` (COLMAP's text reader cannot even parse nan)."""
    import pycolmap

    write_colmap(root, n=4, points=np.zeros_like(pts))
    sparse = root / "sparse" / "0"
    rec = pycolmap.Reconstruction(str(sparse))
    for pid, xyz in zip(sorted(rec.points3D), pts, strict=True):
        rec.points3D[pid].xyz = xyz
    for f in sparse.glob("*.txt"):
        f.unlink()
    rec.write_binary(str(sparse))
