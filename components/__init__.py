"""Registered building blocks. Importing this package registers every built-in component."""

from components import data, gaussians, gradients, losses, medium, rasterizers  # noqa: F401  (registration side effects)
