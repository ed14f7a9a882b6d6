"""Typed dataclass configs: the base class, registry-backed choices and safe YAML round trips.

Configs are plain dataclasses so that tyro can turn them into a CLI (each field's docstring
becomes its ``--help`` text). A run's resolved config is written as ``config.yml`` using only
YAML primitives, and read back by *merging those primitives into the method's default config*
with type checks: nothing in the file can name a class or execute code.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import Any, Literal, Union, get_args, get_origin

import yaml

from tridehaze_plugin.errors import ConfigError, shown
from tridehaze_plugin.registry import REGISTRY, Registry


@dataclass(frozen=True)
class RegistryChoice:
    """Marks a ``str`` field as a name in the registry, e.g. ``Annotated[str, RegistryChoice("medium")]``.

    Kept as a string (not a Literal) so that plugins can add names without changing config types;
    :func:`validate` checks the name right after parsing so a typo fails before any work starts.
    """

    kind: str
    allow: tuple[str, ...] = ()
    """Extra accepted values that are not registry names (e.g. ``"auto"``)."""


@dataclass(frozen=True)
class Range:
    """Marks a numeric field's allowed values, e.g. ``Annotated[int, Range(1, 3)]``; checked by
    :func:`check_numbers` right after parsing, so a value that cannot work fails as one line naming
    the flag instead of deep inside a kernel (``--pipeline.rasterizer.tile-size 0`` divided by zero)."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    """True: ``lo`` itself is not allowed."""
    odd: bool = False
    """Only odd integers (window sizes)."""

    def problem(self, value: float) -> str | None:
        """What is wrong with ``value`` (None: it is allowed)."""
        low = self.lo is not None and (value <= self.lo if self.lo_open else value < self.lo)
        if low or (self.hi is not None and value > self.hi) or (self.odd and value % 2 != 1):
            return f"must be {self.describe()}, got {value}"
        return None

    def describe(self) -> str:
        parts = []
        if self.lo is not None:
            parts.append(f"{'>' if self.lo_open else '>='} {_number(self.lo)}")
        if self.hi is not None:
            parts.append(f"<= {_number(self.hi)}")
        text = " and ".join(parts)
        return f"an odd integer {text}" if self.odd else text


def _number(v: float) -> str:
    return str(int(v)) if float(v).is_integer() and abs(v) < 1e15 else f"{v:g}"


NonNegative = Range(0.0)
Positive = Range(0.0, lo_open=True)
SEED_RANGE = Range(0, 2**32 - 1)
"""Seeds feed numpy's generator too, which takes 32 bits."""


@dataclass
class ComponentConfig:
    """Base for every component config: a dataclass that knows how to build its component."""

    def setup(self, **kwargs: Any) -> Any:
        raise NotImplementedError(f"{type(self).__name__} does not build a component")


# --------------------------------------------------------------------------------------
# validation


def validate(cfg: Any, registry: Registry | None = None, _prefix: str = "") -> None:
    """Check every :class:`RegistryChoice` field (recursively) names a registered component."""
    registry = registry or REGISTRY
    hints = _hints(type(cfg))
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        flag = f"--{_prefix}{f.name}".replace("_", "-")
        for meta in _metadata(hints.get(f.name)):
            if (
                isinstance(meta, RegistryChoice)
                and value is not None  # an optional choice left unset
                and value not in meta.allow
                and (meta.kind, value) not in registry
            ):
                raise ConfigError(registry.unknown_message(meta.kind, value), where=flag)
        if dataclasses.is_dataclass(value):
            validate(value, registry, f"{_prefix}{f.name}.")


def check_numbers(cfg: Any, _prefix: str = "") -> None:
    """Reject nan / inf in every float option and values outside a field's declared :class:`Range`
    (recursively, tuples too): parsed from the command line they pass type checks, then hang or
    poison the work (``--fps inf`` spun forever)."""
    hints = _hints(type(cfg))
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        flag = f"--{_prefix}{f.name}".replace("_", "-")
        items = value if isinstance(value, (tuple, list)) else (value,)
        ranges = [m for m in _metadata(hints.get(f.name)) if isinstance(m, Range)]
        for v in items:
            if isinstance(v, float) and not math.isfinite(v):
                raise ConfigError(f"{flag} must be a finite number, got {v}", fix="pass a finite value")
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                for r in ranges:
                    if (problem := r.problem(v)) is not None:
                        raise ConfigError(f"{flag} {problem}")
        if dataclasses.is_dataclass(value):
            check_numbers(value, f"{_prefix}{f.name}.")


def _metadata(hint: Any) -> tuple[Any, ...]:
    """An ``Annotated`` hint's metadata, also inside an optional one (``Annotated[float, R] | None``)."""
    meta = getattr(hint, "__metadata__", ())
    if not meta and get_origin(hint) in (Union, types.UnionType):
        meta = tuple(m for arg in get_args(hint) for m in getattr(arg, "__metadata__", ()))
    return meta


def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls, include_extras=True)


# --------------------------------------------------------------------------------------
# dataclass <-> primitive dict


def to_dict(cfg: Any) -> dict[str, Any]:
    """Dataclass to YAML-safe primitives (Paths become strings, tuples lists)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cfg):
        out[f.name] = _to_primitive(getattr(cfg, f.name))
    return out


def _to_primitive(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return to_dict(value)
    if isinstance(value, PurePath):
        return str(value)
    if isinstance(value, (list, tuple)):
        return [_to_primitive(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _to_primitive(v) for k, v in value.items()}
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"cannot serialise config value of type {type(value).__name__}: {value!r}")


_RETIRED: dict[type, dict[str, Any]] = {}


def retire_options(cls: type, **neutral: Any) -> None:
    """Declare options removed from config class ``cls``, each with the value that meant "off".

    Every run trained while an option existed wrote it to its config.yml; reading such a file, a
    retired key at its neutral value is dropped (the run behaved as the code does now), and any
    other value is an error naming the option: the run used something this code no longer has.
    """
    _RETIRED.setdefault(cls, {}).update(neutral)


def _retired(cls: type) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for klass in reversed(cls.__mro__):
        out.update(_RETIRED.get(klass, {}))
    return out


def _drop_retired(cls: type, names: set[str], data: dict[str, Any], where: str) -> dict[str, Any]:
    """``data`` without the retired keys at their neutral value (see :func:`retire_options`);
    ``names``: the fields of ``cls``, which a retired name never shadows."""
    retired = _retired(cls)
    for key in sorted(k for k in data if k in retired and k not in names):
        if data[key] != retired[key]:
            raise ConfigError(
                f"config key {key}: {shown(data[key])} is an option this version no longer has (retired; "
                f"off is {shown(retired[key])})",
                where=where,
                fix=f"set it to {shown(retired[key])} to load the run as if trained without it, or use a "
                f"checkout from before its removal (git log -S '{key}')",
            )
    return {k: v for k, v in data.items() if k in names or k not in retired}


def merge_dict(default: Any, data: dict[str, Any], where: str = "config") -> Any:
    """Return a copy of dataclass ``default`` with ``data`` merged in, checking every type."""
    if not isinstance(data, dict):
        raise ConfigError(f"expected a mapping, got {type(data).__name__}", where=where)
    hints = _hints(type(default))
    names = {f.name for f in dataclasses.fields(default)}
    data = _drop_retired(type(default), names, data, where)
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(
            f"unknown config key(s) {', '.join(unknown)}",
            where=where,
            fix="the file may come from another version or method; remove the key(s)",
        )
    changes = {}
    for name, raw in data.items():
        current = getattr(default, name)
        changes[name] = _coerce(raw, hints[name], current, f"{where}.{name}")
    return dataclasses.replace(default, **changes)


def _coerce(raw: Any, tp: Any, current: Any, where: str) -> Any:
    origin = get_origin(tp)
    if origin is typing.Annotated:
        return _coerce(raw, get_args(tp)[0], current, where)
    if dataclasses.is_dataclass(current) and not isinstance(current, type):
        return merge_dict(current, raw, where)
    if origin in (Union, types.UnionType):
        args = get_args(tp)
        if raw is None and type(None) in args:
            return None
        errors = []
        for arg in (a for a in args if a is not type(None)):
            try:
                return _coerce(raw, arg, current if _isinstance_loose(current, arg) else None, where)
            except ConfigError as exc:
                errors.append(exc.what)
        raise ConfigError(f"value {shown(raw)} matches none of {tp}: {'; '.join(errors)}", where=where)
    if origin is Literal:
        if raw not in get_args(tp):
            raise ConfigError(f"value {shown(raw)} is not one of {list(get_args(tp))}", where=where)
        return raw
    if origin in (list, tuple):
        return _coerce_sequence(raw, tp, where)
    if origin is dict:
        if not isinstance(raw, dict):
            raise ConfigError(f"expected a mapping, got {type(raw).__name__}", where=where)
        kt, vt = get_args(tp) or (Any, Any)
        return {_coerce(k, kt, None, where): _coerce(v, vt, None, f"{where}.{k}") for k, v in raw.items()}
    return _coerce_scalar(raw, tp, where)


def _coerce_sequence(raw: Any, tp: Any, where: str) -> list | tuple:
    """A list or tuple field: fixed-length tuples item by item, else every item as the item type."""
    origin = get_origin(tp)
    if not isinstance(raw, (list, tuple)):
        raise ConfigError(f"expected a list, got {type(raw).__name__}", where=where)
    args = get_args(tp)
    if origin is tuple and args and args[-1] is not Ellipsis:
        if len(args) != len(raw):
            raise ConfigError(f"expected {len(args)} items, got {len(raw)}", where=where)
        return tuple(
            _coerce(r, a, None, f"{where}[{i}]") for i, (r, a) in enumerate(zip(raw, args, strict=True))
        )
    item_tp = args[0] if args else Any
    items = [_coerce(r, item_tp, None, f"{where}[{i}]") for i, r in enumerate(raw)]
    return tuple(items) if origin is tuple else items


def _coerce_scalar(raw: Any, tp: Any, where: str) -> Any:
    """A leaf value: checked against its exact type (YAML's bool is never taken for an int)."""
    if tp is Any:
        return raw
    if tp in (Path, PurePath):
        if not isinstance(raw, str):
            raise ConfigError(f"expected a path string, got {type(raw).__name__}", where=where)
        return Path(raw)
    if tp is bool:
        if not isinstance(raw, bool):
            raise ConfigError(f"expected true/false, got {shown(raw)}", where=where)
        return raw
    if tp is int:
        if isinstance(raw, bool) or not isinstance(raw, int):
            raise ConfigError(f"expected an integer, got {shown(raw)}", where=where)
        return raw
    if tp is float:
        if isinstance(raw, bool) or not isinstance(raw, (int, float)):
            raise ConfigError(f"expected a number, got {shown(raw)}", where=where)
        return float(raw)
    if tp is str:
        if not isinstance(raw, str):
            raise ConfigError(f"expected a string, got {shown(raw)}", where=where)
        return raw
    if tp is type(None):
        if raw is not None:
            raise ConfigError(f"expected null, got {shown(raw)}", where=where)
        return None
    raise ConfigError(f"unsupported config type {tp}", where=where)


def _isinstance_loose(value: Any, tp: Any) -> bool:
    try:
        return isinstance(value, get_origin(tp) or tp)
    except TypeError:
        return False


# --------------------------------------------------------------------------------------
# YAML files


def dump_yaml(cfg: Any, header: dict[str, Any] | None = None) -> str:
    data = dict(header or {})
    data.update(to_dict(cfg))
    return yaml.safe_dump(data, sort_keys=False)


class _AliasFound(Exception):
    pass


class _DuplicateKey(Exception):
    pass


class _NoAliasLoader(yaml.SafeLoader):
    """``safe_load`` that refuses aliases (``*name``): td-* config files never need them, and a
    few nested ones (an alias bomb) expand to gigabytes. It also refuses a key given twice in one
    mapping, which plain YAML loading resolves silently to the last value."""

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise _AliasFound(f"*{event.anchor} at line {event.start_mark.line + 1}")
        return super().compose_node(parent, index)

    def construct_mapping(self, node: Any, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            if not isinstance(key, (str, int, float, bool)):
                continue  # unhashable keys fail in the base class with their own message
            if key in seen:
                raise _DuplicateKey(f"{shown(key)} at line {key_node.start_mark.line + 1}")
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def read_yaml_mapping(path: Path) -> dict[str, Any]:
    """Read a YAML mapping the ``safe_load`` way (no Python tags, no object construction), with no
    aliases and bounded nesting."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}", fix="pass the config.yml inside a run folder")
    try:
        data = yaml.load(path.read_text(encoding="utf-8"), Loader=_NoAliasLoader)  # noqa: S506 - safe loader
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"config file is not valid YAML: {first}", where=str(path)) from None
    except _AliasFound as exc:
        raise ConfigError(
            f"config file uses a YAML alias ({exc}); td-* config files never do",
            where=str(path),
            fix="write the value out in full",
        ) from None
    except _DuplicateKey as exc:
        raise ConfigError(
            f"config file sets a key twice ({exc})", where=str(path), fix="keep one value for it"
        ) from None
    except RecursionError:
        raise ConfigError("config file is nested too deeply to be a td-* config", where=str(path)) from None
    if not isinstance(data, dict):
        raise ConfigError("config file does not hold a mapping", where=str(path))
    return data
