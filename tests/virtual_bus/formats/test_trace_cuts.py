"""What a kill or a power loss leaves of a trace file, read back (docs/trace-file.md, "What a
kill leaves"): the recorder's file cut at every 4096-byte boundary inside its last write
(where Linux stops a write() when a SIGKILL is pending) and at random byte offsets (what a
power loss may leave). ``read_trace`` returns exactly the whole rows before the cut -- the
rows the writer was given, value for value -- and drops a torn last row with one warning
naming the file, the byte and the length; a torn row in the middle stays an error."""

from __future__ import annotations

import random
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from virtual_bus.formats.errors import TornTailWarning, TraceFileError
from virtual_bus.formats.records import PAGE_BYTES
from virtual_bus.formats.trace import MIN_ROWS, RECORDED_COLUMNS, TraceWriter, read_trace

#: The columns of the bridge's recorder (bridge/recorder.py): the spec's and its own.
COLUMNS = (*RECORDED_COLUMNS, "beta", "lambda", "disturbance", "omega_s", "omega_c", "state")
ROWS = 1000
BLOCK = 100


def recorded(path: Path, seed: int = 0) -> tuple[np.ndarray, int, int]:
    """A recorder's file of :data:`ROWS` rows in blocks of :data:`BLOCK`; returns the rows and
    the file's size before and after its last block went out."""
    rng = np.random.default_rng(seed)
    rows = rng.normal(size=(ROWS, len(COLUMNS))) * 10.0 ** rng.integers(-9, 3, (ROWS, 1))
    rows[:, 0] = np.arange(ROWS) * 1e-3
    writer = TraceWriter(path, COLUMNS, flush_every=BLOCK)
    writer.write_rows(rows[: ROWS - BLOCK])
    before = path.stat().st_size
    writer.write_rows(rows[ROWS - BLOCK :])  # the last block: one write
    after = path.stat().st_size
    writer.close()
    assert after == path.stat().st_size > before + 4 * PAGE_BYTES  # it spans pages
    return rows, before, after


def cuts(before: int, after: int, size: int, n_random: int, seed: int) -> list[int]:
    """Every page boundary inside (before, after), then random offsets in [0, size]."""
    pages = list(range((before // PAGE_BYTES + 1) * PAGE_BYTES, after, PAGE_BYTES))
    rng = random.Random(seed)
    return pages + [rng.randrange(0, size + 1) for _ in range(n_random)]


def expected_cut(data: bytes, cut: int) -> tuple[int, int]:
    """(whole data rows, where the whole lines end) of ``data[:cut]``."""
    end = data.rfind(b"\n", 0, cut) + 1
    return max(0, data.count(b"\n", 0, end) - 1), end


def check_warning(caught: list[warnings.WarningMessage], path: Path, end: int, cut: int) -> None:
    torn = [w for w in caught if issubclass(w.category, TornTailWarning)]
    if end == cut:
        assert not torn
        return
    assert len(torn) == 1, [str(w.message) for w in torn]
    text = str(torn[0].message)
    assert text.startswith(f"{path}: the last {cut - end} bytes (from byte {end})"), text


def test_a_cut_trace_reads_back_to_its_last_whole_row(tmp_path: Path) -> None:
    source = tmp_path / "recording.csv"
    rows, before, after = recorded(source)
    data = source.read_bytes()
    pages = 0
    for cut in cuts(before, after, len(data), 150, seed=1):
        path = tmp_path / f"cut_{cut}.csv"
        path.write_bytes(data[:cut])
        n, end = expected_cut(data, cut)
        pages += cut % PAGE_BYTES == 0 and before < cut < after
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            if n < MIN_ROWS:
                with pytest.raises(TraceFileError) as err:
                    read_trace(path)
                message = str(err.value)
                assert f": {n} data rows, at least" in message or "empty file" in message, message
            else:
                trace = read_trace(path)
                assert len(trace) == n
                got = np.column_stack([trace[c] for c in COLUMNS])
                assert np.array_equal(got, rows[:n])  # nothing invented, nothing changed
        check_warning(caught, path, end, cut)
        path.unlink()
    assert pages >= 4


def test_a_torn_row_in_the_middle_stays_an_error(tmp_path: Path) -> None:
    source = tmp_path / "recording.csv"
    recorded(source)
    lines = source.read_bytes().split(b"\n")
    lines[500] = lines[500][: len(lines[500]) // 2]  # row 500 cut, the rows after it whole
    source.write_bytes(b"\n".join(lines))
    with pytest.raises(TraceFileError, match=re.escape(f"{source}: line 501 has")):
        read_trace(source)


def test_a_clean_file_is_byte_for_byte_what_it_was(tmp_path: Path) -> None:
    """The writer's blocks are the rows as they were before, nothing added: the file equals
    the rows formatted at once."""
    source = tmp_path / "recording.csv"
    rows, _, _ = recorded(source)
    text = (
        ",".join(COLUMNS) + "\n" + "".join(",".join(map(repr, map(float, r))) + "\n" for r in rows)
    )
    assert source.read_text() == text
