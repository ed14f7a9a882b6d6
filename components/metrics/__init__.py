"""Image-quality metrics (evaluation only; nothing here is registered or trained)."""

from components.metrics.lpips import (
    LPIPS,
    LPIPSUnavailable,
    LPIPSWeightsError,
    load_lpips,
    lpips_available,
    lpips_distance,
)

__all__ = [
    "LPIPS",
    "LPIPSUnavailable",
    "LPIPSWeightsError",
    "load_lpips",
    "lpips_available",
    "lpips_distance",
]
