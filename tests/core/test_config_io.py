"""Config round trips through YAML, safe loading, type checks and registry-name validation."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import pytest

from pipelines.engine.config import TrainerConfig
from pipelines.engine.run_config import HEADER_KEYS, load_config, save_config
from tridehaze_plugin.config import RegistryChoice, merge_dict, read_yaml_mapping, to_dict, validate
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


@dataclass
class WithOptional:
    backend: Annotated[str, RegistryChoice("rasterizer")] | None = None


def test_an_optional_registry_choice_is_validated_when_set():
    """``Annotated[str, RegistryChoice(...)] | None``: unset passes, a wrong name is refused."""
    validate(WithOptional())
    validate(WithOptional(backend="torch"))
    with pytest.raises(ConfigError, match="unknown rasterizer 'warp-drive'"):
        validate(WithOptional(backend="warp-drive"))


def test_load_config_missing_and_unknown_method(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.yml")
    p = tmp_path / "c.yml"
    p.write_text("method_name: no-such-method\n")
    with pytest.raises(ConfigError, match="unknown method 'no-such-method'"):
        load_config(p)


def test_a_retired_option_at_its_off_value_still_loads(tmp_path):
    """Runs trained while an option existed carry it in config.yml: at the value that meant off
    they load as before; with any other value the error names the option and what to do."""
    fresh = load_all().get("method", "tri-dehaze").make_config
    cfg = fresh()
    path = tmp_path / "config.yml"
    save_config(cfg, path)
    text = path.read_text()
    assert "strong_bound_floor" not in text and "per_gaussian" not in text  # gone from new files
    data = read_yaml_mapping(path)
    for key in HEADER_KEYS:
        data.pop(key, None)
    data["pipeline"]["strong_bound_floor"] = 0.0
    data["pipeline"]["composite"]["per_gaussian"] = False
    back = merge_dict(fresh(), data)
    assert back == cfg

    data["pipeline"]["strong_bound_floor"] = 0.1
    with pytest.raises(ConfigError) as err:
        merge_dict(fresh(), data, where="config.yml")
    line = err.value.one_line()
    assert "strong_bound_floor: 0.1" in line and "config.yml.pipeline" in line
    assert "set it to 0.0" in line and "git log -S 'strong_bound_floor'" in line
    data["pipeline"]["strong_bound_floor"] = 0.0
    data["pipeline"]["composite"]["per_gaussian"] = True
    with pytest.raises(ConfigError, match="per_gaussian: True is an option this version no longer has"):
        merge_dict(fresh(), data)
    # a key never declared retired is still unknown
    data["pipeline"]["composite"]["per_gaussian"] = False
    data["pipeline"]["strong_bound_flor"] = 0.0
    with pytest.raises(ConfigError, match="unknown config key.*strong_bound_flor"):
        merge_dict(fresh(), data)


def test_retired_options_are_inherited_and_never_shadow_a_field():
    """A subclass sees its bases' retired options; a name that is a field again is merged as one."""
    from dataclasses import dataclass

    from tridehaze_plugin.config import retire_options

    @dataclass
    class Base:
        a: int = 1

    @dataclass
    class Child(Base):
        b: float = 0.5

    retire_options(Base, old=0)
    retire_options(Child, b=0.0)  # retired once, a field again later
    assert merge_dict(Child(), {"old": 0, "b": 2.0}) == Child(b=2.0)
    with pytest.raises(ConfigError, match="old: 3"):
        merge_dict(Child(), {"old": 3})
