"""Exceptions of the file formats the whole project shares: one root, each subclass also
the matching builtin."""

from __future__ import annotations


class FormatError(Exception):
    """Root of every error raised while reading or checking a shared file format."""


class AxisFileError(FormatError, ValueError):
    """An axis file (``docs/axis-file.md``) is malformed or non-physical.

    ``key`` is the dotted key (``"mechanics.load_mass"``) or section, ``value`` what was found.
    """

    def __init__(self, message: str, *, key: str | None = None, value: object = None) -> None:
        super().__init__(message)
        self.key = key
        self.value = value


class TraceFileError(FormatError, ValueError):
    """A servo trace (``docs/trace-file.md``) is malformed; ``column`` / ``row`` name where."""

    def __init__(self, message: str, *, column: str | None = None, row: int | None = None) -> None:
        super().__init__(message)
        self.column = column
        self.row = row


class TraceWarning(UserWarning):
    """A trace column looks implausible for its unit (never rescaled silently)."""
