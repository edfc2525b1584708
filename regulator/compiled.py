""":mod:`regulator.core` and :mod:`regulator.cycle` compiled by numba, once, for every caller.

The bridge's compiled core (:mod:`bridge.cyclecore`) and the simulator's kernel
(:mod:`plant_sim.physics.kernel`) call the same compiled functions: nopython, no fastmath (the
same IEEE operations in the same order: Python's result bit for bit), numba's cache on. One
compilation of each code object matters beyond speed: numba's on-disk cache keys a function by
its code and signature, not by its compile options, so the same function compiled with other
flags by a second caller could be served the first one's machine code.

:func:`load` compiles on its first call (or loads numba's cache) and raises ImportError
without numba; the bridge runs the Python functions then.
"""

from __future__ import annotations

import types
from functools import cache

from . import core, cycle

#: The functions of regulator.core the cycle calls.
CORE_FUNCTIONS = ("position_command", "detector_step", "switching_factor", "regulated_speed")


@cache
def load() -> types.SimpleNamespace:
    """``.core`` (a module of the compiled :data:`CORE_FUNCTIONS`) and ``.cycle`` (a module
    with :func:`regulator.cycle.position_cycle` compiled against it, and the cycle's
    constants)."""
    import numba

    jit = numba.njit(cache=True, nogil=True)  # no fastmath: bit for bit the Python result
    compiled_core = types.ModuleType("regulator.core (compiled)")
    for name in CORE_FUNCTIONS:
        setattr(compiled_core, name, jit(getattr(core, name)))
    compiled_cycle = types.ModuleType("regulator.cycle (compiled)")
    vars(compiled_cycle).update({k: v for k, v in vars(cycle).items() if k.isupper()})
    names = dict(vars(cycle)) | {"core": compiled_core}
    f = cycle.position_cycle
    compiled_cycle.position_cycle = jit(  # type: ignore[attr-defined]
        types.FunctionType(f.__code__, names, f.__name__)
    )
    return types.SimpleNamespace(core=compiled_core, cycle=compiled_cycle)
