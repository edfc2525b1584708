"""Axis configurations shared by several test files."""

from __future__ import annotations

import math

from plant_sim.axis import AxisConfig, AxisKind, Control, Friction, Mechanics, PositionFeedback


def slide_axis() -> AxisConfig:
    """A light rigid slide (10 mm screw pitch, 25 kg), PI speed loop, loop on the motor
    encoder: small and fast to simulate."""
    return AxisConfig(
        kind=AxisKind.LINEAR,
        transmission_ratio=2 * math.pi / 0.01,
        mechanics=Mechanics(motor_inertia=1.2e-4, screw_inertia=0.8e-4, load_mass=25.0),
        friction=Friction(coulomb=0.08, viscous=0.4),
        control=Control(
            kv=30.0,
            ksp=0.1,
            tsi=0.008,
            current_lag=0.0002,
            position_feedback=PositionFeedback.MOTOR,
        ),
    )
