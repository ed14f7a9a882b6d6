"""Building, caching and loading the cpu kernel; the fallback to torch without a compiler."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from components.native import build as native_build
from components.rasterizers import (
    CpuRasterizer,
    RasterizerConfig,
    TorchRasterizer,
    cpu_build,
    cpu_rasterizer,
    resolve_backend,
)

needs_compiler = pytest.mark.skipif(
    not CpuRasterizer.available(), reason="no C++ compiler for the cpu kernel"
)


def _scene():
    g = torch.Generator().manual_seed(0)
    n = 20
    means = torch.cat([torch.rand(n, 2, generator=g) - 0.5, torch.rand(n, 1, generator=g) * 2 + 2], dim=1)
    return dict(
        means=means,
        quats=torch.randn(n, 4, generator=g),
        scales=torch.rand(n, 3, generator=g) * 0.1 + 0.02,
        opacities=torch.rand(n, generator=g),
        colors=torch.rand(n, 3, generator=g),
        viewmats=torch.eye(4)[None],
        Ks=torch.tensor([[[30.0, 0.0, 16.0], [0.0, 30.0, 12.0], [0.0, 0.0, 1.0]]]),
    )


@pytest.fixture
def fresh_kernel_state(monkeypatch):
    """Forget loaded kernels and warnings before and after, so settings made here do not leak."""
    native_build.forget()
    monkeypatch.setattr(cpu_rasterizer, "_warned", set())
    yield monkeypatch
    native_build.forget()


def test_missing_compiler_falls_back_to_torch_with_one_line(fresh_kernel_state, capsys) -> None:
    fresh_kernel_state.setenv("CXX", "/nonexistent/c++")
    assert not CpuRasterizer.available()
    assert resolve_backend("auto", device=torch.device("cpu")) == "torch"
    rast = CpuRasterizer()
    out = rast.rasterize(**_scene(), width=32, height=24)
    err = capsys.readouterr().err
    assert (
        err
        == "warning: cpu rasterizer unavailable (compiler CXX='/nonexistent/c++' not found); using torch\n"
    )
    again = rast.rasterize(**_scene(), width=32, height=24)
    assert capsys.readouterr().err == ""  # warned once
    ref = TorchRasterizer().rasterize(**_scene(), width=32, height=24)
    assert torch.equal(out.rgb, ref.rgb) and torch.equal(again.alpha, ref.alpha)


def test_failing_compiler_makes_the_backend_unavailable(fresh_kernel_state, tmp_path) -> None:
    fake = tmp_path / "broken-c++"
    fake.write_text(
        '#!/bin/sh\nif [ "$1" = --version ]; then echo broken 1.0; exit 0; fi\necho "boom" >&2\nexit 1\n'
    )
    fake.chmod(0o755)
    fresh_kernel_state.setenv("CXX", str(fake))
    fresh_kernel_state.setenv(native_build.CACHE_ENV_VAR, str(tmp_path / "cache"))
    with pytest.raises(cpu_build.KernelUnavailable, match="compiling cpu_raster.cpp failed: boom"):
        cpu_build.load_kernel()
    assert not CpuRasterizer.available()
    # each variant's failure is remembered on disk, so other processes do not retry it
    assert len(list((tmp_path / "cache" / "kernels").glob("*.failed"))) == len(native_build.VARIANTS)
    assert not list((tmp_path / "cache" / "kernels").glob("*.tmp"))


@needs_compiler
def test_compiled_library_is_cached_and_reused(fresh_kernel_state, tmp_path) -> None:
    fresh_kernel_state.setenv(native_build.CACHE_ENV_VAR, str(tmp_path))
    builds = native_build.BUILD_COUNT
    lib = cpu_build.load_kernel()
    assert native_build.BUILD_COUNT == builds + 1
    (so,) = (tmp_path / "kernels").glob("cpu_raster-*.so")
    assert lib.tdh_variant in so.name and not list((tmp_path / "kernels").glob("*.tmp"))
    mtime = so.stat().st_mtime_ns
    native_build.forget()  # as a new process would: look up the cache again
    cpu_build.load_kernel()
    assert native_build.BUILD_COUNT == builds + 1 and so.stat().st_mtime_ns == mtime


@needs_compiler
def test_concurrent_first_builds_are_safe(tmp_path) -> None:
    """Two processes building into an empty cache both load a complete library (atomic rename)."""
    path = Path(native_build.__file__)
    code = (
        "import importlib.util, sys\n"
        f"spec = importlib.util.spec_from_file_location('native_build', {str(path)!r})\n"
        "mod = sys.modules['native_build'] = importlib.util.module_from_spec(spec); spec.loader.exec_module(mod)\n"
        f"spec = mod.NativeLibrary('cpu_raster', mod.Path({str(cpu_build.SOURCE)!r}), 'tdh_abi_version', "
        f"{cpu_build.ABI_VERSION})\n"
        "lib = spec.load(); print(lib.tdh_abi_version(), lib.tdh_variant)\n"
    )  # the builder alone: no torch import, so the two builds really overlap
    env = dict(os.environ, **{native_build.CACHE_ENV_VAR: str(tmp_path)})
    procs = [
        subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    outs = [p.communicate(timeout=300)[0].split() for p in procs]
    assert all(p.returncode == 0 for p in procs) and outs[0] == outs[1]
    assert len(list((tmp_path / "kernels").glob("cpu_raster-*.so"))) == 1
    assert not list((tmp_path / "kernels").glob("*.tmp")) and not list((tmp_path / "kernels").glob("*.o"))


@needs_compiler
def test_loading_does_not_flush_denormals() -> None:
    """-ffast-math only at the compile step: linking it would turn on flush-to-zero process-wide."""
    cpu_build.load_kernel()
    tiny = torch.tensor([1e-40])
    assert (tiny * 1.0).item() > 0.0


def test_native_build_does_not_import_torch() -> None:
    spec = importlib.util.find_spec("components.native.build")
    assert spec is not None and "import torch" not in Path(spec.origin).read_text()


@needs_compiler
def test_auto_prefers_cpu_without_cuda() -> None:
    if not torch.cuda.is_available():
        assert resolve_backend("auto") == "cpu"
    assert isinstance(RasterizerConfig(backend="cpu").setup(), CpuRasterizer)


@needs_compiler
def test_an_edited_shared_header_changes_the_cache_key(tmp_path) -> None:
    """Kernels include shared headers (components/native/csrc); editing one must rebuild them."""
    (tmp_path / "inc").mkdir()
    header = tmp_path / "inc" / "shared.h"
    header.write_text("inline int one() { return 1; }\n")
    source = tmp_path / "k.cpp"
    source.write_text('#include "inc/shared.h"\nextern "C" int abi() { return one(); }\n')
    assert native_build.local_includes(source) == [source.resolve(), header.resolve()]
    lib = native_build.NativeLibrary("k", source, "abi", 1)
    cxx, variant = native_build.find_compiler(), native_build.VARIANTS[-1]
    before = lib.library_path(cxx, variant)
    header.write_text("inline int one() { return 2; }\n")
    assert lib.library_path(cxx, variant) != before
