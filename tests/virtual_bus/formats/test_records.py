"""Files of records appended while running (virtual_bus/formats/records.py): padding keeps
every line inside a 4096-byte page of the file and drops out when the padding lines are
skipped; a short write() is finished, a failed one undone -- against the kernel's own
behaviour (a pipe interrupted by a signal, RLIMIT_FSIZE), not a stand-in for write()."""

from __future__ import annotations

import fcntl
import os
import random
import signal
import subprocess
import sys
import termios
import threading
from pathlib import Path

import numpy as np
import pytest

from tests.paths import checkout_env
from virtual_bus.formats.records import (
    PAGE_BYTES,
    RecordFile,
    file_whole_lines_end,
    padded,
    whole_lines_end,
)

#: Backstop of a wait for the kernel's state (a pipe full): far beyond what it takes.
WAIT_BACKSTOP_S = 60.0


def _lines(rng: random.Random, n: int, longest: int) -> list[bytes]:
    return [b"x" * rng.randrange(1, longest) + b"\n" for _ in range(n)]


def _line_spans(data: bytes) -> list[tuple[int, int]]:
    spans, start = [], 0
    while start < len(data):
        end = data.index(b"\n", start) + 1
        spans.append((start, end))
        start = end
    return spans


@pytest.mark.parametrize("longest", [2, 60, 180, 4095, 9000])
def test_padding_keeps_every_line_inside_a_page_and_drops_out(longest: int) -> None:
    rng = random.Random(longest)
    for _ in range(40):
        lines = _lines(rng, rng.randrange(1, 400), longest)
        offset = rng.choice([0, 1, PAGE_BYTES - 1, PAGE_BYTES, rng.randrange(10**6)])
        out = padded(b"".join(lines), offset)
        spans = _line_spans(out)
        assert [out[a:b] for a, b in spans if out[a:b].strip()] == lines
        for a, b in spans:
            start, end = offset + a, offset + b
            if not out[a:b].strip():  # a padding line ends on a boundary
                assert end % PAGE_BYTES == 0
            if start // PAGE_BYTES != (end - 1) // PAGE_BYTES:  # crosses: longer than a page
                assert start % PAGE_BYTES == 0 and b - a > PAGE_BYTES
        if longest <= PAGE_BYTES:  # every boundary inside the block ends a line
            first = (offset // PAGE_BYTES + 1) * PAGE_BYTES
            assert all(out[k - offset - 1] == 0x0A for k in range(first, offset + len(out), 4096))


def test_a_block_inside_one_page_is_written_as_it_is() -> None:
    data = b"a,b\n1,2\n"
    assert padded(data, 0) == data
    assert padded(data, PAGE_BYTES - len(data)) == data  # ends on the boundary
    assert padded(data, PAGE_BYTES - 2) == b" \n" + data  # the first line would cross
    assert padded(data, PAGE_BYTES - 5) == b"a,b\n\n1,2\n"  # the second line would cross
    assert padded(data, PAGE_BYTES - 6) == b"a,b\n \n1,2\n"


def test_record_file_appends_blocks_and_whole_lines_end(tmp_path: Path) -> None:
    path = tmp_path / "r.log"
    with RecordFile(path, pad=True) as f:
        f.write_lines(["a" * 3000 + "\n", "b" * 3000 + "\n"])
        assert f.offset == path.stat().st_size
    data = path.read_bytes()
    assert data == b"a" * 3000 + b"\n" + padding_of(PAGE_BYTES - 3001) + b"b" * 3000 + b"\n"
    assert whole_lines_end(data + b"(17958") == len(data)
    (tmp_path / "t").write_bytes(data + b"x" * 70_000)  # the tail is read from the end
    assert file_whole_lines_end(tmp_path / "t") == (len(data), len(data) + 70_000)
    (tmp_path / "e").write_bytes(b"no line end")
    assert file_whole_lines_end(tmp_path / "e") == (0, 11)


def padding_of(n: int) -> bytes:
    return b" " * (n - 1) + b"\n"


@pytest.mark.skipif(not hasattr(signal, "pthread_kill"), reason="needs pthread_kill")
def test_a_short_write_is_finished(tmp_path: Path) -> None:
    """A write into a full pipe that a signal interrupts returns what it copied (a short
    write, pipe(7)); the block must still arrive whole and once."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    block = bytes(np.random.default_rng(1).integers(0, 256, 1 << 20, dtype=np.uint8))
    got = bytearray()
    signalled = threading.Event()
    main = threading.main_thread().ident
    assert main == threading.get_ident()
    errors: list[BaseException] = []

    def reader() -> None:
        try:
            with open(fifo, "rb", buffering=0) as r:
                capacity = fcntl.fcntl(r.fileno(), fcntl.F_GETPIPE_SZ)
                waited = threading.Event()
                # the writer is blocked with the pipe full: interrupt it
                for _ in range(int(WAIT_BACKSTOP_S / 0.001)):
                    queued = bytearray(4)
                    fcntl.ioctl(r.fileno(), termios.FIONREAD, queued)
                    if int.from_bytes(queued, sys.byteorder) >= capacity:
                        break
                    waited.wait(0.001)
                signal.pthread_kill(main, signal.SIGUSR1)  # type: ignore[arg-type]
                signalled.set()
                while chunk := r.read(1 << 16):
                    got.extend(chunk)
        except BaseException as exc:
            errors.append(exc)

    interrupted = []
    old = signal.signal(signal.SIGUSR1, lambda *_: interrupted.append(1))
    thread = threading.Thread(target=reader)
    thread.start()
    try:
        with RecordFile(fifo, pad=False) as f:
            f.write(block + b"\n")
    finally:
        signal.signal(signal.SIGUSR1, old)
        thread.join(WAIT_BACKSTOP_S)
    assert not errors, errors
    assert signalled.is_set() and interrupted  # the write was interrupted mid-way
    assert bytes(got) == block + b"\n"


FAILED_WRITE = """
import os, resource, signal, sys
from virtual_bus.formats.records import RecordFile
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of a signal
path = sys.argv[1]
f = RecordFile(path, pad=True)
f.write_lines(["%05d\\n" % k for k in range(1000)])
before = os.path.getsize(path)
resource.setrlimit(resource.RLIMIT_FSIZE, (before + 5000, resource.RLIM_INFINITY))
try:
    f.write_lines(["%05d\\n" % k for k in range(1000, 3000)])  # crosses the limit
except OSError as exc:
    print(exc.errno, before, os.path.getsize(path))
else:
    print("no error")
"""


def test_a_failed_write_leaves_the_file_as_before_the_block(tmp_path: Path) -> None:
    """RLIMIT_FSIZE (as a full disk would): write() copies up to the limit (a short write),
    the next one fails with EFBIG; the file is cut back to the block's start."""
    path = tmp_path / "r.log"
    env = checkout_env()
    done = subprocess.run(
        [sys.executable, "-c", FAILED_WRITE, str(path)],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        check=True,
    )
    errno_, before, after = (int(x) for x in done.stdout.split())
    assert errno_ == 27  # EFBIG
    assert after == before
    kept = [line for line in path.read_bytes().splitlines(keepends=True) if line.strip()]
    assert kept == [b"%05d\n" % k for k in range(1000)]
