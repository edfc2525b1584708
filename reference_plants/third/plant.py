"""The third test plant's parameters (:class:`Physics`, SI, its own names), its closed loop
as a function, and the axis file that describes it as nearly as the format allows
(:func:`axis_of`: what a user would write from the data sheet, the modelling choices the
format cannot state left out)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from virtual_bus.formats.axis import AxisConfig, axis_from_mapping
from virtual_bus.formats.trace import RECORDED_COLUMNS, Trace

from . import physics as P

#: Columns of :func:`simulate`'s trace (trace-file names).
COLUMNS = (*RECORDED_COLUMNS, "disturbance")

#: Largest ω·h of the mechanics step.
MAX_OMEGA_H = 0.05


@dataclass(frozen=True)
class Physics:
    """One axis of the third plant. Load-side quantities in load units (m or rad), forces on
    the load in N (N·m rotary); ``kind`` "linear" or "rotary"."""

    kind: str
    transmission_ratio: float  # motor rad per load unit
    motor_inertia: float  # kg m²
    screw_inertia: float  # kg m², behind the coupling
    coupling_stiffness: float  # N m/rad, torsional, motor to screw
    coupling_damping: float  # N m s/rad
    load_mass: float  # kg (kg m² rotary)
    nut_stiffness: float  # N/m (N m/rad), screw to load
    nut_damping: float  # N s/m
    backlash: float  # load units, total free play of the nut
    coulomb_pos: float  # N, LuGre F_c for v > 0
    coulomb_neg: float  # N, v < 0
    static_pos: float  # N, LuGre F_s (= F_c: no Stribeck peak)
    static_neg: float
    stribeck_speed: float  # load units/s
    bristle_stiffness: float  # σ0, N per load unit
    bristle_damping: float  # σ1, N s per load unit
    viscous_pos: float  # σ2, N s per load unit
    viscous_neg: float
    load_force: float  # N the motor must supply to hold the load (gravity residual)
    periodic_force: float  # N amplitude, position-periodic
    periodic_period: float  # load units
    periodic_phase: float  # rad
    # drive
    kv: float
    ksp: float  # N m s/rad
    tsi: float  # s
    torque_limit: float  # N m (inf: none)
    position_cycle: float
    speed_cycle: float
    current_per_speed_cycle: int
    load_feedback: bool
    speed_filter: float  # s
    setpoint_delay_cycles: int  # dead time of the speed set point, position cycles
    sensor_offset: float  # s, the load scale's reading is this old
    winding_resistance: float  # ohm
    winding_inductance: float  # H
    torque_constant: float  # N m/A (= back-EMF V s/rad)
    bus_voltage: float  # V, the current controller's output limit
    current_lag: float  # s, closed current loop's time constant the PI is tuned for
    encoder_lines: int
    encoder_error: float  # rad, interpolation error amplitude (once per line)
    encoder_quantum: float  # rad
    scale_quantum: float  # load units
    trace_filter: float  # s, anti-alias filter of the traced torque

    def with_(self, **changes: object) -> Physics:
        return replace(self, **changes)  # type: ignore[arg-type]


def _stiffest(ph: Physics) -> float:
    kr = ph.transmission_ratio
    coupling = math.sqrt(ph.coupling_stiffness * (1.0 / ph.motor_inertia + 1.0 / ph.screw_inertia))
    nut = math.sqrt(ph.nut_stiffness * (1.0 / ph.load_mass + 1.0 / (ph.screw_inertia * kr**2)))
    bristle = math.sqrt(ph.bristle_stiffness / ph.load_mass)
    bristle_damp = ph.bristle_damping / ph.load_mass
    electrical = ph.winding_resistance / ph.winding_inductance
    return max(coupling, nut, bristle, bristle_damp, electrical)


def parameters(ph: Physics) -> np.ndarray:
    """The core's parameter vector."""
    q = np.zeros(P.N_PAR)
    q[P.KR] = ph.transmission_ratio
    q[P.JM] = ph.motor_inertia
    q[P.JS] = ph.screw_inertia
    q[P.KC] = ph.coupling_stiffness
    q[P.CC] = ph.coupling_damping
    q[P.M] = ph.load_mass
    q[P.KN] = ph.nut_stiffness
    q[P.CN] = ph.nut_damping
    q[P.HALF_GAP] = 0.5 * ph.backlash
    q[P.FC_P], q[P.FC_N] = ph.coulomb_pos, ph.coulomb_neg
    q[P.FS_P], q[P.FS_N] = ph.static_pos, ph.static_neg
    q[P.VS] = ph.stribeck_speed
    q[P.SIG0], q[P.SIG1] = ph.bristle_stiffness, ph.bristle_damping
    q[P.SIG2_P], q[P.SIG2_N] = ph.viscous_pos, ph.viscous_neg
    q[P.F_CONST] = ph.load_force
    q[P.F_PER], q[P.PER_LEN], q[P.PER_PHASE] = (
        ph.periodic_force,
        ph.periodic_period,
        ph.periodic_phase,
    )
    q[P.KV] = ph.kv
    q[P.KSP] = ph.ksp
    q[P.KI] = ph.ksp / ph.tsi
    q[P.I_LIM] = ph.torque_limit
    q[P.TP] = ph.position_cycle
    q[P.TSC] = ph.speed_cycle
    q[P.NSC] = round(ph.position_cycle / ph.speed_cycle)
    q[P.NCC] = ph.current_per_speed_cycle
    tcc = ph.speed_cycle / ph.current_per_speed_cycle
    q[P.NH] = max(1, math.ceil(tcc * _stiffest(ph) / MAX_OMEGA_H))
    q[P.FB_LOAD] = 1.0 if ph.load_feedback else 0.0
    q[P.SPD_FILT] = ph.speed_filter
    q[P.SP_DELAY_N] = ph.setpoint_delay_cycles
    q[P.OFFSET] = ph.sensor_offset
    q[P.R_W], q[P.L_W] = ph.winding_resistance, ph.winding_inductance
    q[P.KT] = ph.torque_constant
    q[P.KE] = ph.torque_constant
    q[P.U_MAX] = ph.bus_voltage
    # PI current controller cancelling the winding's pole: closed loop ≈ a lag of current_lag
    q[P.CKP] = ph.winding_inductance / ph.current_lag
    q[P.CKI] = ph.winding_resistance / ph.current_lag
    q[P.ENC_LINES] = ph.encoder_lines
    q[P.ENC_ERR] = ph.encoder_error
    q[P.ENC_QUANT] = ph.encoder_quantum
    q[P.SCALE_QUANT] = ph.scale_quantum
    q[P.AA_TAU] = ph.trace_filter
    return q


def simulate(
    ph: Physics, position: np.ndarray, speed: np.ndarray, disturbance_nm: np.ndarray
) -> Trace:
    """Closed loop on the reference (load units, load units/s, per position cycle) and an
    external torque (N·m at the motor, positive pushes towards +x)."""
    position = np.ascontiguousarray(position, dtype=float)
    speed = np.ascontiguousarray(speed, dtype=float)
    dist = np.ascontiguousarray(disturbance_nm, dtype=float)
    out = np.empty((len(position), len(COLUMNS)))
    P.run(parameters(ph), float(position[0]), position, speed, dist, out)
    return Trace({name: out[:, i] for i, name in enumerate(COLUMNS)})


def axis_of(ph: Physics) -> AxisConfig:
    """The axis file a user writes from this axis's data sheet: the motor and the screw rigid
    together (the coupling's torsion is not in the format), the nut's stiffness as the
    elastic element, the LuGre law's steady state as Coulomb + viscous (+ Stribeck) friction
    reflected to the motor, the drive's settings; the winding, the encoder's interpolation
    error and the trace's filter are not in the format."""
    kr = ph.transmission_ratio
    friction: dict[str, float | None] = {
        "coulomb": ph.coulomb_pos / kr,
        "viscous": ph.viscous_pos / kr,
    }
    if ph.coulomb_neg != ph.coulomb_pos or ph.viscous_neg != ph.viscous_pos:
        friction["coulomb_negative"] = ph.coulomb_neg / kr
        friction["viscous_negative"] = ph.viscous_neg / kr
    if ph.static_pos > ph.coulomb_pos:
        friction["stribeck"] = (ph.static_pos - ph.coulomb_pos) / kr
        friction["stribeck_speed"] = ph.stribeck_speed
    elastic = math.isfinite(ph.nut_stiffness)
    wa = math.sqrt(ph.nut_stiffness / ph.load_mass) if elastic else None
    xi = ph.nut_damping * wa / (2.0 * ph.nut_stiffness) if wa else None
    dist: dict[str, float | None] = {}
    if ph.load_force != 0.0:
        dist["constant_torque"] = ph.load_force / kr
    if ph.periodic_force != 0.0:
        dist["periodic_amplitude"] = ph.periodic_force / kr
        dist["periodic_period"] = ph.periodic_period
        dist["periodic_phase"] = ph.periodic_phase
    doc = {
        "axis": {"kind": ph.kind, "transmission_ratio": kr},
        "mechanics": {
            "motor_inertia": ph.motor_inertia,
            "screw_inertia": ph.screw_inertia,
            "load_inertia" if ph.kind == "rotary" else "load_mass": ph.load_mass,
            "antiresonance": wa,
            "damping_ratio": xi,
            "backlash": ph.backlash if ph.backlash > 0.0 else None,
        },
        "friction": friction,
        "disturbance": dist,
        "control": {
            "kv": ph.kv,
            "ksp": ph.ksp,
            "tsi": ph.tsi,
            "position_feedback": "load" if ph.load_feedback else "motor",
            "torque_limit": ph.torque_limit if math.isfinite(ph.torque_limit) else None,
            "current_lag": ph.current_lag,
            "delay": ph.setpoint_delay_cycles * ph.position_cycle or None,
            "position_cycle": ph.position_cycle,
            "speed_cycle": ph.speed_cycle,
            "speed_filter": ph.speed_filter or None,
            "sensor_time_offset": ph.sensor_offset or None,
        },
    }
    # as a user writes the file: a key without a value is left out
    return axis_from_mapping(
        {name: {k: v for k, v in table.items() if v is not None} for name, table in doc.items()}
    )
