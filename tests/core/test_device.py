"""``--device`` resolution: auto, explicit CUDA without a GPU, and a CUDA start that fails."""

from __future__ import annotations

import warnings

import pytest
import torch

from pipelines.engine.device import resolve_device
from tridehaze_plugin.cuda_probe import cuda_status
from tridehaze_plugin.errors import ConfigError

# the warning torch 2.x gives when the driver is there but CUDA cannot start (seen on an H200 under
# the memory-limit tests' RLIMIT_AS)
TORCH_INIT_WARNING = (
    "CUDA initialization: Unexpected error from cudaGetDeviceCount(). Did you run some cuda functions "
    "before calling NumCudaDevices() that might have already set an error? Error 2: out of memory "
    "(Triggered internally at /pytorch/c10/cuda/CUDAFunctions.cpp:119.)"
)


def _failing_start() -> bool:
    warnings.warn(TORCH_INIT_WARNING, UserWarning, stacklevel=2)
    return False


def test_auto_follows_cuda_and_explicit_cuda_without_it_is_a_config_error():
    assert resolve_device("auto", cuda_available=False) == torch.device("cpu")
    assert resolve_device("auto", cuda_available=True) == torch.device("cuda")
    assert resolve_device("cpu", cuda_available=True) == torch.device("cpu")
    with pytest.raises(ConfigError) as err:
        resolve_device("cuda:1", cuda_available=False)
    assert err.value.what == "--device cuda:1 was asked for but CUDA is not available"
    assert err.value.fix == "use --device cpu"
    with pytest.raises(ConfigError, match="must be auto, cpu, cuda or cuda:N"):
        resolve_device("gpu", cuda_available=True)


def test_a_failed_cuda_start_is_one_reason_not_torchs_warning(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", _failing_start)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning that escapes fails the test
        assert cuda_status() == (False, "out of memory")
        assert resolve_device("auto") == torch.device("cpu")
        with pytest.raises(ConfigError) as err:
            resolve_device("cuda")
    assert err.value.what.endswith("is not available (CUDA failed to start: out of memory)")
    assert "\n" not in str(err.value)


def test_other_warnings_from_the_probe_still_reach_the_user(monkeypatch):
    def probe() -> bool:
        warnings.warn("something else", DeprecationWarning, stacklevel=2)
        return False

    monkeypatch.setattr(torch.cuda, "is_available", probe)
    with pytest.warns(DeprecationWarning, match="something else"):
        assert cuda_status() == (False, None)
