"""Shared CLI plumbing: one-line errors for user mistakes, exit code 2, no traceback."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

from tridehaze_plugin.errors import EXIT_USER_ERROR, ConfigError, UserError


def fail(message: str) -> NoReturn:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(EXIT_USER_ERROR)


def run_cli(main: Callable[[], object]) -> None:
    """Run ``main``; a :class:`UserError` becomes one line on stderr and exit code 2."""
    try:
        main()
    except UserError as exc:
        fail(exc.one_line())
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        raise SystemExit(130) from None
    except BrokenPipeError:  # output piped into e.g. `head`: stop quietly like other Unix tools
        sys.stderr.close()
        raise SystemExit(141) from None


def check_output_folder(path: Path, flag: str = "--output-dir") -> None:
    """ConfigError unless ``path`` is a folder, or one can be created there, that we may write to.

    Checked before any work starts, so a typo fails in a second and not after training or rendering.
    """
    target = Path(os.path.expanduser(str(path))).absolute()
    probe = target
    while not probe.exists() and probe != probe.parent:  # the nearest part of the path that exists
        probe = probe.parent
    if not probe.is_dir():
        if probe == target:
            raise ConfigError(f"{flag} is a file, not a folder", where=str(target), fix="pass a folder path")
        raise ConfigError(
            f"{flag} cannot be created: {probe} is a file", where=str(target), fix="pick another folder"
        )
    if not os.access(probe, os.W_OK | os.X_OK):
        raise ConfigError(
            f"{flag} is not writable", where=str(probe), fix="pick another folder or fix its permissions"
        )
