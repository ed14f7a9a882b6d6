"""A real third-party plugin package, pip-installed into a temporary target, is discovered by the CLI."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

PYPROJECT = """
[build-system]
requires = ["setuptools>=70.1"]
build-backend = "setuptools.build_meta"

[project]
name = "toy-tridehaze-plugin"
version = "0.0.1"

[project.entry-points."tridehaze.methods"]
toy-method = "toy_tridehaze_plugin:toy_method"

[project.entry-points."tridehaze.components"]
toy-components = "toy_tridehaze_plugin.losses"
broken = "toy_tridehaze_plugin.broken"

[tool.setuptools]
packages = ["toy_tridehaze_plugin"]
"""

INIT = '''
"""A toy plugin: one method preset and one loss."""
import dataclasses

from tridehaze_plugin.method_spec import MethodSpec


def _config():
    from tridehaze_plugin.registry import REGISTRY
    cfg = REGISTRY.get("method", "vanilla-gs").make_config()
    cfg.pipeline.loss.backend = "toy-l2"
    cfg.max_steps = 7
    return cfg


toy_method = MethodSpec("toy-method", "Toy plugin method using the toy L2 loss.", _config)
'''

LOSSES = '''
from tridehaze_plugin.registry import register


class ToyL2:
    """Mean squared error, registered by the toy plugin."""

    def __init__(self, config):
        self.config = config

    def __call__(self, pred, target):
        loss = ((pred - target) ** 2).mean()
        return loss, {"l2": loss.detach()}


register("loss", "toy-l2", ToyL2)
'''


@pytest.fixture(scope="module")
def plugin_site(tmp_path_factory) -> Path:
    src = tmp_path_factory.mktemp("toy_src")
    (src / "pyproject.toml").write_text(PYPROJECT)
    pkg = src / "toy_tridehaze_plugin"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(textwrap.dedent(INIT))
    (pkg / "losses.py").write_text(textwrap.dedent(LOSSES))
    (pkg / "broken.py").write_text("import a_dependency_that_is_not_installed_123\n")
    target = tmp_path_factory.mktemp("toy_site")
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "--quiet",
            "--no-deps",
            "--no-build-isolation",
            "--target",
            str(target),
            str(src),
        ],
        check=True,
    )
    assert any(p.name.startswith("toy_tridehaze_plugin-") for p in target.glob("*.dist-info"))
    return target


def _run(args: list[str], site: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(site))
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, env=env, timeout=120)


def test_installed_plugin_method_is_listed_and_broken_one_reported(plugin_site):
    res = _run(["tridehaze_plugin.cli.train", "--help"], plugin_site)
    assert res.returncode == 0, res.stderr
    assert "toy-method" in res.stdout and "vanilla-gs" in res.stdout
    # the broken entry point gives one clear warning line and does not stop the CLI
    warn = [ln for ln in res.stderr.splitlines() if "toy_tridehaze_plugin.broken" in ln]
    assert len(warn) == 1, res.stderr
    assert "failed to load" in warn[0] and "a_dependency_that_is_not_installed_123" in warn[0]
    assert "Traceback" not in res.stderr


def test_installed_plugin_components_visible_in_td_info(plugin_site):
    res = _run(["tridehaze_plugin.cli.info"], plugin_site)
    assert res.returncode == 0, res.stderr
    assert "toy-l2" in res.stdout
    assert "failed plugin" in res.stdout


def test_plugin_method_config_uses_plugin_component(plugin_site):
    code = (
        "from tridehaze_plugin.cli.train import parse_args;"
        "c = parse_args(['toy-method', '--pipeline.loss.lambda-ssim', '0.5']);"
        "print(c.method_name, c.pipeline.loss.backend, c.max_steps, c.pipeline.loss.lambda_ssim)"
    )
    env = dict(os.environ, PYTHONPATH=str(plugin_site))
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["toy-method", "toy-l2", "7", "0.5"]
