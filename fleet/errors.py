"""Exceptions of :mod:`fleet`: one root, each subclass also the matching builtin."""

from __future__ import annotations


class FleetError(Exception):
    """Root of every error raised by :mod:`fleet` (the fleet monitor)."""


class RecordingError(FleetError, ValueError):
    """A file that is not a usable recording (not a trace or a log, PDOs missing, corrupt).

    ``path`` names the file; the monitor reports it in one line and goes on with the fleet.
    """

    def __init__(self, message: str, *, path: str | None = None) -> None:
        super().__init__(message)
        self.path = path


class FleetMapError(FleetError, ValueError):
    """An axis map (``--axes MAP.toml``) that cannot be used as a whole."""


class TimeBaseWarning(UserWarning):
    """A recording whose time stamps are not its time base (a lockstep candump log: the SYNC
    frames were stamped with the wall clock of a run faster than real time); the monitor
    reports which time base it used in the recording's ``warning`` column."""
