"""Shared CLI plumbing: one-line errors for user mistakes, exit code 2, no traceback."""

from __future__ import annotations

import contextlib
import errno
import os
import shlex
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

from tridehaze_plugin.errors import EXIT_USER_ERROR, ConfigError, InputWarning, UserError


def fail(message: str) -> NoReturn:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(EXIT_USER_ERROR)


SYSTEM_LIMITS = {
    errno.ENOSPC: "free some space (or point --output-dir elsewhere) and run again; earlier "
    "checkpoints are intact",
    errno.EDQUOT: "free some space within your quota and run again; earlier checkpoints are intact",
    errno.ENAMETOOLONG: "use a shorter path (each name at most 255 bytes)",
    errno.EACCES: "choose a folder you may write to, or fix its permissions",
    errno.EPERM: "choose a folder you may write to, or fix its permissions",
    errno.EROFS: "choose a folder on a writable file system",
}
"""OS errors that are the machine's or the user's limits, not bugs: one line and exit 2."""


def system_limit_message(exc: OSError) -> str:
    where = exc.filename if isinstance(exc.filename, str) else None
    shown_where = f" ({where[:120]}...)" if where and len(where) > 120 else (f" ({where})" if where else "")
    return f"{exc.strerror or type(exc).__name__}{shown_where}; {SYSTEM_LIMITS[exc.errno]}"


def _format_warning(message, category, filename, lineno, line=None) -> str:  # noqa: ANN001 - warnings' hook
    if issubclass(category, InputWarning):
        return f"warning: {message}\n"
    return _default_format(message, category, filename, lineno, line)


_default_format = warnings.formatwarning


def run_cli(main: Callable[[], object]) -> None:
    """Run ``main``; a :class:`UserError` becomes one line on stderr and exit code 2, and an
    :class:`InputWarning` one ``warning:`` line."""
    warnings.formatwarning = _format_warning
    try:
        main()
    except UserError as exc:
        fail(exc.one_line())
    except BrokenPipeError:  # output piped into e.g. `head`: stop quietly like other Unix tools
        # (before OSError, its base class); stdout goes to /dev/null so that the interpreter's
        # final flush of the unread output does not raise a second time
        with contextlib.suppress(OSError, ValueError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        raise SystemExit(141) from None
    except OSError as exc:
        if exc.errno not in SYSTEM_LIMITS:
            raise  # anything else is a bug: keep its traceback
        fail(system_limit_message(exc))
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        raise SystemExit(130) from None


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


def split_train_args(text: str) -> tuple[str, ...]:
    """``--train-args`` as td-train arguments, split like a shell would; a ConfigError (not a
    traceback hours into a grid) when the quoting is broken."""
    try:
        return tuple(shlex.split(text))
    except ValueError as exc:
        raise ConfigError(
            f"--train-args cannot be split into arguments ({exc}): {text[:200]!r}",
            fix='balance the quotes, e.g. --train-args "--pipeline.medium.backend mlp"',
        ) from None
