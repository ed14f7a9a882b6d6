"""What a method is to the registry: a name, a description and a config factory.

Dependency-free on purpose (the bottom layer): a plugin can declare a method without importing
the engine, and the registry can recognise one without importing the presets.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class MethodSpec:
    """A registered method: its CLI name, a one-paragraph description and a config factory
    (a zero-argument callable returning a fully populated trainer config)."""

    name: str
    description: str
    config_factory: Callable[[], Any]

    def make_config(self) -> Any:
        cfg = self.config_factory()
        if cfg.method_name != self.name:
            cfg.method_name = self.name
        return cfg
