"""The simulated drive served (:func:`plant_sim.drive.process.serve`) in a thread, for the
tests that talk to it over a bus they own."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from plant_sim.drive.process import DriveProcessConfig, serve


@contextmanager
def drive_in_thread(
    config: DriveProcessConfig, bus: Any, bound_s: float
) -> Iterator[tuple[threading.Event, list]]:
    """Serve ``config`` on ``bus`` in a thread; yields the stop flag and the drive (a list that
    holds it once booted). Fails if the drive does not boot or raised; at the end stops it,
    joins the thread and shuts ``bus`` down. ``bound_s``: backstop of the waits (a thread that
    hangs; never reached when all is well)."""
    stop, booted = threading.Event(), threading.Event()
    drives: list = []
    errors: list[BaseException] = []

    def body() -> None:
        try:
            serve(config, bus, stop, ready=lambda d: (drives.append(d), booted.set()))
        except BaseException as exc:
            errors.append(exc)
            booted.set()

    thread = threading.Thread(target=body, name="drive")
    thread.start()
    try:
        assert booted.wait(bound_s) and not errors, errors
        yield stop, drives
    finally:
        stop.set()
        thread.join(bound_s)
        bus.shutdown()
    assert not errors, errors
