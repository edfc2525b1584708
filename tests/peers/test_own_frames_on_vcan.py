"""Own frames are never foreign on SocketCAN vcan0 (issue 28), in the guest where the host has
no SocketCAN: the bridge with ``--bus-log`` reads its socket with ``receive_own_messages``
(the log must be the wire as candump records it), so the kernel hands it back every frame it
sends; ``virtual_bus.own_frames`` takes each of them out by the kernel's ``MSG_CONFIRM``.

* with no foreign traffic neither node refuses a frame (the drive's 2105h in its exit line,
  the bridge's 2110h in ``bridge run``'s), with the real-time and the lockstep clock;
* a flood of ``cangen vcan0 -g 0 -I 0 -L 8`` (NMT frames of the wrong length, as fast as
  cangen goes) through a lockstep run with the bus log: the run goes on to its end, every
  flood frame the bridge read is one bad length (2110h:01, equal to the frames of ID 0 its
  log shows it received), and none of its own SYNCs and RPDOs is taken for another node's
  (2110h:02 and :04 stay 0: before, one lost echo made them a second SYNC producer's, and
  the axis stopped with SYNC_CONFLICT in one run of eight).
"""

from __future__ import annotations

import re
import signal
from pathlib import Path

import pytest

from tests import fail_safe as fs
from tests.peers.live_bus import Frame, Program, candump, need_programs

pytestmark = pytest.mark.vcan

VCAN = fs.Wire("socketcan", "vcan0")


@pytest.fixture(scope="module")
def axis(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return fs.axis_file(tmp_path_factory.mktemp("axis"))


@pytest.mark.parametrize("clock", ["realtime", "lockstep"])
def test_no_foreign_traffic_no_refused_frame(axis: Path, clock: str, tmp_path: Path) -> None:
    fs.check_no_refused_frames(VCAN, axis, tmp_path, clock)


def test_an_id_0_flood_with_the_bus_log_never_makes_own_frames_foreign(tmp_path: Path) -> None:
    need_programs("candump", "cangen")
    axis = fs.ROOT / "config" / "paper_axis.toml"
    recorder = candump()
    drive = bridge = flood = None
    try:
        drive = VCAN.drive(axis, "lockstep")
        bridge = VCAN.bridge(
            axis, tmp_path, "--seconds", "1000", "--bus-log", str(tmp_path / "bus.log"),
            clock="lockstep",
        )  # fmt: skip
        recorder.wait_for(lambda lines: sum(" 080#" in x for x in lines) >= 10, "the loop")
        flood = Program(
            ["cangen", "vcan0", "-g", "0", "-I", "0", "-L", "8", "-n", "5000"], "cangen"
        )
        assert flood.finish() == 0, flood.stderr
        last = len(recorder.lines)
        recorder.wait_for(
            lambda lines: sum(" 080#" in x for x in lines[last:]) >= 3, "SYNCs after the flood"
        )
        code = bridge.stop(signal.SIGINT)  # `bridge run` ends the run and reports
        out = "\n".join([*bridge.lines, bridge.stderr])
    finally:
        for p in (flood, bridge, drive):
            fs.stop(p)
        recorder.stop(2)
    assert code == 0 and "SIGINT: the run ended" in out, out  # went on through the flood
    assert "stopped:" not in out, out
    refused = dict(
        (name, int(n))
        for name, n in re.findall(
            r"(\w+) (\d+)", out.split("refused frames (2110h):")[1].splitlines()[0]
        )
    )
    logged = [
        (f, line.rstrip().endswith(" R"))
        for line in (tmp_path / "bus.log").read_text().splitlines()
        if (f := Frame.parse(line)) is not None
    ]
    got = [f for f, rx in logged if rx]
    sent = [f for f, rx in logged if not rx]
    assert sum(f.cob_id == 0x000 and len(f.data) == 8 for f in got) == refused["bad_length"] > 0
    assert refused["second_sync_producer"] == refused["unknown_cob_id"] == 0, out
    # the bridge's own frames are in its log as sent, never as received
    assert not any(f.cob_id in (0x080, 0x202, 0x701) for f in got)
    assert sum(f.cob_id == 0x080 for f in sent) > 10
    # the drive refused only the flood's frames: bad length (NMT needs 2 bytes)
    assert drive is not None
    kinds = re.findall(r"(\w+) \d+", drive.lines[-1].split("refused frames (2105h) ")[1])
    assert kinds == ["bad_length"], drive.lines[-1]
