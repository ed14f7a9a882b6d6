"""Registry: registration, lookup errors, env-var plugins and failing plugins."""

from __future__ import annotations

import sys
import textwrap

import pytest

from tridehaze_plugin import registry as reg_mod
from tridehaze_plugin.errors import PluginError
from tridehaze_plugin.registry import KINDS, Registry, load_all


def test_builtins_cover_core_kinds():
    r = load_all()
    assert "vanilla-gs" in r.names("method")
    assert "torch" in r.names("rasterizer")
    assert "3dgs" in r.names("gaussian_model")
    assert "l1-ssim" in r.names("loss")
    assert {"nerfstudio", "blender", "colmap"} <= set(r.names("dataparser"))


def test_register_and_get_decorator():
    r = Registry()

    @r.register("loss", "toy", description="a toy loss")
    class Toy:
        pass

    assert r.get("loss", "toy") is Toy
    assert r.entry("loss", "toy").description == "a toy loss"
    assert ("loss", "toy") in r
    assert ("loss", "nope") not in r


def test_unknown_kind_and_name_messages():
    r = Registry()
    r.register("medium", "a", object())
    with pytest.raises(ValueError, match="unknown component kind"):
        r.register("shader", "x", object())
    with pytest.raises(PluginError, match=r"unknown medium 'b'; available: a"):
        r.get("medium", "b")


def test_duplicate_registration_is_an_error_unless_replace():
    r = Registry()
    r.register("loss", "x", int)
    with pytest.raises(PluginError, match="registered twice"):
        r.register("loss", "x", float)
    r.register("loss", "x", float, replace=True)
    assert r.get("loss", "x") is float
    r.register("loss", "x", float)  # re-registering the same object (module re-import) is harmless


def test_kinds_are_the_documented_ones():
    assert set(KINDS) == {
        "rasterizer",
        "gaussian_model",
        "medium",
        "gradient_policy",
        "loss",
        "dataparser",
        "method",
    }


def test_env_var_plugin_module_and_callable(tmp_path, monkeypatch):
    (tmp_path / "envplug.py").write_text(
        textwrap.dedent(
            """
            from tridehaze_plugin.registry import register
            register("gradient_policy", "env-policy", object())

            def hook(registry):
                registry.register("gradient_policy", "env-hook", object())
            """
        )
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    r = Registry()
    monkeypatch.setattr(reg_mod, "REGISTRY", r)
    reg_mod._load_env_plugins(r, "envplug, envplug:hook")
    assert not r.failures
    assert {"env-policy", "env-hook"} <= set(r.names("gradient_policy"))
    # the module registered into the global REGISTRY (patched to r); origin recorded
    assert r.entry("gradient_policy", "env-hook").origin == "envplug:hook"
    sys.modules.pop("envplug", None)


def test_failing_plugin_is_reported_not_fatal(tmp_path, monkeypatch):
    (tmp_path / "brokenplug.py").write_text("import this_module_does_not_exist_42\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    r = Registry()
    reg_mod._load_env_plugins(r, "brokenplug,also_missing_module_42")
    assert len(r.failures) == 2
    msg = r.failures[0].message()
    assert "brokenplug" in msg and "ModuleNotFoundError" in msg and "this_module_does_not_exist_42" in msg
    assert "skipped" in msg
    # a later unknown-name lookup points at the failure
    with pytest.raises(PluginError, match="plugin\\(s\\) failed to load"):
        r.get("method", "from-broken-plugin")


def test_patched_entry_points_register_method_and_component(monkeypatch):
    from importlib.metadata import EntryPoint

    from tridehaze_plugin.method_spec import MethodSpec

    r = Registry()
    spec = MethodSpec("ep-method", "from an entry point", lambda: None)
    eps = {
        reg_mod.METHOD_GROUP: [EntryPoint("ep-method", "x:y", reg_mod.METHOD_GROUP)],
        reg_mod.COMPONENT_GROUP: [EntryPoint("ep-comp", "a:b", reg_mod.COMPONENT_GROUP)],
    }
    monkeypatch.setattr(reg_mod, "_entry_points", lambda group: eps[group])
    loaded = {"x:y": spec, "a:b": lambda registry: registry.register("medium", "ep-medium", object())}
    monkeypatch.setattr(EntryPoint, "load", lambda self: loaded[self.value])
    reg_mod._load_entry_points(r)
    assert not r.failures, r.failures
    assert r.get("method", "ep-method") is spec
    assert "ep-medium" in r.names("medium")


def test_a_second_thread_waits_for_the_registry_to_fill(monkeypatch):
    """The first load marks the registry loaded before its imports finish; another thread asking
    meanwhile must wait for them, not get the half-filled registry (two loaders of run configs in
    threads found no method at all)."""
    import threading
    import time

    from tridehaze_plugin import registry

    events: list[str] = []

    def slow_import(name: str) -> None:
        events.append("import starts")
        time.sleep(0.3)
        events.append("import ends")

    monkeypatch.setattr(registry, "_loaded", False)
    monkeypatch.setattr(registry, "builtin_modules", lambda: ["slow"])
    monkeypatch.setattr(registry.importlib, "import_module", slow_import)
    monkeypatch.setattr(registry, "_load_entry_points", lambda reg: None)
    monkeypatch.setattr(registry, "_load_env_plugins", lambda reg, spec: None)
    first = threading.Thread(target=registry.load_all)
    first.start()
    time.sleep(0.05)
    registry.load_all()
    events.append("second returns")
    first.join()
    assert events == ["import starts", "import ends", "second returns"]
