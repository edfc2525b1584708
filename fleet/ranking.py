"""Across the fleet: the tables, the per-axis trends and the ranked list of axes to inspect.

Trend of an axis: least-squares line of its backlash estimate (the lost motion where the
axis file gives no stiffness) over the recordings' dates, slope in load units per month
(30.4375 days) with its standard error. An axis is **warned** when the slope exceeds the
stated growth limit and is significant (slope − 2 σ > 0, at least three dated recordings).
An axis **vibrates** when its latest recording has an episode in eq. 13's band.

Ranking: axes with a reason to inspect come first, ordered by a severity score
``growth / limit + 2 × (share of its last three recordings with an in-band episode)
+ latest backlash / backlash limit``; the reasons are spelt out in the list.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cmdline.quantity import quantity
from virtual_bus.atomic import replacing

from .analyse import RecordingResult
from .episodes import Verdict

DAYS_PER_MONTH = 30.4375

RECORDING_COLUMNS = (
    "path",
    "kind",
    "machine",
    "axis",
    "date",
    "kv_per_s",
    "load_unit",
    "samples",
    "duration_s",
    "dt_s",
    "vibrating_s",
    "verdict",
    "dominant_frequency_hz",
    "max_beta_rad_s",
    "lost_motion",
    "lost_motion_uncertainty",
    "backlash",
    "reversals",
    "torque_unit",
    "error",
    "warning",
)
EPISODE_COLUMNS = (
    "path",
    "machine",
    "axis",
    "date",
    "start_s",
    "end_s",
    "frequency_hz",
    "band_low_hz",
    "band_high_hz",
    "verdict",
    "amplitude",
    "peak_beta_rad_s",
    "speed",
    "direction",
    "position_min",
    "position_max",
)
AXIS_COLUMNS = (
    "rank",
    "axis_id",
    "recordings",
    "bad_files",
    "first_date",
    "last_date",
    "kv_per_s",
    "load_unit",
    "latest_backlash",
    "growth_per_month",
    "growth_sigma_per_month",
    "growth_warning",
    "vibrating",
    "in_band_share_last3",
    "median_frequency_hz",
    "severity",
    "reasons",
)


@dataclass(frozen=True)
class Limits:
    """Warning limits, load units: growth per month and backlash (defaults: µm on a m axis)."""

    growth_per_month: float = 5e-6
    backlash: float = 50e-6

    def __post_init__(self) -> None:
        for name in ("growth_per_month", "backlash"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} = {value!r}: must be a finite number > 0")


@dataclass
class AxisTrend:
    """One axis across its recordings (see the module docstring)."""

    axis_id: str
    results: list[RecordingResult] = field(default_factory=list)
    bad_files: int = 0
    growth_per_month: float = math.nan
    growth_sigma: float = math.nan
    growth_warning: bool = False
    vibrating: bool = False
    in_band_share_last3: float = 0.0
    median_frequency_hz: float = math.nan
    severity: float = 0.0
    reasons: tuple[str, ...] = ()

    @property
    def latest(self) -> RecordingResult | None:
        return self.results[-1] if self.results else None

    def measure(self, r: RecordingResult) -> float:
        return r.backlash if math.isfinite(r.backlash) else r.lost_motion


def _slope(days: np.ndarray, values: np.ndarray) -> tuple[float, float]:
    """Least-squares slope per month and its standard error."""
    months = days / DAYS_PER_MONTH
    a = np.column_stack([months - months.mean(), np.ones_like(months)])
    coef, *_ = np.linalg.lstsq(a, values, rcond=None)
    resid = values - a @ coef
    dof = values.size - 2
    s2 = float(resid @ resid) / dof if dof > 0 else math.nan
    sxx = float(((months - months.mean()) ** 2).sum())
    return float(coef[0]), math.sqrt(s2 / sxx) if sxx > 0 else math.nan


def trends(results: Sequence[RecordingResult], limits: Limits) -> list[AxisTrend]:
    """Per-axis trends and the ranked list (most urgent first)."""
    by_axis: dict[str, AxisTrend] = {}
    for r in sorted(results, key=lambda r: (r.axis_id, r.date is None, r.date or 0, r.path)):
        t = by_axis.setdefault(r.axis_id, AxisTrend(r.axis_id))
        if r.ok:
            t.results.append(r)
        else:
            t.bad_files += 1
    for t in by_axis.values():
        dated = [r for r in t.results if r.date is not None and math.isfinite(t.measure(r))]
        if len(dated) >= 3:
            d0 = dated[0].date
            days = np.array([(r.date - d0).total_seconds() / 86400.0 for r in dated])  # type: ignore[operator]
            values = np.array([t.measure(r) for r in dated])
            if np.ptp(days) > 0:
                t.growth_per_month, t.growth_sigma = _slope(days, values)
                t.growth_warning = bool(
                    t.growth_per_month > limits.growth_per_month
                    and t.growth_per_month - 2.0 * t.growth_sigma > 0.0
                )
        last3 = t.results[-3:]
        if last3:
            t.in_band_share_last3 = sum(r.verdict is Verdict.IN_BAND for r in last3) / len(last3)
        t.vibrating = bool(t.latest is not None and t.latest.verdict is Verdict.IN_BAND)
        freqs = [
            e.frequency_hz for r in t.results for e in r.episodes if e.verdict is Verdict.IN_BAND
        ]
        t.median_frequency_hz = float(np.median(freqs)) if freqs else math.nan
        latest_measure = t.measure(t.latest) if t.latest is not None else math.nan
        unit = t.latest.load_unit if t.latest is not None else "m"
        reasons = []
        if t.vibrating:
            reasons.append(f"vibrates in band at {t.median_frequency_hz:.1f} Hz")
        if t.growth_warning:
            reasons.append(
                f"backlash grows {quantity(t.growth_per_month, unit)}/month, limit "
                f"{quantity(limits.growth_per_month, unit)}/month"
            )
        if math.isfinite(latest_measure) and latest_measure > limits.backlash:
            reasons.append(
                f"backlash {quantity(latest_measure, unit)} above the limit of "
                f"{quantity(limits.backlash, unit)}"
            )
        if t.bad_files:
            reasons.append(f"{t.bad_files} unreadable recording(s)")
        t.reasons = tuple(reasons)
        growth = max(t.growth_per_month, 0.0) if math.isfinite(t.growth_per_month) else 0.0
        t.severity = (
            growth / limits.growth_per_month
            + 2.0 * t.in_band_share_last3
            + (latest_measure / limits.backlash if math.isfinite(latest_measure) else 0.0)
        )
    return sorted(by_axis.values(), key=lambda t: (not t.reasons, -t.severity, t.axis_id))


# --- tables -----------------------------------------------------------------------------------
def _cell(value: object) -> object:
    if isinstance(value, Verdict):
        return value.value
    if hasattr(value, "isoformat"):
        return value.isoformat()  # type: ignore[union-attr]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def recording_rows(results: Sequence[RecordingResult]) -> list[dict[str, object]]:
    rows = []
    for r in results:
        d = dataclasses.asdict(r)
        rows.append({c: _cell(getattr(r, c)) if c in d else None for c in RECORDING_COLUMNS})
    return rows


def episode_rows(results: Sequence[RecordingResult]) -> list[dict[str, object]]:
    rows = []
    for r in results:
        for e in r.episodes:
            row = {"path": r.path, "machine": r.machine, "axis": r.axis, "date": _cell(r.date)}
            for c in EPISODE_COLUMNS[4:]:
                row[c] = _cell(getattr(e, c))
            rows.append(row)
    return rows


def axis_rows(ranked: Sequence[AxisTrend]) -> list[dict[str, object]]:
    rows = []
    for rank, t in enumerate(ranked, 1):
        latest = t.latest
        dates = [r.date for r in t.results if r.date is not None]
        rows.append(
            {
                "rank": rank,
                "axis_id": t.axis_id,
                "recordings": len(t.results),
                "bad_files": t.bad_files,
                "first_date": _cell(min(dates)) if dates else None,
                "last_date": _cell(max(dates)) if dates else None,
                "kv_per_s": _cell(latest.kv_per_s) if latest else None,
                "load_unit": latest.load_unit if latest else "",
                "latest_backlash": _cell(t.measure(latest)) if latest else None,
                "growth_per_month": _cell(t.growth_per_month),
                "growth_sigma_per_month": _cell(t.growth_sigma),
                "growth_warning": t.growth_warning,
                "vibrating": t.vibrating,
                "in_band_share_last3": t.in_band_share_last3,
                "median_frequency_hz": _cell(t.median_frequency_hz),
                "severity": round(t.severity, 4),
                "reasons": "; ".join(t.reasons),
            }
        )
    return rows


def write_table(
    rows: Sequence[dict[str, object]], columns: Sequence[str], stem: Path
) -> list[Path]:
    """``stem.csv`` and ``stem.parquet`` of the rows (columns in this order)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    csv_path = stem.with_suffix(".csv")
    with replacing(csv_path) as tmp, tmp.open("w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=list(columns))
        writer.writeheader()
        for row in rows:
            writer.writerow({k: ("" if v is None else v) for k, v in row.items()})
    table = (
        pa.Table.from_pylist(list(rows), schema=_schema(rows, columns))
        if rows
        else (pa.table({c: pa.array([], pa.string()) for c in columns}))
    )
    parquet_path = stem.with_suffix(".parquet")
    with replacing(parquet_path) as tmp:
        pq.write_table(table, tmp)
    return [csv_path, parquet_path]


def _schema(rows: Sequence[dict[str, object]], columns: Sequence[str]):
    import pyarrow as pa

    fields = []
    for c in columns:
        sample = next((r[c] for r in rows if r.get(c) is not None), None)
        kind = (
            pa.bool_()
            if isinstance(sample, bool)
            else pa.int64()
            if isinstance(sample, int)
            else pa.float64()
            if isinstance(sample, float)
            else pa.string()
        )
        fields.append(pa.field(c, kind))
    return pa.schema(fields)
