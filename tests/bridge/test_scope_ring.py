"""The live scope's ring (bridge.scope_ring) across two processes: the writer here, the reader
a second Python process that gets the ring as an inherited file descriptor, as the scope's
server does. Each step is driven over a pipe (no clock): the test writes, asks the reader to
take, and checks what came out against the sequence it wrote.

* sequence: every sample taken once, in order, its values those written for its number;
* wrap-around: samples past the end of the ring come out whole and in order;
* a reader that falls behind gets the newest samples and counts the rest as dropped (taken +
  dropped = written), and the bridge's end reads that count back;
* under a writer that never stops (the loop), no sample comes out torn: the reader's
  re-check of the write sequence throws away every slot the writer may have been rewriting;
* the write sequence, read by the reader while the writer publishes, never goes back (a
  publication is one store: struct.pack_into's zero-fill first showed it as 0 for a moment,
  which let the re-check keep every slot).
"""

from __future__ import annotations

import json
import selectors
import subprocess
import sys
from collections.abc import Iterator

import pytest

from bridge.scope_ring import COLUMNS, RingWriter
from tests.paths import checkout_env

CAPACITY = 16

READER = """
import json, sys
from bridge.scope_ring import RingReader
ring = RingReader(int(sys.argv[1]))
def consistent(r):  # the values the writer derives from the sequence number
    s = r[0]
    want = (s * 1e-3, -s * 1e-6, s + 0.5, 1.0 / max(s, 1), 2.0 * s, s * 1e-9, -1.0, s % 3, s % 7)
    return s > 0 and r[1:] == want
for line in sys.stdin:
    if line.startswith("watch "):  # the write sequence read N times while the writer runs
        n, last, back = int(line.split()[1]), 0, 0
        print(json.dumps({"watching": True}), flush=True)
        for _ in range(n):
            seq = ring.write_seq
            back += seq < last
            last = seq
        print(json.dumps({"backwards": back, "last": last}), flush=True)
        continue
    if line.strip() == "follow":  # take until the writer has closed and all is read
        taken = bad = 0
        said = False
        while True:
            closed = ring.closed
            rows = ring.take()
            taken += len(rows)
            if taken >= 1000 and not said:  # the writer goes on until it hears this
                print(json.dumps({"progress": taken}), flush=True)
                said = True
            bad += sum(not consistent(r) for r in rows)
            if closed and ring.last == ring.write_seq:
                break
        print(json.dumps({"taken": taken, "bad": bad, "dropped": ring.dropped}), flush=True)
        continue
    rows = ring.take()
    print(json.dumps({
        "seqs": [r[0] for r in rows],
        "consistent": all(consistent(r) for r in rows),
        "dropped": ring.dropped,
        "pushed": ring.write_seq,
        "meta": ring.meta().decode(),
        "message": ring.message(),
        "closed": ring.closed,
    }), flush=True)
"""


def push(ring: RingWriter, n: int) -> None:
    for _ in range(n):
        s = ring.seq + 1
        ring.push(s * 1e-3, -s * 1e-6, s + 0.5, 1.0 / s, 2.0 * s, s * 1e-9, -1.0, s % 3, s % 7)


class Reader:
    def __init__(self, ring: RingWriter) -> None:
        env = checkout_env()
        self.proc = subprocess.Popen(
            [sys.executable, "-c", READER, str(ring.fd)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            pass_fds=(ring.fd,),
            env=env,
        )

    def say(self, what: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(what + "\n")
        self.proc.stdin.flush()

    def ask(self, what: str = "take") -> dict[str, object]:
        assert self.proc.stdout is not None
        self.say(what)
        line = self.proc.stdout.readline()
        assert line, ("the reader ended", self.proc.wait())
        return json.loads(line)


@pytest.fixture
def ring() -> Iterator[RingWriter]:
    ring = RingWriter(CAPACITY)
    yield ring
    ring.close()


@pytest.fixture
def reader(ring: RingWriter) -> Iterator[Reader]:
    reader = Reader(ring)
    yield reader
    assert reader.proc.stdin is not None
    reader.proc.stdin.close()
    assert reader.proc.wait() == 0


def test_samples_cross_in_order_wrap_around_and_a_late_reader_counts_the_dropped(
    ring: RingWriter, reader: Reader
) -> None:
    assert len(COLUMNS) == 10
    first = reader.ask()
    assert first["seqs"] == [] and first["dropped"] == 0 and first["pushed"] == 0
    push(ring, 10)
    got = reader.ask()
    assert got["seqs"] == list(range(1, 11)) and got["consistent"] and got["dropped"] == 0
    # 15 more: slots 11..25 wrap past the ring's end (16 slots)
    push(ring, 15)
    got = reader.ask()
    assert got["seqs"] == list(range(11, 26)) and got["consistent"] and got["dropped"] == 0
    # the reader falls behind by 40 > 16: it gets the newest it can trust, the rest counted
    push(ring, 40)
    got = reader.ask()
    seqs = got["seqs"]
    assert isinstance(seqs, list) and got["consistent"]
    assert seqs == list(range(66 - len(seqs), 66)) and CAPACITY - 2 <= len(seqs) < CAPACITY
    assert got["dropped"] == 40 - len(seqs) and got["pushed"] == 65
    assert ring.dropped == got["dropped"]  # written back for the bridge's end
    # nothing new: nothing taken, nothing more dropped
    got = reader.ask()
    assert got["seqs"] == [] and got["dropped"] == 40 - len(seqs)


def test_meta_message_and_the_end_reach_the_reader(ring: RingWriter, reader: Reader) -> None:
    ring.set_meta(b'{"cycle_s": 0.001}')
    ring.set_message("Δ following error 1.2 mm > 1 mm")
    got = reader.ask()
    assert json.loads(str(got["meta"])) == {"cycle_s": 0.001}
    assert got["message"] == "Δ following error 1.2 mm > 1 mm" and got["closed"] is False
    ring.set_message("none")
    ring.mark_closed()
    got = reader.ask()
    assert got["message"] == "none" and got["closed"] is True


def push_until_the_reader_speaks(ring: RingWriter, reader: Reader) -> dict[str, object]:
    """The writer as the loop is: it never waits for the reader and pushes until the reader
    has something to say (a backstop: 10^8 samples); what it said."""
    assert reader.proc.stdout is not None
    with selectors.DefaultSelector() as sel:
        sel.register(reader.proc.stdout, selectors.EVENT_READ)
        while not sel.select(0):
            push(ring, 1000)
            assert ring.seq < 100_000_000, "the reader never spoke"
    return json.loads(reader.proc.stdout.readline())


def test_a_reader_racing_the_writer_never_takes_a_torn_sample(
    ring: RingWriter, reader: Reader
) -> None:
    assert reader.proc.stdout is not None
    reader.say("follow")
    # the reader says when it has taken 1000 samples while racing the writer; 10,000 more
    assert "progress" in push_until_the_reader_speaks(ring, reader)
    push(ring, 10_000)
    ring.mark_closed()
    got = json.loads(reader.proc.stdout.readline())
    assert got["bad"] == 0, got
    assert got["taken"] + got["dropped"] == ring.seq and got["taken"] >= 1000, got


def test_the_write_sequence_never_goes_back_while_the_writer_publishes(
    ring: RingWriter, reader: Reader
) -> None:
    assert reader.ask("watch 300000") == {"watching": True}
    got = push_until_the_reader_speaks(ring, reader)
    assert got["backwards"] == 0 and 0 < got["last"] <= ring.seq, got
