"""td-info lists every registered component with its description as plain text."""

from __future__ import annotations

import os
import subprocess
import sys


def test_td_info_prints_descriptions_verbatim():
    env = {**os.environ, "COLUMNS": "200"}
    out = subprocess.run(
        [sys.executable, "-m", "tridehaze_plugin.cli.info"],
        capture_output=True,
        text=True,
        env=env,
        check=True,
    ).stdout
    # brackets in a docstring are not rich markup: the Fourier encoder's formula survives
    assert "[x, sin(2^k pi x), cos(2^k pi x)]" in out
    for name in ("triplane", "gaussian-bound", "cpu", "torch", "md-tgc", "tri-dehaze-fast"):
        assert name in out
    assert "Medium carried by the Gaussians" in out
    rows = [line.split("│") for line in out.splitlines() if line.count("│") == 5]
    undescribed = [r[2].strip() for r in rows if r[1].strip() and not r[4].strip()]
    assert not undescribed, f"registered without a description: {undescribed}"
