"""A fingerprint of the framework's source, so a benchmark never resumes or reuses runs of other code.

A run folder's settings (method, overrides, steps, seed) say nothing about the code that trained it:
a stopped run resumed after the code changed would finish under the new code from the old code's
checkpoint, and a stored result would be reported as the new code's. The fingerprint hashes the
sources that can change a number (Python, the native kernels' C++), not the docs or the tests.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from pathlib import Path

SOURCE_SUFFIXES = (".py", ".cpp", ".h", ".cu")
"""Files whose change can change a run's numbers."""


def source_fingerprint(roots: Iterable[Path]) -> str:
    """A short hash of every source file under ``roots`` (relative paths and contents, in a fixed
    order: the same tree gives the same hash on any machine)."""
    digest = hashlib.sha256()
    for root in roots:
        files = sorted(p for p in root.rglob("*") if p.suffix in SOURCE_SUFFIXES and p.is_file())
        for path in files:
            if "__pycache__" in path.parts:
                continue
            digest.update(f"{root.name}/{path.relative_to(root).as_posix()}\0".encode())
            digest.update(path.read_bytes())
            digest.update(b"\0")
    return digest.hexdigest()[:16]


def code_fingerprint() -> str:
    """The fingerprint of this installation's ``tridehaze_plugin``, ``components`` and ``pipelines``
    as they are now (read afresh at each call, about 10 ms: a sweep may outlive an edit of the code)."""
    import components
    import pipelines
    import tridehaze_plugin

    return source_fingerprint(Path(pkg.__file__).parent for pkg in (tridehaze_plugin, components, pipelines))
