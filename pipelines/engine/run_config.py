"""A run's ``config.yml``: written from the resolved config, reloaded by merging into the method's defaults.

Only YAML primitives are written and ``yaml.safe_load`` reads them back; the method name
selects the registered preset whose dataclasses receive the values, with type checks, so a
config file can never construct arbitrary objects.
"""

from __future__ import annotations

from pathlib import Path

from components.data.images import write_bytes_atomic
from pipelines.engine.config import TrainerConfig
from tridehaze_plugin import __version__
from tridehaze_plugin.config import dump_yaml, merge_dict, read_yaml_mapping, validate
from tridehaze_plugin.errors import ConfigError
from tridehaze_plugin.registry import load_all

HEADER_KEYS = ("tridehaze_version",)


def config_text(cfg: TrainerConfig) -> str:
    return dump_yaml(cfg, header={"tridehaze_version": __version__})


def write_text_atomic(path: Path, text: str) -> None:
    write_bytes_atomic(path, text.encode("utf-8"))


def save_config(cfg: TrainerConfig, path: Path) -> None:
    write_text_atomic(path, config_text(cfg))


def load_config(path: Path) -> TrainerConfig:
    """Rebuild a run's :class:`TrainerConfig` from its ``config.yml`` safely."""
    path = Path(path)
    data = read_yaml_mapping(path)
    for key in HEADER_KEYS:
        data.pop(key, None)
    method = data.get("method_name")
    if not isinstance(method, str):
        raise ConfigError(
            "config has no 'method_name'", where=str(path), fix="pass a config.yml written by td-train"
        )
    registry = load_all()
    if ("method", method) not in registry:
        raise ConfigError(registry.unknown_message("method", method), where=str(path))
    cfg = merge_dict(registry.get("method", method).make_config(), data, where=path.name)
    validate(cfg, registry)
    return cfg
