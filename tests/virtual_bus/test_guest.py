"""``python -m virtual_bus guest``: a command in a User-mode Linux guest with vcan0 up.

Checked against the real thing where a kernel that boots here is at hand (``linux.uml`` on
PATH or one fetched with ``--fetch-kernel``; skipped with the reason otherwise): the
guest's own kernel reports vcan0 (``ip -details link``), a raw CAN socket opens there, exit
statuses and output come back, a guest that goes silent is stopped. Debian bookworm's
``linux.uml`` on a CPU with AMX is the known kernel that cannot boot: its panic line is
recognised. Bad input: one line, exit 2 (arguments) or 1 (the guest).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.paths import ROOT, checkout_env
from virtual_bus.__main__ import main
from virtual_bus.guest.kernel import (
    FP_REGS_PANIC,
    GuestError,
    GuestProblem,
    Kernel,
    cpu_flags,
    describe_kernel,
    fetch_kernel,
    find_kernel,
    module_order,
    require_tool,
)
from virtual_bus.guest.vm import GuestConfig, boot_probe, guest_env, init_script, run_in_guest


@pytest.fixture(scope="module")
def kernel() -> Kernel:
    try:
        return find_kernel(None, boot_probe)
    except GuestError as exc:
        pytest.skip(f"no User-mode Linux guest here: {exc}")


def _one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and ": error: " in err, err
    return err


# --- bad input ---------------------------------------------------------------------------------
def _exit_status(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as stop:  # argparse's refusal
        return int(stop.code or 0)


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["guest"], "give a command after --"),
        (["guest", "--mem", "10", "--", "true"], "allowed 128..65536"),
        (["guest", "--kernel", "/no/such/linux.uml", "--", "true"], "no such file"),
        (["guest", "--check", "--", "true"], "take no command"),
        (["guest", "--stall-s", "0", "--", "true"], "must be a finite number > 0"),
    ],
)
def test_bad_arguments_one_line_exit_2(
    argv: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _exit_status(argv) == 2
    assert says in _one_line_error(capsys)


def test_a_file_that_is_no_uml_kernel_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fake = tmp_path / "linux.uml"
    fake.write_text("#!/bin/sh\necho 'not a kernel' >&2; exit 3\n")
    fake.chmod(0o755)
    assert main(["guest", "--kernel", str(fake), "--", "true"]) == 1
    assert "is not a User-mode Linux kernel" in _one_line_error(capsys)


def test_a_missing_program_names_its_package() -> None:
    with pytest.raises(GuestError) as err:
        require_tool("no-such-program-here", "busybox-static")
    assert err.value.problem is GuestProblem.MISSING_TOOL
    assert "apt-get install busybox-static" in str(err.value)
    assert isinstance(err.value, OSError)


def test_fetching_without_apt_says_what_to_do_and_changes_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))  # no apt-get, dpkg-deb, patchelf
    with pytest.raises(GuestError, match="needs apt-get") as err:
        fetch_kernel(tmp_path / "cache")
    assert err.value.problem is GuestProblem.MISSING_TOOL and "--kernel PATH" in str(err.value)
    assert not (tmp_path / "cache").exists()


# --- the kernel's modules ----------------------------------------------------------------------
def test_module_order_puts_dependencies_first_and_skips_built_in(tmp_path: Path) -> None:
    """modules.dep as depmod writes it (a module's dependencies, the last loaded first)."""
    (tmp_path / "modules.dep").write_text(
        "kernel/net/can/can.ko:\n"
        "kernel/drivers/net/can/vcan.ko: kernel/drivers/net/can/dev/can-dev.ko\n"
        "kernel/drivers/net/can/dev/can-dev.ko:\n"
        "kernel/net/can/can-raw.ko: kernel/net/can/can.ko\n"
    )
    (tmp_path / "modules.builtin").write_text("kernel/net/can/can-bcm.ko\n")
    order = [p.relative_to(tmp_path).as_posix() for p in module_order(tmp_path)]
    assert order == [
        "kernel/drivers/net/can/dev/can-dev.ko",
        "kernel/drivers/net/can/vcan.ko",
        "kernel/net/can/can.ko",
        "kernel/net/can/can-raw.ko",
    ]
    (tmp_path / "modules.builtin").write_text("")
    with pytest.raises(GuestError, match="no module 'can-bcm'") as err:
        module_order(tmp_path)
    assert err.value.problem is GuestProblem.NO_MODULES


def test_no_module_tree_is_said(tmp_path: Path) -> None:
    with pytest.raises(GuestError, match=r"modules\.dep missing"):
        module_order(tmp_path / "7.2.7")


def test_init_script_quotes_the_command_and_environment(tmp_path: Path) -> None:
    (tmp_path / "modules.dep").write_text("a/vcan.ko:\na/can-raw.ko:\na/can-bcm.ko:\n")
    kernel = Kernel(Path("/k/linux.uml"), "7.2.7", tmp_path, "test")
    script = init_script(
        kernel,
        ["printf", "%s", "it's $HOME"],
        tmp_path,
        Path("/a dir"),
        {"X": "a b'c"},
        ("vcan0",),
        "/bin/busybox",
    )
    assert "printf %s 'it'\"'\"'s $HOME'" in script
    assert "export X='a b'\"'\"'c'" in script
    assert "cd '/a dir'" in script


def test_guest_environment_leaves_host_sockets_out() -> None:
    env = guest_env({"SSH_AUTH_SOCK": "/run/x", "PATH": "/bin", "A-B": "1", "HOME": "/root"})
    assert env == {"PATH": "/bin", "HOME": "/root"}


# --- the kernel Debian bookworm ships, on a CPU with AMX ------------------------------------------
@pytest.mark.skipif(
    shutil.which("linux.uml") is None or "amx_tile" not in cpu_flags(),
    reason="needs linux.uml on PATH and a CPU with AMX (the known panic)",
)
def test_the_amx_panic_of_an_old_kernel_is_named_in_one_sentence() -> None:
    path = Path(shutil.which("linux.uml") or "")
    kernel = describe_kernel(path, "on PATH")
    if kernel.version.split(".")[0] not in ("5", "6"):
        pytest.skip(f"linux.uml on PATH is {kernel.version}: not one of the old kernels")
    reason = boot_probe(kernel)
    if reason is None:
        pytest.skip(f"linux.uml {kernel.version} boots on this CPU")
    assert FP_REGS_PANIC in reason and "AMX" in reason and "\n" not in reason


# --- a real guest --------------------------------------------------------------------------------
def test_the_guest_has_vcan0_and_gives_back_exit_status_and_output(kernel: Kernel) -> None:
    code = (
        "import socket, subprocess, sys\n"
        "s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)\n"
        "s.bind(('vcan0',))\n"
        "print(subprocess.run(['ip', '-details', 'link', 'show', 'vcan0'],"
        " capture_output=True, text=True).stdout)\n"
        "print('to stderr', file=sys.stderr)\n"
        "sys.exit(7)\n"
    )
    result = run_in_guest([sys.executable, "-c", code], kernel, GuestConfig(mem_mb=512))
    assert result.returncode == 7
    assert b"vcan0:" in result.stdout and b"link/can" in result.stdout
    assert b" vcan " in result.stdout  # the link kind ip reports
    assert result.stderr == b"to stderr\n"
    assert 0 < result.boot_s <= result.wall_s


def test_environment_and_directory_come_along(kernel: Kernel, tmp_path: Path) -> None:
    env = {**os.environ, "GUEST_TEST_VALUE": "a b'c\"$d"}
    result = run_in_guest(
        ["sh", "-c", 'printf "%s|%s" "$GUEST_TEST_VALUE" "$(pwd)"; touch made-here'],
        kernel,
        GuestConfig(mem_mb=256, cwd=tmp_path, env=env),
    )
    assert result.returncode == 0
    assert result.stdout.decode() == f"a b'c\"$d|{tmp_path}"
    assert (tmp_path / "made-here").is_file()  # the host's files, written in the guest


def test_a_command_that_does_not_exist_is_its_shells_127(kernel: Kernel) -> None:
    result = run_in_guest(["no-such-command-xyz"], kernel, GuestConfig(mem_mb=256))
    assert result.returncode == 127 and b"not found" in result.stderr


def test_a_silent_guest_is_stopped_by_its_own_progress(kernel: Kernel) -> None:
    """Output resets the bound: 3 lines 1 s apart pass a 2 s bound, then silence ends it."""
    script = "for i in 1 2 3; do echo $i; sleep 1; done; sleep 600"
    with pytest.raises(GuestError) as err:
        run_in_guest(["sh", "-c", script], kernel, GuestConfig(mem_mb=256, stall_s=2.5))
    assert err.value.problem is GuestProblem.STALLED
    assert "wrote nothing for 2.5 s" in str(err.value) and "last line: 3" in str(err.value)


def test_the_command_line_runs_the_guest(kernel: Kernel) -> None:
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "virtual_bus",
            "guest",
            "--mem",
            "256",
            "--",
            "sh",
            "-c",
            "cat /sys/class/net/vcan0/type; exit 4",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=checkout_env(),
    )
    assert done.returncode == 4
    assert done.stdout == "280\n"  # ARPHRD_CAN
    assert "booted in" in done.stderr
