"""Shape regularisers on the Gaussians' scales.

Needles (one axis much longer than the other two) fit the training views seen along them as a
dot and show as streaks from any other angle: a novel-view artefact that no photometric term sees.
Discs (two long axes, one thin) are what surfaces need and are left alone.
"""

from __future__ import annotations

import math

from torch import Tensor


def elongation_penalty(log_scales: Tensor, max_ratio: float) -> Tensor:
    """Mean over Gaussians of how far ln(largest / middle scale) exceeds ln(``max_ratio``).

    log_scales: [N, 3]. In log space the gradient stays bounded for any ratio, so a needle is
    thickened steadily instead of by one large step; 0 for an empty model.
    """
    if log_scales.shape[0] == 0:
        return log_scales.sum() * 0.0
    top2 = log_scales.topk(2, dim=-1).values  # [N, 2] largest, middle
    excess = (top2[:, 0] - top2[:, 1] - math.log(max_ratio)).clamp(min=0.0)  # [N]
    return excess.mean()
