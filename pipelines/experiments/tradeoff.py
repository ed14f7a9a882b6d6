"""The speed-accuracy grid: every knob that costs time, swept one at a time around a base config.

A full factorial grid over eight knobs is far beyond a CPU budget, so each knob is varied alone
(the other knobs at the base values) and a few combined settings (the preset candidates) are added;
the Pareto front is then taken over all of them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pipelines.engine.config import TrainerConfig
from pipelines.experiments.ablation import Variant
from pipelines.tridehaze.methods import tri_dehaze_fast, tri_dehaze_quality

BASE_METHOD = "tri-dehaze"
BASE_STEPS = 1500


@dataclass(frozen=True)
class Knob:
    """One time-costing setting and the values to try (the base value first)."""

    name: str
    flag: str | None
    """The td-train flag; None for the step count (a run setting, not an override)."""
    values: tuple[str, ...]


KNOBS: tuple[Knob, ...] = (
    Knob("steps", None, ("1500", "500", "1000", "3000")),
    Knob("downscale", "--downscale", ("1", "2")),
    Knob("max-gaussians", "--pipeline.densify.max-gaussians", ("1000000", "5000", "20000")),
    Knob("grow-grad2d", "--pipeline.densify.grow-grad2d", ("0.0002", "0.0004", "0.0001")),
    Knob("samples", "--pipeline.composite.num-samples", ("16", "4", "8", "32")),
    Knob("medium-res", "--pipeline.medium.resolution", ("64", "16", "32", "128")),
    Knob("coarse-rays", "--pipeline.composite.coarse-rays", ("1200", "300", "4800")),
    Knob("sh-degree", "--pipeline.model.sh-degree", ("3", "0", "1")),
    Knob("rasterizer", "--pipeline.rasterizer.backend", ("cpu", "torch")),
    Knob("medium", "--pipeline.medium.backend", ("triplane", "constant", "none", "auto")),
    Knob("growth", "--pipeline.densify.growth", ("schedule", "plateau")),
    Knob("freeze-fraction", "--pipeline.freeze-fraction", ("0.75", "0.5", "0.2")),
)
"""Knobs of issue 8 with their values; the first value of each is the base (tri-dehaze's default)."""

COMBOS: dict[str, Callable[[], TrainerConfig]] = {"fast": tri_dehaze_fast, "quality": tri_dehaze_quality}
"""Combined settings measured next to the one-knob sweeps: the registered speed presets themselves,
so a preset is always exactly what the bench measured."""


def knob_flags(settings: dict[str, str]) -> tuple[list[str], int | None]:
    """td-train flags for knob ``settings`` (base values left out) and the step count, if set."""
    flags: list[str] = []
    steps = None
    for knob in KNOBS:
        value = settings.get(knob.name)
        if value is None or value == knob.values[0]:
            continue
        if knob.flag is None:
            steps = int(value)
        else:
            flags += [knob.flag, value]
    return flags, steps


def _scaled(steps: int, base_steps: int) -> int:
    """A step count given for the default budget (BASE_STEPS), rescaled to ``base_steps``."""
    return max(1, round(steps * base_steps / BASE_STEPS))


def _variant(name: str, settings: dict[str, str], base_steps: int) -> Variant:
    overrides, steps = knob_flags(settings)
    scaled = base_steps if steps is None else _scaled(steps, base_steps)
    return Variant(name, BASE_METHOD, tuple(overrides), label=name, max_steps=scaled)


def parse_knobs(specs: list[str] | None) -> dict[str, tuple[str, ...]]:
    """``["steps", "samples=4,8"]`` -> the chosen knobs with the non-base values to try
    (a bare name takes all of them); None selects every knob."""
    by_name = {k.name: k for k in KNOBS}
    if specs is None:
        return {k.name: k.values[1:] for k in KNOBS}
    chosen: dict[str, tuple[str, ...]] = {}
    for spec in specs:
        name, _, values = spec.partition("=")
        if name not in by_name:
            raise ValueError(f"unknown knob {name!r}; use one of {', '.join(by_name)}")
        knob = by_name[name]
        if not values:
            chosen[name] = knob.values[1:]
            continue
        picked = tuple(v.strip() for v in values.split(",") if v.strip())
        unknown = [v for v in picked if v not in knob.values[1:]]
        if unknown or not picked:
            raise ValueError(f"knob {name} has no value {', '.join(unknown) or '(empty)'}; "
                             f"try {', '.join(knob.values[1:])}")  # fmt: skip
        chosen[name] = picked
    return chosen


def grid(
    knobs: list[str] | None = None, combos: bool | list[str] = True, base_steps: int = BASE_STEPS
) -> list[Variant]:
    """The base run, each knob's other values one at a time, then the combinations; ``base_steps``
    rescales every step count (names keep the values at the default budget). ``knobs`` as in
    :func:`parse_knobs`."""
    chosen = parse_knobs(knobs)
    variants = [_variant("base", {}, base_steps)]
    for knob in KNOBS:
        for value in chosen.get(knob.name, ()):
            variants.append(_variant(f"{knob.name}={value}", {knob.name: value}, base_steps))
    chosen_combos = list(COMBOS) if combos is True else list(combos or [])
    for name in chosen_combos:
        if name not in COMBOS:
            raise ValueError(f"unknown combination {name!r}; use one of {', '.join(COMBOS)}")
        preset = COMBOS[name]()
        variants.append(
            Variant(name, preset.method_name, label=name, max_steps=_scaled(preset.max_steps, base_steps))
        )
    return variants


def pareto_front(
    points: list[dict[str, Any]],
    cost: str = "wall_seconds",
    gain: str = "psnr",
    higher_is_better: bool = True,
) -> list[str]:
    """Names of the points no other point beats on both cost (lower) and gain (higher, or lower
    with ``higher_is_better=False``, e.g. LPIPS)."""
    sign = 1.0 if higher_is_better else -1.0
    front = []
    for p in points:
        if p.get(cost) is None or p.get(gain) is None:
            continue
        dominated = any(
            q is not p
            and q.get(cost) is not None
            and q.get(gain) is not None
            and q[cost] <= p[cost]
            and sign * q[gain] >= sign * p[gain]
            and (q[cost] < p[cost] or sign * q[gain] > sign * p[gain])
            for q in points
        )
        if not dominated:
            front.append(p["name"])
    return front
