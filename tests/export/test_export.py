"""td-export: the 3DGS PLY round-trips, the original-frame export renders like the trained model, the
medium grid matches the field, and bad input is a one-line error with nothing written."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from components.data.images import read_image
from components.data.scene import SceneTransform
from components.export.quaternions import matrix_to_quat, quat_to_matrix
from components.export.splat_ply import (
    SplatData,
    ply_properties,
    read_splat_ply,
    to_original_frame,
    write_splat_ply,
)
from components.gaussians.model import GaussianModel, GaussianModelConfig
from components.rasterizers.torch_reference import TorchRasterizer
from pipelines.engine.run_loader import load_run
from tridehaze_plugin.cli.common import run_cli
from tridehaze_plugin.cli.export import main as export_main
from tridehaze_plugin.errors import UserError


def random_splat(n: int, degree: int, seed: int = 0) -> SplatData:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4)).astype(np.float32)
    return SplatData(
        means=rng.normal(size=(n, 3)).astype(np.float32),
        sh0=rng.normal(size=(n, 1, 3)).astype(np.float32),
        shN=(0.3 * rng.normal(size=(n, (degree + 1) ** 2 - 1, 3))).astype(np.float32),
        opacity_logits=rng.normal(size=n).astype(np.float32),
        log_scales=(rng.normal(size=(n, 3)) - 3).astype(np.float32),
        quats=q / np.linalg.norm(q, axis=1, keepdims=True),
    )


def random_rotation(seed: int) -> np.ndarray:
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_ply_round_trip_and_layout(tmp_path, degree):
    data = random_splat(57, degree, seed=degree)
    size = write_splat_ply(tmp_path / "s.ply", data)
    blob = (tmp_path / "s.ply").read_bytes()
    assert size == len(blob)
    header = blob[: blob.index(b"end_header\n") + len(b"end_header\n")].decode()
    assert "format binary_little_endian 1.0" in header and "element vertex 57" in header
    props = [line.split()[2] for line in header.splitlines() if line.startswith("property float")]
    k1 = (degree + 1) ** 2 - 1
    assert props == ply_properties(3 * k1)
    assert props[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert props[-8:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert len(blob) - len(header) == 57 * 4 * (17 + 3 * k1)
    back = read_splat_ply(tmp_path / "s.ply")
    for name in ("means", "sh0", "shN", "opacity_logits", "log_scales", "quats"):
        np.testing.assert_array_equal(getattr(back, name), getattr(data, name), err_msg=name)
    if k1:  # channel-major f_rest: the first K-1 values of a row are the red channel's coefficients
        row = np.frombuffer(blob[len(header) :], "<f4").reshape(57, -1)[0]
        np.testing.assert_array_equal(row[9 : 9 + k1], data.shN[0, :, 0])


def test_reader_rejects_point_clouds(tmp_path):
    from components.data.ply import write_ply_points
    from tridehaze_plugin.errors import DataError

    write_ply_points(tmp_path / "p.ply", np.zeros((3, 3)))
    with pytest.raises(DataError, match="lacks the 3DGS properties"):
        read_splat_ply(tmp_path / "p.ply")


def test_quaternion_helpers():
    for seed in range(5):
        R = random_rotation(seed)
        np.testing.assert_allclose(quat_to_matrix(matrix_to_quat(R)), R, atol=1e-12)


@torch.no_grad()
def _render(data: SplatData, c2w: torch.Tensor, K: torch.Tensor, w: int, h: int) -> torch.Tensor:
    deg = data.sh_degree
    model = GaussianModel(GaussianModelConfig(sh_degree=deg), data.model_params())
    view = torch.linalg.inv(c2w)[None].float()
    out = TorchRasterizer().rasterize(
        model.means, model.quats, model.scales, model.opacities, model.sh_coeffs, view, K[None], w, h,
        background=torch.zeros(3), sh_degree=deg,
    )  # fmt: skip
    return out.rgb[0]


def test_original_frame_renders_like_the_normalised_model():
    """Undoing a rotated, scaled, shifted dataparser transform moves Gaussians, orientations and the
    view-dependent colour consistently: the same camera (carried along) sees the same image."""
    data = random_splat(60, 3, seed=4)
    data.means *= 0.4
    data.shN *= 2.0  # strong view dependence, so a wrong SH rotation shows
    R = random_rotation(7)
    tr = SceneTransform(torch.from_numpy(R), torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64), 0.37)
    orig = to_original_frame(data, tr)
    w, h = 40, 30
    K = torch.tensor([[36.0, 0, 20], [0, 36.0, 15], [0, 0, 1]])
    for angle in (0.0, 1.3):
        # a camera at distance 3 looking at the origin (normalised frame), OpenCV axes
        pos = np.array([3 * math.sin(angle), 0.4, -3 * math.cos(angle)])
        z = -pos / np.linalg.norm(pos)
        x = np.cross(np.array([0.0, 1.0, 0.0]), z)
        x /= np.linalg.norm(x)
        c2w_n = np.eye(4)
        c2w_n[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
        c2w_n[:3, 3] = pos
        c2w_o = np.eye(4)  # x_n = s (R x_o + t) -> x_o = R^T (x_n / s - t)
        c2w_o[:3, :3] = R.T @ c2w_n[:3, :3]
        c2w_o[:3, 3] = R.T @ (pos / tr.scale - tr.translation.numpy())
        a = _render(data, torch.from_numpy(c2w_n), K, w, h)
        b = _render(orig, torch.from_numpy(c2w_o), K, w, h)
        assert float(a.abs().mean()) > 0.05  # something is visible
        torch.testing.assert_close(b, a, atol=1e-5, rtol=0)  # measured 1.3e-6 (float32)
    # without the SH rotation the view-dependent colour would differ
    wrong = SplatData(**{**orig.__dict__, "shN": data.shN.copy()})
    assert float((_render(wrong, torch.from_numpy(c2w_o), K, w, h) - a).abs().max()) > 1e-2


# ---------------------------------------------------------------------------- td-export on runs


def test_export_tri_dehaze_run(tri_run, tmp_path, capsys):
    out = tmp_path / "exp"
    export_main(["--load-config", str(tri_run), "--output-dir", str(out), "--medium-resolution", "24"])
    said = capsys.readouterr().out
    assert "Gaussians" in said and "medium.npz" in said
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(
        [
            "splat.ply",
            ".tridehaze-output.json",
            "medium.npz",
            "export.json",
            "extinction_xy.png",
            "extinction_xz.png",
            "extinction_yz.png",
        ]
    )
    assert not list(tmp_path.glob(".exp.tmp-*"))
    run = load_run(tri_run)
    model, tr = run.pipeline.model, run.datamanager.scene.transform
    ply = read_splat_ply(out / "splat.ply")
    assert len(ply) == model.num_gaussians
    expect = to_original_frame(SplatData.from_model(model), tr)
    np.testing.assert_allclose(ply.means, expect.means, rtol=0, atol=1e-6)
    # the original frame is the dataset's: means map back onto the normalised ones
    back = tr.apply_points(torch.from_numpy(ply.means.astype(np.float64))).float()
    torch.testing.assert_close(back, model.means.detach(), atol=1e-5, rtol=0)
    np.testing.assert_allclose(
        ply.log_scales, model.log_scales.detach().numpy() - math.log(tr.scale), atol=1e-5
    )
    meta = json.loads((out / "export.json").read_text())
    assert (
        meta["gaussians"] == model.num_gaussians and meta["ply_bytes"] == (out / "splat.ply").stat().st_size
    )
    # the medium grid: beta at a grid point (mapped to the normalised world) equals the field, in dataset units
    med = np.load(out / "medium.npz")
    assert med["beta"].shape == (24, 24, 24) and str(med["frame"]) == "original"
    assert med["light"].shape == (6, 16, 16, 16, 3)
    for ijk in [(0, 0, 0), (5, 17, 23), (12, 12, 12)]:
        p = med["grid_to_world"] @ np.array([*ijk, 1.0])
        x_n = tr.apply_points(torch.from_numpy(p[None, :3])).float()
        with torch.no_grad():
            beta = run.pipeline.medium(x_n, torch.tensor([[0.0, 0.0, 1.0]])).beta
        assert med["beta"][ijk] == pytest.approx(float(beta) * tr.scale, rel=1e-4)
    assert read_image(out / "extinction_xy.png").shape[2] == 3


def test_export_normalized_frame_and_no_medium(plain_run, tmp_path, capsys):
    out = tmp_path / "plain"
    export_main(["--load-config", str(plain_run), "--output-dir", str(out), "--frame", "normalized"])
    assert "no medium: only the PLY" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == [".tridehaze-output.json", "export.json", "splat.ply"]
    model = load_run(plain_run).pipeline.model
    ply = read_splat_ply(out / "splat.ply")
    np.testing.assert_array_equal(ply.means, model.means.detach().numpy())
    np.testing.assert_array_equal(ply.shN, model.shN.detach().numpy())


def test_export_gaussian_bound_medium(bound_run, tmp_path):
    out = tmp_path / "bound"
    export_main(["--load-config", str(bound_run), "--output-dir", str(out)])
    med = np.load(out / "medium.npz")
    n = len(read_splat_ply(out / "splat.ply"))
    assert str(med["kind"]) == "gaussian-bound"
    assert med["beta_per_gaussian"].shape == (n,) and med["light_per_gaussian"].shape == (n, 3)
    assert not list(out.glob("extinction_*.png"))


def test_export_errors_are_one_line_and_write_nothing(tri_run, tmp_path, capsys):
    with pytest.raises(UserError, match="run config not found"):
        export_main(["--load-config", str(tmp_path / "nope.yml"), "--output-dir", str(tmp_path / "o")])
    full = tmp_path / "full"
    full.mkdir()
    (full / "keep.txt").write_text("x")
    with pytest.raises(UserError, match="not empty"):
        export_main(["--load-config", str(tri_run), "--output-dir", str(full)])
    assert [p.name for p in full.iterdir()] == ["keep.txt"]
    with pytest.raises(UserError, match="medium-resolution"):
        export_main(
            [
                "--load-config",
                str(tri_run),
                "--output-dir",
                str(tmp_path / "o"),
                "--medium-resolution",
                "1",
            ]
        )
    assert not (tmp_path / "o").exists()
    with pytest.raises(SystemExit) as exc:  # as the console script runs it: one line, exit code 2
        run_cli(lambda: export_main(["--load-config", str(tmp_path / "nope.yml")]))
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: run config not found") and err.count("\n") == 1


def test_overwrite_replaces_only_a_folder_td_export_wrote(tri_run, tmp_path):
    """Issue 22: ``--overwrite`` onto a folder holding a run and a user's file deleted both."""
    top = tmp_path / "dir"
    run = Path(shutil.copytree(tri_run.parent, top / "sub" / "run"))
    (top / "important.txt").write_text("keep me")
    before = sorted(p.relative_to(top) for p in top.rglob("*"))
    for target in (top, run):  # a folder holding a run, and the run folder itself
        with pytest.raises(UserError, match="--overwrite refused: td-export did not write this folder"):
            export_main(
                ["--load-config", str(run / "config.yml"), "--output-dir", str(target), "--overwrite"]
            )
    assert sorted(p.relative_to(top) for p in top.rglob("*")) == before
    assert (top / "important.txt").read_text() == "keep me"

    out = tmp_path / "export"
    export_main(["--load-config", str(tri_run), "--output-dir", str(out)])
    export_main(["--load-config", str(tri_run), "--output-dir", str(out), "--overwrite"])  # its own: fine
    assert (out / "splat.ply").is_file() and (out / "export.json").is_file()
    (out / "notes.md").write_text("mine")
    with pytest.raises(UserError, match=r"holds 1 file\(s\) td-export did not write \(notes.md\)"):
        export_main(["--load-config", str(tri_run), "--output-dir", str(out), "--overwrite"])
    assert (out / "notes.md").read_text() == "mine"
