"""Loss bank: registered loss terms (kind ``loss``)."""

from components.losses import reconstruction  # noqa: F401  (registers)
