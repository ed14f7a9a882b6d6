"""The view-shared medium field: extinction beta(x) and medium light L(x, v) backends."""

from components.medium import fields, gaussian_bound, reference  # noqa: F401  (registers)
