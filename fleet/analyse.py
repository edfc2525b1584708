"""One recording in, one :class:`RecordingResult` out: the unit of work of a fleet run.

:func:`analyse` never raises for a bad recording: the result carries ``error`` (one line) and
the fleet run goes on. It is a plain module-level function of picklable arguments, so Dask
can ship it to any worker; it reads the recording in chunks (:mod:`.readers`), so a 24 h
recording needs no more memory than a 25 s one.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import math
import warnings
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from plant_sim.errors import PlantSimError
from regulator.errors import RegulatorError
from virtual_bus.formats import FormatError
from virtual_bus.formats.axis import AxisConfig, PositionFeedback, load_axis
from virtual_bus.formats.errors import TornTailWarning

from .candump import layout_for
from .chunks import Chunk
from .episodes import DetectorSetup, Episode, EpisodeFinder, Verdict
from .errors import RecordingError, TimeBaseWarning
from .lost_motion import LostMotionEstimator
from .readers import open_chunks
from .sources import RecordingKind, Source

#: Load speed below which an axis counts as standing still, per load unit and second
#: (1 mm/s on a linear axis, 1 mrad/s on a rotary one).
STANDSTILL_SPEED = 1e-3
#: Reference acceleration above which a sample is not steady for the lost motion, units/s².
STEADY_ACCEL = 0.05


@dataclass(frozen=True)
class RecordingResult:
    """What the monitor learnt from one recording (all plain values: a table row + episodes).

    duration_s, samples, dt_s: the recording. vibrating_s: time inside episodes.
    verdict: in_band if any episode vibrates in eq. 13's band, else outside_band if any
    vibrates, else none. lost_motion/_uncertainty: load units (nan where not measurable),
    reversals: how many reversals it rests on; backlash: the lost motion less the elastic
    wind-up (:class:`~.lost_motion.LostMotion`), nan for a rigid axis file or torque in ‰.
    error: one line when the file was unusable. warning: one line when the reader dropped a
    torn tail (a recorder killed mid-write; the whole records before it were analysed) or
    read a lockstep log on the SYNC count's time base (:mod:`.candump`).
    """

    path: str
    kind: str
    machine: str
    axis: str
    date: dt.datetime | None
    kv_per_s: float = math.nan
    load_unit: str = ""
    samples: int = 0
    duration_s: float = 0.0
    dt_s: float = math.nan
    vibrating_s: float = 0.0
    verdict: Verdict = Verdict.NONE
    dominant_frequency_hz: float = math.nan
    max_beta_rad_s: float = 0.0
    lost_motion: float = math.nan
    lost_motion_uncertainty: float = math.nan
    backlash: float = math.nan
    reversals: int = 0
    torque_unit: str = ""
    error: str = ""
    warning: str = ""
    episodes: tuple[Episode, ...] = field(default_factory=tuple)

    @property
    def ok(self) -> bool:
        return not self.error

    @property
    def axis_id(self) -> str:
        """``MACHINE/AXIS``, or the file's name where its path names neither (a file given
        directly): two such files are two axes as far as the monitor can know."""
        if not (self.machine or self.axis):
            return Path(self.path).name
        return f"{self.machine or '?'}/{self.axis or '?'}"


@lru_cache(maxsize=256)
def _axis(path: Path) -> AxisConfig:
    return load_axis(path)


def _first_chunk_dt(chunk: Chunk) -> float:
    if len(chunk) < 2:
        raise RecordingError("fewer than 2 samples in the first block")
    return float(np.median(np.diff(chunk.time_s)))


def analyse(source: Source) -> RecordingResult:
    """Episodes, verdict and lost motion of one recording (see the module docstring)."""
    base = RecordingResult(
        path=str(source.path),
        kind=source.kind.value,
        machine=source.machine,
        axis=source.axis,
        date=source.date,
    )
    if source.axis_file is None:
        return dataclasses.replace(
            base,
            error=f"{source.path}: no axis file for {source.axis_id}: give --axis FILE or "
            "an [[axis]] entry with axis_file in --axes MAP.toml",
        )
    try:
        axis = _axis(source.axis_file)
    except (FormatError, PlantSimError, OSError) as exc:
        return dataclasses.replace(base, error=f"{source.path}: axis file: {exc}")
    base = dataclasses.replace(base, kv_per_s=axis.control.kv, load_unit=axis.load_unit)
    reported = (TornTailWarning, TimeBaseWarning)
    with warnings.catch_warnings(record=True) as caught:
        for category in reported:
            warnings.simplefilter("always", category)
        result = _analyse_or_error(source, axis, base)
    torn = [str(w.message) for w in caught if issubclass(w.category, reported)]
    for w in caught:  # any other warning goes on as it came
        if not issubclass(w.category, reported):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return dataclasses.replace(result, warning="; ".join(torn)) if torn else result


def _analyse_or_error(source: Source, axis: AxisConfig, base: RecordingResult) -> RecordingResult:
    try:
        return _analyse(source, axis, base)
    except RecordingError as exc:
        text = str(exc)
        if not text.startswith(str(source.path)):
            text = f"{source.path}: {text}"
        return dataclasses.replace(base, error=text)
    except RegulatorError as exc:
        return dataclasses.replace(
            base, error=f"{source.path}: cannot run the detector on it: {exc}"
        )
    except (OSError, MemoryError) as exc:
        return dataclasses.replace(base, error=f"{source.path}: {type(exc).__name__}: {exc}")


def _analyse(source: Source, axis: AxisConfig, base: RecordingResult) -> RecordingResult:
    layout = None
    if source.kind is RecordingKind.CANDUMP:
        try:
            layout = layout_for(axis.kind, source.drive_profile, axis.control.position_cycle)
        except (PlantSimError, ValueError, OSError) as exc:  # a profile that cannot be used
            raise RecordingError(f"drive profile {source.drive_profile}: {exc}") from None
    chunks = open_chunks(source.path, source.kind, layout)
    first = next(chunks, None)
    if first is None:
        raise RecordingError(f"{source.path}: holds no samples", path=str(source.path))
    dt_s = _first_chunk_dt(first)
    kr = axis.transmission_ratio
    finder = EpisodeFinder(
        DetectorSetup(
            kv_per_s=axis.control.kv,
            transmission_ratio=kr,
            feedback_on_load=axis.control.position_feedback is PositionFeedback.LOAD,
            dt_s=dt_s,
        )
    )
    lost = LostMotionEstimator(
        transmission_ratio=kr,
        kv_per_s=axis.control.kv,
        dt_s=dt_s,
        speed_threshold=STANDSTILL_SPEED,
        accel_limit=STEADY_ACCEL,
        stiffness=axis.stiffness,
    )
    samples, t0, t_end, torque_unit = 0, float(first.time_s[0]), float(first.time_s[-1]), ""
    chunk: Chunk | None = first
    while chunk is not None:
        finder.feed(chunk)
        lost.feed(chunk)
        samples += len(chunk)
        t_end = float(chunk.time_s[-1])
        torque_unit = chunk.torque_unit
        chunk = next(chunks, None)
    episodes = tuple(finder.finish())
    verdict = Verdict.NONE
    if any(e.verdict is Verdict.IN_BAND for e in episodes):
        verdict = Verdict.IN_BAND
    elif episodes:
        verdict = Verdict.OUTSIDE_BAND
    longest = max(episodes, key=lambda e: e.end_s - e.start_s, default=None)
    lm = lost.result()
    return dataclasses.replace(
        base,
        samples=samples,
        duration_s=t_end - t0,
        dt_s=dt_s,
        vibrating_s=sum(e.end_s - e.start_s for e in episodes),
        verdict=verdict,
        dominant_frequency_hz=longest.frequency_hz if longest else math.nan,
        max_beta_rad_s=finder.max_beta,
        lost_motion=lm.value if lm else math.nan,
        lost_motion_uncertainty=lm.uncertainty if lm else math.nan,
        reversals=lm.reversals if lm else 0,
        backlash=lm.backlash if lm and torque_unit == "N·m" else math.nan,
        torque_unit=torque_unit,
        episodes=episodes,
    )
