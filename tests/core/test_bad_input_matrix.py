"""Malformed input to td-train, td-eval, td-render and td-synth: exit code 2 and one clear line.

Every case runs the command's entry point (all cases in one fresh process, a few again each in its
own process to show the two agree) and checks: exit code 2, no traceback, stderr is the
single line ``error: <what> (<where>); <how to fix>`` starting with the expected text (tyro's own
parse errors for malformed values print a box instead: accepted, still exit 2 without a
traceback), and a finished run folder made once for the module is byte-identical afterwards
(same files, bytes and modification times; several cases point straight at it).
The table is listed in docs/stability.md.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pytest
from rich.console import Console

from components.data.ply import write_ply_points
from pipelines.engine.trainer import Trainer
from tests.tiny_scenes import tiny_hazy_scene
from tridehaze_plugin.cli.export import main as export_main
from tridehaze_plugin.cli.train import parse_args


@dataclass(frozen=True)
class Case:
    command: str
    """train, eval, render, synth, export or ablate."""
    args: tuple[str, ...]
    """Arguments; ``{run}``, ``{config}``, ``{scene}`` and ``{fx}`` (prepared bad inputs) are filled in."""
    expect: str
    """Start of the message after ``error: ``; for a tyro box, text somewhere in it."""
    box: bool = False
    """A tyro parse error (boxed, several lines) rather than our one-line error."""
    warnings: int = 0
    """``warning:`` lines expected before the error (the input is also odd in a way that alone
    would only be warned about)."""
    env: dict[str, str] = field(default_factory=dict)


TRAIN = ("tri-dehaze", "--output-dir", "{fx}/out", "--max-steps", "2", "--threads", "1",
         "--pipeline.rasterizer.backend", "torch", "--no-eval-at-end")  # fmt: skip
EVAL = ("--lpips", "off")  # LPIPS is not the subject (see the xfail case below for why this matters)
NO_LPIPS = {"TRIDEHAZE_LPIPS_WEIGHTS": "/missing/alexnet.ckpt"}


def _flag_cases(*rows: tuple[str, str, str]) -> dict[str, Case]:
    """td-train on the good scene with one flag set to a bad value: (flag, value, expected start)."""
    return {
        f"train: {flag} {value}": Case("train", (*TRAIN, "--data", "{scene}", flag, value), expect)
        for flag, value, expect in rows
    }


CASES: dict[str, Case] = {
    # ------------------------------------------------------------------------------ td-train
    "train: missing --data folder": Case(
        "train", (*TRAIN, "--data", "{fx}/absent"), "dataset folder not found"
    ),
    "train: empty dataset folder": Case(
        "train", (*TRAIN, "--data", "{fx}/empty"), "cannot tell the dataset format"
    ),
    "train: corrupt image file": Case(
        "train", (*TRAIN, "--data", "{fx}/corrupt"), "image is corrupt or not a supported image format"
    ),
    "train: transforms.json is not JSON": Case("train", (*TRAIN, "--data", "{fx}/not_json"), "invalid JSON"),
    "train: image size differs from the intrinsics": Case(
        "train", (*TRAIN, "--data", "{fx}/wrong_size"), "image is 16x12 but its camera says 32x24"
    ),
    "train: transform_matrix of the wrong shape": Case(
        "train", (*TRAIN, "--data", "{fx}/bad_pose"), "transform_matrix must be a 4x4"
    ),
    **{  # a run folder outside --output-dir: climbing out, nested, the parent itself
        f"train: --timestamp {stamp}": Case(
            "train", (*TRAIN, "--data", "{scene}", "--timestamp", stamp), "--timestamp must be one plain"
        )
        for stamp in ("../../../../x", "a/b", "..")
    },
    "train: --pipeline.lambda-depth inf": Case(
        "train",
        (*TRAIN, "--data", "{scene}", "--pipeline.lambda-depth", "inf"),
        "--pipeline.lambda-depth must be a finite number",
    ),
    **{  # every step was skipped, then "the last good checkpoint is kept" with none written
        f"train: seed points all {kind}": Case(
            "train", (*TRAIN, "--data", f"{{fx}}/points_{kind}"), "none of the 50 seed points is usable"
        )
        for kind in ("nan", "inf", "1e30")
    },
    "train: negative --max-steps": Case(
        "train", (*TRAIN, "--data", "{scene}", "--max-steps", "-5"), "--max-steps must be >= 1"
    ),
    "train: --pipeline.t-min 0": Case(
        "train", (*TRAIN, "--data", "{scene}", "--pipeline.t-min", "0"), "--pipeline.t-min must be in (0, 1]"
    ),
    "train: --pipeline.t-min 1.5": Case(
        "train",
        (*TRAIN, "--data", "{scene}", "--pipeline.t-min", "1.5"),
        "--pipeline.t-min must be in (0, 1]",
    ),
    "train: unknown rasterizer backend": Case(
        "train",
        (*TRAIN, "--data", "{scene}", "--pipeline.rasterizer.backend", "vulkan"),
        "unknown rasterizer 'vulkan'",
    ),
    "train: --output-dir is a file": Case(
        "train", (*TRAIN, "--data", "{scene}", "--output-dir", "{fx}/a_file"), "--output-dir is a file"
    ),
    "train: --max-steps not a number": Case(
        "train", (*TRAIN, "--data", "{scene}", "--max-steps", "many"), "Error parsing --max-steps", box=True
    ),
    "train: --resume a folder without config.yml": Case(
        "train", ("--resume", "{fx}/no_config"), "no config.yml in the run folder to resume"
    ),
    "train: --resume together with --load-config": Case(
        "train",
        ("--resume", "{run}", "--load-config", "{config}"),
        "--resume and --load-config exclude each other",
    ),
    "train: --resume with a negative --max-steps": Case(
        "train", ("--resume", "{run}", "--max-steps", "-1"), "--max-steps must be >= 1"
    ),
    "train: --resume with --data pointing at a corrupt dataset": Case(
        "train",
        ("--resume", "{run}", "--data", "{fx}/corrupt"),
        "image is corrupt or not a supported image format",
    ),
    "train: --resume a run whose checkpoint is truncated": Case(
        "train",
        ("--resume", "{fx}/truncated"),
        "checkpoint is corrupt, truncated or not a tridehaze checkpoint",
    ),
    "train: --resume a checkpoint from another config": Case(
        "train", ("--resume", "{fx}/other_config"), "checkpoint does not match the run's config"
    ),
    "train: --load-config with python tags (unsafe YAML)": Case(
        "train", ("--load-config", "{fx}/unsafe/config.yml"), "config file is not valid YAML"
    ),
    # ------------------------------------------ flag values that used to reach the code (one each)
    **_flag_cases(
        ("--downscale", "1000", "--downscale 1000 makes frame"),
        ("--pipeline.medium.resolution", "0", "--pipeline.medium.resolution must be >= 2"),
        ("--pipeline.loss.ssim-window", "4", "--pipeline.loss.ssim-window must be an odd integer"),
        ("--pipeline.loss.ssim-window", "1", "--pipeline.loss.ssim-window must be an odd integer"),
        ("--pipeline.rasterizer.tile-size", "0", "--pipeline.rasterizer.tile-size must be >= 1"),
        ("--pipeline.model.sh-degree", "9", "--pipeline.model.sh-degree must be >= 0 and <= 3"),
        ("--seed", str(2**65), "--seed must be >= 0 and <= 4294967295"),
        ("--seed", "-1", "--seed must be >= 0"),
    ),
    "ablate: unterminated quote in --train-args": Case(
        "ablate",
        ("--scenes", "{scene}", "--output-dir", "{fx}/abl", '--train-args=--seed "7'),
        "--train-args cannot be split into arguments",
    ),  # fmt: skip
    "train: --timestamp longer than a file name may be": Case(
        "train", (*TRAIN, "--data", "{scene}", "--timestamp", "t" * 300), "--timestamp must be one plain"
    ),
    "train: --output-dir longer than the system allows": Case(
        "train", (*TRAIN, "--data", "{scene}", "--output-dir", "{fx}/" + "d" * 300), "File name too long"
    ),
    # ------------------------------------------------ values that used to be accepted silently
    **_flag_cases(
        ("--pipeline.model.means-lr", "-1", "--pipeline.model.means-lr must be >= 0"),
        ("--pipeline.medium.lr", "-0.1", "--pipeline.medium.lr must be >= 0"),
        ("--pipeline.rasterizer.near-plane", "-1", "--pipeline.rasterizer.near-plane must be > 0"),
        ("--pipeline.rasterizer.far-plane", "0.001", "--pipeline.rasterizer.far-plane (0.001) must be"),
        ("--pipeline.composite.far", "-2", "--pipeline.composite.far must be > 0"),
        ("--optimizer.means-lr-final-ratio", "-1", "--optimizer.means-lr-final-ratio must be > 0"),
    ),
    **{
        f"train: dataset with {what}": Case("train", (*TRAIN, "--data", f"{{fx}}/{name}"), expect, warnings=w)
        for name, what, expect, w in (
            ("fx_huge", "a focal length that puts every point off-screen", "no seed point projects", 0),
            ("cx_off", "principal points far off the image", "no seed point projects", 1),
            ("k1_fold", "distortion that folds the image", "cannot undistort frame", 0),
            ("k1_huge", "absurdly large distortion", "cannot undistort frame", 0),
            ("far_cam", "a camera a billion units from the rest", "camera of frame", 0),
            ("bad_depth", "depth maps of another shape", "map is 40x5 but its image is 32x24", 0),
        )
    },
    "train: config.yml that sets a key twice": Case(
        "train",
        ("--load-config", "{fx}/dup_key/config.yml"),
        "config file sets a key twice ('max_steps' at line 3)",
    ),
    "eval: config.yml that sets a key twice": Case(
        "eval", ("--load-config", "{fx}/dup_key/config.yml", *EVAL), "config file sets a key twice"
    ),
    # ------------------------------------- runaway memory or time on small files (run under a cap)
    "train: --load-config with a YAML alias bomb in max_steps": Case(
        "train", ("--load-config", "{fx}/bomb/config.yml"), "config file uses a YAML alias (*a at line"
    ),
    "train: --load-config nested 100k deep": Case(
        "train", ("--load-config", "{fx}/deep/config.yml"), "config file is nested too deeply"
    ),
    "train: --load-config with a megabyte-long value": Case(
        "train", ("--load-config", "{fx}/long_value/config.yml"), "expected an integer, got 'xxxxx"
    ),
    "train: transforms.json nested 100k deep": Case(
        "train", (*TRAIN, "--data", "{fx}/deep_json"), "JSON nested too deeply"
    ),
    "eval: config.yml with a YAML alias bomb": Case(
        "eval", ("--load-config", "{fx}/bomb/config.yml", *EVAL), "config file uses a YAML alias"
    ),
    "render: config.yml nested 100k deep": Case(
        "render",
        ("--load-config", "{fx}/deep/config.yml", "--output-dir", "{fx}/r"),
        "config file is nested too deeply",
    ),
    # ------------------------------------------------------------------------------- td-eval
    "eval: missing config.yml": Case(
        "eval", ("--load-config", "{fx}/no_config/config.yml", *EVAL), "config file not found"
    ),
    "eval: config.yml with python tags": Case(
        "eval", ("--load-config", "{fx}/unsafe/config.yml", *EVAL), "config file is not valid YAML"
    ),
    "eval: truncated checkpoint": Case(
        "eval",
        ("--load-config", "{fx}/truncated/config.yml", *EVAL),
        "checkpoint is corrupt, truncated or not a tridehaze checkpoint",
    ),
    "eval: checkpoint from another config": Case(
        "eval",
        ("--load-config", "{fx}/other_config/config.yml", *EVAL),
        "checkpoint does not match the run's config",
    ),
    "eval: the run's dataset is gone": Case(
        "eval", ("--load-config", "{fx}/data_gone/config.yml", *EVAL), "dataset folder not found"
    ),
    "eval: --output-path not .json": Case(
        "eval",
        ("--load-config", "{config}", "--output-path", "{fx}/eval.txt", *EVAL),
        "--output-path must end in .json",
    ),
    "eval: --output-path is a folder": Case(
        "eval",
        ("--load-config", "{config}", "--output-path", "{fx}/folder.json", *EVAL),
        "--output-path is a folder",
    ),
    "eval: --lpips on without its weights": Case(
        "eval", ("--load-config", "{config}", "--lpips", "on"), "LPIPS is unavailable", env=NO_LPIPS
    ),
    # ----------------------------------------------------------------------------- td-render
    "render: missing config.yml": Case(
        "render",
        ("--load-config", "{fx}/no_config/config.yml", "--output-dir", "{fx}/r"),
        "config file not found",
    ),
    "render: truncated checkpoint": Case(
        "render",
        ("--load-config", "{fx}/truncated/config.yml", "--output-dir", "{fx}/r"),
        "checkpoint is corrupt, truncated or not a tridehaze checkpoint",
    ),
    "render: unknown output name (into the run folder)": Case(
        "render",
        ("--load-config", "{config}", "--outputs", "clean,normals", "--output-dir", "{run}/renders"),
        "unknown output(s) normals for --outputs",
    ),
    "render: --num-frames 1 (into the run folder)": Case(
        "render",
        ("--load-config", "{config}", "--path", "orbit", "--num-frames", "1", "--output-dir", "{run}/v"),
        "--num-frames must be at least 2",
    ),
    "render: --fps 0": Case(
        "render",
        ("--load-config", "{config}", "--path", "orbit", "--fps", "0", "--output-dir", "{fx}/r"),
        "--fps must be in (0, 1000]",
    ),
    "render: --fps inf (spun forever in the video writer)": Case(
        "render",
        ("--load-config", "{config}", "--path", "orbit", "--fps", "inf", "--output-dir", "{fx}/r"),
        "--fps must be a finite number",
    ),
    "render: --fps 1e308": Case(
        "render",
        ("--load-config", "{config}", "--path", "orbit", "--fps", "1e308", "--output-dir", "{fx}/r"),
        "--fps must be in (0, 1000]",
    ),
    "render: --output-dir is a file": Case(
        "render", ("--load-config", "{config}", "--output-dir", "{fx}/a_file"), "--output-dir is a file"
    ),
    "render: unknown --device": Case(
        "render",
        ("--load-config", "{config}", "--device", "tpu", "--output-dir", "{fx}/r"),
        "--device must be auto, cpu, cuda or cuda:N",
    ),
    # ------------------------------------------------------------------------------ td-synth
    "synth: haze --beta nan": Case(
        "synth",
        ("haze", "--data", "{scene}", "--output-dir", "{fx}/h", "--beta", "nan"),
        "--beta must be a finite number",
    ),
    "synth: haze --airlight with inf": Case(
        "synth",
        ("haze", "--data", "{scene}", "--output-dir", "{fx}/h", "--airlight", "0.8", "inf", "0.8"),
        "--airlight must be a finite number",
    ),
    "synth: scene --width 0": Case(
        "synth", ("scene", "--output-dir", "{fx}/s", "--width", "0"), "--width must be >= 1"
    ),
    "synth: scene negative --num-views": Case(
        "synth", ("scene", "--output-dir", "{fx}/s", "--num-views", "-2"), "--num-views must be >= 1"
    ),
    "synth: scene --output-dir is a file": Case(
        "synth", ("scene", "--output-dir", "{fx}/a_file"), "--output-dir is a file, not a folder"
    ),
    "synth: scene --output-dir is the run folder": Case(
        "synth", ("scene", "--output-dir", "{run}"), "output folder exists and is not empty"
    ),
    "synth: scene unknown --layout": Case(
        "synth",
        ("scene", "--output-dir", "{fx}/s", "--layout", "castle"),
        "invalid choice 'castle'",
        box=True,
    ),
    "synth: scene --beta-scale nan": Case(
        "synth",
        ("scene", "--output-dir", "{fx}/s", "--beta-scale", "nan"),
        "--beta-scale must be a finite number",
    ),
    "synth: scene --test-every 1": Case(
        "synth", ("scene", "--output-dir", "{fx}/s", "--test-every", "1"), "--test-every must be 0 or >= 2"
    ),
    "synth: haze --beta with --median-transmittance": Case(
        "synth",
        (
            "haze",
            "--data",
            "{scene}",
            "--output-dir",
            "{fx}/h",
            "--beta",
            "0.1",
            "--median-transmittance",
            "0.4",
        ),
        "give either --beta or --median-transmittance, not both",
    ),
    "synth: haze into the run folder": Case(
        "synth",
        ("haze", "--data", "{scene}", "--output-dir", "{run}", "--beta", "0.1"),
        "output folder exists and is not empty",
    ),
    "synth: gallery --output is a folder": Case(
        "synth",
        ("gallery", "--output", "{fx}/empty", "--width", "8", "--height", "8"),
        "--output must end in .png",
    ),
    # ------------------------------------------- --overwrite replaces only the tool's own output
    **{  # the run, the folder that holds it, a user's folder, a dataset td-synth wrote
        f"export: --overwrite onto {what}": Case(
            "export",
            ("--load-config", "{config}", "--output-dir", target, "--overwrite"),
            "--overwrite refused: td-export did not write this folder",
        )
        for what, target in {
            "the run folder": "{run}",
            "the folder that holds the run": "{outputs}",
            "a user's folder": "{fx}/notes",
            "a dataset written by td-synth": "{scene}",
        }.items()
    },
    "export: --overwrite onto its own export with a user's file added": Case(
        "export",
        ("--load-config", "{config}", "--output-dir", "{fx}/export_plus", "--overwrite"),
        "--overwrite refused: the folder holds 1 file(s) td-export did not write (notes.md)",
    ),
    "synth: scene --overwrite onto the run folder": Case(
        "synth",
        ("scene", "--output-dir", "{run}", "--overwrite"),
        "--overwrite refused: td-synth did not write this folder",
    ),
    "synth: haze --overwrite onto the run folder": Case(
        "synth",
        ("haze", "--data", "{scene}", "--output-dir", "{run}", "--beta", "0.1", "--overwrite"),
        "--overwrite refused: td-synth did not write this folder",
    ),
    "eval: unknown --device": Case(
        "eval", ("--load-config", "{config}", "--device", "tpu", *EVAL), "--device must be"
    ),
    "eval: missing config.yml, --lpips auto without LPIPS weights": Case(
        "eval", ("--load-config", "{fx}/no_config/config.yml"), "config file not found", env=NO_LPIPS
    ),
}


# ------------------------------------------------------------------------------------ fixtures
def _copy_scene(scene: Path, dst: Path) -> Path:
    shutil.copytree(scene, dst)
    return dst


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> dict[str, Path]:
    """A tiny dataset, a finished tri-dehaze run on it (the folder that must stay intact) and bad inputs."""
    root = tmp_path_factory.mktemp("bad_input")
    scene = tiny_hazy_scene(root / "scene", layout="room", haze="homogeneous", seed=4, test_every=4)
    cfg = parse_args([
        "tri-dehaze", "--data", str(scene), "--output-dir", str(root / "outputs"), "--max-steps", "4",
        "--steps-per-save", "2", "--timestamp", "run", "--pipeline.rasterizer.backend", "torch",
        "--no-eval-at-end", "--threads", "1",
    ])  # fmt: skip
    run = Trainer(cfg, console=Console(quiet=True)).train().run_dir

    fx = root / "fx"
    fx.mkdir()
    (fx / "empty").mkdir()
    (fx / "no_config").mkdir()
    (fx / "folder.json").mkdir()
    (fx / "a_file").write_text("not a folder\n")
    (_copy_scene(scene, fx / "corrupt") / "images" / "0001.png").write_bytes(
        b"\x89PNG\r\n\x1a\n but not really"
    )
    (_copy_scene(scene, fx / "zero_byte") / "images" / "0001.png").write_bytes(b"")
    (_copy_scene(scene, fx / "not_json") / "transforms.json").write_text('{"frames": [')
    cv2.imwrite(
        str(_copy_scene(scene, fx / "wrong_size") / "images" / "0001.png"), np.zeros((12, 16, 3), np.uint8)
    )
    meta = json.loads((_copy_scene(scene, fx / "bad_pose") / "transforms.json").read_text())
    meta["frames"][0]["transform_matrix"] = [[1.0, 0.0], [0.0, 1.0]]
    (fx / "bad_pose" / "transforms.json").write_text(json.dumps(meta))
    (fx / "notes").mkdir()
    (fx / "notes" / "todo.txt").write_text("mine\n")
    export_main(["--load-config", str(run / "config.yml"), "--output-dir", str(fx / "export_plus")])
    (fx / "export_plus" / "notes.md").write_text("mine\n")
    levels = ["&a [1, 1, 1, 1, 1, 1, 1, 1, 1]"]  # 9 ** 9 integers once expanded
    for i in range(1, 9):
        levels.append(f"&{'abcdefghi'[i]} [" + ", ".join([f"*{'abcdefghi'[i - 1]}"] * 9) + "]")
    for name, body in {
        "bomb": f"max_steps: [{', '.join(levels)}]\n",
        "deep": "max_steps: " + "[" * 100_000 + "]" * 100_000 + "\n",
        "long_value": "method_name: tri-dehaze\nmax_steps: " + "x" * 1_000_000 + "\n",
    }.items():
        (fx / name).mkdir()
        (fx / name / "config.yml").write_text(body)
    (_copy_scene(scene, fx / "deep_json") / "transforms.json").write_text("[" * 100_000 + "]" * 100_000)
    for kind, value in {"nan": np.nan, "inf": np.inf, "1e30": 1e30}.items():
        meta = json.loads((scene / "transforms.json").read_text())
        copy = _copy_scene(scene, fx / f"points_{kind}")
        write_ply_points(copy / meta["ply_file_path"], np.full((50, 3), value))
        np.save(copy / meta["point_tracks_file_path"], np.stack([np.arange(50), np.zeros(50, int)], axis=1))
    _bad_cameras(scene, fx)
    (fx / "dup_key").mkdir()
    (fx / "dup_key" / "config.yml").write_text("method_name: tri-dehaze\nmax_steps: 5\nmax_steps: 7\n")
    (fx / "unsafe").mkdir()
    (fx / "unsafe" / "config.yml").write_text("method_name: !!python/object/apply:os.system ['echo pwned']\n")

    def run_copy(name: str) -> Path:
        return Path(shutil.copytree(run, fx / name))

    newest = sorted((run_copy("truncated") / "checkpoints").glob("*.ckpt"))[-1]
    newest.write_bytes(newest.read_bytes()[:200])
    shutil.rmtree(run_copy("no_checkpoint") / "checkpoints")
    text = (
        run_copy("other_config") / "config.yml"
    ).read_text()  # a vanilla-gs config over tri-dehaze weights
    assert "method_name: tri-dehaze" in text and "backend: triplane" in text
    text = text.replace("method_name: tri-dehaze", "method_name: vanilla-gs").replace(
        "backend: triplane", "backend: none"
    )
    (fx / "other_config" / "config.yml").write_text(text)
    text = (run_copy("data_gone") / "config.yml").read_text()
    (fx / "data_gone" / "config.yml").write_text(text.replace(str(scene), str(root / "deleted_scene")))
    return {
        "run": run, "config": run / "config.yml", "scene": scene, "fx": fx, "root": root,
        "outputs": root / "outputs",
    }  # fmt: skip


def _bad_cameras(scene: Path, fx: Path) -> None:
    """Datasets whose frames each pass their own checks but whose cameras make training meaningless."""

    def variant(name: str, edit) -> None:  # noqa: ANN001 - edits the parsed transforms.json
        meta = json.loads((_copy_scene(scene, fx / name) / "transforms.json").read_text())
        edit(meta, fx / name)
        (fx / name / "transforms.json").write_text(json.dumps(meta))

    def each(**values):  # noqa: ANN202
        return lambda meta, _: [f.update(values) for f in meta["frames"]]

    def far(meta, _) -> None:  # noqa: ANN001
        meta["frames"][2]["transform_matrix"][0][3] = 1e9

    def depth(meta, root: Path) -> None:  # noqa: ANN001
        (root / "bad_depth").mkdir()
        for i, f in enumerate(meta["frames"]):
            np.save(root / "bad_depth" / f"{i}.npy", np.ones((5, 40), np.float32))
            f["depth_file_path"] = f"bad_depth/{i}.npy"

    variant("fx_huge", each(fl_x=1e9, fl_y=1e9))
    variant("cx_off", each(cx=1e6))
    variant("k1_fold", each(k1=-50.0))
    variant("k1_huge", each(k1=1e6))
    variant("far_cam", far)
    variant("bad_depth", depth)


def _snapshot(folder: Path) -> dict[str, tuple[bytes | None, int]]:
    """Every path under ``folder``: its bytes (None for a folder) and modification time."""
    out: dict[str, tuple[bytes | None, int]] = {}
    for p in sorted(folder.rglob("*")):
        st = p.lstat()
        out[str(p.relative_to(folder))] = (p.read_bytes() if p.is_file() else None, st.st_mtime_ns)
    return out


def _guarded(world: dict[str, Path]) -> dict[str, dict[str, tuple[bytes | None, int]]]:
    """The folders no case may change: the finished run, the dataset and the user's folders."""
    fx = world["fx"]
    return {str(p): _snapshot(p) for p in (world["run"], world["scene"], fx / "notes", fx / "export_plus")}


@pytest.fixture(scope="module")
def pristine(world) -> dict[str, dict[str, tuple[bytes | None, int]]]:
    return _guarded(world)


def _cap_memory() -> None:
    """4 GB of address space for the cases' process: a runaway case fails the test instead of
    the machine (torch and pycolmap need about 1.3 GB)."""
    resource.setrlimit(resource.RLIMIT_AS, (4 * 2**30, 4 * 2**30))


def _run(case: Case, world: dict[str, Path]) -> subprocess.CompletedProcess:
    """One case in its own process (the real entry point, as a user runs it)."""
    args = [a.format(**{k: str(v) for k, v in world.items()}) for a in case.args]
    env = dict(os.environ, OMP_NUM_THREADS="1", TRIDEHAZE_CACHE=str(world["root"] / "cache"), **case.env)
    env.pop("TRIDEHAZE_PLUGINS", None)
    return subprocess.run(
        [sys.executable, "-m", f"tridehaze_plugin.cli.{case.command}", *args],
        capture_output=True,
        text=True,
        timeout=300,
        preexec_fn=_cap_memory,
        cwd=world["root"],
        env=env,
    )


@pytest.fixture(scope="module")
def batch(world) -> dict[str, subprocess.CompletedProcess]:
    """Every case of the matrix, run one after another in a single fresh process
    (tests/core/bad_input_batch.py: torch is imported once instead of 46 times)."""
    cases = {
        name: {
            "module": c.command,
            "args": [a.format(**{k: str(v) for k, v in world.items()}) for a in c.args],
            "env": {"OMP_NUM_THREADS": "1", "TRIDEHAZE_CACHE": str(world["root"] / "cache"), **c.env},
            "cwd": str(world["root"]),
        }
        for name, c in CASES.items()
    }
    spec, out = world["root"] / "cases.json", world["root"] / "results.json"
    spec.write_text(json.dumps(cases))
    env = dict(os.environ, OMP_NUM_THREADS="1")
    env.pop("TRIDEHAZE_PLUGINS", None)
    subprocess.run(
        [sys.executable, "-m", "tests.core.bad_input_batch", str(spec), str(out)],
        cwd=Path(__file__).resolve().parents[2], env=env, check=True, timeout=900, preexec_fn=_cap_memory,
    )  # fmt: skip
    results = json.loads(out.read_text())
    return {n: subprocess.CompletedProcess([], r["returncode"], "", r["stderr"]) for n, r in results.items()}


def _check(case: Case, res: subprocess.CompletedProcess) -> None:
    assert res.returncode == 2, (res.returncode, res.stdout[-2000:], res.stderr[-2000:])
    assert "Traceback" not in res.stderr, res.stderr
    if case.box:
        assert case.expect in res.stderr, res.stderr
        return
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 + case.warnings, res.stderr
    assert all(ln.startswith("warning: ") for ln in lines[:-1]), res.stderr
    lines = lines[-1:]
    assert lines[0].startswith(f"error: {case.expect}"), lines[0]


def test_the_matrix_is_big_and_covers_every_command():
    per_command = {
        c: sum(case.command == c for case in CASES.values())
        for c in ("train", "eval", "render", "synth", "export")
    }
    assert len(CASES) >= 24 and min(per_command.values()) >= 5, per_command


@pytest.mark.parametrize("name", list(CASES))
def test_bad_input_is_one_line_exit_2_and_leaves_the_run_intact(batch, world, pristine, name):
    _check(CASES[name], batch[name])
    assert _guarded(world) == pristine, "an existing run, dataset or user folder was changed"


@pytest.mark.parametrize("name", ["train: negative --max-steps", "eval: truncated checkpoint",
                                  "render: unknown output name (into the run folder)", "synth: scene --width 0"])  # fmt: skip
def test_the_real_entry_points_agree_with_the_batch(batch, world, pristine, name):
    """A few cases again as separate processes: the batch runner changes nothing a user would see."""
    res = _run(CASES[name], world)
    _check(CASES[name], res)
    assert res.stderr.strip() == batch[name].stderr.strip()
    assert _guarded(world) == pristine
