"""Run :func:`~.analyse.analyse` over the fleet on Dask: local processes or a cluster.

``workers=0`` runs in this process (no Dask; for debugging and small tests). Otherwise the
tasks go to a ``dask.distributed`` client: a :class:`~distributed.LocalCluster` of
``workers`` single-threaded processes started here (the default), or an existing scheduler
(``tcp://HOST:8786``) whose workers must have this project installed. At most
``in_flight`` tasks are submitted at a time and each result is handed to ``sink`` as it
completes, so memory stays bounded by ``in_flight`` results whatever the fleet's size. The
results reach ``sink`` in completion order; every consumer sorts by path, so a local and a
cluster run give identical tables.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator, Sequence

from ..errors import SchedulerError
from .analyse import RecordingResult, analyse
from .sources import Source

#: Tasks submitted ahead of the results consumed (bounds memory on the client).
IN_FLIGHT_PER_WORKER = 8


@contextlib.contextmanager
def dask_client(scheduler: str | None, workers: int) -> Iterator[object]:
    """A connected ``distributed.Client``: to ``scheduler``, or to a new LocalCluster."""
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise SchedulerError(
                f"Dask scheduler {scheduler}: cannot connect ({type(exc).__name__}: {exc}); "
                "give the address of a running dask scheduler, e.g. tcp://HOST:8786"
            ) from None
        try:
            yield client
        finally:
            client.close()
        return
    cluster = LocalCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=True,
        dashboard_address=None,
        silence_logs=40,  # logging.ERROR: one line per bad file is ours to print
        # workers import the project from the client's working copy
        env={
            "PYTHONPATH": os.pathsep.join(
                p for p in (os.getcwd(), os.environ.get("PYTHONPATH", "")) if p
            )
        },
    )
    try:
        client = Client(cluster)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


def run_fleet(
    sources: Sequence[Source],
    sink: Callable[[RecordingResult], None],
    workers: int = 2,
    scheduler: str | None = None,
) -> None:
    """Analyse every source, handing each result to ``sink`` as it completes."""
    if workers == 0 and scheduler is None:
        for source in sources:
            sink(analyse(source))
        return
    from distributed import as_completed

    with dask_client(scheduler, workers) as client:
        n_workers = max(1, len(client.scheduler_info().get("workers", {})) or workers)  # type: ignore[attr-defined]
        limit = IN_FLIGHT_PER_WORKER * n_workers
        pending = iter(sources)
        first = [client.submit(analyse, s, pure=False) for s in _take(pending, limit)]  # type: ignore[attr-defined]
        stream = as_completed(first)
        for future in stream:
            sink(future.result())
            future.release()
            for s in _take(pending, 1):
                stream.add(client.submit(analyse, s, pure=False))  # type: ignore[attr-defined]


def _take(it: Iterator[Source], n: int) -> list[Source]:
    out = []
    for _ in range(n):
        try:
            out.append(next(it))
        except StopIteration:
            break
    return out
