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


class FmuError(PlantSimError, ValueError):
    """An FMU that cannot serve as an axis (not an FMU, not co-simulation, no binary for this
    platform, a mapped variable missing or of the wrong causality or unit, a parameter it does
    not have) or that fails to instantiate or initialise; the message names the FMU and what
    it reported."""


class PlantFault(PlantSimError, RuntimeError):
    """A plant that failed while it stepped (:meth:`plant_sim.plant.Plant.advance`): the
    simulated drive faults on it as on a device error (EMCY 6100h)."""


class FmuStepError(PlantFault):
    """An FMU that failed while it ran (``fmi2DoStep``, ``fmi2GetReal`` ... returned an error):
    the simulated drive treats it as a drive fault. ``call`` names the FMI function,
    ``messages`` what the FMU logged."""

    def __init__(self, message: str, *, call: str = "", messages: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.call = call
        self.messages = messages
