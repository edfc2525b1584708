"""virtual_bus.netns and the udp_multicast bus: refused on the host's interfaces, a private
namespace created and always removed, own frames not echoed (as on a CAN controller)."""

from __future__ import annotations

import sys

import pytest

from virtual_bus import BusConfig, open_bus
from virtual_bus.errors import BusConfigError, NetnsError
from virtual_bus.netns import NetworkNamespace, private_namespace_problem
from virtual_bus.udp import LoopbackUdpBus


@pytest.fixture
def netns_ok(netns_skip_reason: str | None) -> None:
    if netns_skip_reason is not None:
        pytest.skip(netns_skip_reason)


def test_udp_multicast_is_refused_where_the_host_has_interfaces() -> None:
    problem = private_namespace_problem()
    if problem is None:
        pytest.skip("this test runs inside a private namespace: nothing to refuse")
    with pytest.raises(BusConfigError, match="private network namespace"):
        LoopbackUdpBus()
    with pytest.raises(BusConfigError, match="private network namespace"):
        BusConfig(interface="udp_multicast")


def test_namespace_is_removed_when_the_block_fails(netns_ok: None) -> None:
    with pytest.raises(RuntimeError, match="boom"), NetworkNamespace.create() as ns:
        assert ns.exists()
        raise RuntimeError("boom")
    assert not ns.exists()


def test_a_taken_name_is_one_clear_error_and_the_first_namespace_stays(netns_ok: None) -> None:
    with NetworkNamespace.create() as first:
        with pytest.raises(NetnsError, match="netns add"):
            NetworkNamespace.create(first.name)
        assert first.exists()
    assert not first.exists()


ECHO = """
from virtual_bus import BusConfig, open_bus
from virtual_bus.netns import private_namespace_problem
import can
print(private_namespace_problem())
a = open_bus(BusConfig(interface="udp_multicast"))
b = open_bus(BusConfig(interface="udp_multicast"))
try:
    a.send(can.Message(arbitration_id=0x101, data=b"a", is_extended_id=False))
    got_b = b.recv(10.0)
    b.send(can.Message(arbitration_id=0x102, data=b"b", is_extended_id=False))
    got_a = a.recv(10.0)  # without the filter: a's own 0x101 would come first
    print(hex(got_b.arbitration_id), got_b.channel, hex(got_a.arbitration_id), got_a.channel)
finally:
    a.shutdown()
    b.shutdown()
"""


def test_inside_a_namespace_frames_cross_and_own_frames_do_not_echo(
    private_netns: NetworkNamespace, subprocess_env: dict[str, str]
) -> None:
    done = private_netns.run([sys.executable, "-c", ECHO], timeout_s=60, env=subprocess_env)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["None", "0x101 239.74.163.2 0x102 239.74.163.2"]


def test_open_bus_refuses_udp_receive_own_messages_on_the_host() -> None:
    with pytest.raises(BusConfigError):
        open_bus(BusConfig(interface="udp_multicast", receive_own_messages=True))


GROUPS = """
from virtual_bus import BusConfig
from virtual_bus.errors import BusConfigError
for channel in ("can0", "vcan0", "10.0.0.1", "239.74.163.2", "ff15::7079", "::1", "999.1.1.1"):
    try:
        BusConfig(interface="udp_multicast", channel=channel)
        print(channel, "ok")
    except BusConfigError as exc:
        print(channel, "refused:", exc)
"""


def test_a_udp_channel_must_be_a_multicast_group(
    private_netns: NetworkNamespace, subprocess_env: dict[str, str]
) -> None:
    """Inside a namespace (where udp_multicast is allowed) the channel is a multicast group:
    ``can0`` is refused by the configuration with what is allowed, not by the resolver
    ("[Errno -3] Temporary failure in name resolution") after the bus was half made."""
    done = private_netns.run([sys.executable, "-c", GROUPS], timeout_s=60, env=subprocess_env)
    assert done.returncode == 0, done.stderr
    said = dict(line.split(" ", 1) for line in done.stdout.splitlines())
    assert said.pop("239.74.163.2") == "ok" and said.pop("ff15::7079") == "ok"
    for channel, answer in said.items():
        assert answer.startswith("refused: udp_multicast channel"), (channel, answer)
        assert "224.0.0.0/4" in answer and "ff00::/8" in answer
