"""The layers import only downward; every import (function-local ones too) is checked from the source.

bottom (registry, config base, errors, method spec, the CUDA probe) < components < pipelines < CLI; inside
``pipelines/`` the rooms are ordered too: engine < evaluation < viewer < tridehaze < experiments.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

BOTTOM = {"tridehaze_plugin", "tridehaze_plugin.errors", "tridehaze_plugin.registry",
          "tridehaze_plugin.config", "tridehaze_plugin.method_spec",
          "tridehaze_plugin.cuda_probe"}  # fmt: skip
ROOMS = ("pipelines.engine", "pipelines.evaluation", "pipelines.viewer", "pipelines.tridehaze",
         "pipelines.experiments")  # fmt: skip
"""The rooms of ``pipelines/`` from the lowest up: a room imports only rooms before it (and itself)."""


def rank(module: str) -> tuple[int, int] | None:
    """(layer, room) of one of our modules; None for anything else (stdlib, third party)."""
    top = module.split(".")[0]
    if module in BOTTOM:
        return (0, 0)
    if top == "components":
        return (1, 0)
    if top == "pipelines":
        for i, room in enumerate(ROOMS):
            if module == room or module.startswith(room + "."):
                return (2, i + 1)
        return (2, 0)  # the package itself
    if module.startswith("tridehaze_plugin.cli"):
        return (3, 0)
    if top == "tridehaze_plugin":
        raise AssertionError(f"{module} is in no layer: add it to BOTTOM or move it to its room")
    return None


def module_name(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


def imports(source: str, module: str) -> list[tuple[int, str]]:
    """Every module an import statement in ``source`` names, with its line."""
    out = []
    package = module if module.endswith("__init__") else module.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the package
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                name = f"{base}.{node.module}" if node.module else base
            else:
                name = node.module or ""
            # `from pkg import sub` may name a module: rank "pkg.sub", trimmed to what exists
            out += [(node.lineno, f"{name}.{a.name}") for a in node.names]
    return out


def violations(path: Path, source: str | None = None) -> list[str]:
    module = module_name(path)
    mine = rank(module)
    if mine is None:
        return []
    bad = []
    for line, target in imports(source if source is not None else path.read_text(), module):
        theirs = _rank_existing(target)
        if theirs is not None and theirs > mine:
            bad.append(f"{path.relative_to(ROOT)}:{line}: {module} imports {target} (a higher layer)")
    return bad


def _rank_existing(target: str) -> tuple[int, int] | None:
    """Rank of ``target``, trimming a trailing attribute name (``from pkg.mod import func``)."""
    parts = target.split(".")
    while parts:
        name = ".".join(parts)
        if (ROOT / Path(*parts)).with_suffix(".py").exists() or (
            ROOT / Path(*parts) / "__init__.py"
        ).exists():
            return rank(name)
        parts.pop()
    return None


def source_files() -> list[Path]:
    return sorted(
        p for d in ("tridehaze_plugin", "components", "pipelines") for p in (ROOT / d).rglob("*.py")
    )


def test_every_import_points_down():
    bad = [v for p in source_files() for v in violations(p)]
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize(
    ("path", "line"),
    [
        ("tridehaze_plugin/registry.py", "from pipelines.tridehaze.methods import tri_dehaze"),
        ("components/medium/fields.py", "import pipelines.engine.trainer"),
        ("components/synth/haze_existing.py", "    from pipelines.engine.run_loader import load_run"),
        ("pipelines/engine/trainer.py", "from pipelines.viewer import TrainingViewer"),
        ("pipelines/tridehaze/pipeline.py", "from pipelines.experiments.tradeoff import KNOBS"),
        ("pipelines/engine/config.py", "from tridehaze_plugin.cli.common import run_cli"),
    ],
)
def test_a_forbidden_import_is_caught(path, line):
    """The check is not vacuous: adding one upward import to a real module fails it."""
    file = ROOT / path
    source = (
        file.read_text() + "\n\ndef _probe():\n" + (line if line.startswith("    ") else "    " + line) + "\n"
    )
    assert not violations(file)
    assert violations(file, source), f"{line!r} in {path} was not caught"


def test_allowed_imports_pass():
    file = ROOT / "pipelines/experiments/tradeoff.py"
    source = (
        file.read_text()
        + "\nfrom pipelines.engine.trainer import Trainer\nfrom components.medium.base import MediumConfig\n"
    )
    assert violations(file, source) == []
