"""Single-image baselines of the restoration protocol: what the same test views give with no 3D.

A 3D dehazing method earns its cost only where it clearly beats restoring each test photo on its
own. Wherever a view has both a hazy input and a clean reference, the report carries:

- ``hazy_input``: the hazy photo itself against the reference (doing nothing);
- ``dcp_2d``: the photo dehazed on its own by the dark channel prior (He et al. 2009, the
  guided-filter refined transmittance of ``components.losses.dcp``), against the reference.

Both are scored like the method's restoration (PSNR, SSIM, LPIPS where available), on the same
views at the same resolution, so the numbers sit in one table.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from components.losses.dcp import dehaze, estimate_dcp

BASELINES: tuple[str, ...] = ("hazy_input", "dcp_2d")
"""Keys of the report's ``baselines`` block, in table order."""
LABELS: dict[str, str] = {"hazy_input": "hazy input", "dcp_2d": "single-image DCP (2D)"}
"""Row labels of the baselines in tables."""


def dcp_restore(hazy: Tensor) -> Tensor:
    """One hazy view [H, W, 3] in [0, 1] dehazed on its own by the dark channel prior [H, W, 3]."""
    arr = np.ascontiguousarray(hazy.detach().float().cpu().numpy())  # [H, W, 3]
    out = dehaze(arr, estimate_dcp(arr))  # [H, W, 3] float32 in [0, 1]
    return torch.from_numpy(out).to(device=hazy.device, dtype=hazy.dtype)


def baseline_images(hazy: Tensor) -> dict[str, Tensor]:
    """Each baseline's restored image [H, W, 3] of one hazy view, keyed as in ``BASELINES``."""
    return {"hazy_input": hazy, "dcp_2d": dcp_restore(hazy)}
