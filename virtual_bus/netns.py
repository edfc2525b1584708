"""Private Linux network namespaces: two processes on one bus without touching the host.

python-can's ``udp_multicast`` interface carries CAN frames as UDP multicast datagrams, so
two processes can share one bus without SocketCAN. On the host that traffic would leave on
the host's network interfaces; inside a private network namespace whose only interface is
``lo`` it cannot go anywhere else. :class:`NetworkNamespace` creates such a namespace with
iproute2 (``ip netns add``), brings ``lo`` up with a route for IPv4 multicast, runs commands
in it (``ip netns exec``) and removes it again, also when the block fails::

    with NetworkNamespace.create() as ns:
        drive = ns.popen([sys.executable, "-m", "plant_sim", "drive", ...])
        ns.run([sys.executable, "-m", "bridge", "run", "--interface", "udp_multicast", ...])

The bus group is python-can's ``UdpMulticastBus.DEFAULT_GROUP_IPv4`` (239.74.163.2). Its
default IPv6 group (ff15:7079:...) is not delivered over ``lo`` (measured on kernel 6.18:
``Ip6OutMcastPkts`` counts up, nothing arrives, with or without an ``ff00::/8`` route on lo),
so :data:`UDP_GROUP` is the IPv4 one.

:func:`private_namespace_problem` says whether the *current* process is in such a namespace
(only ``lo``); ``virtual_bus`` refuses ``udp_multicast`` anywhere else.
"""

from __future__ import annotations

import os
import socket
import subprocess
import uuid
from collections.abc import Sequence
from dataclasses import dataclass

from virtual_bus.closing import Closing
from virtual_bus.errors import NetnsError

#: python-can's UdpMulticastBus.DEFAULT_GROUP_IPv4: the bus channel inside a namespace.
UDP_GROUP = "239.74.163.2"
#: The IPv4 multicast range routed to ``lo`` inside the namespace.
MULTICAST_ROUTE = "224.0.0.0/4"
#: Name prefix of the namespaces this module creates (``ip netns list`` shows them).
NAME_PREFIX = "vbus-"
_IP_TIMEOUT_S = 10.0


def interface_names() -> tuple[str, ...]:
    """Names of the network interfaces of the current network namespace (``if_nameindex``,
    asked of the kernel, so right also where /sys belongs to another namespace)."""
    return tuple(name for _, name in socket.if_nameindex())


def private_namespace_problem() -> str | None:
    """None if this process's network namespace has no interface but ``lo`` (multicast
    cannot leave it); else why not, naming the interfaces."""
    others = [name for name in interface_names() if name != "lo"]
    if others:
        return f"this network namespace has the interfaces {', '.join(sorted(others))}"
    return None


def _run_ip(args: Sequence[str]) -> subprocess.CompletedProcess[str]:
    command = ["ip", *args]
    try:
        return subprocess.run(
            command, capture_output=True, text=True, check=False, timeout=_IP_TIMEOUT_S
        )
    except FileNotFoundError as exc:
        raise NetnsError(
            "cannot run `ip`: iproute2 is not installed", command=tuple(command)
        ) from exc


def _check(result: subprocess.CompletedProcess[str]) -> None:
    if result.returncode != 0:
        said = (result.stderr or result.stdout).strip().splitlines()
        first = said[0] if said else f"exit status {result.returncode}"
        hint = ""
        if "not permitted" in first.lower() or "permission" in first.lower():
            hint = " (needs root or CAP_SYS_ADMIN)"
        raise NetnsError(
            f"`{' '.join(result.args)}` failed: {first}{hint}", command=tuple(result.args)
        )


def netns_problem() -> str | None:
    """None if this host lets this process create network namespaces, else why not (for
    test skips). Creates and removes one namespace to find out."""
    try:
        with NetworkNamespace.create():
            return None
    except NetnsError as exc:
        return str(exc)


@dataclass
class NetworkNamespace(Closing):
    """A network namespace made by :meth:`create`; :meth:`close` (or the ``with`` block)
    deletes it. Processes still running in it are not killed by the deletion: stop the
    ones you started first (the namespace lives on until they exit)."""

    name: str
    _closed: bool = False

    @classmethod
    def create(cls, name: str | None = None) -> NetworkNamespace:
        """``ip netns add NAME``, ``lo`` up, ``224.0.0.0/4`` routed to ``lo``. A failure
        after the namespace exists removes it again. Raises :class:`NetnsError`."""
        name = name or f"{NAME_PREFIX}{uuid.uuid4().hex[:10]}"
        _check(_run_ip(["netns", "add", name]))
        ns = cls(name)
        try:
            _check(ns._ip("link", "set", "lo", "up"))
            _check(ns._ip("route", "add", MULTICAST_ROUTE, "dev", "lo"))
        except BaseException:
            ns.close()
            raise
        return ns

    def _ip(self, *args: str) -> subprocess.CompletedProcess[str]:
        return _run_ip(["netns", "exec", self.name, "ip", *args])

    def command(self, argv: Sequence[str]) -> list[str]:
        """``argv`` run inside the namespace (``ip netns exec NAME ...``)."""
        return ["ip", "netns", "exec", self.name, *argv]

    def run(
        self, argv: Sequence[str], timeout_s: float, env: dict[str, str] | None = None
    ) -> subprocess.CompletedProcess[str]:
        """Run ``argv`` inside the namespace to its end (text output captured)."""
        return subprocess.run(
            self.command(argv),
            capture_output=True,
            text=True,
            check=False,
            timeout=timeout_s,
            env=env,
        )

    def popen(
        self, argv: Sequence[str], env: dict[str, str] | None = None
    ) -> subprocess.Popen[str]:
        """Start ``argv`` inside the namespace (stdout/stderr piped, text). The caller stops
        and waits for it before the namespace is closed."""
        return subprocess.Popen(
            self.command(argv),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )

    def exists(self) -> bool:
        return os.path.exists(f"/run/netns/{self.name}")

    def close(self) -> None:
        """``ip netns delete NAME`` (idempotent)."""
        if self._closed:
            return
        self._closed = True
        _check(_run_ip(["netns", "delete", self.name]))
