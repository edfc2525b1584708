"""FaultInjectingBus: every fault kind against a replay of the documented seeded decisions,
conservation of frames, fake-clock delays, python-can/canopen integration."""

from __future__ import annotations

import dataclasses
import itertools
import math
import uuid
from collections import Counter
from collections.abc import Iterator

import can
import canopen
import pytest
from canopen.objectdictionary import ODVariable
from canopen.objectdictionary.datatypes import UNSIGNED32

from virtual_bus import (
    BusConfig,
    Direction,
    FaultConfig,
    FaultConfigError,
    FaultInjectingBus,
    FaultKind,
    Interface,
    open_bus,
)
from virtual_bus.faults import decision_rng

TEST_IDS = (0x201, 0x202, 0x203, 0x204)  # outside the default burst range 0x001..0x07F


class FakeClock:
    """Injected clock: time only moves when the test says so."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


def frame(i: int, dlc: int = 8) -> can.Message:
    """Frame number ``i`` (dlc >= 2): id from TEST_IDS, ``i`` in the first two data bytes."""
    data = (i.to_bytes(2, "big") + bytes(range(2, 8)))[:dlc]
    return can.Message(arbitration_id=TEST_IDS[i % len(TEST_IDS)], data=data, is_extended_id=False)


def number(msg: can.Message) -> int:
    return int.from_bytes(bytes(msg.data[:2]), "big")


class Rig:
    """A unique virtual channel with a plain sender; opens more ends, shuts all down."""

    def __init__(self) -> None:
        self.config = BusConfig(interface=Interface.VIRTUAL, channel=f"faults-{uuid.uuid4().hex}")
        self._opened: list[can.BusABC] = []
        self.sender = self.plain()

    def plain(self) -> can.BusABC:
        bus = open_bus(self.config)
        self._opened.append(bus)
        return bus

    def faulty(self, config: FaultConfig, clock: FakeClock | None = None) -> FaultInjectingBus:
        bus = FaultInjectingBus(open_bus(self.config), config, clock or FakeClock())
        self._opened.append(bus)
        return bus

    def close(self) -> None:
        for bus in self._opened:
            bus.shutdown()


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = Rig()
    try:
        yield r
    finally:
        r.close()


def drain(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (msg := bus.recv(timeout=0)) is not None:
        out.append(msg)
    return out


def run_receive(
    rig: Rig, config: FaultConfig, n: int, clock: FakeClock | None = None
) -> tuple[FaultInjectingBus, list[can.Message]]:
    """Send frames 0..n-1 on the plain sender and receive them through a new faulty end."""
    faulty = rig.faulty(config, clock)
    for i in range(n):
        rig.sender.send(frame(i))
    return faulty, drain(faulty)


def replay(seed: int, direction: Direction, n: int) -> list[dict[FaultKind, float]]:
    """The documented decision draws: len(FaultKind) uniforms per frame, in FaultKind order."""
    rng = decision_rng(seed, direction)
    return [{kind: rng.random() for kind in FaultKind} for _ in range(n)]


# ---------------------------------------------------------------------- config


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("drop_p", -0.1),
        ("drop_p", 1.01),
        ("duplicate_p", math.nan),
        ("delay_p", True),
        ("reorder_p", "0.5"),
        ("wrong_length_p", 2),
        ("burst_p", -1e-9),
        ("delay_s", -1.0),
        ("delay_s", math.inf),
        ("burst_ids", (0x80, 0x10)),
        ("burst_ids", (0, 0x800)),
        ("burst_ids", (1,)),
        ("burst_length", 0),
        ("burst_dlc", 9),
        ("seed", -1),
        ("direction", "receive"),
    ],
)
def test_bad_fault_config_is_rejected_naming_value(field: str, value: object) -> None:
    with pytest.raises(FaultConfigError, match=field.removesuffix("_p")) as info:
        FaultConfig(**{field: value})  # type: ignore[arg-type]
    assert isinstance(info.value, ValueError)
    assert repr(value) in str(info.value) or str(value) in str(info.value)


# ------------------------------------------------------------ faults off


def test_faults_off_pass_everything(bus_pair: tuple[can.BusABC, can.BusABC]) -> None:
    sender, receiver = bus_pair
    receiver.set_filters([{"can_id": 0x200, "can_mask": 0x7F8}])  # ignore foreign vcan0 traffic
    faulty = FaultInjectingBus(receiver, FaultConfig(direction=Direction.BOTH), FakeClock())
    for i in range(200):
        sender.send(frame(i))
    got = [faulty.recv(timeout=1.0) for _ in range(200)]
    assert [number(m) for m in got if m is not None] == list(range(200))
    faulty.send(frame(7))
    echo = sender.recv(timeout=1.0)
    assert echo is not None and number(echo) == 7
    c = faulty.counters
    assert c.count() == 0
    assert c.frames_in[Direction.RECEIVE] == c.frames_out[Direction.RECEIVE] == 200
    assert c.frames_in[Direction.SEND] == c.frames_out[Direction.SEND] == 1


# ----------------------------------------------------------- single fault kinds


@pytest.mark.parametrize("seed", [0, 1, 12345])
def test_drop_count_is_exact_and_accounts_for_every_frame(rig: Rig, seed: int) -> None:
    n, p = 1000, 0.3
    faulty, got = run_receive(rig, FaultConfig(seed=seed, drop_p=p), n)
    expected = {
        i for i, u in enumerate(replay(seed, Direction.RECEIVE, n)) if u[FaultKind.DROP] < p
    }
    received = [number(m) for m in got]
    assert received == [i for i in range(n) if i not in expected]  # the very frames, in order
    c = faulty.counters
    assert c.count(FaultKind.DROP) == len(expected)
    assert len(received) + c.count(FaultKind.DROP) == n  # delivered + dropped = sent
    sent_by_id = Counter(frame(i).arbitration_id for i in range(n))
    got_by_id = Counter(m.arbitration_id for m in got)
    assert c.by_id(FaultKind.DROP) == dict(sent_by_id - got_by_id)


def test_drop_rate_over_many_seeds_is_near_p(rig: Rig) -> None:
    """Binomial: 100 seeds x 200 frames at p = 0.2; the pooled rate must lie within 4.5
    standard errors of p, and the per-seed counts must vary like a binomial's."""
    seeds, n, p = 100, 200, 0.2
    per_seed = []
    for seed in range(seeds):
        faulty, got = run_receive(rig, FaultConfig(seed=seed, drop_p=p), n)
        faulty.shutdown()
        assert len(got) + faulty.counters.count(FaultKind.DROP) == n
        per_seed.append(n - len(got))
    rate = sum(per_seed) / (seeds * n)
    assert abs(rate - p) < 4.5 * math.sqrt(p * (1 - p) / (seeds * n))
    mean = sum(per_seed) / seeds
    var = sum((k - mean) ** 2 for k in per_seed) / (seeds - 1)
    assert 0.5 * n * p * (1 - p) < var < 1.6 * n * p * (1 - p)


def test_duplicates_follow_their_original(rig: Rig) -> None:
    n, p, seed = 500, 0.25, 3
    faulty, got = run_receive(rig, FaultConfig(seed=seed, duplicate_p=p), n)
    dup = [
        i for i, u in enumerate(replay(seed, Direction.RECEIVE, n)) if u[FaultKind.DUPLICATE] < p
    ]
    expected = []
    for i in range(n):
        expected += [i, i] if i in dup else [i]
    assert [number(m) for m in got] == expected
    c = faulty.counters
    assert c.count(FaultKind.DUPLICATE) == len(dup)
    assert len(got) == n + c.count(FaultKind.DUPLICATE)


def test_wrong_length_frames_really_change_length(rig: Rig) -> None:
    n, p, seed = 400, 0.5, 9
    faulty = rig.faulty(FaultConfig(seed=seed, wrong_length_p=p))
    originals = [frame(i, dlc=2 + i % 7) for i in range(n)]  # dlc 2..8
    for msg in originals:
        rig.sender.send(msg)
    got = drain(faulty)
    hit = {
        i for i, u in enumerate(replay(seed, Direction.RECEIVE, n)) if u[FaultKind.WRONG_LENGTH] < p
    }
    assert len(got) == n
    changed = set()
    for i, (sent, out) in enumerate(zip(originals, got, strict=True)):
        assert out.dlc == len(out.data) and 0 <= out.dlc <= 8
        keep = min(sent.dlc, out.dlc)
        assert bytes(out.data[:keep]) == bytes(sent.data[:keep])
        if out.dlc != sent.dlc:
            changed.add(i)
    assert changed == hit  # every hit changed the DLC, nothing else did
    assert faulty.counters.count(FaultKind.WRONG_LENGTH) == len(hit)
    assert {out.dlc for i, out in enumerate(got) if i in hit} == set(range(9))


def test_wrong_length_remote_frame_changes_dlc_only(rig: Rig) -> None:
    faulty = rig.faulty(FaultConfig(wrong_length_p=1.0))
    rig.sender.send(can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1))
    out = faulty.recv(timeout=0)
    assert out is not None and out.is_remote_frame and out.dlc != 1 and len(out.data) == 0


def test_reorder_swaps_with_next_frame(rig: Rig) -> None:
    faulty, got = run_receive(rig, FaultConfig(reorder_p=1.0), 7)
    assert [number(m) for m in got] == [1, 0, 3, 2, 5, 4]
    c = faulty.counters
    assert c.count(FaultKind.REORDER) == 4  # frames 0, 2, 4 and 6 were held back
    assert c.pending[Direction.RECEIVE] == 1  # frame 6 still waits for a successor
    assert len(got) + c.pending[Direction.RECEIVE] == 7


def test_reorder_count_is_exact(rig: Rig) -> None:
    n, p, seed = 600, 0.2, 5
    faulty, got = run_receive(rig, FaultConfig(seed=seed, reorder_p=p), n)
    order, held = [], None
    for i, u in enumerate(replay(seed, Direction.RECEIVE, n)):
        if u[FaultKind.REORDER] < p and held is None:
            held = i
            continue
        order.append(i)
        if held is not None:
            order.append(held)
            held = None
    received = [number(m) for m in got]
    assert received == order
    inversions = sum(a > b for a, b in itertools.pairwise(received))
    assert faulty.counters.count(FaultKind.REORDER) == inversions + (held is not None)


def test_delayed_frames_release_at_the_fake_clock_time(rig: Rig) -> None:
    sender = rig.sender
    clock = FakeClock()
    faulty = rig.faulty(FaultConfig(delay_p=1.0, delay_s=0.5), clock)
    for i in range(3):
        sender.send(frame(i))
    assert faulty.recv(timeout=0) is None  # all three entered the delay line at t = 0
    clock.now_s = 0.2
    sender.send(frame(3))
    assert faulty.recv(timeout=0) is None  # frame 3 enters at t = 0.2
    clock.now_s = 0.4999
    assert faulty.recv(timeout=0) is None
    clock.now_s = 0.5
    assert [number(m) for m in drain(faulty)] == [0, 1, 2]
    clock.now_s = 0.6999
    assert faulty.recv(timeout=0) is None
    clock.now_s = 0.7
    assert [number(m) for m in drain(faulty)] == [3]
    c = faulty.counters
    assert c.count(FaultKind.DELAY) == 4 and c.pending[Direction.RECEIVE] == 0


def test_delay_on_send_releases_to_the_inner_bus(rig: Rig) -> None:
    receiver = rig.sender  # the plain end receives what the faulty end sends
    clock = FakeClock()
    faulty = rig.faulty(FaultConfig(direction=Direction.SEND, delay_p=1.0, delay_s=0.25), clock)
    faulty.send(frame(0))
    assert receiver.recv(timeout=0) is None
    clock.now_s = 0.25
    faulty.release_due()
    out = receiver.recv(timeout=0)
    assert out is not None and number(out) == 0
    assert faulty.counters.count(FaultKind.DELAY, direction=Direction.SEND) == 1


def test_bursts_precede_their_trigger_with_high_priority_ids(rig: Rig) -> None:
    n, p, seed, length = 300, 0.1, 11, 3
    config = FaultConfig(seed=seed, burst_p=p, burst_length=length, burst_ids=(0x001, 0x07F))
    faulty, got = run_receive(rig, config, n)
    triggers = [
        i for i, u in enumerate(replay(seed, Direction.RECEIVE, n)) if u[FaultKind.BURST] < p
    ]
    bursts = [m for m in got if m.arbitration_id <= 0x07F]
    assert all(0x001 <= m.arbitration_id <= 0x07F and m.dlc == 8 for m in bursts)
    assert len(bursts) == length * len(triggers) == faulty.counters.count(FaultKind.BURST)
    originals = [m for m in got if m.arbitration_id in TEST_IDS]
    assert [number(m) for m in originals] == list(range(n))
    for t in triggers:  # the `length` frames right before trigger t are its burst
        at = next(k for k, m in enumerate(got) if m.arbitration_id in TEST_IDS and number(m) == t)
        assert all(m.arbitration_id <= 0x07F for m in got[at - length : at])
    assert sum(faulty.counters.by_id(FaultKind.BURST).values()) == len(bursts)


# ----------------------------------------------------------- combined accounting


@pytest.mark.parametrize("seed", [2, 77])
def test_everything_on_conserves_frames_in_both_directions(rig: Rig, seed: int) -> None:
    sender = rig.sender
    clock = FakeClock()
    config = FaultConfig(
        seed=seed,
        direction=Direction.BOTH,
        drop_p=0.1,
        wrong_length_p=0.1,
        duplicate_p=0.1,
        delay_p=0.1,
        delay_s=1.0,
        reorder_p=0.1,
        burst_p=0.05,
    )
    faulty = rig.faulty(config, clock)
    n = 400
    for i in range(n):
        sender.send(frame(i))
        faulty.send(frame(i))
        clock.now_s += 0.01
    got = drain(faulty)
    clock.now_s += 2.0
    faulty.release_due()
    got += drain(faulty)
    echoed = drain(sender)
    c = faulty.counters
    for direction, out in ((Direction.RECEIVE, got), (Direction.SEND, echoed)):

        def k(kind: FaultKind, d: Direction = direction) -> int:
            return c.count(kind, direction=d)

        assert c.frames_in[direction] == n
        assert c.frames_out[direction] == len(out)
        # conservation: in + duplicates + bursts == out + drops + pending
        assert n + k(FaultKind.DUPLICATE) + k(FaultKind.BURST) == (
            len(out) + k(FaultKind.DROP) + c.pending[direction]
        )
        assert c.pending[direction] <= 2  # only the reorder slot may still hold frames
        for kind in FaultKind:
            assert k(kind) > 0, kind
    assert c.count() == c.count(direction=Direction.RECEIVE) + c.count(direction=Direction.SEND)


def test_direction_limits_where_faults_apply(rig: Rig) -> None:
    sender = rig.sender
    faulty = rig.faulty(FaultConfig(direction=Direction.SEND, drop_p=1.0))
    sender.send(frame(1))
    got = faulty.recv(timeout=0)
    assert got is not None and number(got) == 1  # receive path untouched
    faulty.send(frame(2))
    assert sender.recv(timeout=0) is None  # send path drops
    assert set(faulty.counters.frames_in) == {Direction.SEND}
    assert faulty.counters.count(FaultKind.DROP, direction=Direction.SEND, can_id=0x203) == 1


def test_same_seed_same_faults_other_seed_other_faults(rig: Rig) -> None:
    config = FaultConfig(seed=4, drop_p=0.2, duplicate_p=0.2, reorder_p=0.2, wrong_length_p=0.2)
    runs = []
    for cfg in (config, config, dataclasses.replace(config, seed=5)):
        faulty, got = run_receive(rig, cfg, 200)
        faulty.shutdown()
        runs.append([(m.arbitration_id, bytes(m.data)) for m in got])
    assert runs[0] == runs[1]
    assert runs[0] != runs[2]


# ------------------------------------------------------ python-can behaviour


def test_python_can_filters_and_shutdown(rig: Rig) -> None:
    sender = rig.sender
    faulty = rig.faulty(FaultConfig(duplicate_p=1.0))
    receiver = faulty.inner
    assert type(faulty).recv is can.BusABC.recv  # public path is python-can's own
    faulty.set_filters([{"can_id": 0x202, "can_mask": 0x7FF}])
    for i in range(8):
        sender.send(frame(i))
    # python-can's recv(timeout=0) returns None when the head frame fails the filter, so
    # poll once per frame that passed the stage (8 originals + 8 duplicates).
    got = [m for _ in range(16) if (m := faulty.recv(timeout=0)) is not None]
    assert [number(m) for m in got] == [1, 1, 5, 5]
    assert faulty.recv(timeout=0) is None
    assert faulty.state is receiver.state
    assert faulty.protocol is receiver.protocol
    faulty.shutdown()
    assert receiver._is_shutdown  # the inner bus is shut down with the wrapper
    with pytest.raises(can.CanOperationError):
        faulty.send(frame(0))


# -------------------------------------------------------------------- canopen


def _od() -> canopen.ObjectDictionary:
    od = canopen.ObjectDictionary()
    var = ODVariable("Probe value", 0x2000, 0)
    var.data_type = UNSIGNED32
    var.default = 0xC0FFEE
    od.add_object(var)
    return od


@pytest.fixture
def sdo_networks(
    request: pytest.FixtureRequest,
) -> Iterator[tuple[canopen.RemoteNode, FaultInjectingBus]]:
    """A LocalNode (id 5) on a plain virtual bus and a RemoteNode for it on a
    FaultInjectingBus over a second virtual bus of the same channel."""
    channel = f"sdo-{uuid.uuid4().hex[:12]}"
    config = BusConfig(interface=Interface.VIRTUAL, channel=channel)
    server_net = canopen.Network(open_bus(config))
    faulty = FaultInjectingBus(open_bus(config), request.param, FakeClock())
    client_net = canopen.Network(faulty)
    for net in (server_net, client_net):
        net.NOTIFIER_CYCLE = 0.05  # short notifier poll so disconnect joins quickly
        net.connect()
    server_net.create_node(5, _od())
    remote = client_net.add_node(5, _od())
    remote.sdo.RESPONSE_TIMEOUT = 0.1
    try:
        yield remote, faulty
    finally:
        client_net.disconnect()
        server_net.disconnect()


@pytest.mark.parametrize("sdo_networks", [FaultConfig()], indirect=True)
def test_canopen_sdo_upload_through_fault_bus(sdo_networks) -> None:
    remote, faulty = sdo_networks
    assert remote.sdo.upload(0x2000, 0) == (0xC0FFEE).to_bytes(4, "little")
    c = faulty.counters
    assert c.count() == 0 and c.frames_out[Direction.RECEIVE] >= 1


@pytest.mark.parametrize("sdo_networks", [FaultConfig(drop_p=1.0)], indirect=True)
def test_canopen_sdo_times_out_when_everything_is_dropped(sdo_networks) -> None:
    remote, faulty = sdo_networks
    with pytest.raises(canopen.SdoCommunicationError, match="No SDO response"):
        remote.sdo.upload(0x2000, 0)
    c = faulty.counters
    assert c.frames_out[Direction.RECEIVE] == 0
    assert c.count(FaultKind.DROP) == c.frames_in[Direction.RECEIVE]
