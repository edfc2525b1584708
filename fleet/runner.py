"""Run :func:`~.analyse.analyse` over the fleet on Dask: local processes or a cluster
(:mod:`plant_sim.parallel`). Results reach ``sink`` in completion order; every consumer sorts
by path, so a local and a cluster run give identical tables."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from plant_sim.parallel import dask_client, run_tasks

from .analyse import RecordingResult, analyse
from .sources import Source

__all__ = ["dask_client", "run_fleet"]


def run_fleet(
    sources: Sequence[Source],
    sink: Callable[[RecordingResult], None],
    workers: int = 2,
    scheduler: str | None = None,
) -> None:
    """Analyse every source, handing each result to ``sink`` as it completes."""
    run_tasks(analyse, sources, sink, workers, scheduler)
