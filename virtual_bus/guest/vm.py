"""Run a command in a User-mode Linux guest with SocketCAN ``vcan0`` up.

Where the host kernel has no SocketCAN (containers, WSL, CI runners, this project's
development VM), a User-mode Linux (UML) kernel started as an ordinary process gives a real
kernel CAN stack. :func:`run_in_guest` boots one (:mod:`virtual_bus.guest.kernel` chooses
it) with the host's root file system as its root (``hostfs``: every host file is there
under its own path, read and written with the rights of the user running the guest), loads
the CAN modules, creates ``vcan0``, runs the command in the current directory with the
current environment, and returns its exit status; the guest is gone afterwards.

No block device is given (no ``ubd0=``): UML takes a POSIX lock on a ubd's file, and one
lock on ``/dev/null`` (a common ``ubd0=/dev/null``) is machine-wide, so a second guest
booted that way beside a first fails to open it and panics ("Segfault with no mm") or hangs.
Its default ``ubd0`` is ``root_fs`` in the current directory, which is why the kernel
starts in the fresh ``RUN`` folder (it says "Failed to initialize ubd device 0" and goes on).

    linux.uml mem=2048M rootfstype=hostfs rootflags=/ rw con=null con0=null,fd:1 quiet
              init=RUN/init.sh      (started in RUN)

``RUN`` is a fresh folder under the cache folder: ``init.sh`` is the guest's PID 1 (a
``/bin/sh`` script: mounts proc, sysfs, devtmpfs, devpts, tmpfs on /run and /dev/shm;
``busybox insmod`` of each module; ``ip link add dev vcan0 type vcan``; the command; its exit
status into ``RUN/status``; ``busybox poweroff -f``). The command's standard output and error
go to ``RUN/stdout`` and ``RUN/stderr``, which the host follows while the guest runs (hostfs
writes through to the host file at once) and copies to its own; the kernel's console goes to
``RUN/console`` (kept when the guest fails, for the message).

A guest that hangs is bounded by its own progress, not by a wall-clock limit on the whole
run: while the guest runs, any byte it writes (console, standard output or error) is
progress; when it writes nothing for ``stall_s`` (default 600 s) it is stopped and the
error names the last line it wrote. A slow guest on a busy host is never stopped while it
still reports anything.
"""

from __future__ import annotations

import contextlib
import os
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from virtual_bus.errors import BusConfigError
from virtual_bus.guest.kernel import (
    GuestError,
    GuestProblem,
    Kernel,
    cache_dir,
    diagnose_console,
    module_order,
    require_tool,
)

#: Guest memory (MB): the default, and the range allowed.
DEFAULT_MEM_MB = 2048
MEM_RANGE_MB = (128, 65536)
#: Default bound on the guest's silence (s): see the module docstring.
DEFAULT_STALL_S = 600.0
#: How often the host looks at the guest's output files (s).
POLL_S = 0.05
#: Environment variables not passed into the guest (they name host sockets or the shell).
_HOST_ONLY_ENV = frozenset(
    {"SSH_AUTH_SOCK", "DBUS_SESSION_BUS_ADDRESS", "DISPLAY", "WAYLAND_DISPLAY", "XDG_RUNTIME_DIR"}
    | {"PWD", "OLDPWD", "SHLVL", "_"}
)
#: Lines the init script writes to the console (the host reads them back).
MARK_BOOTED = "guest: vcan0 up"
MARK_SETUP_FAILED = "guest: setup failed:"


@dataclass(frozen=True)
class GuestConfig:
    """How the guest runs its command.

    mem_mb: guest memory (MB, 128..65536); stall_s: stop a guest that writes nothing for
    this long (s, > 0); cwd: the command's directory (default: the current one); env: its
    environment (default: the current one, less :data:`_HOST_ONLY_ENV`); interfaces: vcan
    interfaces to create and bring up.
    """

    mem_mb: int = DEFAULT_MEM_MB
    stall_s: float = DEFAULT_STALL_S
    cwd: Path | None = None
    env: Mapping[str, str] | None = None
    interfaces: tuple[str, ...] = ("vcan0",)

    def __post_init__(self) -> None:
        low, high = MEM_RANGE_MB
        if isinstance(self.mem_mb, bool) or not isinstance(self.mem_mb, int):
            raise BusConfigError(f"mem_mb = {self.mem_mb!r}: a whole number of MB")
        if not low <= self.mem_mb <= high:
            raise BusConfigError(f"mem_mb = {self.mem_mb}: allowed {low}..{high} MB")
        if not (isinstance(self.stall_s, int | float) and 0 < self.stall_s < float("inf")):
            raise BusConfigError(f"stall_s = {self.stall_s!r}: a finite number of s > 0")
        from virtual_bus.vcan import check_ifname

        for name in self.interfaces:
            check_ifname(name)


@dataclass(frozen=True)
class GuestResult:
    """What the command did in the guest: exit status, output, and the guest's timings
    (``boot_s``: start of the kernel to vcan0 up; ``wall_s``: the whole guest)."""

    returncode: int
    stdout: bytes
    stderr: bytes
    boot_s: float
    wall_s: float
    kernel: Kernel = field(repr=False)


def guest_env(env: Mapping[str, str] | None = None) -> dict[str, str]:
    """The environment the command gets in the guest (see :class:`GuestConfig`)."""
    source = os.environ if env is None else env
    return {
        k: v
        for k, v in source.items()
        if k not in _HOST_ONLY_ENV and k.isidentifier() and "\0" not in v
    }


def init_script(
    kernel: Kernel,
    argv: Sequence[str],
    run_dir: Path,
    cwd: Path,
    env: Mapping[str, str],
    interfaces: Sequence[str],
    busybox: str,
) -> str:
    """The guest's PID 1 (see the module docstring). ``argv`` empty: only boot and report
    (the probe)."""
    q = shlex.quote
    lines = [
        "#!/bin/sh",
        "# PID 1 of a User-mode Linux guest (virtual_bus.guest); never exits: powers off",
        "export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
        f"BB={q(busybox)}",
        f"RUN={q(str(run_dir))}",
        'fail() { echo "' + MARK_SETUP_FAILED + ' $*"; $BB poweroff -f; }',
        "echo guest: init running",
    ]
    if not argv:
        lines += ['echo "guest: probe ok"', "$BB poweroff -f"]
        return "\n".join(lines) + "\n"
    lines += [
        "mount -t proc proc /proc || fail mount proc",
        "mount -t sysfs sys /sys || fail mount sysfs",
        "mount -t devtmpfs dev /dev 2>/dev/null",
        "mkdir -p /dev/pts /dev/shm",
        "mount -t devpts devpts /dev/pts || fail mount devpts",
        "mount -t tmpfs tmpfs /run || fail mount /run",
        "mount -t tmpfs tmpfs /dev/shm || fail mount /dev/shm",
        "ip link set lo up 2>/dev/null",
    ]
    for ko in module_order(kernel.modules):
        lines.append(f'out=$($BB insmod {q(str(ko))} 2>&1) || fail "insmod {ko.name}: $out"')
    for name in interfaces:
        lines += [
            f'out=$(ip link add dev {name} type vcan 2>&1) || fail "ip link add {name}: $out"',
            f'out=$(ip link set up {name} 2>&1) || fail "ip link set up {name}: $out"',
        ]
    lines += [f'echo "{MARK_BOOTED}"', "export " + "HOME=" + q(env.get("HOME", "/root"))]
    lines += [f"export {k}={q(v)}" for k, v in sorted(env.items())]
    lines += [
        f"cd {q(str(cwd))} || fail cd {q(str(cwd))}",
        " ".join(q(a) for a in argv) + ' </dev/null >"$RUN/stdout" 2>"$RUN/stderr"',
        'echo $? > "$RUN/status.tmp" && mv "$RUN/status.tmp" "$RUN/status"',
        "sync",
        "$BB poweroff -f",
    ]
    return "\n".join(lines) + "\n"


class _Follower:
    """Copies what a growing file gained since the last look to a stream; keeps all of it."""

    def __init__(self, path: Path, sink: BinaryIO | None) -> None:
        self.path = path
        self.sink = sink
        self.data = bytearray()

    def poll(self) -> bool:
        """Read what is new; whether there was anything."""
        try:
            with self.path.open("rb") as f:
                f.seek(len(self.data))
                new = f.read()
        except FileNotFoundError:
            return False
        if not new:
            return False
        self.data += new
        if self.sink is not None:
            self.sink.write(new)
            self.sink.flush()
        return True


def _kernel_args(kernel: Kernel, mem_mb: int, init: Path) -> list[str]:
    return [
        str(kernel.path),
        f"mem={mem_mb}M",
        "rootfstype=hostfs",
        "rootflags=/",
        "rw",
        "con=null",
        "con0=null,fd:1",
        "quiet",
        f"init={init}",
    ]


def _stop(proc: subprocess.Popen[bytes]) -> None:
    """Kill the guest: the kernel process and every host process it made (its group)."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


def _new_run_dir() -> Path:
    base = cache_dir() / "runs"
    try:
        base.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix="run-", dir=base))
    except OSError:
        return Path(tempfile.mkdtemp(prefix="backlash-guest-"))


def _boot(
    kernel: Kernel,
    argv: Sequence[str],
    config: GuestConfig,
    stdout: BinaryIO | None,
    stderr: BinaryIO | None,
    clock: Callable[[], float],
) -> GuestResult:
    busybox = require_tool("busybox", "busybox-static")
    if argv:
        require_tool("ip", "iproute2")
    cwd = (config.cwd or Path.cwd()).resolve()
    env = guest_env(config.env)
    run_dir = _new_run_dir()
    keep = False
    try:
        init = run_dir / "init.sh"
        init.write_text(init_script(kernel, argv, run_dir, cwd, env, config.interfaces, busybox))
        init.chmod(0o755)
        console_path = run_dir / "console"
        outs = [_Follower(run_dir / "stdout", stdout), _Follower(run_dir / "stderr", stderr)]
        console = _Follower(console_path, None)
        t0 = clock()
        boot_s = float("nan")
        with console_path.open("wb") as console_file:
            proc = subprocess.Popen(
                _kernel_args(kernel, config.mem_mb, init),
                stdin=subprocess.DEVNULL,
                stdout=console_file,
                stderr=subprocess.STDOUT,
                cwd=run_dir,  # no root_fs here: no block device
                start_new_session=True,  # its own group: stopped as a whole
            )
            try:
                last = clock()
                while True:
                    done = proc.poll() is not None
                    grew = console.poll()
                    for f in outs:
                        grew = f.poll() or grew
                    now = clock()
                    if grew:
                        last = now
                        if boot_s != boot_s and MARK_BOOTED.encode() in console.data:
                            boot_s = now - t0
                    if done:
                        break
                    if now - last > config.stall_s:
                        _stop(proc)
                        raise GuestError(
                            f"the guest wrote nothing for {config.stall_s:g} s and was stopped "
                            f"(last line: {_last(outs, console)})",
                            problem=GuestProblem.STALLED,
                        )
                    time.sleep(POLL_S)
            finally:
                _stop(proc)
        wall_s = clock() - t0
        text = console.data.decode(errors="replace")
        status_file = run_dir / "status"
        if not argv:  # the probe
            if "guest: probe ok" in text:
                return GuestResult(0, b"", b"", wall_s, wall_s, kernel)
            raise GuestError(diagnose_console(text), problem=GuestProblem.KERNEL_CANNOT_BOOT)
        for line in text.splitlines():
            if line.startswith(MARK_SETUP_FAILED):
                keep = True
                raise GuestError(
                    f"the guest ({kernel.describe()}) could not set up SocketCAN: "
                    f"{line[len(MARK_SETUP_FAILED) :].strip()}",
                    problem=GuestProblem.SETUP_FAILED,
                )
        if not status_file.is_file():
            keep = True
            where = "before its command ended" if boot_s == boot_s else "before vcan0 was up"
            raise GuestError(
                f"the guest ({kernel.describe()}) ended {where}: {diagnose_console(text)}; "
                f"console kept in {console_path}",
                problem=GuestProblem.CRASHED,
            )
        code = int(status_file.read_text().strip() or "1")
        return GuestResult(code, bytes(outs[0].data), bytes(outs[1].data), boot_s, wall_s, kernel)
    finally:
        if not keep:
            shutil.rmtree(run_dir, ignore_errors=True)


def _last(outs: Sequence[_Follower], console: _Follower) -> str:
    for f in (*outs, console):
        lines = [ln for ln in bytes(f.data).decode(errors="replace").splitlines() if ln.strip()]
        if lines:
            return lines[-1].strip()[-160:]
    return "none"


def boot_probe(kernel: Kernel) -> str | None:
    """Boot ``kernel`` with an init that only reports back: ``None`` if it ran, else why
    not (the probe of :func:`virtual_bus.guest.kernel.find_kernel`)."""
    try:
        _boot(kernel, (), GuestConfig(mem_mb=256, stall_s=120.0), None, None, time.monotonic)
    except GuestError as exc:
        if exc.problem is GuestProblem.MISSING_TOOL:
            raise
        return str(exc)
    return None


def run_in_guest(
    argv: Sequence[str],
    kernel: Kernel,
    config: GuestConfig = GuestConfig(),
    stdout: BinaryIO | None = None,
    stderr: BinaryIO | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> GuestResult:
    """Run ``argv`` in a guest booted from ``kernel`` (see the module docstring); its
    output is copied to ``stdout``/``stderr`` (binary streams) as it comes. Raises
    :class:`GuestError` when the guest cannot run it (the command's own failure is its exit
    status in the result)."""
    if not argv:
        raise BusConfigError("no command to run in the guest")
    return _boot(kernel, list(argv), config, stdout, stderr, clock)


def default_streams() -> tuple[BinaryIO, BinaryIO]:
    """The process's own standard output and error as binary streams."""
    return sys.stdout.buffer, sys.stderr.buffer
