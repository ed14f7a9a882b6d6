"""User-facing errors.

Anything the *user* can fix (a wrong path, a corrupt image, a bad option) is raised as
:class:`UserError`. The command-line entry points catch it, print one line and exit with
code 2, never a traceback. Programming errors stay ordinary exceptions so that they
surface with a traceback for developers.
"""

from __future__ import annotations

EXIT_USER_ERROR = 2


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
        return msg


class DataError(UserError):
    """A dataset folder or file that cannot be used as given."""


class ConfigError(UserError):
    """A configuration value or combination that cannot work."""


class PluginError(UserError):
    """A plugin or registered component that cannot be found or loaded."""
