"""Project-wide pytest fixtures.

* ``no_leaks`` (autouse): fails a test that leaves a thread running or a python-can
  ``virtual`` bus open (python-can registers every open VirtualBus queue in
  ``can.interfaces.virtual.channels``). A test or fixture that keeps something on purpose
  registers it with ``leak_allowance.keep(thread_or_virtual_bus)``.
* ``bus_mode``: each bus mode (``virtual``; ``socketcan`` on vcan0, marked ``vcan``);
  ``bus_pair``: two connected buses of that mode, shut down at teardown.
* Tests marked ``vcan`` are skipped where vcan0 is not available. ``dev.py test`` runs the
  suite in two parts where the host has no SocketCAN (:data:`VCAN_PART_ENV`): ``without``
  deselects the tests marked ``vcan`` (the host's part), ``only`` keeps just them (the part
  run in a User-mode Linux guest, ``python -m virtual_bus guest``), where a missing vcan0
  fails them instead of skipping them.
* ``private_netns``: a private network namespace (``virtual_bus.netns``) created for the test
  and removed after it; skips with the reason where ``ip netns`` is not allowed (not root, no
  iproute2). ``subprocess_env``: the environment for a Python subprocess that imports this
  checkout's packages.
"""

from __future__ import annotations

import functools
import os
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field

import can
import can.interfaces.virtual as can_virtual
import pytest

from tests.paths import checkout_env
from virtual_bus import BusConfig, Interface, available_modes, open_bus, resolve
from virtual_bus.netns import NetworkNamespace, netns_problem

pytest_plugins = ["pytester"]

#: Total time the leak check waits for new threads that are about to finish.
LEAK_GRACE_S = 1.0


@dataclass
class LeakAllowance:
    """Threads and virtual buses that may outlive the test that created them."""

    threads: set[threading.Thread] = field(default_factory=set)
    queue_ids: set[int] = field(default_factory=set)

    def keep(self, item: threading.Thread | can.BusABC) -> None:
        """Allow ``item`` (a thread, or a python-can VirtualBus) to stay alive."""
        if isinstance(item, threading.Thread):
            self.threads.add(item)
        elif isinstance(item, can_virtual.VirtualBus):
            self.queue_ids.add(id(item.queue))
        else:
            raise TypeError(f"can keep a Thread or a VirtualBus, not {type(item).__name__}")


@dataclass(frozen=True)
class Snapshot:
    """Live threads and open virtual-bus queues (by id) at one moment."""

    threads: frozenset[threading.Thread]
    queue_ids: frozenset[int]


def take_snapshot() -> Snapshot:
    with can_virtual.channels_lock:
        queues = frozenset(id(q) for qs in can_virtual.channels.values() for q in qs)
    return Snapshot(frozenset(threading.enumerate()), queues)


def find_leaks(
    before: Snapshot, allowance: LeakAllowance | None = None, grace_s: float = LEAK_GRACE_S
) -> list[str]:
    """Describe threads and virtual buses that appeared since ``before`` and are still alive
    (new threads get a join of at most ``grace_s`` in total to finish)."""
    allowed = allowance or LeakAllowance()
    new = [
        t
        for t in threading.enumerate()
        if t not in before.threads
        and t not in allowed.threads
        and t is not threading.current_thread()
    ]
    deadline = time.monotonic() + grace_s
    for thread in new:
        thread.join(max(0.0, deadline - time.monotonic()))
    problems = [f"thread {t.name!r} still running" for t in new if t.is_alive()]
    with can_virtual.channels_lock:
        for channel, queues in can_virtual.channels.items():
            leaked = [
                q
                for q in queues
                if id(q) not in before.queue_ids and id(q) not in allowed.queue_ids
            ]
            if leaked:
                problems.append(
                    f"python-can virtual channel {channel!r}: {len(leaked)} bus(es) not shut down"
                )
    return problems


@pytest.fixture(scope="session")
def leak_allowance() -> LeakAllowance:
    """Register threads/virtual buses that may legitimately outlive a test."""
    return LeakAllowance()


@pytest.fixture(autouse=True)
def no_leaks(leak_allowance: LeakAllowance) -> Iterator[None]:
    before = take_snapshot()
    yield
    problems = find_leaks(before, leak_allowance)
    if problems:
        pytest.fail("test leaked: " + "; ".join(problems), pytrace=False)


#: ``without``: deselect the tests marked vcan; ``only``: deselect all others (see above).
VCAN_PART_ENV = "BACKLASH_BRIDGE_VCAN_PART"


def _vcan_part() -> str | None:
    part = os.environ.get(VCAN_PART_ENV) or None
    if part not in (None, "without", "only"):
        raise pytest.UsageError(f"{VCAN_PART_ENV}={part!r}: allowed 'without', 'only' or unset")
    return part


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    part = _vcan_part()
    if part is None:
        return
    want = part == "only"
    keep, drop = [], []
    for item in items:
        (keep if (item.get_closest_marker("vcan") is not None) == want else drop).append(item)
    if drop:
        config.hook.pytest_deselected(items=drop)
        items[:] = keep


@functools.cache
def _vcan_skip_reason() -> str | None:
    if Interface.SOCKETCAN in available_modes():
        return None
    return "no SocketCAN vcan0 here: " + resolve(BusConfig()).reason


def pytest_runtest_setup(item: pytest.Item) -> None:
    if item.get_closest_marker("vcan") is not None and (reason := _vcan_skip_reason()):
        if _vcan_part() == "only":  # the guest was to have vcan0: a failure, not a skip
            pytest.fail(reason, pytrace=False)
        pytest.skip(reason)


@pytest.fixture(
    params=[
        pytest.param(Interface.VIRTUAL, id="virtual"),
        pytest.param(Interface.SOCKETCAN, id="vcan0", marks=pytest.mark.vcan),
    ]
)
def bus_mode(request: pytest.FixtureRequest) -> Interface:
    """Each bus mode; the SocketCAN one (vcan0) is skipped where the host lacks it."""
    return request.param


@pytest.fixture
def bus_pair(bus_mode: Interface) -> Iterator[tuple[can.BusABC, can.BusABC]]:
    """Two buses on one channel (each end of the loop), shut down at teardown. Virtual
    channels are unique per test; SocketCAN uses vcan0 (shared with the whole host)."""
    if bus_mode is Interface.SOCKETCAN:
        config = BusConfig(interface=Interface.SOCKETCAN, channel="vcan0")
    else:
        config = BusConfig(interface=bus_mode, channel=f"pytest-{uuid.uuid4().hex[:12]}")
    first = open_bus(config)
    try:
        second = open_bus(config)
    except BaseException:
        first.shutdown()
        raise
    try:
        yield first, second
    finally:
        first.shutdown()
        second.shutdown()


@pytest.fixture(scope="session")
def netns_skip_reason() -> str | None:
    """Why this host does not let the tests create a network namespace (None: it does)."""
    problem = netns_problem()
    return None if problem is None else f"cannot create a network namespace here: {problem}"


@pytest.fixture
def private_netns(netns_skip_reason: str | None) -> Iterator[NetworkNamespace]:
    """A private network namespace (only ``lo``, IPv4 multicast routed to it), removed at
    teardown (stop the processes you started in it first)."""
    if netns_skip_reason is not None:
        pytest.skip(netns_skip_reason)
    with NetworkNamespace.create() as ns:
        yield ns
    assert not ns.exists()


@pytest.fixture(scope="session")
def subprocess_env() -> dict[str, str]:
    """os.environ with PYTHONPATH = this checkout (a subprocess imports these packages)."""
    return checkout_env()
