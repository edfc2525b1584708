"""Importer of the EMPS recordings (``shared/data/emps``) into servo traces (trace-file.md).

EMPS (Janot, Gautier, Brunot 2019) is a prismatic axis: DC motor, ball screw, carriage; only
the motor encoder is measured, already expressed on the load side in metres. The axis is
therefore an axis of transmission ratio 1: motor units = load units = m, torque = force in N
(trace-file.md allows this for data recorded that way).

The controller of the recording (shared/data/emps/README.md), sampled at 1 ms::

    vir(k) - pulses_N(k) = kp*kv*(qg(k) - qm(k)) - kv*dqm(k),   |vir - pulses_N| <= 10 V
    dqm(k) = (qf(k) - qf(k-1)) / T,   qf(k) = 0.5*qm(k) + 0.5*qm(k-1)   (two-tap average)

and the force on the carriage is ``gtau * vir``.

Columns written, and why:

- ``position_reference`` = qg, ``motor_position`` = qm (m).
- ``motor_torque`` = gtau*(vir - pulses_N), the **controller's own output**, not the force
  gtau*vir on the carriage. The pulses are volts added after the controller; for the rigid
  carriage they act exactly like an external force gtau*pulses_N, and that is how the trace
  spec and the simulator separate them: ``motor_torque`` is what the speed controller asked
  for (it saturates at gtau*10 V), ``disturbance`` is the known external force, and the
  simulator adds the two. Writing gtau*vir would count the pulses twice on replay.
- ``disturbance`` = gtau*pulses_N (N, positive pushes towards +x), 0 in the estimation file.
- ``motor_speed`` = dqm, the controller's filtered speed (m/s).

Timing follows the simulator (:func:`plant_sim.physics.simulate.simulate`), so that a
recording and a simulation of it compare row by row: row k holds the positions sampled at t_k, the
``disturbance`` that acts over the coming cycle [t_k, t_k+1), and the drive's *actual values*
at t_k: the torque that acted over the cycle that ends at t_k (an ideal current loop's actual
value) and the speed actual value measured one cycle earlier. Hence, with recording sample k::

    motor_torque[k] = gtau*(vir(k-1) - pulses_N(k-1)),  motor_speed[k] = dqm(k-1)

The first three samples are dropped (dqm(k-1) needs qm(k-3)). Run as
``python -m plant_sim emps --out DIR`` (see ``--help``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.io

from virtual_bus.formats.trace import MIN_ROWS, Trace, first_non_increasing
from virtual_bus.shipped import SHARED_DIR

from ..errors import PlantSimError

#: The EMPS recordings: ``data/emps`` of the third-party material beside the checkout.
DATA_DIR = SHARED_DIR / "data" / "emps"
ESTIMATION_FILE = "DATA_EMPS.mat"
VALIDATION_FILE = "DATA_EMPS_PULSES.mat"

#: Variables every EMPS file must hold (``pulses_N`` is optional: validation file only).
REQUIRED_VARIABLES = ("t", "qm", "qg", "vir", "gtau", "kp", "kv")
SIGNALS = ("t", "qm", "qg", "vir")
GAINS = ("gtau", "kp", "kv")
PULSES = "pulses_N"

#: Control-voltage saturation of the recording, V (README).
VOLTAGE_LIMIT_V = 10.0
#: Recording samples dropped at the start: motor_speed[k] = dqm(k-1) needs qm(k-3).
DROPPED_SAMPLES = 3


class EmpsFileError(PlantSimError, ValueError):
    """An EMPS .mat file is unreadable or lacks what the importer needs; ``variable`` names
    the offending MATLAB variable (None for the file as a whole)."""

    def __init__(self, message: str, *, variable: str | None = None) -> None:
        super().__init__(message)
        self.variable = variable


@dataclass(frozen=True)
class EmpsRecording:
    """The raw content of one EMPS file (SI units; voltages in V).

    time_s, qm_m (motor encoder on the load side), qg_m (position reference), vir_v (control
    voltage incl. pulses), pulses_v (0 where the file has no ``pulses_N``), the drive gain
    gtau_n_per_v (N/V), the position gain kp_per_s (1/s) and velocity gain kv_v_s_per_m.
    """

    source: Path
    time_s: np.ndarray
    qm_m: np.ndarray
    qg_m: np.ndarray
    vir_v: np.ndarray
    pulses_v: np.ndarray
    gtau_n_per_v: float
    kp_per_s: float
    kv_v_s_per_m: float
    has_pulses: bool

    @property
    def cycle_s(self) -> float:
        """Median sample time, s (1 ms)."""
        return float(np.median(np.diff(self.time_s)))

    @property
    def force_n(self) -> np.ndarray:
        """Force on the carriage, gtau*vir (N), per recording sample."""
        return self.gtau_n_per_v * self.vir_v

    @property
    def controller_voltage_v(self) -> np.ndarray:
        """The controller's own output vir - pulses_N (V)."""
        return self.vir_v - self.pulses_v


def _vector(path: Path, doc: dict, name: str) -> np.ndarray:
    raw = np.asarray(doc[name])
    if raw.ndim > 2 or (raw.ndim == 2 and min(raw.shape) != 1):
        raise EmpsFileError(
            f"{path}: variable {name!r} has shape {raw.shape}, expected a vector", variable=name
        )
    try:
        values = raw.astype(float).ravel()
    except (TypeError, ValueError):
        raise EmpsFileError(
            f"{path}: variable {name!r} is {raw.dtype}, expected numbers", variable=name
        ) from None
    if not np.all(np.isfinite(values)):
        bad = int(np.argmax(~np.isfinite(values)))
        raise EmpsFileError(
            f"{path}: variable {name!r}, sample {bad}: {values[bad]} (NaN/inf not allowed)",
            variable=name,
        )
    return values


def _gain(path: Path, doc: dict, name: str) -> float:
    values = _vector(path, doc, name)
    if values.size != 1 or not values[0] > 0:
        raise EmpsFileError(
            f"{path}: variable {name!r} = {values.tolist()}: expected one number > 0",
            variable=name,
        )
    return float(values[0])


def read_emps_mat(path: str | Path) -> EmpsRecording:
    """Read and check one EMPS .mat file (MATLAB v5, :func:`scipy.io.loadmat`).

    Raises :class:`EmpsFileError` naming the file and the missing or malformed variable.
    """
    path = Path(path)
    if not path.is_file():
        raise EmpsFileError(f"{path}: no such file")
    try:
        doc = scipy.io.loadmat(path)
    except (OSError, ValueError, TypeError, NotImplementedError) as exc:
        raise EmpsFileError(f"{path}: not a readable MATLAB v5 .mat file ({exc})") from None
    present = sorted(k for k in doc if not k.startswith("__"))
    missing = [name for name in REQUIRED_VARIABLES if name not in doc]
    if missing:
        raise EmpsFileError(
            f"{path}: missing variable(s) {', '.join(missing)}; an EMPS file needs "
            f"{', '.join(REQUIRED_VARIABLES)} (optional {PULSES}), this one has "
            f"{', '.join(present) or 'none'}",
            variable=missing[0],
        )
    signals = {name: _vector(path, doc, name) for name in SIGNALS}
    has_pulses = PULSES in doc
    if has_pulses:
        signals[PULSES] = _vector(path, doc, PULSES)
    n = len(signals["t"])
    for name, values in signals.items():
        if len(values) != n:
            raise EmpsFileError(
                f"{path}: variable {name!r} has {len(values)} samples, 't' has {n}",
                variable=name,
            )
    if n < MIN_ROWS + DROPPED_SAMPLES:
        raise EmpsFileError(
            f"{path}: {n} samples, at least {MIN_ROWS + DROPPED_SAMPLES} needed", variable="t"
        )
    i = first_non_increasing(signals["t"])
    if i is not None:
        raise EmpsFileError(
            f"{path}: variable 't', sample {i}: {float(signals['t'][i])!r} does not increase "
            f"(previous {float(signals['t'][i - 1])!r})",
            variable="t",
        )
    gains = {name: _gain(path, doc, name) for name in GAINS}
    return EmpsRecording(
        source=path,
        time_s=signals["t"],
        qm_m=signals["qm"],
        qg_m=signals["qg"],
        vir_v=signals["vir"],
        pulses_v=signals[PULSES] if has_pulses else np.zeros(n),
        gtau_n_per_v=gains["gtau"],
        kp_per_s=gains["kp"],
        kv_v_s_per_m=gains["kv"],
        has_pulses=has_pulses,
    )


def filtered_speed(qm_m: np.ndarray, cycle_s: float) -> np.ndarray:
    """The recording controller's speed dqm (m/s): backward difference of the two-tap average
    ``0.5*qm(k) + 0.5*qm(k-1)``, i.e. (qm(k) - qm(k-2)) / (2T). Samples 0 and 1 are NaN."""
    dqm = np.full(len(qm_m), np.nan)
    dqm[2:] = (qm_m[2:] - qm_m[:-2]) / (2.0 * cycle_s)
    return dqm


def control_law_residual_v(rec: EmpsRecording) -> float:
    """RMS (V) of the recorded controller output minus the README's control law rebuilt from
    qg and qm; a check that the file is read the documented way (~0.004 V estimation,
    ~0.05 V validation, against an RMS control voltage of ~1.6 V)."""
    dqm = filtered_speed(rec.qm_m, rec.cycle_s)
    law = rec.kp_per_s * rec.kv_v_s_per_m * (rec.qg_m - rec.qm_m) - rec.kv_v_s_per_m * dqm
    law = np.clip(law, -VOLTAGE_LIMIT_V, VOLTAGE_LIMIT_V)
    residual = (rec.controller_voltage_v - law)[2:]
    return float(np.sqrt(np.mean(residual**2)))


def emps_trace(rec: EmpsRecording) -> Trace:
    """The recording as a servo trace in the simulator's row timing (module docstring)."""
    k = np.arange(DROPPED_SAMPLES, len(rec.time_s))
    dqm = filtered_speed(rec.qm_m, rec.cycle_s)
    return Trace(
        {
            "time": rec.time_s[k],
            "position_reference": rec.qg_m[k],
            "motor_position": rec.qm_m[k],
            "motor_speed": dqm[k - 1],
            "motor_torque": rec.gtau_n_per_v * rec.controller_voltage_v[k - 1],
            "disturbance": rec.gtau_n_per_v * rec.pulses_v[k],
        }
    )


@dataclass(frozen=True)
class ImportedFile:
    """One converted recording: where from, where to, and what was read."""

    recording: EmpsRecording
    target: Path
    rows: int


def import_emps(sources: Sequence[str | Path], out_dir: str | Path) -> list[ImportedFile]:
    """Convert each .mat file to ``OUT_DIR/<stem>.csv``. Every file is read and checked
    before anything is written (a bad file leaves the output directory untouched)."""
    recordings = [read_emps_mat(src) for src in sources]
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise EmpsFileError(f"{out}: exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    done = []
    for rec in recordings:
        trace = emps_trace(rec)
        target = out / f"{rec.source.stem}.csv"
        trace.to_csv(target)
        done.append(ImportedFile(rec, target, len(trace)))
    return done
