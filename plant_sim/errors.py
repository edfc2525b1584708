"""Exceptions of :mod:`plant_sim`: one root, each subclass also the matching builtin."""

from __future__ import annotations


class PlantSimError(Exception):
    """Root of every error raised by :mod:`plant_sim`."""


class ScenarioError(PlantSimError, ValueError):
    """Inputs of a simulation run (references, disturbances, options) do not fit together."""


class MonitorError(PlantSimError):
    """Root of the fleet monitor's errors (:mod:`plant_sim.fleet`)."""


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
