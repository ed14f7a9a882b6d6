"""Gaussians as a standard 3D Gaussian Splatting PLY (the INRIA ``point_cloud.ply`` layout).

One ``vertex`` element, binary little-endian float32 properties in this order::

    x y z  nx ny nz  f_dc_0 f_dc_1 f_dc_2  f_rest_0 .. f_rest_{3(K-1)-1}  opacity
    scale_0 scale_1 scale_2  rot_0 rot_1 rot_2 rot_3

* ``f_dc_c``: the degree-0 SH coefficient of colour channel c (colour = 0.2821 f_dc + 0.5);
* ``f_rest``: the higher bands **channel-major**: ``f_rest_{c (K-1) + j}`` is coefficient j+1 of
  channel c (all red coefficients, then green, then blue), as the INRIA code writes
  ``features_rest.transpose(1, 2).flatten(1)``;
* ``opacity``: the logit (sigmoid gives the opacity); ``scale_i``: natural log of the standard
  deviations; ``rot``: quaternion (w, x, y, z), normalised; normals are zero.

This is what SIBR, SuperSplat, antimatter15/splat, gsplat's and nerfstudio's exporters write and
read. :func:`read_splat_ply` reads it back (also files written by those tools).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch

from components.data.images import write_bytes_atomic
from components.data.scene import SceneTransform
from components.export.quaternions import matrix_to_quat, quat_multiply
from components.export.sh_rotation import rotate_sh
from tridehaze_plugin.errors import DataError


@dataclass
class SplatData:
    """N Gaussians in the 3DGS parameterisation (numpy, float32)."""

    means: np.ndarray  # [N, 3]
    sh0: np.ndarray  # [N, 1, 3]
    shN: np.ndarray  # [N, K-1, 3]  # noqa: N815 - conventional name
    opacity_logits: np.ndarray  # [N]
    log_scales: np.ndarray  # [N, 3]
    quats: np.ndarray  # [N, 4] (w, x, y, z), unit length

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return int(round(math.sqrt(self.shN.shape[1] + 1))) - 1

    @staticmethod
    def from_model(model) -> SplatData:
        """Copy the parameters of a :class:`~components.gaussians.model.GaussianModel`."""

        def arr(t: torch.Tensor) -> np.ndarray:
            return t.detach().float().cpu().numpy().copy()

        return SplatData(
            means=arr(model.means),
            sh0=arr(model.sh0),
            shN=arr(model.shN),
            opacity_logits=arr(model.opacity_logits),
            log_scales=arr(model.log_scales),
            quats=arr(model.normalized_quats),
        )

    def model_params(self) -> dict[str, torch.Tensor]:
        """The parameter dict a ``GaussianModel`` is built from."""
        return {
            "means": torch.from_numpy(self.means),
            "quats": torch.from_numpy(self.quats),
            "log_scales": torch.from_numpy(self.log_scales),
            "opacity_logits": torch.from_numpy(self.opacity_logits),
            "sh0": torch.from_numpy(self.sh0),
            "shN": torch.from_numpy(self.shN),
        }


# ------------------------------------------------------------------------------ frames


def to_original_frame(data: SplatData, transform: SceneTransform) -> SplatData:
    """Undo the dataparser similarity ``x_new = s (R x + t)``: Gaussians in the dataset's own world.

    Means: ``x = R^T (x_new / s - t)``; log-scales minus ``ln s``; orientations and the view-
    dependent colour (SH bands >= 1) rotated by ``R^T``. Opacity and the DC colour are unchanged.
    """
    R = transform.rotation.detach().cpu().double().numpy()  # [3, 3]
    t = transform.translation.detach().cpu().double().numpy()  # [3]
    s = float(transform.scale)
    means = (data.means.astype(np.float64) / s - t) @ R  # (R^T v) as a row-vector product
    q_rt = matrix_to_quat(R.T)  # [4]
    quats = quat_multiply(q_rt[None], data.quats.astype(np.float64))
    quats /= np.linalg.norm(quats, axis=-1, keepdims=True)
    shN = rotate_sh(data.shN.astype(np.float64), R.T) if data.shN.shape[1] else data.shN  # noqa: N806
    return SplatData(
        means=means.astype(np.float32),
        sh0=data.sh0.copy(),
        shN=np.asarray(shN, np.float32),
        opacity_logits=data.opacity_logits.copy(),
        log_scales=(data.log_scales.astype(np.float64) - math.log(s)).astype(np.float32),
        quats=quats.astype(np.float32),
    )


# ------------------------------------------------------------------------------ PLY I/O


def ply_properties(num_rest: int) -> list[str]:
    """Property names in file order for ``num_rest`` = 3 (K-1) higher-band coefficients."""
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(num_rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )


def encode_splat_ply(data: SplatData) -> bytes:
    n = len(data)
    k1 = data.shN.shape[1]
    names = ply_properties(3 * k1)
    table = np.zeros((n, len(names)), dtype="<f4")
    table[:, 0:3] = data.means
    table[:, 6:9] = data.sh0.reshape(n, 3)
    # channel-major: [N, K-1, 3] -> [N, 3, K-1] -> [N, 3 (K-1)]
    table[:, 9 : 9 + 3 * k1] = np.transpose(data.shN, (0, 2, 1)).reshape(n, 3 * k1)
    j = 9 + 3 * k1
    table[:, j] = data.opacity_logits
    table[:, j + 1 : j + 4] = data.log_scales
    table[:, j + 4 : j + 8] = data.quats
    header = ["ply", "format binary_little_endian 1.0"]  # no comment line: some web viewers choke on it
    header += [f"element vertex {n}"] + [f"property float {p}" for p in names] + ["end_header"]
    return ("\n".join(header) + "\n").encode("ascii") + np.ascontiguousarray(table).tobytes()


def write_splat_ply(path: Path, data: SplatData) -> int:
    """Write ``data`` atomically; returns the file size in bytes."""
    blob = encode_splat_ply(data)
    write_bytes_atomic(Path(path), blob)
    return len(blob)


def read_splat_ply(path: Path) -> SplatData:
    """Read a 3DGS PLY (binary or ASCII); DataError when it is not one."""
    from components.data.ply import read_ply_vertex

    path = Path(path)
    v = read_ply_vertex(path, "PLY file")
    names = set(v.dtype.names or ())
    need = {"x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"}
    need |= {f"scale_{i}" for i in range(3)} | {f"rot_{i}" for i in range(4)}
    missing = sorted(need - names)
    if missing:
        raise DataError(
            f"PLY lacks the 3DGS properties {', '.join(missing)}",
            where=str(path),
            fix="this is a point cloud, not a Gaussian splat file",
        )
    n_rest = sum(1 for p in names if p.startswith("f_rest_"))
    if n_rest % 3 or (n_rest // 3 + 1) not in (1, 4, 9, 16):
        raise DataError(f"PLY has {n_rest} f_rest properties; expected 0, 9, 24 or 45", where=str(path))
    k1 = n_rest // 3
    n = len(v)

    def cols(keys: list[str]) -> np.ndarray:
        return (
            np.stack([np.asarray(v[k], np.float32) for k in keys], axis=1) if keys else np.zeros((n, 0), "f4")
        )

    rest = cols([f"f_rest_{i}" for i in range(n_rest)]).reshape(n, 3, k1).transpose(0, 2, 1)
    return SplatData(
        means=cols(["x", "y", "z"]),
        sh0=cols(["f_dc_0", "f_dc_1", "f_dc_2"]).reshape(n, 1, 3),
        shN=np.ascontiguousarray(rest, dtype=np.float32),
        opacity_logits=np.asarray(v["opacity"], np.float32).copy(),
        log_scales=cols([f"scale_{i}" for i in range(3)]),
        quats=cols([f"rot_{i}" for i in range(4)]),
    )


def splat_fields() -> list[str]:
    return [f.name for f in fields(SplatData)]
