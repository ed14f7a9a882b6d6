"""Config round trips through YAML, safe loading, type checks and registry-name validation."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipelines.engine.config import TrainerConfig
from pipelines.engine.run_config import load_config, save_config
from tridehaze_plugin.config import merge_dict, read_yaml_mapping, to_dict, validate
from tridehaze_plugin.errors import ConfigError
from tridehaze_plugin.registry import load_all


def _vanilla() -> TrainerConfig:
    return load_all().get("method", "vanilla-gs").make_config()


def test_round_trip_is_exact(tmp_path):
    cfg = _vanilla()
    cfg.max_steps = 123
    cfg.dataset.data = Path("/some/where")
    cfg.pipeline.background = (0.25, 0.5, 1.0)
    cfg.pipeline.loss.lambda_ssim = 0.3
    path = tmp_path / "config.yml"
    save_config(cfg, path)
    back = load_config(path)
    assert back == cfg
    assert isinstance(back.dataset.data, Path)
    assert isinstance(back.pipeline.background, tuple)


def test_yaml_with_python_tags_is_refused(tmp_path):
    path = tmp_path / "config.yml"
    path.write_text("method_name: vanilla-gs\nmax_steps: !!python/object/apply:os.system ['echo pwned']\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        read_yaml_mapping(path)


def test_wrong_types_and_unknown_keys_are_refused():
    cfg = _vanilla()
    with pytest.raises(ConfigError, match="expected an integer.*max_steps"):
        merge_dict(cfg, {"max_steps": "many"})
    with pytest.raises(ConfigError, match="unknown config key"):
        merge_dict(cfg, {"pipeline": {"not_a_field": 1}})
    with pytest.raises(ConfigError, match="expected 3 items"):
        merge_dict(cfg, {"pipeline": {"background": [0, 0]}})
    with pytest.raises(ConfigError, match="expected true/false"):
        merge_dict(cfg, {"eval_at_end": "yes"})


def test_to_dict_only_primitives():
    def walk(x):
        if isinstance(x, dict):
            for v in x.values():
                walk(v)
        elif isinstance(x, list):
            for v in x:
                walk(v)
        else:
            assert x is None or isinstance(x, (bool, int, float, str)), type(x)

    walk(to_dict(_vanilla()))


def test_registry_choice_validation_names_the_flag():
    cfg = _vanilla()
    cfg.pipeline.rasterizer.backend = "warp-drive"
    with pytest.raises(ConfigError) as err:
        validate(cfg)
    msg = str(err.value)
    assert (
        "unknown rasterizer 'warp-drive'" in msg and "--pipeline.rasterizer.backend" in msg and "torch" in msg
    )
    cfg.pipeline.rasterizer.backend = "auto"  # allowed extra value
    validate(cfg)


def test_load_config_missing_and_unknown_method(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.yml")
    p = tmp_path / "c.yml"
    p.write_text("method_name: no-such-method\n")
    with pytest.raises(ConfigError, match="unknown method 'no-such-method'"):
        load_config(p)
