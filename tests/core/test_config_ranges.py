"""Declared ranges (``Annotated[int, Range(...)]``) are checked for every tool after parsing, name
the flag, and apply to configs built in code too."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated

import pytest

from components.medium.base import MediumConfig
from tridehaze_plugin.config import NonNegative, Positive, Range, check_numbers
from tridehaze_plugin.errors import ConfigError


@pytest.mark.parametrize(
    ("rng", "value", "problem"),
    [
        (Range(1, 3), 0, "must be >= 1 and <= 3, got 0"),
        (Range(1, 3), 4, "must be >= 1 and <= 3, got 4"),
        (Range(1, 3), 3, None),
        (Positive, 0.0, "must be > 0, got 0.0"),
        (NonNegative, 0.0, None),
        (Range(3, 63, odd=True), 4, "must be an odd integer >= 3 and <= 63, got 4"),
        (Range(3, 63, odd=True), 11, None),
        (Range(0, 2**32 - 1), 2**65, "must be >= 0 and <= 4294967295, got 36893488147419103232"),
    ],
)
def test_range_problem(rng, value, problem):
    assert rng.problem(value) == problem


@dataclass
class Inner:
    rate: Annotated[float | None, NonNegative] = None
    sizes: Annotated[tuple[int, ...], Range(1)] = (1, 2)


@dataclass
class Outer:
    inner: Inner = field(default_factory=Inner)
    flag: bool = False


@pytest.mark.parametrize(
    ("inner", "message"),
    [
        (Inner(rate=-1.0), "--inner.rate must be >= 0, got -1.0"),
        (Inner(sizes=(1, 0)), "--inner.sizes must be >= 1, got 0"),
        (Inner(rate=float("inf")), "--inner.rate must be a finite number"),
    ],
)
def test_nested_fields_and_tuples_are_checked(inner, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(".", r"\.")):
        check_numbers(Outer(inner=inner))


@dataclass
class OptionalOutside:
    rate: Annotated[float, NonNegative] | None = None


def test_a_range_on_an_optional_field_is_checked():
    """``Annotated[float, R] | None`` (the range inside the union) as well as ``Annotated[float | None, R]``."""
    with pytest.raises(ConfigError, match="--rate must be >= 0, got -1.0"):
        check_numbers(OptionalOutside(rate=-1.0))
    check_numbers(OptionalOutside(rate=None))
    check_numbers(OptionalOutside(rate=0.5))


def test_none_and_bools_pass():
    check_numbers(Outer(inner=Inner(rate=None), flag=True))


def test_a_config_built_in_code_is_checked_too():
    with pytest.raises(ConfigError, match="--pipeline.medium.sh-degree must be >= 0 and <= 2, got 7"):
        MediumConfig(sh_degree=7).check_values()
    MediumConfig().check_values()
