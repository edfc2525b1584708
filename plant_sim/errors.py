"""Exceptions of :mod:`plant_sim`: one root, each subclass also the matching builtin."""

from __future__ import annotations


class PlantSimError(Exception):
    """Root of every error raised by :mod:`plant_sim`."""


class ScenarioError(PlantSimError, ValueError):
    """Inputs of a simulation run (references, disturbances, options) do not fit together."""


class SchedulerError(PlantSimError, ConnectionError):
    """A Dask scheduler that cannot be reached (``--scheduler ADDRESS``; :mod:`.parallel`)."""


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
