"""Coverage regulariser: the rendered alpha of each pixel pushed towards 0 or 1.

With a medium, coverage is a second haze knob: a pixel the Gaussians leave partly uncovered
marches its ray further into the haze (or shows the light from the far bound), so surfaces can
turn half transparent and trade their colour for haze. A haze-agnostic 3DGS fit covers almost
every pixel; this term asks the same of a medium fit without choosing the side: sky and empty
background stay free to be uncovered.
"""

from __future__ import annotations

import torch
from torch import Tensor

ALPHA_EPS = 1e-4
"""Coverage is clamped to [eps, 1 - eps] so the entropy's gradient stays finite at 0 and 1."""


def coverage_entropy(alpha: Tensor) -> Tensor:
    """Mean binary entropy (nats) of the coverage ``alpha`` [H, W, 1] (any shape): 0 where every
    pixel is fully covered or empty, ln 2 where every pixel is half covered."""
    a = alpha.clamp(ALPHA_EPS, 1.0 - ALPHA_EPS)
    return -(a * torch.log(a) + (1.0 - a) * torch.log1p(-a)).mean()
