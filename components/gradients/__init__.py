"""Gradient policies (kind ``gradient_policy``): how the gradient reaching the clean radiance is scaled."""

from components.gradients import policies  # noqa: F401  (registers)
