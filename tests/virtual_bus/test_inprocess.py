"""virtual_bus.inprocess.InProcessBus against python-can's own VirtualBus.

The reference is python-can: ``copy.deepcopy`` of a message (what VirtualBus.send delivers)
and what a plain ``can.Bus(interface="virtual")`` end sends and receives on the same channel.
"""

from __future__ import annotations

import copy
import logging
import uuid

import can
import pytest

from virtual_bus import BusConfig, Interface, open_bus
from virtual_bus.inprocess import InProcessBus, copy_message

FIELDS = tuple(name for name in can.Message.__slots__ if not name.startswith("__"))

MESSAGES = [
    can.Message(arbitration_id=0x181, data=b"\x01\x02\x03", is_extended_id=False),
    can.Message(arbitration_id=0x80, data=b"", is_extended_id=False),
    can.Message(arbitration_id=0x1ABCDEF0, data=bytes(range(8)), is_extended_id=True),
    can.Message(arbitration_id=0x602, is_remote_frame=True, dlc=8, is_extended_id=False),
    can.Message(is_error_frame=True, arbitration_id=0x20000004, data=bytes(8)),
    can.Message(arbitration_id=0x123, data=bytes(range(64)), is_fd=True, bitrate_switch=True),
    can.Message(arbitration_id=0x7FF, data=bytearray(b"\xff"), error_state_indicator=True),
]


def fields(msg: can.Message) -> dict[str, object]:
    values = {name: getattr(msg, name) for name in FIELDS}
    values["data_type"] = type(msg.data)
    values["type"] = type(msg)
    return values


@pytest.mark.parametrize("msg", MESSAGES, ids=lambda m: f"0x{m.arbitration_id:X}")
def test_copy_is_what_deepcopy_gives(msg: can.Message) -> None:
    msg.timestamp = 1234.5
    msg.channel = "x"
    expected, got = copy.deepcopy(msg), copy_message(msg)
    assert fields(got) == fields(expected)
    assert got.data is not msg.data


@pytest.mark.parametrize("sender_fast", [True, False], ids=["fast-to-plain", "plain-to-fast"])
def test_frames_are_python_cans_both_ways(sender_fast: bool) -> None:
    """Sent by one kind of end, received by both kinds: the same frames python-can's own
    virtual bus delivers (fields, order), whoever sends."""
    channel = f"inproc-{uuid.uuid4().hex[:8]}"
    fast_tx, fast_rx = InProcessBus(channel), InProcessBus(channel)
    plain_tx = can.Bus(interface="virtual", channel=channel)
    plain_rx = can.Bus(interface="virtual", channel=channel)
    try:
        sender = fast_tx if sender_fast else plain_tx
        others = (fast_rx, plain_rx, plain_tx if sender_fast else fast_tx)
        for msg in MESSAGES:
            sender.send(msg)
        for receiver in others:
            got = [receiver.recv(0.0) for _ in MESSAGES]
            assert receiver.recv(0.0) is None
            for sent, received in zip(MESSAGES, got, strict=True):
                assert received is not None
                expected = copy.deepcopy(sent)
                expected.timestamp, expected.channel, expected.is_rx = (
                    received.timestamp,
                    channel,
                    True,
                )
                assert fields(received) == fields(expected)
        assert sender.recv(0.0) is None  # no own frames
    finally:
        for bus in (fast_tx, fast_rx, plain_tx, plain_rx):
            bus.shutdown()


def test_receive_own_messages_and_timeout() -> None:
    channel = f"inproc-{uuid.uuid4().hex[:8]}"
    bus = InProcessBus(channel, receive_own_messages=True)
    try:
        assert bus.recv(0.001) is None
        bus.send(MESSAGES[0])
        own = bus.recv(0.0)
        assert own is not None and own.is_rx is False and bytes(own.data) == b"\x01\x02\x03"
        assert bus.recv(0.0) is None
    finally:
        bus.shutdown()
    with pytest.raises(can.CanOperationError):
        bus.recv(0.0)


def test_filters_are_python_cans() -> None:
    channel = f"inproc-{uuid.uuid4().hex[:8]}"
    tx, rx = InProcessBus(channel), InProcessBus(channel)
    try:
        rx.set_filters([{"can_id": 0x181, "can_mask": 0x7FF, "extended": False}])
        for msg in MESSAGES:
            tx.send(msg)
        got = rx.recv(0.0)
        assert got is not None and got.arbitration_id == 0x181
        assert rx.recv(0.0) is None
    finally:
        tx.shutdown()
        rx.shutdown()


def test_receive_logging_is_python_cans(caplog: pytest.LogCaptureFixture) -> None:
    channel = f"inproc-{uuid.uuid4().hex[:8]}"
    tx, rx = InProcessBus(channel), InProcessBus(channel)
    try:
        with caplog.at_level(rx.RECV_LOGGING_LEVEL, logger="can.bus"):
            tx.send(MESSAGES[0])
            rx.recv(0.0)
        assert [r.getMessage().startswith("Received: ") for r in caplog.records] == [True]
    finally:
        tx.shutdown()
        rx.shutdown()
    assert logging.getLogger("can.bus").level == logging.NOTSET


def test_open_bus_gives_the_in_process_bus() -> None:
    config = BusConfig(interface=Interface.VIRTUAL, channel=f"inproc-{uuid.uuid4().hex[:8]}")
    bus = open_bus(config)
    try:
        assert isinstance(bus, InProcessBus)
    finally:
        bus.shutdown()
