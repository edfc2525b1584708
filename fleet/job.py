"""The whole monitor run: discover, analyse (Dask), tabulate, trend, draw, index.

Kept apart from the command line so that tests and the benchmark call the same function.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from .analyse import RecordingResult
from .ranking import (
    AXIS_COLUMNS,
    EPISODE_COLUMNS,
    RECORDING_COLUMNS,
    AxisTrend,
    Limits,
    axis_rows,
    episode_rows,
    recording_rows,
    trends,
    write_table,
)
from .runner import run_fleet
from .sources import Discovery


@dataclass(frozen=True)
class FleetRun:
    """Outcome of :func:`monitor`: results sorted by path, ranked axes, files written."""

    results: tuple[RecordingResult, ...]
    ranked: tuple[AxisTrend, ...]
    files: tuple[Path, ...]
    elapsed_s: float

    @property
    def processed(self) -> int:
        return sum(r.ok for r in self.results)

    @property
    def failed(self) -> int:
        return sum(not r.ok for r in self.results)


def monitor(
    discovery: Discovery,
    out: Path,
    limits: Limits | None = None,
    workers: int = 2,
    scheduler: str | None = None,
    figures: bool = True,
    on_result: Callable[[RecordingResult], None] | None = None,
) -> FleetRun:
    """Analyse the discovered fleet and write tables, figures and ``index.html`` to ``out``."""
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    collected: list[RecordingResult] = []

    def sink(result: RecordingResult) -> None:
        collected.append(result)
        if on_result is not None:
            on_result(result)

    run_fleet(discovery.sources, sink, workers=workers, scheduler=scheduler)
    results = tuple(sorted(collected, key=lambda r: r.path))
    limits = limits or Limits()
    ranked = tuple(trends(results, limits))
    files: list[Path] = []
    files += write_table(recording_rows(results), RECORDING_COLUMNS, out / "recordings")
    files += write_table(episode_rows(results), EPISODE_COLUMNS, out / "episodes")
    files += write_table(axis_rows(ranked), AXIS_COLUMNS, out / "axes")
    if figures:
        from .figures import fig4_fleet, has_episodes, index_html, trend_axes, trends_figure

        for stale in ("fig4_fleet.png", "trends.png"):  # a figure with nothing to draw
            (out / stale).unlink(missing_ok=True)  # leaves no older run's figure behind
        if has_episodes(results):
            files.append(fig4_fleet(results, out / "fig4_fleet.png"))
        if trend_axes(ranked):
            files.append(trends_figure(ranked, out / "trends.png"))
        files.append(index_html(ranked, results, files, out / "index.html", limits))
    return FleetRun(results, ranked, tuple(files), time.perf_counter() - t0)


# --- the demo fleet's truth ---------------------------------------------------------------
CLASSES = ("clean", "growing", "vibrating", "corrupt")


def classify(trend: AxisTrend) -> str:
    """What the monitor says of an axis, in the demo's four classes."""
    if trend.bad_files:
        return "corrupt"
    if trend.vibrating:
        return "vibrating"
    if trend.growth_warning:
        return "growing"
    return "clean"


def confusion(ranked: Sequence[AxisTrend], truth_file: Path) -> dict[str, dict[str, int]]:
    """truth class -> predicted class -> number of axes."""
    truth = json.loads(truth_file.read_text())
    matrix = {t: dict.fromkeys(CLASSES, 0) for t in CLASSES}
    predicted = {t.axis_id: classify(t) for t in ranked}
    for axis_id, entry in truth.items():
        matrix[entry["condition"]][predicted.get(axis_id, "clean")] += 1
    return matrix


def confusion_markdown(matrix: dict[str, dict[str, int]]) -> str:
    head = "| truth \\ monitor | " + " | ".join(CLASSES) + " |"
    rule = "|---" * (len(CLASSES) + 1) + "|"
    rows = [f"| {t} | " + " | ".join(str(matrix[t][p]) for p in CLASSES) + " |" for t in CLASSES]
    return "\n".join([head, rule, *rows])
