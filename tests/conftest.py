"""Suite-wide test settings.

``--device cuda`` runs the method tests (pipeline, medium, compositing, gradient policies, losses,
stability) with their tensors and training runs on the GPU, so anything CPU-only by accident (a
tensor made on the default device, a numpy round trip) fails there; the default, cpu, is what CI runs.

The suite runs in parallel worker processes (pytest-xdist, ``-n auto`` in ``make test``), each
test process and every CLI process it starts with one torch / OpenMP thread: two workers with two
threads each on two cores cost more than they gain (benchmarks/suite_workers.py).
``TD_TEST_THREADS=default`` leaves the threads to torch (for that benchmark).
"""

from __future__ import annotations

import os
from pathlib import Path

ONE_THREAD = os.environ.get("TD_TEST_THREADS", "1") != "default"
if ONE_THREAD:
    os.environ["OMP_NUM_THREADS"] = "1"  # before torch is imported; inherited by the CLI processes

import pytest  # noqa: E402
import torch  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("TRIDEHAZE_SHARED", REPO.parent / "shared"))
"""The team's shared folder (real scenes); CI clones the repo with ``shared/`` beside it."""
REAL_DATA = SHARED / "data" / "real"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--device",
        default="cpu",
        help="torch device for the tests that take one, e.g. cuda for the GPU run of the suite",
    )


def pytest_configure(config: pytest.Config) -> None:
    if ONE_THREAD:
        torch.set_num_threads(1)  # in case torch was imported before this file
    _device(config)  # a bad --device stops the run before collection: a GPU run must not pass on cpu


def _device(config: pytest.Config) -> torch.device:
    """``--device`` as a ``torch.device``; asking for CUDA without one is a usage error, not a skip."""
    name = config.getoption("--device")
    try:
        device = torch.device(name)
    except RuntimeError as exc:
        raise pytest.UsageError(f"--device {name!r} is not a torch device ({exc})") from None
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise pytest.UsageError(f"--device {name} was asked for but CUDA is not available here")
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise pytest.UsageError(f"--device {name}: only {torch.cuda.device_count()} CUDA device(s) here")
    return device


@pytest.fixture(scope="session")
def device(pytestconfig: pytest.Config) -> torch.device:
    """The torch device the method tests put their tensors, modules and training runs on (``--device``)."""
    return _device(pytestconfig)


def require_real(scene: str) -> Path:
    """Path of a real scene; skipped locally when absent, but a failure in CI (it must be there)."""
    path = REAL_DATA / scene
    if not path.is_dir():
        if os.environ.get("CI"):
            pytest.fail(f"real scene {path} is missing in CI (expected ../shared beside the clone)")
        pytest.skip(f"real scene {path} not available")
    return path
