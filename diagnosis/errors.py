"""Exceptions of :mod:`diagnosis`: one root (:class:`DiagnosisError`), each subclass also the
matching builtin, so the CLI turns them into one line + exit 2."""

from __future__ import annotations


class DiagnosisError(Exception):
    """Root of every error raised by :mod:`diagnosis`."""


class DiagnosisInputError(DiagnosisError, ValueError):
    """An axis file and a recording do not fit together (missing column for the feedback the
    axis closes its loop on, transmission ratio that contradicts the recording, ...).

    ``column`` names the recording column concerned, ``key`` the axis-file key, when known.
    """

    def __init__(self, message: str, *, column: str | None = None, key: str | None = None) -> None:
        super().__init__(message)
        self.column = column
        self.key = key


class DiagnosisOptionError(DiagnosisError, ValueError):
    """An option of the diagnosis is outside its allowed range (message gives value and range)."""
