#!/usr/bin/env python3
"""Create or reuse the project's virtual environment, then run the main job, tests or benchmarks.

    python3 dev.py [--quiet] demo [ARGS]    the main job (see README)
    python3 dev.py [--quiet] test [ARGS]    the whole test suite (pytest ARGS); where this
                                            kernel has no SocketCAN, the tests marked vcan
                                            run in a User-mode Linux guest on a real vcan0
    python3 dev.py [--quiet] bench [ARGS]   re-measure the README's figures (--help)
    python3 dev.py [--quiet] first-run      the demo and the start-up tests from an empty
                                            numba cache with every CPU busy (--help)
    python3 dev.py [--quiet] python ARGS    any command in the environment

Only the standard library is used here, so this runs on a fresh Python 3.11.
The environment lives in `.venv/`; it is (re)installed when `pyproject.toml` changes, with
pip's own progress shown (`--quiet`: none).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import venv
import xml.etree.ElementTree as ET
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
STAMP = VENV / ".installed-from"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
PY = BIN / ("python.exe" if os.name == "nt" else "python")
README = ROOT / "README.md"
BEGIN, END = "<!-- bench:begin -->", "<!-- bench:end -->"


def _say(text: str, quiet: bool) -> None:
    if not quiet:
        print(f"dev.py: {text}", file=sys.stderr, flush=True)


def _ensure_venv(quiet: bool) -> None:
    want = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    if PY.exists() and STAMP.exists() and STAMP.read_text().strip() == want:
        return
    t0 = time.monotonic()
    if not PY.exists():
        _say(f"creating the virtual environment {VENV} (with pip, ~10 s)", quiet)
        venv.EnvBuilder(with_pip=True).create(VENV)
    _say(
        "installing the project and its dependencies (numpy, scipy, numba, matplotlib, "
        "python-can, canopen, ...): the first time ~2 min, pip's progress follows",
        quiet,
    )
    pip = [str(PY), "-m", "pip", "install", "--disable-pip-version-check"]
    pip += ["-q"] if quiet else ["--progress-bar", "on" if sys.stderr.isatty() else "off"]
    subprocess.run([*pip, "-e", f"{ROOT}[test]"], check=True, stdout=sys.stderr)
    STAMP.write_text(want + "\n")
    _say(f"environment ready ({time.monotonic() - t0:.0f} s)", quiet)


# --- test --------------------------------------------------------------------------------------
#: tests/conftest.py: "without" deselects the tests marked vcan, "only" keeps just them.
VCAN_PART_ENV = "BACKLASH_BRIDGE_VCAN_PART"
#: pytest's exit status when it collected nothing (a part whose selection is empty).
PYTEST_NO_TESTS = 5


def host_vcan_problem() -> str | None:
    """None when this host runs the vcan tests itself (a raw CAN socket opens and vcan0
    exists), else why not."""
    import socket

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


def test(rest: Sequence[str], quiet: bool, extra_env: dict[str, str] | None = None) -> int:
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
    _say(f"the tests marked vcan will be skipped: {problem}, and {guest}", False)
    code = subprocess.run(pytest, cwd=ROOT, env=env).returncode
    if os.environ.get("CI") == "true":
        _say("CI needs the vcan tests: failing (see the line above)", False)
        return code or 1
    return code


def _two_parts(rest: Sequence[str], problem: str, quiet: bool, env: dict[str, str]) -> int:
    """The host runs every test not marked vcan while a User-mode Linux guest
    (``python -m virtual_bus guest``) runs the tests marked vcan on its vcan0: one CPU
    each. The host's output comes as it runs, the guest's after it; then one summary of
    both parts (from their JUnit XML files)."""
    _say(
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
                    _say("waiting for the guest's part (the tests marked vcan)", quiet)
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


# --- first run on a busy machine ------------------------------------------------------------------
#: The tests a first run on a busy machine broke (issue 21) and those that start drives,
#: bridges and guests: selected by name, so that they are found wherever they live.
FIRST_RUN_TESTS = (
    "bridge_commands_run_or_refuse or loop_over_the_bus or other_pdo_numbers"
    " or sdo_configuration_while or (drive and test_process) or two_processes"
    " or compiles_before or waits_for_the_drive"
    " or candump or cangen or canbusload or lockstep_frames or persistent_pdo_loss"
)


def _demo_cmd(rest: Sequence[str], quiet: bool) -> list[str]:
    cmd = [str(PY), "-m", "hil", "demo", *(rest or ["--out", "out/demo"])]
    return [*cmd, "--quiet"] if quiet else cmd


def first_run(argv: Sequence[str], quiet: bool) -> int:
    """The README's two commands as a first run on a busy machine (issue 21): an empty numba
    cache (``NUMBA_CACHE_DIR`` a fresh folder, so every compiled function compiles) and
    every CPU kept busy by a spinning process beside them; the demo, then the tests that
    start drives and bridges (:data:`FIRST_RUN_TESTS`, or the pytest arguments given)."""
    parser = argparse.ArgumentParser(
        prog="python3 dev.py first-run",
        description="Run the demo and the start-up tests from an empty numba cache while "
        "busy processes keep every CPU loaded: what a fresh clone meets on a busy machine.",
    )
    parser.add_argument(
        "--busy",
        type=int,
        default=os.cpu_count() or 2,
        help="spinning processes beside them (default: one per CPU)",
    )
    parser.add_argument(
        "pytest_args",
        nargs=argparse.REMAINDER,
        help="pytest arguments (e.g. `tests -q` for the whole suite); default: the start-up tests",
    )
    # pytest's own options (-q, -k ...) pass through, first or not
    args, unknown = parser.parse_known_args(argv)
    if args.busy < 0:
        parser.error("--busy must be >= 0")
    pytest_args = [*unknown, *args.pytest_args] or ["-q", "-k", FIRST_RUN_TESTS]
    with tempfile.TemporaryDirectory(prefix="dev-first-run-") as tmp_dir:
        tmp = Path(tmp_dir)
        (tmp / "numba-cache").mkdir()
        env = {"NUMBA_CACHE_DIR": str(tmp / "numba-cache")}
        spin = [sys.executable, "-c", "while True: pass"]
        busy = [subprocess.Popen(spin) for _ in range(args.busy)]
        _say(f"empty numba cache {env['NUMBA_CACHE_DIR']}, {args.busy} busy processes", False)
        try:
            t0 = time.monotonic()
            demo = subprocess.run(
                _demo_cmd(["--out", str(tmp / "demo")], quiet),
                cwd=ROOT,
                env={**os.environ, **env},
                stdout=subprocess.DEVNULL,
            ).returncode
            demo_s = time.monotonic() - t0
            _say(f"first run: the demo exited {demo} after {demo_s:.0f} s", False)
            if demo != 0:
                return demo
            t0 = time.monotonic()
            code = test(pytest_args, quiet, env)
            _say(
                f"first run: the demo passed in {demo_s:.0f} s; the tests exited {code} "
                f"after {time.monotonic() - t0:.0f} s, both with {args.busy} busy processes",
                False,
            )
            return code
        finally:
            for p in busy:
                p.kill()
                p.wait()


# --- bench -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Figure:
    """One figure of a benchmark: where it is in the command's JSON (dotted keys; "wall_s" is
    the command's wall time), its unit and the factor from the JSON's SI value to that unit."""

    label: str
    keys: str
    unit: str
    scale: float = 1.0


@dataclass(frozen=True)
class Bench:
    """A command of the project (``python -m ...`` args; ``{out}`` is a fresh directory) and
    the JSON file it writes there (``result``) holding its figures; ``setup``: commands run
    before it, untimed (a setup that fails, e.g. data not present, leaves the figures out);
    ``needs``: a program it runs (not installed: the figures are left out, saying so)."""

    name: str
    args: tuple[str, ...]
    result: str
    figures: tuple[Figure, ...]
    setup: tuple[tuple[str, ...], ...] = ()
    needs: str = ""


#: The shared FMU family's seed 0 with a large free play (shared/plants/README.md).
FMU_SEED0 = ("--fmu", "{shared}/plants/axis_family.fmu", "--fmu-param", "seed=0,family=1")


def _args(args: Sequence[str], out: str) -> list[str]:
    """A bench's arguments with ``{out}`` and ``{shared}`` (the third-party folder) filled."""
    shared = os.environ.get("BACKLASH_SHARED") or str(ROOT.parent / "shared")
    return [a.replace("{out}", out).replace("{shared}", shared) for a in args]


def _shown(args: Sequence[str]) -> str:
    return " ".join(a.replace("{out}", "DIR").replace("{shared}", "../shared") for a in args)


def _benches(realtime_s: float) -> tuple[Bench, ...]:
    wall = Figure("wall time of the command", "wall_s", "s")
    rt = f"real time {realtime_s:g} s"
    cmp = "offline_comparison.max_following_error_difference"
    return (
        Bench(
            "paper",
            ("plant_sim", "paper", "--out", "{out}"),
            "summary.json",
            (
                Figure("Fig. 8 limit-cycle frequency", "runs.ordinary.dominant_frequency_hz", "Hz"),
                Figure(
                    "Fig. 8 p2p following error", "runs.ordinary.p2p_following_error", "µm", 1e6
                ),
                Figure(
                    "Fig. 9 p2p following error", "runs.regulated.p2p_following_error", "µm", 1e6
                ),
                Figure("p2p reduction by the regulator", "p2p_reduction", "%", 100.0),
                Figure("Fig. 9 lowest λ", "runs.regulated.min_lambda", "1"),
                wall,
            ),
        ),
        Bench(
            "paper-2.5ms",
            ("plant_sim", "paper", "--out", "{out}", "--position-cycle", "0.0025"),
            "summary.json",
            (
                Figure(
                    "2.5 ms: limit-cycle frequency", "runs.ordinary.dominant_frequency_hz", "Hz"
                ),
                Figure("2.5 ms: p2p reduction", "p2p_reduction", "%", 100.0),
            ),
        ),
        Bench(
            "sweep",
            ("plant_sim", "sweep", "--out", "{out}"),
            "sweep.json",
            (
                Figure("sweep: vibrating cells (of 24)", "verdicts.vibrating_cells", "cells"),
                Figure("sweep: vibrating cells in the band", "verdicts.in_band", "cells"),
                Figure("sweep: f / k_v (least squares)", "verdicts.f_over_kv", "1"),
                Figure("sweep: R² of f = c·k_v", "verdicts.f_over_kv_r2", "1"),
                Figure(
                    "sweep: spread of f over δ",
                    "verdicts.max_relative_spread_over_backlash",
                    "%",
                    100.0,
                ),
                Figure(
                    "sweep: amplitude / (δ/2), lowest",
                    "verdicts.amplitude_over_half_backlash_min",
                    "1",
                ),
                Figure(
                    "sweep: amplitude / (δ/2), highest",
                    "verdicts.amplitude_over_half_backlash_max",
                    "1",
                ),
                wall,
            ),
        ),
        Bench(
            "bridge-demo",
            ("hil", "demo", "--out", "{out}"),
            "summary.json",
            (
                Figure("over the bus: p2p reduction", "p2p_reduction", "%", 100.0),
                Figure(
                    "bus vs offline, regulated: max following-error difference",
                    f"bridge.runs.regulated.{cmp}",
                    "nm",
                    1e9,
                ),
                Figure(
                    "bus vs offline, ordinary: max following-error difference",
                    f"bridge.runs.ordinary.{cmp}",
                    "µm",
                    1e6,
                ),
                wall,
            ),
        ),
        Bench(
            "bridge-demo-fmu",
            ("hil", "demo", "--out", "{out}", *FMU_SEED0),
            "summary.json",
            (
                Figure(
                    "FMU axis over the bus: Fig. 8 limit-cycle frequency",
                    "runs.ordinary.dominant_frequency_hz",
                    "Hz",
                ),
                Figure("FMU axis over the bus: p2p reduction", "p2p_reduction", "%", 100.0),
                wall,
            ),
        ),
        Bench(
            "fmu-sweep",
            (
                "hil",
                "sweep",
                "limit-cycle",
                "--fmu",
                "{shared}/plants/axis_family.fmu",
                "--fmu-param",
                "family=1",
                "--seeds",
                "1000-1199",
                "--out",
                "{out}/sweep",
            ),
            "sweep/summary.json",
            (
                Figure(
                    "sweep of 200 FMU axes (family 1): with a sustained limit cycle",
                    "figures.with a sustained limit cycle",
                    "axes",
                ),
                Figure(
                    "sweep: of them cut by >= 90 % by the default β_T",
                    "figures.of them cut by >= 90 % by the default beta_T",
                    "axes",
                ),
                Figure("sweep: time per axis in a worker", "seconds_per_seed.median", "s"),
                wall,
            ),
        ),
        Bench(
            "emps-diagnose",
            (
                "plant_sim",
                "diagnose",
                "{out}/emps/DATA_EMPS.csv",
                "--axis",
                "config/emps_nominal.toml",
                "--out",
                "{out}/diagnosis",
            ),
            "diagnosis/report.json",
            (
                Figure("EMPS diagnosis: time of the diagnosis", "timings_s.total", "s"),
                Figure("EMPS diagnosis: its evidence stage", "timings_s.evidence", "s"),
                Figure(
                    "EMPS diagnosis: torque fit, fitted model",
                    "fit_after.motor_torque.fit_percent",
                    "%",
                ),
                wall,
            ),
            setup=(("plant_sim", "emps", "--out", "{out}/emps"),),
        ),
        Bench(
            "plant_sim-bench",
            ("plant_sim", "bench", "--all", "--json", "{out}/bench.json"),
            "bench.json",
            (
                Figure("kernel: section X real-time factor", "kernel_realtime_factor", "×"),
                Figure("solve_ivp reference: real-time factor", "reference_realtime_factor", "×"),
                Figure("kernel speed-up over the reference", "speedup_vs_reference", "×"),
                Figure("peak memory (RSS)", "peak_rss_mb", "MB"),
                Figure("section IX identification", "bench_identify.elapsed_s", "s"),
                Figure(
                    "diagnosis of a 12,500-sample recording: evidence stage (worst of 2)",
                    "bench_diagnose.worst_evidence_s",
                    "s",
                ),
                Figure(
                    "diagnosis of a 12,500-sample recording: whole (worst of 2)",
                    "bench_diagnose.worst_wall_s",
                    "s",
                ),
                wall,
            ),
        ),
        Bench(
            "bridge-bench",
            (
                "hil",
                "bench",
                "--seconds",
                f"{realtime_s:g}",
                "--json",
                "{out}/bench.json",
                *FMU_SEED0,
            ),
            "bench.json",
            (
                Figure("lockstep, full stack", "lockstep.cycles_per_s", "cycles/s"),
                Figure(
                    "lockstep, the FMU's axis (seed 0, family 1) as the drive's plant, same run",
                    "lockstep_fmu.cycles_per_s",
                    "cycles/s",
                ),
                Figure(
                    "lockstep with trace and bus log", "lockstep_recording.cycles_per_s", "cycles/s"
                ),
                Figure(
                    "solve_ivp reference in the same run: real-time factor",
                    "reference.realtime_factor",
                    "×",
                ),
                Figure(
                    "lockstep per unit of the reference's speed (host-independent)",
                    "lockstep.cycles_per_s_per_reference_factor",
                    "cycles/s per ×",
                ),
                Figure(
                    f"{rt}: SYNC-to-set-point latency median", "realtime.latency_us_median", "µs"
                ),
                Figure(f"{rt}: latency p99", "realtime.latency_us_p99", "µs"),
                Figure(f"{rt}: latency max", "realtime.latency_us_max", "µs"),
                Figure(f"{rt}: skipped SYNCs", "realtime.skipped_syncs", "SYNCs"),
                Figure(f"{rt}: cycles without all TPDOs", "realtime.missed_tpdo_cycles", "cycles"),
                wall,
            ),
        ),
        *(_realtime_bench(rate_hz, realtime_s) for rate_hz in (1000, 2000)),
        *(_host_latency_bench(rate_hz, realtime_s) for rate_hz in (1000, 2000)),
        Bench(
            "monitor",
            ("fleet", "monitor-bench", "--counts", "100,1000", "--json", "{out}/m.json"),
            "m.json",
            (
                Figure("fleet monitor, 100 recordings", "recordings_per_min.100", "recordings/min"),
                Figure(
                    "fleet monitor, 1,000 recordings", "recordings_per_min.1000", "recordings/min"
                ),
                Figure("one analysis of 25 s: peak RSS", "analysis_peak_rss_mb.25 s", "MB"),
                Figure("one analysis of 600 s: peak RSS", "analysis_peak_rss_mb.600 s", "MB"),
                wall,
            ),
        ),
    )


def _realtime_settings(rate_hz: int, seconds: float) -> tuple[str, ...]:
    """What the real-time bench and its host floor (cyclictest) run with alike: the rate, the
    length, SCHED_FIFO priority 50 on CPU 1."""
    return tuple(f"--seconds {seconds:g} --rate-hz {rate_hz} --rt-priority 50 --cpu 1".split())


def _realtime_bench(rate_hz: int, seconds: float) -> Bench:
    """The bridge alone at ``rate_hz`` with every real-time option, busy polling included
    (root: the simulated drive runs as its own process in a private network namespace, with
    the same options on the other CPU)."""
    rt = f"{rate_hz} Hz, SCHED_FIFO, {seconds:g} s"
    return Bench(
        f"bridge-realtime-{rate_hz // 1000}k",
        (
            "hil",
            "bench",
            "--skip-lockstep",
            *_realtime_settings(rate_hz, seconds),
            "--lock-memory",
            "--freeze-gc",
            "--busy-poll",
            "--json",
            "{out}/bench.json",
        ),
        "bench.json",
        (
            Figure(f"{rt}: latency median", "realtime.latency_us_median", "µs"),
            Figure(f"{rt}: latency p99", "realtime.latency_us_p99", "µs"),
            Figure(f"{rt}: latency max", "realtime.latency_us_max", "µs"),
            Figure(f"{rt}: bridge's share p99", "realtime.compute_us_p99", "µs"),
            Figure(f"{rt}: skipped SYNCs", "realtime.skipped_syncs", "SYNCs"),
            Figure(f"{rt}: cycles without all TPDOs", "realtime.missed_tpdo_cycles", "cycles"),
            Figure(f"{rt}: loop CPU per cycle", "realtime.cpu_us_per_cycle", "µs"),
            Figure(
                f"{rt}: loop CPU per cycle, share of the period",
                "realtime.cpu_fraction_of_period",
                "%",
                100.0,
            ),
            Figure(f"{rt}: the loop's work (CPU) median", "realtime.work_cpu_us_median", "µs"),
            Figure(f"{rt}: the loop's work (CPU) p99", "realtime.work_cpu_us_p99", "µs"),
            Figure(f"{rt}: drive CPU per cycle", "realtime.drive_cpu_us_per_cycle", "µs"),
            Figure(f"{rt}: skipped by the loop's own work", "realtime.own_skipped_syncs", "SYNCs"),
            Figure(f"{rt}: skipped after host stalls", "realtime.host_skipped_syncs", "SYNCs"),
            Figure(
                f"{rt}: cyclictest just before: wake-ups later than the loop's slack",
                "realtime.host_latency.over_slack",
                "wake-ups",
            ),
            Figure(
                f"{rt}: cyclictest just before: wake-ups a cycle late",
                "realtime.host_latency.late_cycles",
                "wake-ups",
            ),
            Figure(
                f"{rt}: cyclictest just before: p99", "realtime.host_latency.latency_us_p99", "µs"
            ),
        ),
    )


def _host_latency_bench(rate_hz: int, seconds: float) -> Bench:
    """cyclictest (rt-tests) with the real-time bench's settings: the floor any loop at that
    rate meets on this host (``python -m bridge host-latency``)."""
    host = f"host floor (cyclictest), {rate_hz} Hz, {seconds:g} s"
    return Bench(
        f"host-latency-{rate_hz // 1000}k",
        (
            "bridge",
            "host-latency",
            *_realtime_settings(rate_hz, seconds),
            "--json",
            "{out}/host.json",
        ),
        "host.json",
        (
            Figure(f"{host}: wake-up latency p99", "host_latency.latency_us_p99", "µs"),
            Figure(f"{host}: wake-up latency max", "host_latency.latency_us_max", "µs"),
            Figure(f"{host}: wake-ups one cycle late", "host_latency.late_cycles", "cycles"),
            Figure(f"{host}: hypervisor steal, CPU 1", "host_latency.host_steal_ms.cpu1", "ms"),
        ),
        needs="cyclictest",
    )


def _lookup(doc: object, keys: str) -> float | None:
    for key in keys.split("."):
        if not isinstance(doc, dict) or key not in doc:
            return None
        doc = doc[key]
    return float(doc) if isinstance(doc, int | float) and not isinstance(doc, bool) else None


def _run_bench(bench: Bench, quiet: bool) -> dict[str, float | None]:
    if bench.needs and shutil.which(bench.needs) is None:
        _say(f"{bench.needs} is not installed: {bench.name} left out", quiet)
        return {f.label: None for f in bench.figures}
    with tempfile.TemporaryDirectory(prefix="dev-bench-") as tmp:
        for setup in bench.setup:
            cmd = [str(PY), "-m", *_args(setup, tmp), "--quiet"]
            if subprocess.run(cmd, cwd=ROOT, stdout=subprocess.DEVNULL).returncode != 0:
                _say(f"`{' '.join(setup)}` failed: {bench.name} left out", quiet)
                return {f.label: None for f in bench.figures}
        args = _args(bench.args, tmp)
        cmd = [str(PY), "-m", *args, *(["--quiet"] if quiet else [])]
        t0 = time.perf_counter()
        done = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        if done.returncode != 0:
            raise SystemExit(f"dev.py bench: `{' '.join(args)}` failed (exit {done.returncode})")
        doc = json.loads((Path(tmp) / bench.result).read_text())
    doc["wall_s"] = wall
    return {f.label: _lookup(doc, f.keys) for f in bench.figures}


def _number(value: float) -> str:
    return f"{value:,.0f}" if 1000 <= abs(value) < 1e7 else f"{value:.3g}"


def _table(rows: list[tuple[Bench, Figure, list[float | None]]], runs: int, note: str) -> str:
    lines = [
        f"Measured by `python3 dev.py bench --runs {runs}` ({note}); "
        "min / median / max over the runs.",
        "",
        "| figure | min | median | max | unit | command (`python -m ...`) |",
        "|---|---|---|---|---|---|",
    ]
    for bench, fig, values in rows:
        got = [v * fig.scale for v in values if v is not None]
        cells = (
            [_number(min(got)), _number(statistics.median(got)), _number(max(got))]
            if got
            else ["-", "-", "-"]
        )
        command = _shown(bench.args)
        lines.append(f"| {fig.label} | {' | '.join(cells)} | {fig.unit} | `{command}` |")
    return "\n".join(lines)


def replace_between_markers(text: str, table: str) -> str:
    """``text`` with everything between the bench markers replaced by ``table``."""
    pattern = re.compile(re.escape(BEGIN) + r".*?" + re.escape(END), re.DOTALL)
    if len(pattern.findall(text)) != 1:
        raise SystemExit(f"dev.py bench: README.md needs exactly one {BEGIN} ... {END} block")
    return pattern.sub(lambda _: f"{BEGIN}\n{table}\n{END}", text)


def bench(argv: Sequence[str], quiet: bool, run: Callable[[Bench, bool], dict] = _run_bench) -> int:
    parser = argparse.ArgumentParser(
        prog="python3 dev.py bench",
        description="Re-measure the figures of the README (paper reproduction, sweep, bus demo, "
        "benchmarks): each command several times; the table between the bench markers in "
        "README.md is rewritten with min/median/max and the command beside each figure.",
    )
    parser.add_argument("--runs", type=int, default=3, help="runs of each command (default 3)")
    parser.add_argument(
        "--realtime-seconds",
        type=float,
        default=60.0,
        help="length of hil bench's real-time run (default 60)",
    )
    parser.add_argument(
        "--only", nargs="+", metavar="NAME", help="only these benchmarks (names: see the table)"
    )
    parser.add_argument(
        "--no-readme", action="store_true", help="print the table, leave README.md alone"
    )
    args = parser.parse_args(argv)
    if args.runs < 1 or not args.realtime_seconds > 0:
        parser.error("--runs must be >= 1 and --realtime-seconds > 0")
    benches = _benches(args.realtime_seconds)
    if args.only:
        unknown = sorted(set(args.only) - {b.name for b in benches})
        if unknown:
            parser.error(f"--only: unknown {unknown}; known: {[b.name for b in benches]}")
        benches = tuple(b for b in benches if b.name in args.only)
    results: dict[str, list[dict[str, float | None]]] = {b.name: [] for b in benches}
    total = len(benches) * args.runs
    step = 0
    t0 = time.monotonic()
    for i in range(args.runs):
        for b in benches:
            step += 1
            _say(
                f"[{time.monotonic() - t0:6.0f} s] {step}/{total}: python -m "
                + _shown(b.args)
                + f" (run {i + 1} of {args.runs})",
                quiet,
            )
            results[b.name].append(run(b, quiet))
    rows = [(b, f, [r[f.label] for r in results[b.name]]) for b in benches for f in b.figures]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    note = f"{time.strftime('%Y-%m-%d')}, {os.cpu_count()} CPUs, load average {load:.1f} at the end"
    table = _table(rows, args.runs, note)
    print(table)
    if not args.no_readme:
        README.write_text(replace_between_markers(README.read_text(encoding="utf-8"), table))
        _say(f"rewrote the table between the bench markers of {README}", quiet)
    return 0


def main(argv: list[str]) -> int:
    quiet = bool(argv) and argv[0] in ("--quiet", "-q")
    if quiet:
        argv = argv[1:]
    if not argv or argv[0] not in {"demo", "test", "python", "bench", "first-run"}:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    _ensure_venv(quiet)
    verb, rest = argv[0], argv[1:]
    if verb == "bench":
        return bench(rest, quiet)
    if verb == "demo":
        cmd = _demo_cmd(rest, quiet)
    elif verb == "test":
        return test(rest, quiet)
    elif verb == "first-run":
        return first_run(rest, quiet)
    else:
        cmd = [str(PY), *rest]
    return subprocess.run(cmd, cwd=ROOT).returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
