"""Shared CLI plumbing: one-line errors for user mistakes, exit code 2, no traceback."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import NoReturn

from tridehaze_plugin.errors import EXIT_USER_ERROR, UserError


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
