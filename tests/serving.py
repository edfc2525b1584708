"""The simulated drive served (:func:`plant_sim.drive.process.serve`) in a thread, for the
tests that talk to it over a bus they own, or as its own process in a network namespace."""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
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


@contextmanager
def drive_process_in(ns: Any, axis: Path, *extra: str, bound_s: float) -> Iterator[Any]:
    """``python -m plant_sim drive`` on udp_multicast in the network namespace ``ns``
    (:class:`virtual_bus.netns.NetworkNamespace`) with ``axis`` and the options ``extra``:
    yields once it said its boot-up went out, SIGTERM and its end afterwards. ``bound_s``:
    backstop of the wait for its boot-up line."""
    from tests.command_line import next_line
    from tests.paths import checkout_env

    env = checkout_env()
    argv = [sys.executable, "-m", "plant_sim", "drive", "--interface", "udp_multicast"]
    drive = ns.popen([*argv, "--axis", str(axis), *extra], env=env)
    try:
        line = next_line(drive, bound_s)
        assert line.startswith("drive 2: boot-up sent"), (line, drive.poll())
        yield drive
    finally:
        drive.send_signal(signal.SIGTERM)
        drive.communicate(timeout=60)
