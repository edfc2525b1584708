"""SocketCAN host side: interface names, kernel/interface probing and vcan setup via ``ip``.

``setup_vcan`` runs exactly ``ip link add dev NAME type vcan`` and ``ip link set up NAME`` as
argument lists (no shell) through an injectable runner, and turns ``ip``'s stderr into one
honest sentence (missing rights, missing kernel module, name taken by a non-vcan interface).
Nothing here sends a CAN frame.
"""

from __future__ import annotations

import json
import re
import socket
import subprocess
from collections.abc import Callable, Sequence
from enum import Enum
from pathlib import Path

from virtual_bus.errors import BusConfigError, VcanProblem, VcanSetupError

#: Linux ``IFNAMSIZ`` (include/uapi/linux/if.h): buffer size including the terminating NUL.
IFNAMSIZ = 16
#: Allowed interface names: 1..15 ASCII letters, digits, ``_ . -``; no leading ``-``/``.``
#: (stricter than the kernel's ``dev_valid_name``, which also forbids ``/``, ``:`` and
#: whitespace, so that a name can never be mistaken for an ``ip`` option).
_IFNAME_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]*")
#: ``ARPHRD_CAN`` (include/uapi/linux/if_arp.h), the value of /sys/class/net/<name>/type.
ARPHRD_CAN = 280
DEFAULT_VCAN_CHANNEL = "vcan0"

Runner = Callable[[Sequence[str]], "subprocess.CompletedProcess[str]"]


def check_ifname(name: str) -> str:
    """Return ``name`` if it is a valid Linux interface name, else raise ``BusConfigError``."""
    if not isinstance(name, str):
        raise BusConfigError(f"interface name must be a string, got {name!r}")
    if not 1 <= len(name) <= IFNAMSIZ - 1:
        raise BusConfigError(
            f"interface name {name!r} has {len(name)} characters; "
            f"allowed 1..{IFNAMSIZ - 1} (IFNAMSIZ={IFNAMSIZ} incl. NUL)"
        )
    if not _IFNAME_RE.fullmatch(name):
        raise BusConfigError(
            f"interface name {name!r} has characters outside the allowed set: "
            "ASCII letters, digits, '_', '.', '-' (not first: '.' or '-')"
        )
    return name


class LinkKind(Enum):
    """What /sys says about a network interface name."""

    MISSING = "does not exist"
    VCAN = "virtual CAN interface"
    CAN = "hardware CAN interface"
    NOT_CAN = "not a CAN interface"


class HostProbe:
    """Reads the host's SocketCAN support; the default reads the real kernel and /sys.

    Tests substitute a subclass (or any object with the same two methods) so both branches of
    :func:`virtual_bus.open.resolve` run without touching the host.
    """

    def __init__(self, sys_class_net: Path = Path("/sys/class/net")) -> None:
        self._sys_class_net = sys_class_net

    def af_can_problem(self) -> str | None:
        """``None`` if a raw CAN socket can be created, else the reason (no frame is sent)."""
        if not hasattr(socket, "AF_CAN") or not hasattr(socket, "CAN_RAW"):
            return "this Python has no socket.AF_CAN (not Linux?)"
        try:
            sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
        except OSError as exc:
            return (
                f"the kernel refuses socket(AF_CAN, SOCK_RAW, CAN_RAW): {exc.strerror} "
                "(load the can and can_raw modules)"
            )
        sock.close()
        return None

    def link_kind(self, name: str) -> LinkKind:
        """Classify interface ``name`` from /sys/class/net (virtual devices live in
        /sys/devices/virtual/net, CAN devices have type ARPHRD_CAN=280)."""
        node = self._sys_class_net / name
        if not node.exists():
            return LinkKind.MISSING
        try:
            link_type = int((node / "type").read_text().strip())
        except (OSError, ValueError):
            return LinkKind.NOT_CAN
        if link_type != ARPHRD_CAN:
            return LinkKind.NOT_CAN
        is_virtual = "/devices/virtual/" in str(node.resolve())
        return LinkKind.VCAN if is_virtual else LinkKind.CAN


def run_ip(args: Sequence[str]) -> subprocess.CompletedProcess[str]:
    """Default runner: run ``args`` without a shell, capture text output, never raise on
    a non-zero exit status."""
    return subprocess.run(list(args), capture_output=True, text=True, check=False, timeout=10)


class SetupOutcome(Enum):
    """What :func:`setup_vcan` did."""

    CREATED = "created and brought up"
    ALREADY_EXISTED = "already existed; brought up"


def _first_line(text: str) -> str:
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[0] if lines else "(no message)"


def _classify(stderr: str) -> VcanProblem:
    """Map ``ip``'s stderr to a problem. Texts are iproute2's/the kernel's own:
    ``RTNETLINK answers: Operation not permitted``, ``Error: Unknown device type.`` (newer
    iproute2 with extack) / ``RTNETLINK answers: Operation not supported`` (older) when the
    vcan module is missing, ``Cannot find device "NAME"``."""
    low = stderr.lower()
    if "operation not permitted" in low or "permission denied" in low:
        return VcanProblem.NOT_PERMITTED
    if "unknown device type" in low or "operation not supported" in low or "modprobe" in low:
        return VcanProblem.NO_VCAN_MODULE
    if "cannot find device" in low:
        return VcanProblem.NO_SUCH_DEVICE
    return VcanProblem.OTHER


def _message(
    problem: VcanProblem, name: str, command: Sequence[str], returncode: int, stderr: str
) -> str:
    cmd = " ".join(command)
    said = _first_line(stderr)
    if problem is VcanProblem.NOT_PERMITTED:
        return (
            f"cannot set up {name}: `{cmd}` needs root or CAP_NET_ADMIN "
            f"(ip said: {said}); run it with sudo"
        )
    if problem is VcanProblem.NO_VCAN_MODULE:
        return (
            f"cannot create {name}: this kernel has no vcan module (ip said: {said}); "
            "try `sudo modprobe vcan`, or use the in-process virtual bus"
        )
    if problem is VcanProblem.NO_SUCH_DEVICE:
        return f"cannot bring up {name}: no such interface (ip said: {said})"
    return f"`{cmd}` failed with exit status {returncode}: {said}"


def _run(runner: Runner, command: tuple[str, ...]) -> subprocess.CompletedProcess[str]:
    try:
        return runner(command)
    except FileNotFoundError as exc:
        raise VcanSetupError(
            f"cannot run `{command[0]}`: the ip command (iproute2) is not installed",
            problem=VcanProblem.NO_IP_COMMAND,
            command=command,
            returncode=None,
            stderr="",
        ) from exc


def _fail(
    name: str, command: tuple[str, ...], result: subprocess.CompletedProcess[str]
) -> VcanSetupError:
    problem = _classify(result.stderr)
    return VcanSetupError(
        _message(problem, name, command, result.returncode, result.stderr),
        problem=problem,
        command=command,
        returncode=result.returncode,
        stderr=result.stderr,
    )


def _link_kind_via_ip(runner: Runner, name: str) -> str | None:
    """``linkinfo.info_kind`` of ``name`` from ``ip -details -json link show``, or None."""
    command = ("ip", "-details", "-json", "link", "show", "dev", name)
    result = _run(runner, command)
    if result.returncode != 0:
        raise _fail(name, command, result)
    try:
        links = json.loads(result.stdout)
        return links[0].get("linkinfo", {}).get("info_kind")
    except (ValueError, IndexError, AttributeError, TypeError):
        return None


def setup_vcan(name: str = DEFAULT_VCAN_CHANNEL, runner: Runner = run_ip) -> SetupOutcome:
    """Create vcan interface ``name`` and bring it up (``ip link add`` + ``ip link set up``).

    An existing vcan interface of that name is only brought up; an existing interface of
    another kind is refused and left untouched. Raises :class:`BusConfigError` for an invalid
    name and :class:`VcanSetupError` (with ``problem``) when ``ip`` fails.
    """
    check_ifname(name)
    add = ("ip", "link", "add", "dev", name, "type", "vcan")
    result = _run(runner, add)
    outcome = SetupOutcome.CREATED
    if result.returncode != 0:
        if "file exists" not in result.stderr.lower():
            raise _fail(name, add, result)
        kind = _link_kind_via_ip(runner, name)
        if kind != "vcan":
            raise VcanSetupError(
                f"{name} already exists and is not a vcan interface (kind: {kind or 'none'}); "
                "refusing to touch it, choose another name",
                problem=VcanProblem.NOT_VCAN,
                command=add,
                returncode=result.returncode,
                stderr=result.stderr,
            )
        outcome = SetupOutcome.ALREADY_EXISTED
    up = ("ip", "link", "set", "up", name)
    result = _run(runner, up)
    if result.returncode != 0:
        raise _fail(name, up, result)
    return outcome
