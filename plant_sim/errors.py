"""Exceptions of :mod:`plant_sim`: one root, each subclass also the matching builtin."""

from __future__ import annotations


class PlantSimError(Exception):
    """Root of every error raised by :mod:`plant_sim`."""


class AxisFileError(PlantSimError, ValueError):
    """An axis file (``axis-file.md``) is malformed or non-physical.

    ``key`` is the dotted key (``"mechanics.load_mass"``) or section, ``value`` what was found.
    """

    def __init__(self, message: str, *, key: str | None = None, value: object = None) -> None:
        super().__init__(message)
        self.key = key
        self.value = value


class TraceFileError(PlantSimError, ValueError):
    """A servo trace (``trace-file.md``) is malformed; ``column`` / ``row`` name where."""

    def __init__(self, message: str, *, column: str | None = None, row: int | None = None) -> None:
        super().__init__(message)
        self.column = column
        self.row = row


class TraceWarning(UserWarning):
    """A trace column looks implausible for its unit (never rescaled silently)."""


class ScenarioError(PlantSimError, ValueError):
    """Inputs of a simulation run (references, disturbances, options) do not fit together."""


class MonitorError(PlantSimError):
    """Root of the fleet monitor's errors (:mod:`plant_sim.monitor`)."""


class RecordingError(MonitorError, ValueError):
    """A file that is not a usable recording (not a trace or a log, PDOs missing, corrupt).

    ``path`` names the file; the monitor reports it in one line and goes on with the fleet.
    """

    def __init__(self, message: str, *, path: str | None = None) -> None:
        super().__init__(message)
        self.path = path


class FleetMapError(MonitorError, ValueError):
    """An axis map (``--axes MAP.toml``) that cannot be used as a whole."""


class SchedulerError(MonitorError, ConnectionError):
    """A Dask scheduler that cannot be reached (``--scheduler ADDRESS``)."""
