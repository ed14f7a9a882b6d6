"""User-facing errors.

Anything the *user* can fix (a wrong path, a corrupt image, a bad option) is raised as
:class:`UserError`. The command-line entry points catch it, print one line and exit with
code 2, never a traceback. Programming errors stay ordinary exceptions so that they
surface with a traceback for developers.
"""

from __future__ import annotations

import reprlib
from typing import Any

EXIT_USER_ERROR = 2
MAX_MESSAGE = 600
"""Characters of an error line: a message quoting user data must stay one readable line."""

_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxtuple, _REPR.maxdict = 3, 6, 6, 6
_REPR.maxstring, _REPR.maxother, _REPR.maxlong = 80, 80, 40


def shown(value: Any) -> str:
    """``repr(value)`` bounded in size and work, for quoting user data in an error message (a YAML
    alias bomb or a 100k-deep list must not be expanded to print it)."""
    return _REPR.repr(value)


def first_few(names: list[str], n: int = 3) -> str:
    """The first ``n`` names, comma-separated, with ``...`` when there are more: a message names
    examples, not all of a long list."""
    return ", ".join(names[:n]) + (", ..." if len(names) > n else "")


class UserError(Exception):
    """An error caused by input the user controls; the message says what, where and what to do."""

    def __init__(self, what: str, *, where: str | None = None, fix: str | None = None) -> None:
        self.what = what
        self.where = where
        self.fix = fix
        super().__init__(self.one_line())

    def one_line(self) -> str:
        parts = [self.what]
        if self.where:
            parts.append(f"({self.where})")
        msg = " ".join(parts)
        if self.fix:
            msg += f"; {self.fix}"
        return msg if len(msg) <= MAX_MESSAGE else msg[: MAX_MESSAGE - 5] + " ..."


class DataError(UserError):
    """A dataset folder or file that cannot be used as given."""


class ConfigError(UserError):
    """A configuration value or combination that cannot work."""


class PluginError(UserError):
    """A plugin or registered component that cannot be found or loaded."""


class InputWarning(UserWarning):
    """Something in the user's input was odd but work went on; the td-* tools print it as one
    ``warning: ...`` line (no source line from the module that noticed it)."""
