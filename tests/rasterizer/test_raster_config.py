"""Backend selection and config plumbing of the rasterizer component."""

from __future__ import annotations

import pytest
import torch

from components.rasterizers import RasterizerConfig, TorchRasterizer, resolve_backend
from components.rasterizers.base import Rasterizer
from tridehaze_plugin.config import validate
from tridehaze_plugin.errors import ConfigError, PluginError
from tridehaze_plugin.registry import REGISTRY, Registry


class _Fake(Rasterizer):
    ok = True

    @classmethod
    def available(cls) -> bool:
        return cls.ok

    def rasterize(self, *args, **kwargs):  # pragma: no cover - never called
        raise NotImplementedError


class _FakeCpu(_Fake):
    name = "cpu"
    fallback = "torch"


class _FakeGsplat(_Fake):
    name = "gsplat"

    @classmethod
    def runs_on(cls, device: torch.device) -> bool:
        return device.type == "cuda"


def test_torch_backend_is_registered_and_built_with_the_config() -> None:
    assert REGISTRY.get("rasterizer", "torch") is TorchRasterizer
    cfg = RasterizerConfig(backend="torch", near_plane=0.2, tile_size=8)
    rast = cfg.setup()
    assert isinstance(rast, TorchRasterizer) and rast.config is cfg
    validate(cfg)
    validate(RasterizerConfig(backend="auto"))
    with pytest.raises(ConfigError):
        validate(RasterizerConfig(backend="no-such-backend"))
    with pytest.raises(PluginError):
        RasterizerConfig(backend="no-such-backend").setup()


def test_auto_prefers_gsplat_on_cuda_then_cpu_then_torch(capsys) -> None:
    reg = Registry()
    reg.register("rasterizer", "torch", TorchRasterizer)
    assert resolve_backend("auto", reg) == "torch"
    reg.register("rasterizer", "cpu", _FakeCpu)
    assert resolve_backend("auto", reg) == "cpu"
    reg.register("rasterizer", "gsplat", _FakeGsplat)
    expect = "gsplat" if torch.cuda.is_available() else "cpu"
    assert resolve_backend("auto", reg) == expect
    _FakeCpu.ok = False
    _FakeGsplat.ok = False
    try:
        assert resolve_backend("auto", reg) == "torch"
        assert capsys.readouterr().err == ""  # auto falls back silently
        # an explicit backend with a fallback warns in one line and uses it ...
        assert resolve_backend("cpu", reg) == "torch"
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "cpu rasterizer unavailable" in err[0] and "using torch" in err[0]
        # ... one without a fallback is a clear error
        with pytest.raises(ConfigError, match="not available"):
            resolve_backend("gsplat", reg)
    finally:
        _FakeCpu.ok = True
        _FakeGsplat.ok = True


def test_auto_follows_the_run_device_not_the_machine() -> None:
    """A CPU run on a CUDA machine must not get the CUDA-only backend (it crashed inside gsplat)."""
    reg = Registry()
    for name, cls in (("torch", TorchRasterizer), ("cpu", _FakeCpu), ("gsplat", _FakeGsplat)):
        reg.register("rasterizer", name, cls)
    assert resolve_backend("auto", reg, device=torch.device("cpu")) == "cpu"
    assert resolve_backend("auto", reg, device=torch.device("cuda")) == "gsplat"
    _FakeGsplat.ok = False
    try:
        assert resolve_backend("auto", reg, device=torch.device("cuda")) == "cpu"
    finally:
        _FakeGsplat.ok = True
    with pytest.raises(ConfigError, match="does not render on cpu") as err:
        resolve_backend("gsplat", reg, device=torch.device("cpu"))
    assert err.value.where == "--pipeline.rasterizer.backend" and "--device cuda" in err.value.fix


def test_rasterizer_without_config_uses_defaults() -> None:
    rast = TorchRasterizer()
    assert rast.config.backend == "torch" and rast.config.eps2d == 0.3 and rast.config.tile_size == 16


def test_wrong_shapes_fail_readably() -> None:
    rast = TorchRasterizer()
    n = 4
    args = [torch.zeros(n, 3), torch.zeros(n, 4), torch.ones(n, 3), torch.ones(n), torch.ones(n, 3)]
    cams = [torch.eye(4)[None], torch.eye(3)[None]]
    with pytest.raises(ValueError, match="quats"):
        rast.rasterize(args[0], torch.zeros(n, 3), *args[2:], *cams, 8, 8)
    with pytest.raises(ValueError, match="SH coefficients"):
        rast.rasterize(*args, *cams, 8, 8, sh_degree=1)


def test_kernel_threads_follow_torch_threads_and_the_env_var_overrides(monkeypatch) -> None:
    """``td-train --threads 1`` in each of a sweep's parallel runs must mean one kernel thread too
    (every core per run made two runs at once on 2 cores step 1.41x slower)."""
    from components.rasterizers import cpu_rasterizer

    monkeypatch.delenv(cpu_rasterizer.THREADS_ENV_VAR, raising=False)
    monkeypatch.setattr(cpu_rasterizer.os, "sched_getaffinity", lambda pid: set(range(8)), raising=False)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        assert cpu_rasterizer.default_threads() == 1
        torch.set_num_threads(3)
        assert cpu_rasterizer.default_threads() == 3
        monkeypatch.setattr(cpu_rasterizer.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
        assert cpu_rasterizer.default_threads() == 2  # never more than the cores it may use
        monkeypatch.setenv(cpu_rasterizer.THREADS_ENV_VAR, "5")
        assert cpu_rasterizer.default_threads() == 5
    finally:
        torch.set_num_threads(before)
