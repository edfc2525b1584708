"""Tasks on Dask: local processes or an existing cluster, results handed over as they come.

What the fleet monitor (:mod:`fleet`) and the sweeps over many axes
(:mod:`hil.sweep`) share. ``workers=0`` runs in this process (no Dask; for debugging and small
tests). Otherwise the tasks go to a ``dask.distributed`` client: a
:class:`~distributed.LocalCluster` of ``workers`` single-threaded processes started here (the
default), or an existing scheduler (``tcp://HOST:8786``) whose workers must have this project
installed. At most ``IN_FLIGHT_PER_WORKER`` tasks per worker are submitted at a time and each
result is handed to ``sink`` as it completes, so memory stays bounded whatever the number of
tasks. Results reach ``sink`` in completion order: a consumer that needs an order sorts.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar

from .errors import SchedulerError

#: Tasks submitted ahead of the results consumed (bounds memory on the client).
IN_FLIGHT_PER_WORKER = 8

T = TypeVar("T")
R = TypeVar("R")


@contextlib.contextmanager
def dask_client(scheduler: str | None, workers: int) -> Iterator[object]:
    """A connected ``distributed.Client``: to ``scheduler``, or to a new LocalCluster. Its
    own INFO logging (the in-process scheduler's) is kept below ERROR like the workers'."""
    from distributed import Client, LocalCluster

    logging.getLogger("distributed").setLevel(logging.ERROR)

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
        silence_logs=40,  # logging.ERROR: one line per failed task is the caller's to print
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


def run_tasks(
    function: Callable[[T], R],
    items: Iterable[T],
    sink: Callable[[R], None],
    workers: int = 2,
    scheduler: str | None = None,
) -> None:
    """``function(item)`` for every item, each result handed to ``sink`` as it completes
    (module docstring). ``function`` must be importable by the workers (a module-level
    function) and its items and results picklable."""
    if workers == 0 and scheduler is None:
        for item in items:
            sink(function(item))
        return
    from distributed import as_completed

    with dask_client(scheduler, workers) as client:
        n_workers = max(1, len(client.scheduler_info().get("workers", {})) or workers)  # type: ignore[attr-defined]
        limit = IN_FLIGHT_PER_WORKER * n_workers
        pending = iter(items)
        first = [client.submit(function, s, pure=False) for s in _take(pending, limit)]  # type: ignore[attr-defined]
        stream = as_completed(first)
        for future in stream:
            sink(future.result())
            future.release()
            for s in _take(pending, 1):
                stream.add(client.submit(function, s, pure=False))  # type: ignore[attr-defined]


def _take(it: Iterator[T], n: int) -> list[T]:
    out = []
    for _ in range(n):
        try:
            out.append(next(it))
        except StopIteration:
            break
    return out
