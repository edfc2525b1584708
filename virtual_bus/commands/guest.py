"""``python -m virtual_bus guest [--kernel PATH] [--mem MB] -- COMMAND ARGS...``: run a
command in a User-mode Linux guest with SocketCAN vcan0 up (docs/virtual_bus.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from cmdline import cli
from cmdline.progress import Progress
from virtual_bus.guest.kernel import (
    GuestError,
    GuestProblem,
    ProbeCache,
    cache_dir,
    fetch_kernel,
    find_kernel,
    probe,
)
from virtual_bus.guest.vm import (
    DEFAULT_MEM_MB,
    DEFAULT_STALL_S,
    MEM_RANGE_MB,
    GuestConfig,
    boot_probe,
    default_streams,
    run_in_guest,
)

NAME = "guest"
HELP = "run a command in a User-mode Linux guest with SocketCAN vcan0 up (no SocketCAN needed here)"
DESCRIPTION = (
    "Boots a User-mode Linux kernel (linux.uml on PATH if it boots on this CPU, else the "
    "one --fetch-kernel put in the cache) with this machine's files as its root, brings up "
    "vcan0, runs COMMAND in the current directory with the current environment and exits "
    "with its exit status. Guest problems: one line, exit 1."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--kernel", type=cli.existing_file, default=None, help="the UML kernel to boot"
    )
    parser.add_argument(
        "--mem",
        type=cli.bounded_int(*MEM_RANGE_MB),
        default=DEFAULT_MEM_MB,
        metavar="MB",
        help=f"guest memory, MB (default {DEFAULT_MEM_MB})",
    )
    parser.add_argument(
        "--stall-s",
        type=cli.positive_float,
        default=DEFAULT_STALL_S,
        metavar="S",
        help="stop the guest when it writes nothing (console, output) for this long "
        f"(default {DEFAULT_STALL_S:g} s)",
    )
    parser.add_argument(
        "--fetch-kernel",
        action="store_true",
        help="make sure a kernel that boots here is at hand: fetch Debian testing's "
        f"user-mode-linux into {cache_dir()} (apt-get, dpkg-deb, patchelf) unless one boots",
    )
    parser.add_argument(
        "--check",
        action="store_true",
        help="say which kernel would boot (or why none) and exit 0 (or 1)",
    )
    parser.add_argument(
        "argv", nargs=argparse.REMAINDER, metavar="-- COMMAND ARGS", help="what to run"
    )


def run(args: argparse.Namespace) -> int:
    progress = Progress("virtual_bus guest", quiet=args.quiet)
    command = list(args.argv)
    if command and command[0] == "--":
        command = command[1:]
    if not command and not (args.fetch_kernel or args.check):
        raise cli.UsageError("give a command after --, or --fetch-kernel, or --check")
    if command and (args.fetch_kernel or args.check):
        raise cli.UsageError("--fetch-kernel and --check take no command")
    if args.fetch_kernel:
        return _fetch(args, progress)
    kernel = find_kernel(args.kernel, boot_probe)
    if args.check:
        print(f"guest kernel: {kernel.describe()}")
        return 0
    config = GuestConfig(mem_mb=args.mem, stall_s=args.stall_s, cwd=Path.cwd())
    progress.stage(f"booting {kernel.describe()}")
    out, err = default_streams()
    result = run_in_guest(command, kernel, config, out, err)
    progress.stage(
        f"booted in {result.boot_s:.1f} s; `{Path(command[0]).name}` exited "
        f"{result.returncode}; {result.wall_s:.1f} s in the guest"
    )
    return result.returncode


def _fetch(args: argparse.Namespace, progress: Progress) -> int:
    if args.kernel is not None:
        raise cli.UsageError("--fetch-kernel fetches a kernel; --kernel names one: not both")
    try:
        kernel = find_kernel(None, boot_probe)
    except GuestError as exc:
        if exc.problem is not GuestProblem.NO_KERNEL:
            raise
        progress.stage(f"no kernel boots here yet ({exc}); fetching Debian testing's")
        kernel = fetch_kernel()
        reason = probe(kernel, boot_probe, ProbeCache(cache_dir()))
        if reason is not None:
            raise GuestError(
                f"the fetched {kernel.describe()} cannot run here either: {reason}",
                problem=GuestProblem.KERNEL_CANNOT_BOOT,
            ) from None
    print(f"guest kernel: {kernel.describe()}")
    return 0
