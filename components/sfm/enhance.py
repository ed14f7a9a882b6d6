"""Contrast-enhanced copies of hazy photos for feature matching (the dataset keeps the originals).

Haze lowers local contrast, so SIFT finds fewer and weaker keypoints. Two cheap fixes:

* ``clahe``: contrast-limited adaptive histogram equalisation of the L channel in Lab (OpenCV);
* ``dcp``: single-image dark-channel-prior dehazing (``components.losses.dcp``).

Both keep the image size, so keypoints found on the copy are valid on the original.
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

Enhance = Literal["none", "clahe", "dcp"]
ENHANCE_CHOICES: tuple[str, ...] = ("none", "clahe", "dcp")

CLAHE_CLIP = 3.0
"""CLAHE clip limit (OpenCV's default is 40, i.e. almost unlimited; 2-4 is the usual range)."""
CLAHE_TILES = 8
"""CLAHE grid: the image is split into ``CLAHE_TILES x CLAHE_TILES`` tiles."""


def clahe(rgb: np.ndarray) -> np.ndarray:
    """uint8 RGB [H, W, 3] -> uint8 RGB [H, W, 3] with CLAHE applied to the Lab lightness."""
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB)
    op = cv2.createCLAHE(clipLimit=CLAHE_CLIP, tileGridSize=(CLAHE_TILES, CLAHE_TILES))
    lab[:, :, 0] = op.apply(np.ascontiguousarray(lab[:, :, 0]))
    return cv2.cvtColor(lab, cv2.COLOR_LAB2RGB)


def dcp_dehaze(rgb: np.ndarray) -> np.ndarray:
    """uint8 RGB [H, W, 3] -> uint8 RGB [H, W, 3] dehazed with the dark channel prior."""
    from components.losses.dcp import dehaze, estimate_dcp

    out = dehaze(rgb, estimate_dcp(rgb))  # [H, W, 3] float in [0, 1]
    return (out * 255.0 + 0.5).astype(np.uint8)


def enhance_image(rgb: np.ndarray, method: str) -> np.ndarray:
    """Apply ``method`` (``none``, ``clahe`` or ``dcp``) to a uint8 RGB image."""
    if method == "none":
        return rgb
    if method == "clahe":
        return clahe(rgb)
    if method == "dcp":
        return dcp_dehaze(rgb)
    raise ValueError(f"unknown enhancement {method!r}; use one of {', '.join(ENHANCE_CHOICES)}")
