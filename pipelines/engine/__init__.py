"""The training engine: the pipeline contract, the trainer and its config, checkpoints, data access.

Nothing here knows a concrete model or medium; methods plug in through :class:`Pipeline`.
"""
