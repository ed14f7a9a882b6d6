"""Folders as bytes, for sweeps whose workers share no file system with the head.

A scene goes to a worker as one archive in Ray's object store; a finished run folder comes back the
same way (or is written by the worker straight to a storage path). Archives are gzip tars with
relative member names only, unpacked with tarfile's ``data`` filter: an archive cannot write
outside the folder it is unpacked into.
"""

from __future__ import annotations

import hashlib
import io
import os
import shutil
import tarfile
import tempfile
from collections.abc import Callable
from pathlib import Path

CHECKPOINT_DIR = "checkpoints"
"""The run folder's checkpoint sub-folder (td-train's layout), left out of returned runs unless asked."""


def pack_folder(root: Path, keep: Callable[[Path], bool] = lambda rel: True) -> bytes:
    """A gzip tar of ``root``'s files (names relative to it) whose relative path passes ``keep``."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz", compresslevel=1) as tar:  # level 1: images barely compress
        for path in sorted(Path(root).rglob("*")):
            rel = path.relative_to(root)
            if path.is_file() and not path.is_symlink() and keep(rel):
                tar.add(path, arcname=rel.as_posix(), recursive=False)
    return buf.getvalue()


def unpack_folder(data: bytes, dest: Path, replace: bool = True) -> Path:
    """Unpack an archive from :func:`pack_folder` into ``dest``; with ``replace`` an existing
    ``dest`` is swapped out only once the new copy is complete (a failure leaves the old one)."""
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", dir=dest.parent))
    try:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
            tar.extractall(tmp, filter="data")
        if dest.exists():
            if not replace:
                raise FileExistsError(dest)
            old = dest.with_name(f".{dest.name}.old-{os.getpid()}")
            dest.rename(old)
            tmp.rename(dest)
            shutil.rmtree(old, ignore_errors=True)
        else:
            tmp.rename(dest)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return dest


def run_folder_filter(keep_checkpoints: bool) -> Callable[[Path], bool]:
    """Which files of a run folder travel back to the head."""
    return lambda rel: keep_checkpoints or rel.parts[0] != CHECKPOINT_DIR


def folder_fingerprint(root: Path) -> str:
    """Content hash of a folder (relative names and bytes): a worker uses a scene in place only
    when its copy at the same path is this very dataset, not a different one of the same name."""
    h = hashlib.sha256()
    for path in sorted(Path(root).rglob("*")):
        if path.is_file():
            h.update(path.relative_to(root).as_posix().encode() + b"\0")
            with path.open("rb") as f:
                for chunk in iter(lambda: f.read(1 << 20), b""):  # noqa: B023 - consumed at once
                    h.update(chunk)
            h.update(b"\1")
    return h.hexdigest()[:16]


def is_uri(location: str) -> bool:
    """``s3://bucket/x``, ``gs://...``, ``file:///...``: a storage URI rather than a plain path."""
    return "://" in location


def copy_to_storage(local: Path, location: str, rel: str, keep: Callable[[Path], bool]) -> str:
    """Copy the files of ``local`` that pass ``keep`` to ``location/rel`` and return that target.

    ``location`` is a local path or any URI pyarrow's file systems accept (what Ray's
    ``storage_path`` accepts: ``s3://``, ``gs://``, ``abfs://``, ``hdfs://``, ``file://``).
    """
    if not is_uri(location):
        target = Path(location) / rel
        unpack_folder(pack_folder(local, keep), target)
        return str(target)
    try:
        import pyarrow.fs as pafs
    except ImportError as e:  # the cluster extra installs it
        raise RuntimeError(f"storage path {location}: URIs need pyarrow (pip install -e '.[cluster]')") from e
    fs, base = pafs.FileSystem.from_uri(location)
    target = f"{base.rstrip('/')}/{rel}"
    fs.create_dir(target, recursive=True)
    for path in sorted(Path(local).rglob("*")):
        sub = path.relative_to(local)
        if path.is_file() and keep(sub):
            parent = target if sub.parent == Path(".") else f"{target}/{sub.parent.as_posix()}"
            fs.create_dir(parent, recursive=True)
            with path.open("rb") as src, fs.open_output_stream(f"{target}/{sub.as_posix()}") as out:
                shutil.copyfileobj(src, out, 1 << 20)
    return f"{location.rstrip('/')}/{rel}"
