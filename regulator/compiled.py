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
from collections.abc import Callable
from functools import cache
from typing import Any

from . import core, cycle

#: The functions of regulator.core the cycle calls.
CORE_FUNCTIONS = ("position_command", "detector_step", "switching_factor", "regulated_speed")
#: The functions of regulator.cycle, callees first: position_cycle calls measure and apply.
CYCLE_FUNCTIONS = ("measure", "apply", "position_cycle")


def cycle_copy(
    jit: Callable[[Any], Any],
    inline: Callable[[Any], Any],
    compiled_core: types.ModuleType,
    prefix: str = "",
) -> types.ModuleType:
    """:mod:`regulator.cycle` compiled: a module with its constants and its
    :data:`CYCLE_FUNCTIONS`, compiled against ``compiled_core`` (numba calls only compiled
    functions from compiled code). The three share one namespace, in which ``measure`` and
    ``apply`` are their compiled copies made with ``inline`` (numba inlines them into
    ``position_cycle`` at IR level: the same operations, no call); ``position_cycle`` is made
    with ``jit``. ``prefix`` renames the code objects: numba's on-disk cache keys a function
    by its code's name, not its compile options, so a copy compiled with other flags (the
    kernel's fastmath) needs names of its own."""
    names = dict(vars(cycle)) | {"core": compiled_core}
    out = types.ModuleType(f"regulator.cycle ({prefix or 'compiled'})")
    vars(out).update({k: v for k, v in vars(cycle).items() if k.isupper()})
    for function_name in CYCLE_FUNCTIONS:
        f = getattr(cycle, function_name)
        name = prefix + function_name
        code = f.__code__.replace(co_name=name, co_qualname=name) if prefix else f.__code__
        decorator = jit if function_name == "position_cycle" else inline
        names[function_name] = decorator(types.FunctionType(code, names, name))
        setattr(out, function_name, names[function_name])
    return out


@cache
def load() -> types.SimpleNamespace:
    """``.core`` (a module of the compiled :data:`CORE_FUNCTIONS`) and ``.cycle``
    (:func:`cycle_copy` against it)."""
    import numba

    jit = numba.njit(cache=True, nogil=True)  # no fastmath: bit for bit the Python result
    inline = numba.njit(cache=True, nogil=True, inline="always")
    compiled_core = types.ModuleType("regulator.core (compiled)")
    for name in CORE_FUNCTIONS:
        setattr(compiled_core, name, jit(getattr(core, name)))
    return types.SimpleNamespace(core=compiled_core, cycle=cycle_copy(jit, inline, compiled_core))
