"""Which User-mode Linux kernel the guest runner boots: found, probed once, or fetched.

A User-mode Linux (UML) kernel is an ordinary Linux program; booted with the host's root as
its root file system it gives any process a real kernel CAN stack (SocketCAN, ``vcan``)
where the host kernel has none (containers, WSL, CI runners). :mod:`virtual_bus.guest` runs
commands in it; this module chooses the kernel:

1. ``--kernel PATH`` if given;
2. else ``linux.uml`` on ``PATH`` (Debian/Ubuntu package ``user-mode-linux``), if it boots
   on this CPU;
3. else the kernel :func:`fetch_kernel` put in the cache folder (``virtual_bus guest
   --fetch-kernel``): Debian testing's ``user-mode-linux`` with the testing ``libc6`` it
   needs, unpacked with ``dpkg-deb`` and pointed at that libc with ``patchelf``.

Each candidate is booted once (:func:`probe`, about 2 s) and the verdict is kept in the
cache folder, keyed by the kernel file and the CPU's feature flags. Why the probe: older UML
kernels save the user processes' FPU
state in a buffer of fixed size; on a CPU whose XSAVE state is larger (AMX: ``amx_tile`` in
/proc/cpuinfo) the host's ``PTRACE_SETREGSET`` fails and the kernel panics at its first user
process with "userspace - ptrace set fp regs failed, errno = 14" (measured: Debian
bookworm's 6.1 and trixie's 6.12 on a CPU with AMX). Newer kernels (Debian testing's 7.2)
size the buffer at run time.

The kernel's modules (``vcan``, ``can``, ``can-raw``, ``can-bcm`` and what they depend on)
are found beside it, in ``PREFIX/lib/uml/modules/VERSION`` (``PREFIX`` = the directory above
the kernel's ``bin``), and loaded by the guest with ``busybox insmod`` in the order of
``modules.dep``: the guest needs no ``kmod`` and no ``/lib/modules``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import subprocess
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

from virtual_bus.errors import VirtualBusError

#: Modules the guest loads for SocketCAN with vcan (their dependencies are added).
CAN_MODULES = ("vcan", "can-raw", "can-bcm")
#: The kernel's line when it cannot restore a process's FPU state (see the module docstring).
FP_REGS_PANIC = "ptrace set fp regs failed"
#: Debian's archive and suite of the kernel :func:`fetch_kernel` downloads.
DEBIAN_ARCHIVE = "http://deb.debian.org/debian"
DEBIAN_SUITE = "testing"
DEBIAN_KEYRING = Path("/usr/share/keyrings/debian-archive-keyring.gpg")
FETCH_PACKAGES = ("user-mode-linux", "libc6")

Runner = Callable[[Sequence[str], Path | None], "subprocess.CompletedProcess[str]"]


class GuestProblem(Enum):
    """Why a guest cannot run (:class:`GuestError`)."""

    NO_KERNEL = "no User-mode Linux kernel"
    KERNEL_CANNOT_BOOT = "the kernel does not boot here"
    NO_MODULES = "the kernel's CAN modules are missing"
    MISSING_TOOL = "a program the guest needs is missing"
    FETCH_FAILED = "the kernel could not be fetched"
    SETUP_FAILED = "the guest could not set up vcan0"
    STALLED = "the guest stopped making progress"
    CRASHED = "the guest ended before its command did"
    NOT_LINUX = "User-mode Linux runs on Linux x86-64 only"


class GuestError(VirtualBusError, OSError):
    """The guest could not run a command; ``problem`` (:class:`GuestProblem`) says why."""

    def __init__(self, message: str, *, problem: GuestProblem) -> None:
        super().__init__(message)
        self.problem = problem

    def __str__(self) -> str:
        return str(self.args[0])


@dataclass(frozen=True)
class Kernel:
    """A UML kernel: its file, version (``linux.uml --version``), module tree and where it
    came from (for messages)."""

    path: Path
    version: str
    modules: Path
    origin: str

    def describe(self) -> str:
        return f"linux.uml {self.version} ({self.origin}, {self.path})"


def cache_dir() -> Path:
    """``$XDG_CACHE_HOME/backlash-bridge/uml`` (default ``~/.cache/backlash-bridge/uml``):
    the fetched kernel and the probe verdicts; outside any checkout."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "backlash-bridge" / "uml"


def fetched_kernel_path(cache: Path) -> Path:
    """Where :func:`fetch_kernel` puts the kernel (its modules are under the same root)."""
    return cache / "root" / "usr" / "bin" / "linux.uml"


def require_tool(name: str, package: str) -> str:
    """The path of program ``name``, or :class:`GuestError` naming the package to install."""
    found = shutil.which(name)
    if found is None:
        raise GuestError(
            f"{name} is not installed; the guest needs it (Debian/Ubuntu: apt-get install "
            f"{package})",
            problem=GuestProblem.MISSING_TOOL,
        )
    return found


def _run(args: Sequence[str], cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(list(args), cwd=cwd, capture_output=True, text=True, check=False)


def _last_line(text: str) -> str:
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1] if lines else "(no message)"


def kernel_version(path: Path, runner: Runner = _run) -> str:
    """``linux.uml --version`` (UML prints its release and exits)."""
    try:
        done = runner([str(path), "--version"], None)
    except OSError as exc:
        raise GuestError(
            f"cannot run {path}: {exc.strerror or exc}", problem=GuestProblem.KERNEL_CANNOT_BOOT
        ) from None
    version = done.stdout.strip()
    if done.returncode != 0 or not version or len(version.split()) != 1:
        raise GuestError(
            f"{path} is not a User-mode Linux kernel: `{path} --version` said "
            f"{_last_line(done.stdout + done.stderr)!r} (exit {done.returncode})",
            problem=GuestProblem.KERNEL_CANNOT_BOOT,
        )
    return version


def modules_dir(path: Path, version: str) -> Path:
    """``PREFIX/lib/uml/modules/VERSION`` of the kernel at ``PREFIX/bin/linux.uml``."""
    return path.resolve().parent.parent / "lib" / "uml" / "modules" / version


def module_order(modules: Path, wanted: Sequence[str] = CAN_MODULES) -> list[Path]:
    """The ``.ko`` files to load for ``wanted`` (names as ``modinfo`` gives them, ``-`` or
    ``_``), dependencies first, from ``modules.dep``; modules built into the kernel
    (``modules.builtin``) need no file. Raises :class:`GuestError` when one is neither."""
    dep_file = modules / "modules.dep"
    if not dep_file.is_file():
        raise GuestError(
            f"no kernel modules at {modules} (modules.dep missing): the guest cannot load vcan",
            problem=GuestProblem.NO_MODULES,
        )

    def key(name: str) -> str:
        return name.replace("_", "-")

    def stem(rel: str) -> str:
        base = rel.rsplit("/", 1)[-1]
        return key(base.split(".ko", 1)[0])

    deps: dict[str, tuple[str, list[str]]] = {}
    for line in dep_file.read_text().splitlines():
        if ":" not in line:
            continue
        target, rest = line.split(":", 1)
        deps[stem(target)] = (target.strip(), [stem(d) for d in rest.split()])
    builtin_file = modules / "modules.builtin"
    builtin = set()
    if builtin_file.is_file():
        builtin = {stem(line) for line in builtin_file.read_text().split()}
    order: list[Path] = []
    seen: set[str] = set()

    def visit(name: str) -> None:
        if name in seen:
            return
        seen.add(name)
        if name in builtin:
            return
        if name not in deps:
            raise GuestError(
                f"the kernel at {modules.parent.parent.parent.parent} has no module {name!r} "
                f"(not in {dep_file}); it cannot give the guest SocketCAN",
                problem=GuestProblem.NO_MODULES,
            )
        rel, needs = deps[name]
        # modules.dep lists a module's dependencies so that the last one is loaded first
        for dep in reversed(needs):
            visit(dep)
        order.append(modules / rel)

    for name in wanted:
        visit(key(name))
    return order


def describe_kernel(path: Path, origin: str, runner: Runner = _run) -> Kernel:
    """A :class:`Kernel` for the file ``path`` (its version and module tree checked)."""
    if not path.is_file():
        raise GuestError(f"{path}: no such kernel file", problem=GuestProblem.NO_KERNEL)
    if not os.access(path, os.X_OK):
        raise GuestError(f"{path}: not executable", problem=GuestProblem.KERNEL_CANNOT_BOOT)
    version = kernel_version(path, runner)
    kernel = Kernel(path, version, modules_dir(path, version), origin)
    module_order(kernel.modules)  # its CAN modules are there
    return kernel


# --- probe verdicts -----------------------------------------------------------------------------
def cpu_flags() -> str:
    """The first ``flags`` line of /proc/cpuinfo (what decides whether a kernel boots)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return ""


def _probe_key(path: Path) -> str:
    st = path.resolve().stat()
    flags = hashlib.sha256(cpu_flags().encode()).hexdigest()[:16]
    return f"{path.resolve()}|{st.st_size}|{st.st_mtime_ns}|{flags}"


def diagnose_console(console: str) -> str:
    """Why a kernel whose console is ``console`` did not run its init: one sentence."""
    if FP_REGS_PANIC in console:
        return (
            f"it panics at its first process ('userspace - {FP_REGS_PANIC}'): this kernel "
            "keeps a fixed-size FPU buffer smaller than this CPU's XSAVE state (AMX); newer "
            "UML kernels (Debian testing's 7.2) size it at run time"
        )
    if "Bus error - the host /dev/shm or /tmp" in console:
        return (
            "its memory file ran out of room: the guest's memory lives in a file in $TMPDIR "
            "(else /dev/shm); give it more room there or ask for less (--mem)"
        )
    for line in console.splitlines():
        if "Kernel panic" in line:
            return f"it panics: {line.strip()}"
    return f"it did not start its init; its console ended with: {_last_line(console)}"


class ProbeCache:
    """Probe verdicts (``None`` = boots; else why not) kept in ``probes.json``."""

    def __init__(self, cache: Path) -> None:
        self.file = cache / "probes.json"

    def _load(self) -> dict[str, str | None]:
        try:
            data = json.loads(self.file.read_text())
        except (OSError, ValueError):
            return {}
        return data if isinstance(data, dict) else {}

    def get(self, path: Path) -> tuple[bool, str | None]:
        data = self._load()
        key = _probe_key(path)
        return (key in data, data.get(key))

    def put(self, path: Path, verdict: str | None) -> None:
        data = self._load()
        data[_probe_key(path)] = verdict
        with contextlib.suppress(OSError):
            self.file.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.file.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_text(json.dumps(data, indent=1))
            tmp.replace(self.file)


Booter = Callable[[Kernel], str | None]


def probe(kernel: Kernel, boot: Booter, cache: ProbeCache | None = None) -> str | None:
    """Whether ``kernel`` boots here: ``None``, or why not. ``boot`` boots it once with an
    init that only reports back (:func:`virtual_bus.guest.boot_probe`); the verdict is kept
    in ``cache`` so each kernel file is booted once per CPU type."""
    if cache is not None:
        known, verdict = cache.get(kernel.path)
        if known:
            return verdict
    verdict = boot(kernel)
    if cache is not None:
        cache.put(kernel.path, verdict)
    return verdict


def find_kernel(
    explicit: Path | None,
    boot: Booter,
    cache: Path | None = None,
    runner: Runner = _run,
) -> Kernel:
    """The kernel to boot (see the module docstring); :class:`GuestError` with every reason
    when none will do."""
    if os.uname().sysname != "Linux" or os.uname().machine != "x86_64":
        raise GuestError(
            f"User-mode Linux runs on Linux x86-64; this is {os.uname().sysname} "
            f"{os.uname().machine}",
            problem=GuestProblem.NOT_LINUX,
        )
    cache = cache if cache is not None else cache_dir()
    verdicts = ProbeCache(cache)
    if explicit is not None:
        kernel = describe_kernel(explicit, "--kernel", runner)
        reason = probe(kernel, boot, verdicts)
        if reason is not None:
            raise GuestError(
                f"{kernel.describe()} cannot run here: {reason}",
                problem=GuestProblem.KERNEL_CANNOT_BOOT,
            )
        return kernel
    reasons = []
    on_path = shutil.which("linux.uml")
    candidates: list[tuple[Path, str]] = []
    if on_path is not None:
        candidates.append((Path(on_path), "on PATH"))
    else:
        reasons.append("no linux.uml on PATH (package user-mode-linux)")
    fetched = fetched_kernel_path(cache)
    if fetched.is_file():
        candidates.append((fetched, fetched_origin(cache)))
    for path, origin in candidates:
        try:
            kernel = describe_kernel(path, origin, runner)
        except GuestError as exc:
            reasons.append(str(exc))
            continue
        reason = probe(kernel, boot, verdicts)
        if reason is None:
            return kernel
        reasons.append(f"{kernel.describe()} cannot run here: {reason}")
    if not fetched.is_file():
        reasons.append(
            f"none fetched into {cache} yet: `python -m virtual_bus guest --fetch-kernel` "
            f"gets Debian {DEBIAN_SUITE}'s"
        )
    raise GuestError(
        "no User-mode Linux kernel that boots here: " + "; ".join(reasons),
        problem=GuestProblem.NO_KERNEL,
    )


# --- fetching -----------------------------------------------------------------------------------
def _apt_options(apt_dir: Path) -> list[str]:
    """apt-get options for a private package list (only Debian's testing suite): nothing of
    the host's apt state is read or written."""
    opts = {
        "Dir::Etc::SourceList": "/dev/null",
        "Dir::Etc::SourceParts": str(apt_dir / "sources"),
        "Dir::State::Lists": str(apt_dir / "lists"),
        "Dir::Cache": str(apt_dir / "cache"),
        "Dir::State::status": "/dev/null",
    }
    if os.geteuid() == 0:
        # the private folders are not the _apt user's to write into
        opts["APT::Sandbox::User"] = "root"
    return [arg for k, v in opts.items() for arg in ("-o", f"{k}={v}")]


def _checked(runner: Runner, args: Sequence[str], cwd: Path | None, what: str) -> None:
    done = runner(args, cwd)
    if done.returncode != 0:
        raise GuestError(
            f"{what} failed (`{' '.join(args[:2])} ...`, exit {done.returncode}): "
            f"{_last_line(done.stderr or done.stdout)}",
            problem=GuestProblem.FETCH_FAILED,
        )


def fetch_kernel(cache: Path | None = None, runner: Runner = _run) -> Kernel:
    """Download Debian testing's ``user-mode-linux`` and ``libc6`` with apt-get (a private
    package list, nothing installed), unpack both into ``CACHE/root`` and point the kernel at
    that libc (``patchelf --set-interpreter``, ``--set-rpath``). Returns the :class:`Kernel`
    (not yet probed). A complete earlier fetch is replaced only when this one succeeds."""
    cache = cache if cache is not None else cache_dir()
    for tool in ("apt-get", "dpkg-deb"):
        if shutil.which(tool) is None:
            raise GuestError(
                f"fetching a kernel needs {tool} (Debian, Ubuntu) and there is none here: "
                "install user-mode-linux by other means and give --kernel PATH",
                problem=GuestProblem.MISSING_TOOL,
            )
    require_tool("patchelf", "patchelf")
    if not DEBIAN_KEYRING.is_file():
        raise GuestError(
            f"{DEBIAN_KEYRING} is missing: apt cannot check Debian's archive "
            "(apt-get install debian-archive-keyring)",
            problem=GuestProblem.MISSING_TOOL,
        )
    try:
        cache.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix="fetch-", dir=cache))
    except OSError as exc:
        raise GuestError(
            f"cannot write the cache folder {cache}: {exc.strerror or exc}",
            problem=GuestProblem.FETCH_FAILED,
        ) from None
    try:
        apt_dir = work / "apt"
        for sub in ("sources", "lists/partial", "cache/archives/partial", "debs"):
            (apt_dir / sub).mkdir(parents=True)
        (apt_dir / "sources" / "debian-testing.sources").write_text(
            f"Types: deb\nURIs: {DEBIAN_ARCHIVE}\nSuites: {DEBIAN_SUITE}\n"
            f"Components: main\nSigned-By: {DEBIAN_KEYRING}\n"
        )
        opts = _apt_options(apt_dir)
        _checked(
            runner, ["apt-get", *opts, "update"], None, f"apt-get update of Debian {DEBIAN_SUITE}"
        )
        _checked(
            runner,
            ["apt-get", *opts, "download", *FETCH_PACKAGES],
            apt_dir / "debs",
            f"apt-get download {' '.join(FETCH_PACKAGES)}",
        )
        root = work / "root"
        debs = sorted((apt_dir / "debs").glob("*.deb"))
        names = " ".join(d.name for d in debs)
        for package in FETCH_PACKAGES:
            if not any(d.name.startswith(f"{package}_") for d in debs):
                raise GuestError(
                    f"apt-get download left no {package} package (got: {names or 'nothing'})",
                    problem=GuestProblem.FETCH_FAILED,
                )
        for deb in debs:
            _checked(runner, ["dpkg-deb", "-x", str(deb), str(root)], None, f"unpacking {deb}")
        # final place first: patchelf writes absolute paths into the kernel
        final_root = cache / "root"
        staged = cache / "root.old"
        shutil.rmtree(staged, ignore_errors=True)
        if final_root.exists():
            final_root.rename(staged)
        root.rename(final_root)
        libdir = final_root / "usr" / "lib" / "x86_64-linux-gnu"
        kernel_path = fetched_kernel_path(cache)
        try:
            _checked(
                runner,
                [
                    "patchelf",
                    "--set-interpreter",
                    str(libdir / "ld-linux-x86-64.so.2"),
                    "--set-rpath",
                    str(libdir),
                    str(kernel_path),
                ],
                None,
                "patchelf of the fetched kernel",
            )
            kernel = describe_kernel(
                kernel_path, f"fetched from Debian {DEBIAN_SUITE}: {names}", runner
            )
        except GuestError:
            shutil.rmtree(final_root, ignore_errors=True)
            if staged.exists():
                staged.rename(final_root)
            raise
        shutil.rmtree(staged, ignore_errors=True)
        (cache / "fetched.json").write_text(json.dumps({"packages": [d.name for d in debs]}))
        return kernel
    finally:
        shutil.rmtree(work, ignore_errors=True)


def fetched_origin(cache: Path) -> str:
    """What :func:`fetch_kernel` recorded about the kernel in ``cache`` (for messages)."""
    try:
        names = json.loads((cache / "fetched.json").read_text())["packages"]
        return f"fetched from Debian {DEBIAN_SUITE}: {' '.join(names)}"
    except (OSError, ValueError, KeyError, TypeError):
        return "fetched"
