"""Writing an output folder safely: staged in a temporary sibling folder, renamed into place at the end.

An existing output folder is never damaged: a failed or interrupted run leaves it as it was, and
``overwrite`` swaps the new folder in only once it is complete. ``overwrite`` replaces only a folder
the same tool wrote before: every folder written here carries a manifest (:data:`MANIFEST`) naming
the tool and each file it wrote, and a folder without one, from another tool, or holding anything
the manifest does not list (a run, a dataset, a user's notes) is refused rather than deleted.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from components.data.images import (
    current_umask,
    to_uint8,
    write_array_atomic,
    write_bytes_atomic,
    write_image_atomic,
)
from tridehaze_plugin.errors import UserError, first_few

GL_CV = np.diag([1.0, -1.0, -1.0, 1.0])
"""OpenCV <-> OpenGL camera axes (self-inverse): nerfstudio's ``transform_matrix`` is OpenGL."""


MANIFEST = ".tridehaze-output.json"
"""Written last into every output folder: ``{"tool": ..., "files": [relative paths]}``."""


def check_output_dir(out: Path, overwrite: bool, tool: str, flag: str = "--output-dir") -> Path:
    """The output folder as an absolute path; UserError if it cannot (or must not) be written.

    ``tool`` names the writer (``td-export``): ``overwrite`` may only replace that tool's own folder.
    """
    out = Path(os.path.expanduser(str(out))).absolute()
    if out.exists() and not out.is_dir():
        raise UserError(f"{flag} is a file, not a folder", where=str(out), fix="pass a folder path")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise UserError(
                "output folder exists and is not empty",
                where=str(out),
                fix="pick a new folder, or pass --overwrite to replace it",
            )
        _check_replaceable(out, tool)
    return out


def _check_replaceable(out: Path, tool: str) -> None:
    """UserError unless ``out`` holds exactly what ``tool`` wrote there (its manifest says so)."""
    fix = "pick a new or empty folder (--overwrite replaces only a folder this tool wrote)"
    try:
        manifest = json.loads((out / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        manifest = None
    if not isinstance(manifest, dict) or manifest.get("tool") != tool:
        raise UserError(f"--overwrite refused: {tool} did not write this folder", where=str(out), fix=fix)
    listed = manifest.get("files")
    listed = {str(f) for f in listed} if isinstance(listed, list) else set()
    foreign = sorted(set(_files(out)) - listed - {MANIFEST})
    if foreign:
        raise UserError(
            f"--overwrite refused: the folder holds {len(foreign)} file(s) {tool} did not write "
            f"({first_few(foreign)})",
            where=str(out),
            fix="move them away first, or " + fix,
        )


def _files(root: Path) -> list[str]:
    """Every non-folder entry under ``root`` (links not followed), relative, '/'-separated."""
    out = []
    for dirpath, dirnames, filenames in os.walk(root):
        rel = Path(dirpath).relative_to(root)
        links = [d for d in dirnames if os.path.islink(os.path.join(dirpath, d))]
        out += [(rel / name).as_posix() for name in [*filenames, *links]]
    return out


class OutputTakenError(UserError):
    """The output folder was filled by another writer while this one wrote its staged copy (two
    runs making the same dataset at once); the other's folder is left as it is."""


@contextmanager
def staged_output(out: Path, overwrite: bool, tool: str, flag: str = "--output-dir") -> Iterator[Path]:
    """Yield a temporary folder next to ``out``; on success it replaces ``out`` (atomic rename)."""
    out = check_output_dir(out, overwrite, tool, flag)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    except OSError as exc:
        raise UserError(
            f"cannot create the output folder ({exc.strerror or exc})",
            where=str(out),
            fix="check permissions",
        ) from None
    try:
        yield tmp
        write_json(tmp / MANIFEST, {"tool": tool, "files": sorted(_files(tmp))})
        _commit(tmp, out, overwrite, tool)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def share_like_umask(path: Path) -> None:
    """Give ``path`` (and everything under it) the permissions a plain ``open``/``mkdir`` would have.

    Temporary files and folders are created private (0600 / 0700); a dataset or image meant for
    others must not stay that way after the rename.
    """
    mask = current_umask()
    path = Path(path)
    if path.is_dir():
        for p in [path, *path.rglob("*")]:
            os.chmod(p, (0o777 if p.is_dir() else 0o666) & ~mask)
    else:
        os.chmod(path, 0o666 & ~mask)


def _commit(tmp: Path, out: Path, overwrite: bool, tool: str) -> None:
    share_like_umask(tmp)
    old = None
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:  # appeared while we were writing
            raise OutputTakenError("output folder was filled by someone else while writing", where=str(out))
        _check_replaceable(out, tool)  # again: it may have changed while we were writing
        old = out.with_name(f".{out.name}.old-{uuid.uuid4().hex[:8]}")
        os.rename(out, old)
    elif out.is_dir():
        out.rmdir()
    try:
        os.rename(tmp, out)
    except OSError:
        if old is not None:
            os.rename(old, out)  # put the previous folder back
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def write_json(path: Path, obj: Any) -> None:
    write_bytes_atomic(path, (json.dumps(obj, indent=2) + "\n").encode("utf-8"))


def write_rgb(path: Path, img: np.ndarray) -> None:
    """Float [H, W, 3] in [0, 1] (or uint8) -> 8-bit PNG."""
    write_image_atomic(path, to_uint8(np.asarray(img)))


def write_map(path: Path, arr: np.ndarray) -> None:
    """Per-pixel float map -> ``.npy`` float32."""
    write_array_atomic(path, np.ascontiguousarray(arr, dtype=np.float32))


def frame_entry(
    c2w_cv: np.ndarray, files: dict[str, str], intrinsics: dict[str, float] | None = None
) -> dict:
    """One nerfstudio frame: OpenGL ``transform_matrix`` + file keys (+ per-frame intrinsics)."""
    entry: dict[str, Any] = dict(files)
    if intrinsics:
        entry.update(intrinsics)
    entry["transform_matrix"] = [[float(v) for v in row] for row in (np.asarray(c2w_cv) @ GL_CV)]
    return entry
