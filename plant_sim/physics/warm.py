"""Load the compiled functions a run needs before it starts, and say whether they compiled.

numba compiles a function at its first call and keeps the machine code in its cache
(``__pycache__`` beside the source, or ``NUMBA_CACHE_DIR``): on a fresh checkout the
simulator's kernel, the bridge's cycle and the regulator compile once, about a minute on two
busy cores; afterwards they load in a few seconds. :func:`warm_up` does that before a command's
first stage, so the command can say which it was and how long it took, instead of sitting
silently in its first run.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import numpy as np

from regulator import RegulatorConfig
from virtual_bus.formats.axis import AxisConfig

#: The packages whose compiled functions count (the simulator, the regulator, the bridge).
PACKAGES = ("plant_sim", "regulator", "bridge")


@dataclass(frozen=True)
class WarmUp:
    """What :func:`warm_up` did: ``compiled`` functions compiled (numba's cache misses among
    the module-level functions; 0: all came from the cache) in ``seconds`` of wall time."""

    compiled: int
    seconds: float

    def sentence(self) -> str:
        if self.compiled:
            return (
                f"compiled (numba, first run) in {self.seconds:.0f} s; cached now: later runs "
                "load it in seconds"
            )
        return f"compiled functions loaded from numba's cache in {self.seconds:.1f} s"


def cache_misses() -> int:
    """Functions compiled so far in this process by numba for :data:`PACKAGES` (a function
    loaded from the cache is not counted)."""
    try:
        from numba.core.dispatcher import Dispatcher
    except ImportError:
        return 0
    seen: set[int] = set()
    total = 0
    for name, module in list(sys.modules.items()):
        if module is None or name.split(".")[0] not in PACKAGES:
            continue
        for value in list(vars(module).values()):
            if isinstance(value, Dispatcher) and id(value) not in seen:
                seen.add(id(value))
                total += sum(value.stats.cache_misses.values())
    return total


def warm_up(axis: AxisConfig, kernel: bool = True, bridge: bool = True) -> WarmUp:
    """Load or compile what a closed-loop run of ``axis`` calls: the bridge's cycle
    (:func:`bridge.cyclecore.load`) and, with ``kernel`` (the axis is the compiled kernel's,
    not an FMU's), the drive's plant (:meth:`~plant_sim.physics.model.AxisPlant.warm_up`) and
    the kernel's closed loop (:func:`~plant_sim.physics.simulate.simulate`, a few cycles);
    ``bridge`` False: not the bridge's cycle (a command that runs no bridge)."""
    from bridge import cyclecore

    from .model import AxisPlant
    from .simulate import References, simulate

    t0 = time.monotonic()
    before = cache_misses()
    if bridge:
        cyclecore.load()
    if kernel:
        AxisPlant(axis).warm_up()
        n = 4
        refs = References(np.zeros(n), np.zeros(n), np.zeros(n))
        cycle = axis.control.position_cycle
        for enabled in (False, True):
            reg = RegulatorConfig(kv=axis.control.kv, cycle_s=cycle, enabled=enabled)
            simulate(axis, refs, reg)
    return WarmUp(cache_misses() - before, time.monotonic() - t0)
