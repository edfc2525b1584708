"""Any plant as an FMU: an FMI 2.0 co-simulation FMU as the axis behind the simulated drive
and the offline commands (``docs/fmu.md``).

* :mod:`.model` -- :class:`FmuSpec` (file, parameters, mapping: what a command line or a Dask
  task carries) and :class:`FmuModel` (loaded and checked: FMPy's validation, co-simulation,
  this platform's binary, mapped variables' causality and units, parameters, one
  initialisation);
* :mod:`.mapping` -- which FMU variable is which drive signal (defaults: the shared feed-axis
  family), with units (:mod:`.units`);
* :mod:`.plant` -- :class:`FmuPlant`, a :class:`plant_sim.plant.Plant` stepped one position
  cycle per call;
* :mod:`.nominal` -- the axis file a user writes from the FMU's data sheet.

FMPy (``pip install 'backlash-bridge[sim]'``) is imported only when an FMU is loaded.
"""

from .mapping import Binding, FmuMapping, Signal
from .model import FmuModel, FmuSpec, load_fmu
from .nominal import nominal_axis, nominal_axis_text
from .plant import FmuPlant

__all__ = [
    "Binding",
    "FmuMapping",
    "FmuModel",
    "FmuPlant",
    "FmuSpec",
    "Signal",
    "load_fmu",
    "nominal_axis",
    "nominal_axis_text",
]
