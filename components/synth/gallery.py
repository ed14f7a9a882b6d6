"""``td-synth gallery``: one PNG with hazy | clean | transmittance for a view of each layout, per preset.

Each row is a haze preset, each column triple a layout; the clean view is rendered once per layout
and every preset's medium is marched over it, so rows differ only by the medium.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from components.data.cameras import ViewIntrinsics
from components.data.images import write_image_atomic
from components.synth.generate import HazeName, LayoutName, camera_poses, torch_threads
from components.synth.layouts import make_layout
from components.synth.march import DEFAULT_SAMPLES
from components.synth.medium import PRESETS, make_medium
from components.synth.render import apply_medium, render_clean
from components.synth.writer import share_like_umask
from tridehaze_plugin.errors import ConfigError, UserError

LABEL_W = 92
HEADER_H = 30
PAD = 2


@dataclass
class GalleryConfig:
    """A gallery image of the haze presets (hazy | clean | transmittance)."""

    output: Path = Path("docs/images/synth_gallery.png")
    """PNG to write."""
    layouts: tuple[LayoutName, ...] = ("street", "courtyard", "room", "field")
    """Layouts shown (one view each, one column triple per layout)."""
    presets: tuple[HazeName, ...] = PRESETS  # type: ignore[assignment]
    """Presets shown (one row each)."""
    width: int = 96
    """Tile width in pixels."""
    height: int = 72
    """Tile height in pixels."""
    view: int = 3
    """Which of 8 trajectory views to show for each layout."""
    samples: int = DEFAULT_SAMPLES
    """Ray-marching samples per pixel."""
    seed: int = 0
    """Scene and medium seed."""
    threads: int = 1
    """Torch CPU threads (0: torch default)."""


def _u8(img: np.ndarray) -> np.ndarray:
    return np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)


def colorize_t(T: np.ndarray) -> np.ndarray:
    """T [H, W] in [0, 1] -> RGB uint8 (viridis: dark = opaque haze, yellow = clear)."""
    bgr = cv2.applyColorMap(_u8(T), cv2.COLORMAP_VIRIDIS)
    return bgr[:, :, ::-1]


def _text(img: np.ndarray, s: str, x: int, y: int, scale: float = 0.36) -> None:
    cv2.putText(img, s, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, (20, 20, 20), 1, cv2.LINE_AA)


def make_gallery(cfg: GalleryConfig) -> dict[str, float]:
    """Render and write the gallery; returns each preset's mean transmittance over the shown views."""
    if cfg.width < 8 or cfg.height < 8 or cfg.samples < 1 or not (0 <= cfg.view < 8):
        raise ConfigError("--width/--height must be >= 8, --samples >= 1 and --view in 0..7")
    if not cfg.layouts or not cfg.presets:
        raise ConfigError("give at least one layout and one preset")
    if cfg.output.suffix.lower() != ".png":
        raise UserError("--output must end in .png", where=str(cfg.output))
    t0 = time.perf_counter()
    K = ViewIntrinsics.from_fov(cfg.width, cfg.height, 60.0)
    tw, th = cfg.width, cfg.height
    cols = len(cfg.layouts) * 3
    canvas = np.full(
        (HEADER_H + len(cfg.presets) * (th + PAD), LABEL_W + cols * (tw + PAD), 3), 255, dtype=np.uint8
    )
    means: dict[str, list[float]] = {p: [] for p in cfg.presets}
    with torch_threads(cfg.threads):
        for j, name in enumerate(cfg.layouts):
            layout = make_layout(name, cfg.seed)
            _, poses = camera_poses(layout, "auto", 8)
            view = render_clean(layout, poses[cfg.view], K, 2)
            x0 = LABEL_W + j * 3 * (tw + PAD)
            _text(canvas, name, x0 + 2, 12, 0.42)
            for k, title in enumerate(("hazy", "clean", "T")):
                _text(canvas, title, x0 + k * (tw + PAD) + 2, 25, 0.32)
            for r, preset in enumerate(cfg.presets):
                hz = apply_medium(view, make_medium(preset, layout.medium_context(), cfg.seed), cfg.samples)
                T = hz.transmittance.numpy()
                means[preset].append(float(T.mean()))
                y0 = HEADER_H + r * (th + PAD)
                tiles = (_u8(hz.hazy.numpy()), _u8(view.clean.numpy()), colorize_t(T))
                for k, tile in enumerate(tiles):
                    xs = x0 + k * (tw + PAD)
                    canvas[y0 : y0 + th, xs : xs + tw] = tile
    out = {p: float(np.mean(v)) for p, v in means.items()}
    for r, preset in enumerate(cfg.presets):
        y0 = HEADER_H + r * (th + PAD)
        _text(canvas, preset, 4, y0 + th // 2, 0.4)
        _text(canvas, f"mean T {out[preset]:.2f}", 4, y0 + th // 2 + 14, 0.32)
    try:
        write_image_atomic(cfg.output, canvas)
        share_like_umask(cfg.output)
    except OSError as exc:
        raise UserError(f"cannot write the gallery ({exc.strerror or exc})", where=str(cfg.output)) from None
    out["seconds"] = time.perf_counter() - t0
    return out
