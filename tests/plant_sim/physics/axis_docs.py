"""A small axis file as a mapping, for the tests of one control key at a time."""

from __future__ import annotations


def small_axis(**control: object) -> dict[str, object]:
    """A light linear axis (k_r 628.3, 25 kg, P position and speed loop) with ``control``'s
    keys added to its ``[control]`` table."""
    return {
        "axis": {"kind": "linear", "transmission_ratio": 628.3},
        "mechanics": {"motor_inertia": 1e-4, "load_mass": 25.0},
        "control": {"kv": 30.0, "ksp": 0.1, **control},
    }
