"""CANopenNode, the industrial C stack these tests put on the other end of vcan0.

The source is third-party (``shared/peers/canopenlinux``: CANopenLinux with the CANopenNode
submodule, Apache-2.0, see ``shared/peers/README.md``); it is never copied into this
repository. :func:`build` copies it to a cache folder outside git, runs ``make`` there and
keeps the binaries keyed by the SHA-256 of the source tree, so a second test run reuses them
(``BACKLASH_PEERS_CACHE`` moves the cache; ``BACKLASH_PEERS`` names the ``shared/peers``
folder when it is not beside the checkout).

:class:`Gateway` runs ``canopend IFACE -i NODE -c stdio``: its CiA 309-3 ASCII gateway
(``[seq] node read|write index sub type value``, ``[seq] node start|stop|preop``) on
standard input/output, and its log (EMCY received, heartbeat consumer state changes) on
standard error, which syslog's ``LOG_PERROR`` writes there. Nothing here sleeps: every wait
reads the program's output until what is awaited arrives, bounded by :data:`BOUND_S` (a
bound for a stuck program, never reached when all is well).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import re
import selectors
import shutil
import socket
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from virtual_bus.shipped import SHARED_DIR

#: Upper bound of any wait for canopend's output (a stuck program, not a slow machine).
BOUND_S = 120.0
#: SDO client time-out of the gateway, ms (CANopenNode's default 500 ms is short for a
#: Python server on a loaded one-CPU guest; this bound is never reached when all is well).
SDO_TIMEOUT_MS = 20_000


class PeerUnavailable(Exception):
    """CANopenNode cannot be built here (the message says why); tests skip with it."""


def peers_dir() -> Path | None:
    """``shared/peers``: $BACKLASH_PEERS, else the third-party folder beside the checkout
    (:data:`virtual_bus.shipped.SHARED_DIR`, which ``$BACKLASH_SHARED`` moves)."""
    folder = Path(os.environ.get("BACKLASH_PEERS") or SHARED_DIR / "peers")
    return folder if (folder / "canopenlinux" / "Makefile").is_file() else None


def cache_dir() -> Path:
    env = os.environ.get("BACKLASH_PEERS_CACHE")
    if env:
        return Path(env)
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "backlash-bridge" / "peers"


def source_hash(source: Path) -> str:
    """SHA-256 over the relative paths and contents of every file of ``source``."""
    digest = hashlib.sha256()
    for path in sorted(p for p in source.rglob("*") if p.is_file()):
        digest.update(str(path.relative_to(source)).encode() + b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()


@dataclass(frozen=True)
class Binaries:
    canopend: Path
    cocomm: Path
    folder: Path  # the built copy of the source (example/DS301_profile.eds is in it)
    built_s: float | None  # seconds make took now; None: taken from the cache

    @property
    def demo_eds(self) -> Path:
        """CANopenNode's EDS of the demo object dictionary canopend serves."""
        return self.folder / "CANopenNode" / "example" / "DS301_profile.eds"


def build() -> Binaries:
    """canopend and cocomm, built once per source hash (PeerUnavailable: no source, no
    compiler or no make here; a failing build raises RuntimeError with make's output)."""
    peers = peers_dir()
    if peers is None:
        raise PeerUnavailable(
            "CANopenNode source not found: shared/peers/canopenlinux beside the checkout "
            "(or set BACKLASH_PEERS to the shared/peers folder)"
        )
    missing = [tool for tool in ("make", "cc") if shutil.which(tool) is None]
    if missing:
        raise PeerUnavailable(
            f"no {' and no '.join(missing)} on PATH to build CANopenNode (apt install gcc make)"
        )
    source = peers / "canopenlinux"
    key = source_hash(source)[:16]
    root = cache_dir()
    root.mkdir(parents=True, exist_ok=True)
    folder = root / f"canopenlinux-{key}"
    binaries = Binaries(folder / "canopend", folder / "cocomm" / "cocomm", folder, None)
    with open(root / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one build at a time (parallel test runs)
        if binaries.canopend.is_file() and binaries.cocomm.is_file():
            return binaries
        work = Path(tempfile.mkdtemp(prefix="build-", dir=root))
        try:
            copy = work / "canopenlinux"
            shutil.copytree(source, copy)
            t0 = time.perf_counter()
            for args in (["make"], ["make", "-C", "cocomm"]):
                done = subprocess.run(args, cwd=copy, capture_output=True, text=True, check=False)
                if done.returncode != 0:
                    raise RuntimeError(
                        f"{' '.join(args)} in a copy of {source} failed "
                        f"({done.returncode}):\n{done.stdout[-2000:]}{done.stderr[-2000:]}"
                    )
            built_s = time.perf_counter() - t0
            shutil.rmtree(folder, ignore_errors=True)
            copy.rename(folder)
        finally:
            shutil.rmtree(work, ignore_errors=True)
    return Binaries(binaries.canopend, binaries.cocomm, folder, built_s)


# --- the gateway ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Answer:
    """One gateway response: ``value`` (the text after the sequence number) or the SDO
    abort code CANopenNode reports (``abort``), or another gateway error (``error``)."""

    text: str

    @property
    def ok(self) -> bool:
        return not self.text.startswith("ERROR:")

    @property
    def abort(self) -> int | None:
        m = re.match(r"ERROR:0x([0-9A-Fa-f]{8})", self.text)
        return int(m.group(1), 16) if m else None

    @property
    def data(self) -> bytes:
        """The value of a read with the ``hex`` data type."""
        if not self.ok:
            raise ValueError(f"not data: {self.text}")
        return bytes.fromhex(self.text)


_RESPONSE = re.compile(r"^\[(\d+)\]\s*(.*?)\s*$")
_EMCY = re.compile(
    r"Emergency message from node 0x([0-9A-F]{2}): errorCode=0x([0-9A-F]{4}), "
    r"errorRegister=0x([0-9A-F]{2}), errorBit=0x([0-9A-F]{2}), infoCode=0x([0-9A-F]{8})"
)
_HB = re.compile(
    r"Remote node ID = 0x([0-9A-F]{2}) \(index = (\d+)\): NMT state changed to: \"([a-z-]+)\""
)


@dataclass(frozen=True)
class Emcy:
    node: int
    code: int
    register: int
    bit: int
    info: int


class Gateway:
    """``canopend`` as node ``node_id`` on ``interface`` with its ASCII gateway on stdio.

    Use as a context manager; the process ends (SIGTERM, then bounded wait) on exit.
    """

    def __init__(self, binaries: Binaries, interface: str, node_id: int, workdir: Path):
        self.node_id = node_id
        self.log: list[str] = []  # canopend's log lines (standard error)
        self._seq = 0
        self._out = b""
        self._err = b""
        self._responses: dict[int, str] = {}
        # canopend's "stdio" gateway reads commands from fd 0 and writes the responses to
        # fd 0 as well (a terminal is both): a socket pair stands in for the terminal
        self._sock, child = socket.socketpair()
        try:
            self.proc = subprocess.Popen(
                [
                    str(binaries.canopend),
                    interface,
                    "-i",
                    str(node_id),
                    "-s",
                    f"{workdir}/n{node_id}_",
                    "-c",
                    "stdio",
                ],
                stdin=child,
                stdout=child,
                stderr=subprocess.PIPE,
                cwd=workdir,
            )
        finally:
            child.close()
        assert self.proc.stderr is not None
        self._sock.setblocking(False)
        os.set_blocking(self.proc.stderr.fileno(), False)
        self._sel = selectors.DefaultSelector()
        self._sel.register(self._sock, selectors.EVENT_READ)
        self._sel.register(self.proc.stderr, selectors.EVENT_READ)
        self.wait_log(lambda line: 'command interface on "standard IO" started' in line)
        self.command(f"set sdo_timeout {SDO_TIMEOUT_MS}")

    # --- I/O --------------------------------------------------------------------------------
    def _pump(self, done: Callable[[], bool], what: str) -> None:
        deadline = time.monotonic() + BOUND_S
        while not done():
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(
                    f"canopend: no {what} within {BOUND_S:.0f} s; log: {self.log[-5:]}"
                )
            if not self._sel.get_map():
                raise RuntimeError(
                    f"canopend ended ({self.proc.poll()}) before {what}; log: {self.log[-5:]}"
                )
            for key, _ in self._sel.select(min(left, 1.0)):
                stream = key.fileobj
                chunk = stream.recv(65536) if stream is self._sock else stream.read1(65536)  # type: ignore[union-attr]
                if not chunk:
                    self._sel.unregister(stream)
                    continue
                if stream is self._sock:
                    self._out += chunk
                    *lines, self._out = self._out.split(b"\n")
                    for line in lines:
                        m = _RESPONSE.match(line.decode("ascii", "replace"))
                        if m:
                            self._responses[int(m.group(1))] = m.group(2)
                else:
                    self._err += chunk
                    *lines, self._err = self._err.split(b"\n")
                    self.log += [line.decode("ascii", "replace").rstrip() for line in lines]

    def command(self, text: str) -> Answer:
        """Send one gateway command and return its response."""
        self._seq += 1
        seq = self._seq
        self._sock.sendall(f"[{seq}] {text}\r\n".encode("ascii"))
        self._pump(lambda: seq in self._responses, f"answer to [{seq}] {text!r}")
        return Answer(self._responses.pop(seq))

    def wait_log(self, predicate: Callable[[str], bool], start: int = 0) -> str:
        """The first log line from index ``start`` on that satisfies ``predicate``."""
        found: list[str] = []

        def done() -> bool:
            found[:] = [line for line in self.log[start:] if predicate(line)][:1]
            return bool(found)

        self._pump(done, "log line")
        return found[0]

    # --- services ---------------------------------------------------------------------------
    def read(self, node: int, index: int, sub: int) -> Answer:
        return self.command(f"{node} read 0x{index:04X} {sub} hex")

    def write(self, node: int, index: int, sub: int, data: bytes) -> Answer:
        """Download ``data`` as it is (any length; CANopenNode chooses expedited up to 4
        bytes, segmented above)."""
        if not data:
            return self.command(f'{node} write 0x{index:04X} {sub} hex ""')
        return self.command(f"{node} write 0x{index:04X} {sub} hex {data.hex(' ')}")

    def nmt(self, node: int, what: str) -> Answer:
        """``what``: start, stop, preop, reset node, reset comm."""
        return self.command(f"{node} {what}")

    def emcys(self, start: int = 0) -> list[Emcy]:
        out = []
        for line in self.log[start:]:
            m = _EMCY.search(line)
            if m:
                out.append(Emcy(*(int(g, 16) for g in m.groups())))
        return out

    def heartbeat_states(self, start: int = 0) -> list[tuple[int, str]]:
        """(node-ID, NMT state) of each heartbeat consumer state change logged."""
        return [
            (int(m.group(1), 16), m.group(3))
            for line in self.log[start:]
            if (m := _HB.search(line))
        ]

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.proc.wait(BOUND_S)
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stderr is not None:
            self.proc.stderr.close()
        self._sock.close()
        self._sel.close()

    def __enter__(self) -> Gateway:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@contextlib.contextmanager
def gateway(binaries: Binaries, node_id: int, interface: str = "vcan0") -> Iterator[Gateway]:
    with (
        tempfile.TemporaryDirectory(prefix="canopend-") as tmp,
        Gateway(binaries, interface, node_id, Path(tmp)) as gw,
    ):
        yield gw
