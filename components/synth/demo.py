"""The built-in demo scene: a small hazy dataset generated once into the cache, used when td-train gets no --data.

Generation is deterministic, so the folder name is a hash of the settings (plus a version to bump
when the generator's output changes); a present and complete folder is reused as is. Writing is
staged in a temporary sibling folder and renamed, so an interrupted or concurrent first run never
leaves a half-written demo behind.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, replace
from pathlib import Path

from components.data.cache import cache_root
from components.synth.generate import SceneConfig, generate_scene
from tridehaze_plugin.errors import UserError

DEMO_VERSION = 1
"""Bump when the generator changes what the demo looks like, so stale copies are not reused."""

DEMO = SceneConfig(
    output_dir=Path("demo"),
    layout="courtyard",
    haze="patchy",
    seed=0,
    num_views=24,
    width=128,
    height=96,
    num_points=3000,
    seed_cloud="clean",
)
"""24 orbit views at 128x96 of a courtyard in patchy haze with a sun glow in the medium light."""


def demo_dir(cache_dir: Path | None = None, cfg: SceneConfig = DEMO) -> Path:
    settings = asdict(cfg)
    for k in ("output_dir", "overwrite", "threads"):
        settings.pop(k)
    key = hashlib.sha256(json.dumps([DEMO_VERSION, settings], sort_keys=True).encode()).hexdigest()[:12]
    return cache_root(cache_dir) / "synth" / f"demo-{cfg.layout}-{cfg.haze}-{key}"


def is_complete(path: Path) -> bool:
    """Whether ``path`` holds a finished dataset: its metadata (written last) and every frame's files."""
    try:
        meta = json.loads((path / "transforms.json").read_text(encoding="utf-8"))
        if not (path / "synth_meta.json").is_file():
            return False
        for fr in meta["frames"]:
            for k, v in fr.items():
                if k.endswith("file_path") and not (path / v).is_file():
                    return False
        return (path / meta["ply_file_path"]).is_file()
    except (OSError, ValueError, KeyError, TypeError):
        return False


def demo_scene_path(cache_dir: Path | None = None) -> Path:
    """The demo dataset's folder, generating it (a few seconds) on first use."""
    path = demo_dir(cache_dir)
    if is_complete(path):
        return path
    try:
        # replace only a broken leftover; a folder completed meanwhile by another process wins the race
        generate_scene(replace(DEMO, output_dir=path, overwrite=path.exists()))
    except UserError:
        if is_complete(path):  # another process finished it first
            return path
        raise
    except OSError as exc:
        if is_complete(path):
            return path
        raise UserError(
            f"cannot write the demo scene ({exc.strerror or exc})",
            where=str(path),
            fix="pass --cache-dir DIR (or set $TRIDEHAZE_CACHE) to a writable folder",
        ) from None
    return path
