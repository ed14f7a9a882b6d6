"""Component registry: every swappable building block is registered by *kind* and *name*.

Components register themselves when their module is imported. The built-ins are this
distribution's own ``tridehaze.components`` entry points (pyproject.toml), imported first by
:func:`load_all`; third-party packages add theirs in three ways, mirroring nerfstudio:

* entry point group ``tridehaze.components``: the entry point names a module (imported for
  its registration side effects) or a callable taking the :class:`Registry`;
* entry point group ``tridehaze.methods``: the entry point names a :class:`MethodSpec`
  (or a zero-argument callable returning one); it is registered under its own name;
* environment variable ``TRIDEHAZE_PLUGINS``: a comma-separated list of ``module`` or
  ``module:attribute`` items handled like ``tridehaze.components`` entries, for quick
  experiments without packaging.

A plugin that fails to import never breaks the built-ins: it is reported in one line and
skipped, and an unknown-name lookup later mentions the failure.
"""

from __future__ import annotations

import importlib
import os
import sys
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any

from tridehaze_plugin.errors import PluginError
from tridehaze_plugin.method_spec import MethodSpec

KINDS: tuple[str, ...] = (
    "rasterizer",
    "gaussian_model",
    "medium",
    "gradient_policy",
    "loss",
    "dataparser",
    "method",
)
"""The kinds of component the framework knows. Plugins may not invent new kinds."""

COMPONENT_GROUP = "tridehaze.components"
METHOD_GROUP = "tridehaze.methods"
PLUGIN_ENV_VAR = "TRIDEHAZE_PLUGINS"

DISTRIBUTION = "tridehaze"
"""This project's distribution: its own ``tridehaze.components`` entry points are the built-ins
(declared in pyproject.toml, so this bottom layer never names the layers above it)."""


@dataclass(frozen=True)
class Entry:
    """One registered component."""

    kind: str
    name: str
    obj: Any
    description: str = ""
    origin: str = ""
    """Module (or plugin source) that registered it; shown by ``td-info``."""


@dataclass(frozen=True)
class PluginFailure:
    """A plugin that could not be loaded, kept so later errors can point at it."""

    source: str
    """Where it came from, e.g. ``entry point tridehaze.methods:my-method``."""
    target: str
    """What was being imported, e.g. ``my_pkg.method:spec``."""
    error: str

    def message(self) -> str:
        return (
            f"plugin {self.target!r} ({self.source}) failed to load: {self.error}; "
            "it is skipped (fix or uninstall it to silence this)"
        )


@dataclass
class Registry:
    """Maps (kind, name) to a component object (usually a class or a factory)."""

    _entries: dict[str, dict[str, Entry]] = field(default_factory=lambda: {k: {} for k in KINDS})
    failures: list[PluginFailure] = field(default_factory=list)
    _current_origin: str | None = None

    def register(
        self,
        kind: str,
        name: str,
        obj: Any = None,
        *,
        description: str = "",
        replace: bool = False,
    ) -> Any:
        """Register ``obj`` under ``kind``/``name``; usable as a decorator when ``obj`` is omitted."""
        if kind not in self._entries:
            raise ValueError(f"unknown component kind {kind!r}; kinds are {', '.join(KINDS)}")
        if not name or not isinstance(name, str):
            raise ValueError(f"component name must be a non-empty string, got {name!r}")

        def _do(target: Any) -> Any:
            existing = self._entries[kind].get(name)
            origin = self._current_origin or getattr(target, "__module__", "") or ""
            if existing is not None and not replace and existing.obj is not target:
                raise PluginError(
                    f"{kind} {name!r} is registered twice (by {existing.origin} and {origin})",
                    fix="rename one of them or pass replace=True to override deliberately",
                )
            desc = description or _first_doc_line(target)
            self._entries[kind][name] = Entry(kind, name, target, desc, origin)
            return target

        return _do if obj is None else _do(obj)

    def get(self, kind: str, name: str) -> Any:
        return self.entry(kind, name).obj

    def entry(self, kind: str, name: str) -> Entry:
        if kind not in self._entries:
            raise ValueError(f"unknown component kind {kind!r}")
        try:
            return self._entries[kind][name]
        except KeyError:
            raise PluginError(self.unknown_message(kind, name)) from None

    def unknown_message(self, kind: str, name: str) -> str:
        avail = ", ".join(sorted(self._entries[kind])) or "none"
        msg = f"unknown {kind} {name!r}; available: {avail}"
        if self.failures:
            msg += f" ({len(self.failures)} plugin(s) failed to load: run `td-info` to see why)"
        return msg

    def names(self, kind: str) -> list[str]:
        return sorted(self._entries[kind])

    def entries(self, kind: str) -> list[Entry]:
        return [self._entries[kind][n] for n in self.names(kind)]

    def __contains__(self, key: tuple[str, str]) -> bool:
        kind, name = key
        return name in self._entries.get(kind, {})


def _first_doc_line(obj: Any) -> str:
    doc = getattr(obj, "description", None)
    if isinstance(doc, str) and doc:
        return doc
    doc = getattr(obj, "__doc__", None) or ""
    return doc.strip().splitlines()[0] if doc.strip() else ""


REGISTRY = Registry()
"""The process-wide registry used by the CLI."""


def register(kind: str, name: str, obj: Any = None, *, description: str = "", replace: bool = False) -> Any:
    """Register into the global :data:`REGISTRY` (decorator form when ``obj`` is omitted)."""
    return REGISTRY.register(kind, name, obj, description=description, replace=replace)


def method(name: str, description: str) -> Callable[[Callable[[], Any]], Callable[[], Any]]:
    """Decorator registering a config factory as the method ``name`` (the factory is returned as is)."""

    def wrap(factory: Callable[[], Any]) -> Callable[[], Any]:
        register("method", name, MethodSpec(name=name, description=description, config_factory=factory))
        return factory

    return wrap


_loaded = False
_loading = threading.RLock()
"""Held while the registry fills: another thread waits for it (it found an empty registry), while
an import inside the fill, on the same thread, passes through and sees it loaded."""


def load_all(*, force: bool = False, warn: Callable[[str], None] | None = None) -> Registry:
    """Import built-ins, then entry-point and environment plugins, once per process."""
    global _loaded
    with _loading:
        if _loaded and not force:
            return REGISTRY
        _loaded = True
        for module in builtin_modules():
            importlib.import_module(module)  # a broken built-in is a bug: let it raise
        warn = warn or _warn_stderr
        before = len(REGISTRY.failures)
        _load_entry_points(REGISTRY)
        _load_env_plugins(REGISTRY, os.environ.get(PLUGIN_ENV_VAR, ""))
        for failure in REGISTRY.failures[before:]:
            warn(failure.message())
        return REGISTRY


def _warn_stderr(msg: str) -> None:
    print(f"warning: {msg}", file=sys.stderr)


def _entry_points(group: str) -> Iterable[metadata.EntryPoint]:
    return metadata.entry_points(group=group)


def _is_builtin(ep: metadata.EntryPoint) -> bool:
    dist = ep.dist  # None for entry points built by hand (tests)
    return dist is not None and dist.name == DISTRIBUTION


def builtin_modules() -> list[str]:
    """Modules whose import registers the built-in components and methods, in entry-point name order."""
    found = sorted((ep for ep in _entry_points(COMPONENT_GROUP) if _is_builtin(ep)), key=lambda ep: ep.name)
    if not found:
        raise PluginError(
            f"the built-in components are not registered: no {COMPONENT_GROUP} entry points of "
            f"the {DISTRIBUTION!r} distribution were found",
            fix="install the project (pip install -e . from its folder) rather than running it from a path",
        )
    return [ep.value for ep in found]


def _load_entry_points(reg: Registry) -> None:
    for ep in _entry_points(COMPONENT_GROUP):
        if _is_builtin(ep):
            continue
        _load_one(reg, f"entry point {COMPONENT_GROUP}:{ep.name}", ep.value, ep.load, method_name=None)
    for ep in _entry_points(METHOD_GROUP):
        _load_one(reg, f"entry point {METHOD_GROUP}:{ep.name}", ep.value, ep.load, method_name=ep.name)


def _load_env_plugins(reg: Registry, spec: str) -> None:
    for item in (s.strip() for s in spec.split(",")):
        if not item:
            continue
        _load_one(reg, f"${PLUGIN_ENV_VAR}", item, lambda item=item: _import_target(item), method_name=None)


def _import_target(target: str) -> Any:
    module_name, _, attr = target.partition(":")
    obj: Any = importlib.import_module(module_name)
    for part in filter(None, attr.split(".")):
        obj = getattr(obj, part)
    return obj


def _load_one(
    reg: Registry, source: str, target: str, loader: Callable[[], Any], method_name: str | None
) -> None:
    reg._current_origin = target
    try:
        obj = loader()
        if isinstance(obj, type(sys)):
            return  # a module: importing it registered its components
        if method_name is not None or isinstance(obj, MethodSpec):
            spec = obj if isinstance(obj, MethodSpec) else obj()
            if not isinstance(spec, MethodSpec):
                raise TypeError(f"expected a MethodSpec, got {type(spec).__name__}")
            reg.register("method", method_name or spec.name, spec, description=spec.description)
        elif callable(obj):
            obj(reg)
        else:
            raise TypeError(
                f"expected a module, a MethodSpec or a callable(registry), got {type(obj).__name__}"
            )
    except Exception as exc:  # noqa: BLE001 - any plugin failure is reported, never fatal
        reg.failures.append(PluginFailure(source, target, f"{type(exc).__name__}: {exc}"))
    finally:
        reg._current_origin = None
