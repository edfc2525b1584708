"""The commissioning tests over the bus (bridge freqresp, bridge tune) against the simulated
CiA 402 drive: in one process on python-can's virtual bus (SDO start-up, SYNC, PDOs, the
drive's state machine and physics), and as two processes over udp_multicast in a private
network namespace. What the bridge writes is read back with python canopen's own SDO client
from a bridge rebuilt on the same parameter store. Bad input stops the axis with the reason
and leaves the stored parameters unchanged."""

from __future__ import annotations

import json
import math
import signal
import struct
import sys
import uuid
from pathlib import Path

import can
import canopen
import pytest

from bridge.commission.freqresp import ExcitationPlan, measure
from bridge.commission.session import CommissioningStopped
from bridge.commission.tune import TuneOptions, tune
from bridge.cycle import BridgeState, StopReason
from bridge.node import Bridge, BridgeConfig
from bridge.params import BridgeParams
from bridge.timing import LockstepPacer
from hil.harness import simulated_axis
from plant_sim.paper.outputs import LIMIT_CYCLE_VISCOUS
from regulator import RegulatorConfig
from regulator.frequency_response import Multisine
from regulator.tuning import Outcome, TuningError
from tests.command_line import next_line
from tests.paths import CONFIG
from virtual_bus import BusConfig, Interface, open_bus
from virtual_bus.formats.axis import AxisConfig, dump_axis, load_axis
from virtual_bus.netns import UDP_GROUP, NetworkNamespace

PAPER = load_axis(CONFIG / "paper_axis.toml")
LIMIT_CYCLE = PAPER.with_values({"friction.viscous": LIMIT_CYCLE_VISCOUS})
LINEAR = PAPER.with_values({"mechanics.backlash": 0.0, "friction.coulomb": 0.0})
BOOT_TIMEOUT_S = 120.0


def _params(axis: AxisConfig = PAPER) -> BridgeParams:
    return BridgeParams.for_axis(axis, RegulatorConfig(kv=axis.control.kv, cycle_s=0.001))


def _stored(store: Path) -> dict[str, str]:
    return json.loads(store.read_text())["objects"] if store.exists() else {}


def _read_beta_t_over_sdo(store: Path) -> float:
    """A bridge rebuilt on ``store``; python canopen's SDO client reads its 2002h."""
    channel = f"reread-{uuid.uuid4().hex[:8]}"
    config = BusConfig(interface=Interface.VIRTUAL, channel=channel)
    a, b = open_bus(config), open_bus(config)
    try:
        bridge = Bridge(
            a, _params(), PAPER.kind, LockstepPacer(0.001), config=BridgeConfig(store_path=store)
        )
        tool = canopen.Network(b)
        node = canopen.RemoteNode(1, canopen.import_od(str(CONFIG / "bridge.eds"), 1))
        tool.add_node(node)
        notifier = can.Notifier(b, tool.listeners, 0.02)
        try:
            with bridge.serving():
                node.sdo.RESPONSE_TIMEOUT = 2.0
                raw = node.sdo.upload(0x2002, 0)
                enabled = node.sdo.upload(0x2001, 0)
        finally:
            notifier.stop(2.0)
            bridge.close()
    finally:
        a.shutdown()
        b.shutdown()
    assert enabled == b"\x01"
    return struct.unpack("<f", raw)[0]


def test_frequency_response_over_the_bus_finds_the_drives_antiresonance() -> None:
    """The simulated drive with the linearised paper axis: the notch measured over the bus
    (60FFh sent, 606Ch and 6077h received every SYNC) holds 600 rad/s; the bridge's
    parameters are restored and nothing is stored."""
    plan = ExcitationPlan(
        Multisine(0.001, 1024, 1.0, 450.0, 1.0, corner_hz=20.0),
        periods=3,
        realizations=2,
        torque_limit=150.0,
    )
    with simulated_axis(LINEAR, _params(LINEAR)) as sim:
        before = sim.bridge.controller.params
        fr = measure(sim.bridge, plan)
        assert sim.bridge.controller.params == before
        assert sim.bridge.controller.state is BridgeState.DISABLED
    assert fr.antiresonance.resolved and fr.antiresonance.contains(600.0), fr.describe()
    assert fr.admittance is not None  # 6077h is in the contract's layout
    assert 40.0 < fr.bandwidth.frequency_hz < 80.0
    assert fr.summary()["travel"] < 1e-3  # standstill: the position loop held the axis


def test_tune_over_the_bus_writes_and_stores_beta_t(tmp_path: Path) -> None:
    """Section X's axis on the simulated drive: the procedure finds beta_T, writes 2002h and
    stores it (1010h); a bridge rebuilt on the store answers 2002h with it over SDO."""
    store = tmp_path / "bridge-store.json"
    seen = []
    with simulated_axis(
        LIMIT_CYCLE, _params(LIMIT_CYCLE), bridge_config=BridgeConfig(store_path=store)
    ) as sim:
        report = tune(
            sim.bridge, TuneOptions(torque_limit=150.0), LIMIT_CYCLE, on_trial=seen.append
        )
        assert sim.bridge.controller.params.beta_t_rad_s == pytest.approx(report.beta_t_rad_s)
    result = report.result
    assert result.outcome is Outcome.FOUND and report.stored
    assert result.beta_t_rad_s == pytest.approx(result.last_stable_rad_s / 2)
    assert len(seen) == len(result.trials) + 2  # reference, trials, confirmation
    assert _read_beta_t_over_sdo(store) == pytest.approx(result.beta_t_rad_s, rel=1e-6)


def test_a_travel_limit_too_short_refuses_the_test_and_changes_nothing(tmp_path: Path) -> None:
    store = tmp_path / "bridge-store.json"
    with simulated_axis(
        LIMIT_CYCLE, _params(LIMIT_CYCLE), bridge_config=BridgeConfig(store_path=store)
    ) as sim:
        c = sim.bridge.controller
        c.set_params(c.params.with_value("position_limit_max", 0.01))  # 10 mm of travel
        start = sim.drive.plant.load_position
        # every rung's path leaves the travel: refused, naming each, before anything moves
        with pytest.raises(TuningError, match="leaves the travel") as info:
            tune(sim.bridge, TuneOptions(torque_limit=150.0), LIMIT_CYCLE)
        assert str(info.value).count("leaves the travel") >= 4
        assert sim.drive.plant.load_position == pytest.approx(start, abs=1e-9)
    assert not store.exists()


def test_a_drive_that_cannot_follow_the_excitation_is_stopped(tmp_path: Path) -> None:
    """A torque limit the excitation needs more than: the axis stops with TEST_LIMIT."""
    plan = ExcitationPlan(
        Multisine(0.001, 1024, 1.0, 450.0, 3.0, corner_hz=50.0), 3, 2, torque_limit=20.0
    )
    store = tmp_path / "bridge-store.json"
    config = BridgeConfig(store_path=store)
    with simulated_axis(LINEAR, _params(LINEAR), bridge_config=config) as sim:
        with pytest.raises(CommissioningStopped, match="TEST_LIMIT: torque") as info:
            measure(sim.bridge, plan)
        assert info.value.reason is StopReason.TEST_LIMIT
        assert sim.bridge.controller.state is BridgeState.STOPPED
        assert sim.bridge.controller.omega_r == 0.0
    assert not store.exists()


def test_a_tuning_run_without_limit_cycle_stores_nothing(tmp_path: Path) -> None:
    """The paper's own friction damps the limit cycle out: refused with the reason, the axis
    disabled, the stored parameters unchanged."""
    store = tmp_path / "bridge-store.json"
    store_before = b'{"format": "backlash-bridge parameter store", "version": 1, "objects": {}}'
    store.write_bytes(store_before)
    with simulated_axis(PAPER, _params(), bridge_config=BridgeConfig(store_path=store)) as sim:
        with pytest.raises(TuningError, match="excites a limit cycle under ordinary control"):
            tune(sim.bridge, TuneOptions(torque_limit=150.0, repeats=1), PAPER)
        assert sim.bridge.controller.state is BridgeState.DISABLED
    assert store.read_bytes() == store_before


# --- two processes -----------------------------------------------------------------------------
@pytest.mark.slow
def test_bridge_tune_against_the_drive_as_its_own_process(
    private_netns: NetworkNamespace, tmp_path: Path, subprocess_env: dict[str, str]
) -> None:
    """`python -m plant_sim drive` and `python -m bridge tune` as two processes over
    udp_multicast (lockstep), the safety limits of the bus command; then `bridge tune`'s
    report and the store it wrote."""
    axis_file = tmp_path / "limit_cycle.toml"
    axis_file.write_text(dump_axis(LIMIT_CYCLE, "paper axis, section X's figures"))
    store, out = tmp_path / "store.json", tmp_path / "tune"
    command = [sys.executable, "-m", "plant_sim", "drive", "--interface", "udp_multicast"]
    drive = private_netns.popen(
        [*command, "--axis", str(axis_file), "--clock", "lockstep"], env=subprocess_env
    )
    try:
        line = next_line(drive, BOOT_TIMEOUT_S)
        assert line.startswith("drive 2: boot-up sent on udp_multicast group"), line
        argv = ["tune", "--interface", "udp_multicast", "--channel", UDP_GROUP]
        argv += ["--axis", str(axis_file), "--store", str(store), "--out", str(out)]
        argv += ["--clock", "lockstep", "--torque-limit", "150", "--repeats", "1"]
        run = private_netns.run(
            [sys.executable, "-m", "bridge", *argv], timeout_s=900, env=subprocess_env
        )
    finally:
        drive.send_signal(signal.SIGTERM)
        drive.communicate(timeout=30)
    assert run.returncode == 0, run.stderr
    report = json.loads((out / "tune.json").read_text())
    assert report["outcome"] == "found" and report["stored"]
    beta = report["beta_t_rad_s"]
    assert struct.unpack("<f", bytes.fromhex(_stored(store)["2002h:00"]))[0] == pytest.approx(
        beta, rel=1e-6
    )
    said = run.stdout.strip().splitlines()[-1]  # the result, what it costs, where it went
    assert said.startswith(f"beta_T = {beta:.4g} rad/s; ") and "following error" in said
    assert said.endswith(f"; written to 2002h, stored in {store} (1010h)"), said
    assert not math.isnan(beta)
