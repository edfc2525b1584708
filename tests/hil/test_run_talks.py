"""``bridge run`` talks (issue 29 item 4, bridge.status): the start-up plan and the stored
parameters on stderr, a live status line only on a terminal, a verdict line, ``--json``.

* two processes over udp_multicast in a private network namespace the test creates: the
  simulated drive (``python -m plant_sim drive``, real-time clock) and ``bridge run`` (real
  time) with its stderr on a pseudo-terminal: the plan, the drive's mode and layout, the
  store's values, live lines rewritten in place while the axis moves, the verdict; again with
  stderr on a pipe and ``--json``: no live line, and the verdict's end position is the one
  python canopen's master reads from the drive afterwards (60E4h:01);
* in one process on the virtual bus: the verdict's figures against the trace the recorder
  wrote (largest following error, smallest λ, vibration episodes counted from β and β_T
  over the rows), on the paper's section X with and without the regulator.
"""

from __future__ import annotations

import io
import json
import os
import pty
import re
import struct
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from bridge.cycle import BridgeState
from bridge.interpolator import Table
from bridge.node import BridgeConfig
from bridge.params import BridgeParams
from bridge.run import RunOptions, RunResult
from bridge.status import RunTalk
from hil.harness import play_references, simulated_axis
from plant_sim.paper.outputs import LIMIT_CYCLE_VISCOUS
from plant_sim.paper.scenarios import SectionX
from regulator import RegulatorConfig
from tests.hil.test_two_processes import READER
from tests.paths import ROOT, checkout_env
from tests.serving import drive_process_in
from virtual_bus import BusConfig, Interface
from virtual_bus.formats.axis import dump_axis, load_axis
from virtual_bus.formats.trace import read_trace
from virtual_bus.netns import UDP_GROUP, NetworkNamespace

PAPER_AXIS = ROOT / "config" / "paper_axis.toml"
EDS = ROOT / "config" / "drive.eds"
#: A real-time loop a busy 2-core machine keeps (section X's second case: 2.5 ms, tests of
#: issue 28 alike); the status line is about the terminal, not about keeping the cycle.
CYCLE_S = 0.0025
TARGET_M = 0.02
FEED_M_S = 0.01  # 2 s of motion: the live line is rewritten several times
BETA_T = 0.125  # stored (2002h), exact in float32
PDO_TOLERANCE = 50  # stored (200Ah): a busy host may hold the drive off its CPU a few cycles
#: Backstop of a wait for a program's state (a program that ends ends the wait at once).
BOUND_S = 900.0
#: Attempts of a run a starved host may spoil (tests/fail_safe.py's ATTEMPTS alike), and the
#: skipped SYNCs that say it was (125 ms at 2.5 ms: half the drive's heartbeat consumer time).
ATTEMPTS = 3
STARVED_SYNCS = 50
LIVE = re.compile(
    r"\rbridge run: t (?P<t>[\d.,]+) s  x (?P<x>[−\d.,]+) (?P<xu>mm|µm|nm|m)  "
    r"e (?P<e>[−\d.,]+) (?P<eu>mm|µm|nm|m)  β [\d.,e+−-]+ rad/s  λ [\d.,e+−-]+  "
    r"bus (?P<bus>[\d.,]+) %  missed \d+  skipped (?P<skipped>\d+)  (?P<state>[A-Z_]+)\x1b\[K"
)
SCALE = {"m": 1.0, "mm": 1e-3, "µm": 1e-6, "nm": 1e-9}


def _metres(text: str, unit: str) -> float:
    return float(text.replace(",", "").replace("−", "-")) * SCALE[unit]


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The axis file at :data:`CYCLE_S` and a parameter store with β_T and 200Ah."""
    tmp = tmp_path_factory.mktemp("talk")
    axis = tmp / "axis.toml"
    paper = load_axis(PAPER_AXIS).with_values({"control.position_cycle": CYCLE_S})
    axis.write_text(dump_axis(paper, "paper axis, 2.5 ms position cycle"))
    store = tmp / "store.json"
    objects = {"2002h:00": struct.pack("<f", BETA_T).hex(), "200Ah:00": f"{PDO_TOLERANCE:02x}"}
    doc = {"format": "backlash-bridge parameter store", "version": 1, "objects": objects}
    store.write_text(json.dumps(doc))
    return axis, store


@pytest.fixture(scope="module")
def udp_drive(
    netns_skip_reason: str | None, files: tuple[Path, Path]
) -> Iterator[NetworkNamespace]:
    """A namespace with the simulated drive (real-time clock) serving in it."""
    if netns_skip_reason is not None:
        pytest.skip(netns_skip_reason)
    with NetworkNamespace.create() as ns, drive_process_in(ns, files[0], bound_s=BOUND_S):
        yield ns


def _bridge_argv(files: tuple[Path, Path], *extra: str) -> list[str]:
    """``bridge run`` in real time; ``extra`` after the common options (moves: 0 -> 20 mm,
    unless ``--move`` is in ``extra``)."""
    axis, store = files
    moves = () if "--move" in extra else ("--move", f"target={TARGET_M},feed={FEED_M_S}")
    return [
        *("run", "--interface", "udp_multicast", "--channel", UDP_GROUP),
        *("--axis", str(axis), "--store", str(store), "--clock", "realtime"),
        *(*moves, "--hold", "0.5", "--overrun-limit", "1000000", *extra),
    ]


def _read_all(fd: int, into: list[bytes]) -> None:
    """Everything the pseudo-terminal's other end gets, until the program has closed it."""
    while True:
        try:
            chunk = os.read(fd, 4096)
        except OSError:  # EIO: no process holds the terminal any more
            return
        if not chunk:
            return
        into.append(chunk)


def _on_a_terminal(udp_drive: NetworkNamespace, files: tuple[Path, Path]) -> tuple[str, str]:
    """``bridge run`` with its stderr on a pty: (stdout, what the terminal got)."""
    master, slave = pty.openpty()
    got: list[bytes] = []
    env = checkout_env()
    argv = [sys.executable, "-m", "bridge", *_bridge_argv(files)]
    try:
        proc = subprocess.Popen(
            udp_drive.command(argv), stdout=subprocess.PIPE, stderr=slave, text=True, env=env
        )
    finally:
        os.close(slave)  # the child holds it now: EOF on the master when the child ends
    reader = threading.Thread(target=_read_all, args=(master, got), daemon=True)
    reader.start()
    try:
        out, _ = proc.communicate(timeout=BOUND_S)
    finally:
        reader.join(60.0)
        os.close(master)
    err = b"".join(got).decode().replace("\r\n", "\n")  # the terminal's line ends
    assert proc.returncode == 0, (out, err)
    return out, err


def test_on_a_terminal_the_run_shows_its_plan_live_lines_and_a_verdict(
    udp_drive: NetworkNamespace, files: tuple[Path, Path]
) -> None:
    spoiled = []
    for _ in range(ATTEMPTS):
        out, err = _on_a_terminal(udp_drive, files)
        skipped = [int(m["skipped"]) for m in LIVE.finditer(err)]
        if not skipped or skipped[-1] < STARVED_SYNCS:
            break
        # a host that held the loop off its CPU for 125 ms and more: the reference steps
        # once per cycle the loop ran while the drive keeps its last set point through the
        # skipped SYNCs, so the axis gains on the reference and the error the lines show
        # says how the host served the cycles (a median of 240 µm seen, load 6), not eq. 7
        spoiled.append(skipped[-1])
        print(f"run again: the host starved the bridge ({skipped[-1]} skipped SYNCs)")
        if len(spoiled) < ATTEMPTS:  # the drive stays where the run left it: back to 0 first
            home = _bridge_argv(files, "--move", f"target=0,feed={FEED_M_S}")
            env = checkout_env()
            run = udp_drive.run([sys.executable, "-m", "bridge", *home], BOUND_S, env=env)
            assert run.returncode == 0, run.stderr
    starved = len(spoiled) == ATTEMPTS
    # the start-up, before the first live line
    first_live = err.index("\rbridge run: t ")
    startup = err[:first_live]
    assert "bridge run: plan: 1 move(s): to 20 mm at 10 mm/s, then hold 500 ms" in startup
    assert "regulator on (eq. 15): β_T 0.125 rad/s; k_v 25 1/s, position cycle 2.5 ms" in startup
    assert "clock: real time; bus: udp_multicast" in startup
    assert (
        f"parameters loaded from store {files[1]}: β_T 0.125 rad/s (2002h), "
        "PDO loss tolerance 50 cycles (200Ah)"
    ) in startup
    assert "bridge run: drive 2 configured: CYCLIC_SYNCHRONOUS_VELOCITY" in startup
    assert "    TPDO1 0x182: motor_position + load_position" in startup
    # live lines, rewritten in place, while the axis moves
    lines = list(LIVE.finditer(err))
    assert len(lines) >= 3, err
    assert len(lines) == err.count("\rbridge run: t "), "every live line is whole"
    xs = [_metres(m["x"], m["xu"]) for m in lines]
    assert xs == sorted(xs), xs  # forwards
    if not starved:  # moving while the lines are written (starved, they may all be late)
        assert xs[-1] - xs[0] > TARGET_M / 4, xs
    assert all(0.0 <= x <= TARGET_M + 1e-4 for x in xs)
    assert {m["state"] for m in lines} <= {"RUNNING", "ENABLING", "DISABLED"}
    running = [m for m in lines if m["state"] == "RUNNING" and _metres(m["x"], m["xu"]) > 1e-3]
    # on the way: the following error is the feed over k_v (eq. 7), within 20 %, in the
    # median of the lines (a single line may catch the loop after a host stall: 229 µm seen
    # with both CPUs busy, the drive holding the last set point through skipped SYNCs)
    on_the_way = [
        _metres(m["e"], m["eu"])
        for m in running
        if float(m["t"].replace(",", "")) < TARGET_M / FEED_M_S - 0.1
    ]
    assert on_the_way
    if not starved:  # eq. 7 on the way
        assert float(np.median(on_the_way)) == pytest.approx(FEED_M_S / 25.0, rel=0.2)
    # the bus load of 2 TPDOs + SYNC + RPDO every 2.5 ms at 1 Mbit/s: 17.6 % worst case
    loads = [float(m["bus"]) for m in running]
    assert all(5.0 < load < 30.0 for load in loads), loads
    # the live line is erased before the run ends: the verdict stands on its own
    assert err.rstrip("\n").endswith(("\x1b[K", "\n")) and "\r\x1b[K" in err[first_live:]
    (verdict,) = [ln for ln in out.splitlines() if ln.startswith("verdict: ")]
    reached = re.match(r"verdict: target 20 mm (reached|NOT reached) \((.+?) off, ", verdict)
    assert reached is not None, verdict
    off = reached[2]
    # within a few backlash widths (100 µm; 176 µm seen with both CPUs busy)
    assert off.startswith("below") or _metres(*off.split()) < 300e-6
    fe = re.search(r"largest following error ([\d.,]+) (mm|µm|nm) at ", verdict)
    assert fe is not None, verdict
    if not starved:  # starved, the axis gains on the reference at every stall (354 nm seen)
        assert _metres(fe[1], fe[2]) == pytest.approx(FEED_M_S / 25.0, rel=0.2)  # eq. 7
    assert "stop: moves done, held 500 ms" in verdict


def test_json_on_a_pipe_no_live_line_and_the_drives_end_position(
    udp_drive: NetworkNamespace, files: tuple[Path, Path], tmp_path: Path
) -> None:
    env = checkout_env()
    back = (
        "--move",
        f"target={TARGET_M / 2},feed={FEED_M_S}",
        "--move",
        f"target=0,feed={FEED_M_S}",
    )
    argv = [sys.executable, "-m", "bridge", *_bridge_argv(files, *back, "--json")]
    spoiled = []
    for _ in range(ATTEMPTS):
        run = udp_drive.run(argv, timeout_s=BOUND_S, env=env)
        assert run.returncode == 0, run.stderr
        doc = json.loads(run.stdout)  # the whole of stdout
        if doc["skipped_syncs"] < STARVED_SYNCS:
            break
        # a host that held the loop off its CPU for 125 ms and more in all: the end position
        # within the hold then says how the host served the cycles, not the loop
        spoiled.append(doc["skipped_syncs"])
        print(f"run again: the host starved the bridge ({doc['skipped_syncs']} skipped SYNCs)")
    # every attempt starved (a host busy for minutes): what the run says must still hold
    starved = len(spoiled) == ATTEMPTS
    assert "\r" not in run.stderr and "bridge run: plan: " in run.stderr
    v = doc["verdict"]
    assert doc["stop_message"] == "none" and doc["state"] == "DISABLED"
    assert v["target_m"] == 0.0  # the last move's
    # a reversal through the 100 µm backlash: where the load ends within its hold is physics
    # and, in real time, how the host served the cycles: a stall in the reversal can set the
    # load shaking, eq. 15 then fades the load scale out (lambda -> 0: no position correction
    # until beta decays) and the hold may end before it is back (107, 314 µm seen busy,
    # the second on a run with fewer than 50 skipped SYNCs). The end is judged exactly on the
    # lockstep clock (test_the_verdict_is_what_the_trace_says); here: the load came back from
    # 10 mm, and the verdict says whether the end is within the tolerance
    if not starved:  # starved on every attempt, the end is how the host served the hold
        assert abs(v["final_position_m"]) < 1e-3, spoiled
    assert v["target_reached"] is (abs(v["final_position_m"]) <= v["tolerance_m"])
    assert v["stop"] == "moves done, held 500 ms"
    if not starved:  # starved, the axis gains on the reference at every stall (the terminal's)
        assert v["max_following_error_m"] == pytest.approx(FEED_M_S / 25.0, rel=0.2)  # eq. 7
    assert 0.0 < v["min_lambda"] <= 1.0 and v["vibration_episodes"] >= 0
    assert v["beta_t_rad_s"] == BETA_T
    script = tmp_path / "reader.py"
    script.write_text(READER)
    reader = udp_drive.run([sys.executable, str(script)], timeout_s=BOUND_S, env=env)
    assert reader.returncode == 0, reader.stderr
    load_nm = json.loads(reader.stdout)["load_nm"]
    # the drive's 60E4h:01 after the run (1 nm increments): the verdict's end position is the
    # last TPDO the bridge read; after it the drive disabled the motor, and the load may
    # relax a little out of the drive train's wind-up (0.4 µm seen)
    assert v["final_position_m"] == pytest.approx(load_nm * 1e-9, abs=2e-6)


# --- in one process: the verdict's figures against the trace ---------------------------------
@pytest.mark.parametrize("regulated", [False, True], ids=["ordinary", "regulated"])
def test_the_verdict_is_what_the_trace_says(regulated: bool, tmp_path: Path) -> None:
    """Section X on the axis that limit-cycles under ordinary control (the demo's): the
    verdict's largest following error, smallest λ and vibration episodes are those of the
    recorder's rows (β above β_T counted over the rows in RUNNING)."""
    axis = load_axis(PAPER_AXIS).with_values({"friction.viscous": LIMIT_CYCLE_VISCOUS})
    refs = SectionX().references(axis)
    reg = RegulatorConfig(
        kv=axis.control.kv, cycle_s=axis.control.position_cycle, enabled=regulated
    )
    params = BridgeParams.for_axis(axis, reg)
    trace_path = tmp_path / "trace.csv"
    table = Table.from_references(refs)
    options = RunOptions(
        bus=BusConfig(interface=Interface.VIRTUAL), axis=axis, bridge=BridgeConfig(), moves=(table,)
    )
    stream = io.StringIO()
    talk = RunTalk(stream, live=False)
    with simulated_axis(
        axis, params, trace_path=trace_path, disturbance=refs.disturbance_nm
    ) as sim:
        talk.attach(sim.bridge, options)
        try:
            run = play_references(sim, refs)
        finally:
            talk.close()
        result = RunResult(run.cycles, run.state, run.stop_message, 0, 0, 0)
        verdict = talk.verdict(result)
    trace = read_trace(trace_path)
    on = trace["state"] == float(BridgeState.RUNNING.value)
    e = np.abs(trace["position_reference"] - trace["load_position"])[on]
    beta, lam = trace["beta"][on], trace["lambda"][on]
    above = beta > params.beta_t_rad_s
    episodes = int(above[0]) + int(np.count_nonzero(above[1:] & ~above[:-1]))
    assert verdict.max_following_error == pytest.approx(float(e.max()), rel=1e-6)
    assert verdict.min_lambda == pytest.approx(float(lam.min()), rel=1e-6)
    assert verdict.max_beta_rad_s == pytest.approx(float(beta.max()), rel=1e-6)
    assert verdict.vibration_episodes == episodes
    assert verdict.vibrating_s == pytest.approx(np.count_nonzero(above) * reg.cycle_s)
    if regulated:
        assert verdict.min_lambda < 0.5  # the regulator switched (eq. 15)
    else:
        assert verdict.min_lambda == 1.0 and verdict.vibration_episodes >= 1  # Fig. 8
    assert verdict.stop == "moves done, held 1 s"
    assert json.loads(json.dumps(verdict.as_json()))["vibration_episodes"] == episodes
