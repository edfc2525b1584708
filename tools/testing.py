"""``python3 dev.py test [pytest args]``: pytest in the environment; where this kernel has no
SocketCAN, in two parts side by side (the host runs every test not marked vcan, a User-mode
Linux guest the tests marked vcan on its vcan0) and one summary of both (docs/virtual_bus.md).
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from tools.checkout import PY, ROOT, say

#: tests/conftest.py: "without" deselects the tests marked vcan, "only" keeps just them.
VCAN_PART_ENV = "BACKLASH_BRIDGE_VCAN_PART"
#: pytest's exit status when it collected nothing (a part whose selection is empty).
PYTEST_NO_TESTS = 5


def host_vcan_problem() -> str | None:
    """None when this host runs the vcan tests itself (a raw CAN socket opens and vcan0
    exists), else why not."""
    try:
        sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except (AttributeError, OSError) as exc:
        why = getattr(exc, "strerror", None) or exc
        return f"this kernel has no SocketCAN (socket(AF_CAN, SOCK_RAW, CAN_RAW): {why})"
    sock.close()
    if not Path("/sys/class/net/vcan0").exists():
        return "there is no vcan0 here (sudo python3 dev.py python -m virtual_bus setup vcan0)"
    return None


@dataclass(frozen=True)
class Counts:
    """Outcomes of one pytest run, read from its JUnit XML file."""

    passed: int = 0
    failed: int = 0
    skipped: int = 0
    seconds: float = 0.0

    @classmethod
    def from_junit(cls, path: Path) -> Counts | None:
        try:
            root = ET.parse(path).getroot()
        except (OSError, ET.ParseError):
            return None
        suites = [root] if root.tag == "testsuite" else list(root.iter("testsuite"))
        tests = sum(int(s.get("tests", 0)) for s in suites)
        failed = sum(int(s.get("failures", 0)) + int(s.get("errors", 0)) for s in suites)
        skipped = sum(int(s.get("skipped", 0)) for s in suites)
        seconds = sum(float(s.get("time", 0.0)) for s in suites)
        return cls(tests - failed - skipped, failed, skipped, seconds)

    def __add__(self, other: Counts) -> Counts:
        return Counts(
            self.passed + other.passed,
            self.failed + other.failed,
            self.skipped + other.skipped,
            max(self.seconds, other.seconds),
        )

    def text(self) -> str:
        parts = [f"{self.passed} passed"]
        parts += [f"{self.failed} failed"] if self.failed else []
        parts += [f"{self.skipped} skipped"] if self.skipped else []
        return ", ".join(parts)


def combined_status(host: int, guest: int) -> int:
    """One exit status for the two parts: 0 when both passed (a part that selected no test
    counts as passed when the other ran), else the first failure's."""
    if host == guest == PYTEST_NO_TESTS:
        return PYTEST_NO_TESTS
    for code in (host, guest):
        if code not in (0, PYTEST_NO_TESTS):
            return code
    return 0


def _guest_problem() -> str | None:
    """None when `virtual_bus guest` has a kernel that boots here, else its one line."""
    done = subprocess.run(
        [str(PY), "-m", "virtual_bus", "guest", "--check", "--quiet"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    if done.returncode == 0:
        return None
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()] or ["(no message)"]
    return lines[-1].split(": error: ", 1)[-1]


def run(rest: Sequence[str], quiet: bool, extra_env: dict[str, str] | None = None) -> int:
    """pytest ``rest``; where the host has no SocketCAN, in two parts (see the module
    docstring and :func:`_two_parts`). ``extra_env``: added to every part's environment."""
    env = {**os.environ, **(extra_env or {})}
    pytest = [str(PY), "-m", "pytest", *rest]
    problem = host_vcan_problem()
    if problem is None:
        return subprocess.run(pytest, cwd=ROOT, env=env).returncode
    guest = _guest_problem()
    if guest is None:
        return _two_parts(rest, problem, quiet, env)
    say(f"the tests marked vcan will be skipped: {problem}, and {guest}", False)
    code = subprocess.run(pytest, cwd=ROOT, env=env).returncode
    if os.environ.get("CI") == "true":
        say("CI needs the vcan tests: failing (see the line above)", False)
        return code or 1
    return code


def _two_parts(rest: Sequence[str], problem: str, quiet: bool, env: dict[str, str]) -> int:
    """The host runs every test not marked vcan while a User-mode Linux guest
    (``python -m virtual_bus guest``) runs the tests marked vcan on its vcan0: one CPU
    each. The host's output comes as it runs, the guest's after it; then one summary of
    both parts (from their JUnit XML files)."""
    say(
        f"{problem}: the tests marked vcan run in a User-mode Linux guest on its vcan0 "
        "(python -m virtual_bus guest), the others here, side by side",
        quiet,
    )
    with tempfile.TemporaryDirectory(prefix="dev-test-") as tmp_dir:
        tmp = Path(tmp_dir)
        (tmp / "guest-tmp").mkdir()
        host_xml, guest_xml, guest_log = tmp / "host.xml", tmp / "guest.xml", tmp / "guest.log"
        guest_cmd = [
            str(PY),
            "-m",
            "virtual_bus",
            "guest",
            "--",
            str(PY),
            "-m",
            "pytest",
            *rest,
            "-o",
            "cache_dir=.pytest_cache/guest",
            f"--junitxml={guest_xml}",
        ]
        guest_env = {
            **env,
            VCAN_PART_ENV: "only",
            "TMPDIR": str(tmp / "guest-tmp"),  # pytest's tmp_path apart from the host's
            "PYTHONUNBUFFERED": "1",  # its progress is the guest's sign of life
        }
        t0 = time.monotonic()
        with guest_log.open("wb") as log:
            guest = subprocess.Popen(guest_cmd, cwd=ROOT, env=guest_env, stdout=log, stderr=log)
            try:
                host_code = subprocess.run(
                    [str(PY), "-m", "pytest", *rest, f"--junitxml={host_xml}"],
                    cwd=ROOT,
                    env={**env, VCAN_PART_ENV: "without"},
                ).returncode
                host_s = time.monotonic() - t0
                if guest.poll() is None:
                    say("waiting for the guest's part (the tests marked vcan)", quiet)
                guest_code = guest.wait()
            finally:
                if guest.poll() is None:
                    guest.terminate()
                    guest.wait()
        guest_s = time.monotonic() - t0
        print("\n--- the tests marked vcan, in the User-mode Linux guest ---", flush=True)
        sys.stdout.buffer.write(guest_log.read_bytes())
        sys.stdout.flush()
        host, in_guest = Counts.from_junit(host_xml), Counts.from_junit(guest_xml)
        lines = [
            f"here, without the vcan tests: {host.text() if host else 'no result'} "
            f"(exit {host_code}, {host_s:.0f} s)",
            f"in the guest, on vcan0: {in_guest.text() if in_guest else 'no result'} "
            f"(exit {guest_code}, {guest_s:.0f} s)",
        ]
        if host and in_guest:
            lines.append(f"together: {(host + in_guest).text()}")
        code = combined_status(host_code, guest_code)
        print(f"dev.py test: {'; '.join(lines)}", flush=True)
        return code
