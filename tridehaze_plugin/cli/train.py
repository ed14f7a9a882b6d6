"""``td-train METHOD [--data DIR] [options]``: train a registered method.

``td-train --load-config RUN/config.yml [overrides]`` re-runs a saved configuration (read
safely: values are merged into the method's preset, nothing in the file is executed).
``td-train --resume RUN [--max-steps N]`` continues a run in its own folder from its newest
checkpoint (written on schedule and on Ctrl-C).
"""

from __future__ import annotations

import sys
from pathlib import Path

import tyro

from components.synth import demo_scene_path
from pipelines.engine.config import TrainerConfig
from pipelines.engine.run_config import load_config
from pipelines.engine.trainer import Trainer
from pipelines.viewer import TrainingViewer
from tridehaze_plugin.cli.common import check_output_folder, run_cli
from tridehaze_plugin.config import check_numbers, validate
from tridehaze_plugin.errors import ConfigError
from tridehaze_plugin.registry import Registry, load_all

DESCRIPTION = "Train a method on a dataset folder. Pick a method, then see `td-train METHOD --help`."


def method_union(registry: Registry) -> type:
    """A tyro subcommand type with one subcommand per registered method preset."""
    specs = registry.entries("method")
    defaults = {e.name: e.obj.make_config() for e in specs}
    descriptions = {e.name: e.description for e in specs}
    return tyro.extras.subcommand_type_from_defaults(defaults, descriptions, prefix_names=False)


def parse_args(argv: list[str]) -> TrainerConfig:
    registry = load_all()
    if "--load-config" in argv:
        i = argv.index("--load-config")
        if i + 1 >= len(argv):
            raise ConfigError("--load-config needs a path to a run's config.yml")
        default = load_config(argv[i + 1])
        rest = argv[:i] + argv[i + 2 :]
        cfg = tyro.cli(TrainerConfig, args=rest, default=default, prog="td-train", description=DESCRIPTION)
    else:
        cfg = tyro.cli(method_union(registry), args=argv, prog="td-train", description=DESCRIPTION)
    validate(cfg, registry)
    check_numbers(cfg)
    cfg.check_values()
    return cfg


def split_resume(argv: list[str]) -> tuple[Path | None, list[str]]:
    """``--resume RUN`` becomes ``--load-config RUN/config.yml`` plus the run folder to continue."""
    if "--resume" not in argv:
        return None, argv
    i = argv.index("--resume")
    if i + 1 >= len(argv):
        raise ConfigError("--resume needs a run folder (OUTPUT/<scene>/<method>/<timestamp>)")
    run = Path(argv[i + 1])
    if not (run / "config.yml").is_file():
        raise ConfigError(
            "no config.yml in the run folder to resume", where=str(run), fix="pass a run folder"
        )
    if "--load-config" in argv:
        raise ConfigError("--resume and --load-config exclude each other", fix="use one of them")
    return run, [*argv[:i], *argv[i + 2 :], "--load-config", str(run / "config.yml")]


def main(argv: list[str] | None = None) -> None:
    resume, args = split_resume(sys.argv[1:] if argv is None else argv)
    cfg = parse_args(args)
    if resume is None:  # a resumed run stays in its own folder
        check_output_folder(cfg.output_dir)
    if cfg.dataset.data is None:
        cfg.dataset.data = demo_scene_path(cfg.dataset.cache_dir)
        print(f"no --data given: training on the built-in demo scene ({cfg.dataset.data})")
    Trainer(cfg, resume=resume, live_view=TrainingViewer()).train()


def entrypoint() -> None:
    run_cli(main)


if __name__ == "__main__":
    entrypoint()
