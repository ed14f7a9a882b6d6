"""Named pipeline outputs -> one 8-bit RGB frame for the browser (colour maps, split view)."""

from __future__ import annotations

import numpy as np
from torch import Tensor

from pipelines.evaluation.visualize import UNIT_RANGE, to_png


def compose_frame(
    outputs: dict[str, Tensor], name: str, split_with: str | None = None, split_at: float = 0.5
) -> np.ndarray:
    """uint8 RGB [H, W, 3] of output ``name``; with ``split_with`` the part right of ``split_at``
    (a fraction of the width) shows that output instead, with a white line at the seam."""
    left = _image(outputs, name)
    if not split_with:
        return left
    right = _image(outputs, split_with)
    width = left.shape[1]
    x = int(round(min(max(split_at, 0.0), 1.0) * width))
    frame = left.copy()
    frame[:, x:] = right[:, x:]
    if 0 < x < width:
        frame[:, x - 1 : x + 1] = 255
    return frame


def _image(outputs: dict[str, Tensor], name: str) -> np.ndarray:
    """[H, W, 3] colour in [0, 1] -> uint8 RGB; [H, W, 1] -> turbo colour map, transmittance and
    alpha over the fixed range [0, 1] (comparable across views), others (depth) over this frame's
    1-99 % range."""
    if name not in outputs:
        raise KeyError(f"the pipeline returned no output {name!r} (it returned {', '.join(outputs)})")
    value = outputs[name]
    if value.shape[-1] == 1 and name in UNIT_RANGE:
        return to_png(value, (0.0, 1.0))
    return to_png(value)
