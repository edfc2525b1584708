"""A crash loses nothing (issue 34): ``python -m hil demo`` and ``python -m bridge run``
against the simulated drive are killed with SIGKILL at random moments while both CPUs are
kept busy, and every file they leave reads back to its last whole record.

Each trial is a child forked from a warm process (tests/forking.py: the imports and numba's
compiled code are loaded once, not fifty times); the moment is a state -- a file of the run
reaching a random size, after the files of earlier stages exist -- plus a random number of
further looks at it, never a wall-clock delay. What every file must be (docs/trace-file.md
and docs/bridge.md, "What a kill leaves"):

* a trace (``*.csv``): whole rows and at most one torn last row, which ``read_trace`` drops
  with one warning naming the file, the byte and the length (a test parser of its own reads
  the rows too); the demo's rows equal the rows of that index of a complete run (lockstep,
  the drive polled in the loop's thread: deterministic; ``bridge run``'s drive answers from
  its own thread, and a starved one may make a run differ, so there the log is the check);
* a bus log (``*.log``): whole lines only (padding: a kill never tears one); python-can's
  ``LogReader`` and can-utils' ``log2asc`` read it without an error; the demo's frames are
  the complete run's first frames (the start-up's as a set: the drive's own thread orders
  them);
* a trace and the bus log of the same run agree: with S SYNC frames in the log and R rows in
  the trace, |S - R| <= 100 (both go out in blocks of 100 cycles; while the loop runs the
  log's block before the SYNC that starts the next and the trace's right after it, so
  0 <= S - R <= 100; at the end the trace's last rows may go out before the log's last
  frames; a kill inside a block leaves a part of it), and row k's motor position is the
  6064h of the TPDO1 after the log's SYNC k; the monitor's reader reads the log too;
* a file written whole (figures, summary.json, axis_limit_cycle.toml, the traces the demo
  writes at its end): absent, the one it replaces, or complete (equal to the complete run's),
  and at most a hidden ``.NAME.XXXXXXXX.tmp`` beside it.

10 demo and 40 ``bridge run`` trials (``KILL_DEMO=N KILL_BRIDGE=M`` to change, ``KILL_SEED=S``
to draw the moments of a failed run again); the tally printed at the end says how many files
a kill left cut inside a block.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import time
import warnings
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np
import pytest

from fleet.candump import read_candump_chunks
from tests.forking import Forker
from virtual_bus.formats.errors import TornTailWarning, TraceFileError
from virtual_bus.formats.records import PAGE_BYTES
from virtual_bus.formats.trace import MIN_ROWS, read_trace

pytestmark = pytest.mark.slow

DEMO_TRIALS = int(os.environ.get("KILL_DEMO", 10))
BRIDGE_TRIALS = int(os.environ.get("KILL_BRIDGE", 40))
#: Rows (cycles) per block of the recorder and of the bus log (bridge/recorder.py).
BLOCK = 100
#: Backstop of a wait for a moment of a trial (the child ends first: far beyond its run).
MOMENT_BACKSTOP_S = 600.0
INC_RAD = 2 * np.pi / (1 << 20)
#: How close to its size a moment's file must be for the wait to look without pausing.
NEAR_BYTES = 1 << 16
TEMPORARY = re.compile(r"^\.(.+)\.[0-9a-f]{8}\.tmp$")
LOG2ASC = shutil.which("log2asc")

#: The demo's stages in the order it reaches them: (files that exist by then, file that grows)
#: -- the runs of the axis as given, then again with the limit-cycle friction (after
#: as_given_regulated.csv), then figures and summary.
DEMO_STAGES = (
    *(((), name) for name in ("bus_ordinary.log", "ordinary.csv")),
    *(((), name) for name in ("bus_regulated.log", "regulated.csv")),
    (("as_given_regulated.csv",), "bus_ordinary.log"),
    (("as_given_regulated.csv",), "ordinary.csv"),
    (("as_given_regulated.csv",), "bus_regulated.log"),
    (("as_given_regulated.csv",), "regulated.csv"),
    ((), "fig8.png"),
    ((), "fig9.png"),
    ((), "summary.json"),
)
BRIDGE_STAGES = (((), "bus.log"), ((), "trace.csv"))
#: Files the demo writes whole (the others grow while it runs).
WHOLE = {"fig8.png", "fig9.png", "summary.json", "axis_limit_cycle.toml"}


@dataclass(frozen=True)
class Moment:
    after: tuple[str, ...]
    file: str
    nbytes: int
    looks: int  # further looks at the file before the kill: spreads the moment


@dataclass
class Reference:
    """A complete run: its traces (by column), its logs' frames, its files' bytes."""

    folder: Path
    traces: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    frames: dict[str, list[tuple[int, bytes, bool]]] = field(default_factory=dict)
    lines: dict[str, bytes] = field(default_factory=dict)  # the logs, without_times


@dataclass
class Tally:
    check_s: float = 0.0
    run_s: float = 0.0
    torn_traces: int = 0  # ending in a row cut short
    logs_cut: int = 0  # ending on a 4096-byte boundary before their run's end
    killed: int = 0
    ended: int = 0
    pairs: int = 0


@contextlib.contextmanager
def cpu_hogs(n: int) -> Iterator[None]:
    """``n`` spinning processes (this test's own), stopped at the end."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()


def parse_rows(path: Path) -> tuple[list[str], np.ndarray, int, int]:
    """The test's own reading of a trace: header, whole rows, where they end, file size."""
    data = path.read_bytes()
    end = data.rfind(b"\n") + 1
    lines = list(csv.reader(io.StringIO(data[:end].decode())))
    if not lines:
        return [], np.empty((0, 0)), end, len(data)
    header, body = lines[0], lines[1:]
    rows = np.array([[float(x) for x in r] for r in body]).reshape(len(body), len(header))
    return header, rows, end, len(data)


Frame = tuple[int, bytes, bool]


def frames_of(path: Path) -> list[Frame]:
    return [(m.arbitration_id, bytes(m.data), m.is_rx) for m in can.LogReader(str(path))]


def reference(folder: Path) -> Reference:
    ref = Reference(folder)
    for path in folder.iterdir():
        if path.suffix == ".csv":
            header, rows, _, _ = parse_rows(path)
            ref.traces[path.name] = {c: rows[:, j] for j, c in enumerate(header)}
        elif path.suffix == ".log":
            ref.frames[path.name] = frames_of(path)
            ref.lines[path.name] = without_times(path.read_bytes())
    return ref


def without_times(log: bytes) -> bytes:
    """A log's lines without their timestamps (the wall clock's: the rest is lockstep's)."""
    return re.sub(rb"(?m)^\(\d+\.\d+\) ", b"", log)


def wait_for(moment: Moment, out: Path, forker: Forker) -> None:
    """Until the moment has come or the child has ended (bounded by the backstop). Near the
    size it waits for, it looks without pausing: a file grows page by page while a write()
    copies it, so a kill right after the size is seen may stop that very write."""
    target = out / moment.file
    deadline = time.monotonic() + MOMENT_BACKSTOP_S
    while time.monotonic() < deadline:
        if forker.ended():
            return
        size = -1
        with contextlib.suppress(FileNotFoundError):
            if all((out / name).exists() for name in moment.after):
                size = target.stat().st_size
        if size >= moment.nbytes:
            for _ in range(moment.looks):
                target.exists()
            return
        if size < moment.nbytes - NEAR_BYTES:
            time.sleep(0.0005)  # a pause between looks at the state, not a wait for time
    raise TimeoutError(f"{moment} never came")


def check_trace(path: Path, candidates: list[dict[str, np.ndarray]] | None, tally: Tally) -> int:
    """The trace reads back to its last whole row (see the module docstring); its rows.
    ``candidates``: complete runs its rows must begin (None: a run that may differ)."""
    header, rows, end, size = parse_rows(path)
    n = len(rows)
    if n and candidates is not None:  # a complete run's rows of that stage, value for value
        assert any(
            set(ref) == set(header)
            and all(np.array_equal(ref[c][:n], rows[:, j]) for j, c in enumerate(header))
            for ref in candidates
        ), f"{path}: {n} rows are not the first rows of a complete run"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if n >= MIN_ROWS:
            trace = read_trace(path)
            assert len(trace) == n
            assert all(np.array_equal(trace[c], rows[:, j]) for j, c in enumerate(header))
        else:
            with pytest.raises(TraceFileError, match=rf"{n} data rows|empty file"):
                read_trace(path)
    torn = [str(w.message) for w in caught if issubclass(w.category, TornTailWarning)]
    if end < size:
        tally.torn_traces += 1
        assert len(torn) == 1, torn
        assert torn[0].startswith(f"{path}: the last {size - end} bytes (from byte {end})")
    else:
        assert not torn, torn
    return n


def check_log(path: Path, candidates: list[list[Frame]] | None) -> list[Frame]:
    """The log reads back frame for frame with python-can and log2asc; its frames."""
    data = path.read_bytes()
    assert not data or data.endswith(b"\n"), f"{path}: a kill tore a line ({data[-60:]!r})"
    frames = frames_of(path)
    if candidates is not None:
        assert any(same_start(frames, ref) for ref in candidates), f"{path}: frames differ"
    if LOG2ASC is not None and frames:
        channel = data.split(b" ", 2)[1].decode()
        done = subprocess.run(
            [LOG2ASC, "-I", str(path), channel], capture_output=True, text=True, timeout=120
        )
        assert done.returncode == 0 and not done.stderr, (path, done.stderr)
        converted = [ln for ln in done.stdout.splitlines() if re.match(r"\s*\d+\.\d+ 1 ", ln)]
        assert len(converted) == len(frames)
    return frames


def same_start(frames: list[Frame], ref: list[Frame]) -> bool:
    """Whether ``frames`` begin a complete run's ``ref``: from the first SYNC on frame for
    frame (the drive answers in the loop's thread); before it, the start-up's frames, whose
    order the drive's own thread sets (its boot-up before or after the bridge's NMT
    command), as a part of the complete start-up's."""
    sync = next((i for i, f in enumerate(frames) if f[0] == 0x080), len(frames))
    ref_sync = next(i for i, f in enumerate(ref) if f[0] == 0x080)
    if sync == len(frames):
        return not Counter(frames) - Counter(ref[:ref_sync])
    return (
        Counter(frames[:sync]) == Counter(ref[:ref_sync])
        and frames[sync:] == ref[ref_sync : ref_sync + len(frames) - sync]
    )


def check_pair(trace: Path, log: Path, rows: int, frames: list[Frame]) -> None:
    """A trace and the bus log of one run agree (see the module docstring): the counts, and
    row k's motor position is the 6064h of the TPDO1 after the log's SYNC k, decoded here
    (a cycle whose TPDO1 is not in the log is skipped: the bridge kept the value before)."""
    syncs = sum(f[0] == 0x080 for f in frames)
    assert abs(syncs - rows) <= BLOCK, (trace, rows, log, syncs)
    header, values, _, _ = parse_rows(trace)
    motor = values[:, header.index("motor_position")] if rows else np.empty(0)
    k = -1
    compared = 0
    for cob, data, _ in frames:
        if cob == 0x080:
            k += 1
        elif cob == 0x182 and 0 <= k < rows:
            inc = int.from_bytes(data[:4], "little", signed=True)
            assert abs(motor[k] - inc * INC_RAD) <= 1e-3 * INC_RAD, (trace, k, motor[k], inc)
            compared += 1
    assert compared or min(rows, syncs) < 2, (trace, rows, log, syncs)
    with warnings.catch_warnings():  # the monitor's reader reads the killed log too
        warnings.simplefilter("ignore", TornTailWarning)
        decoded = sum(len(c) for c in read_candump_chunks(log)) if syncs else 0
    assert decoded <= syncs


def same_as_reference(path: Path, ref: Reference) -> bool:
    """Whether the file equals the complete run's (a log: but for its timestamps)."""
    theirs = ref.folder / path.name
    if not theirs.exists() or theirs.stat().st_size != path.stat().st_size:
        return False
    if path.name in ref.lines:
        return without_times(path.read_bytes()) == ref.lines[path.name]
    return path.read_bytes() == theirs.read_bytes()


def check_folder(out: Path, ref: Reference, demo: bool, tally: Tally, whole: bool = True) -> None:
    """Every file a trial left (see the module docstring). ``whole``: a file equal to the
    complete run's (a log: but for its timestamps) is checked by that equality alone."""
    counts: dict[str, int] = {}  # rows of a trace, SYNCs of a log
    logged: dict[str, list[Frame]] = {}
    same: set[str] = set()
    for path in sorted(out.iterdir()):
        name = path.name
        if name in ("child.out", "child.err"):
            continue
        if whole and demo and same_as_reference(path, ref):
            same.add(name)
            continue
        temporary = TEMPORARY.match(name)
        if temporary:  # a kill before the rename: the file it was to replace is whole
            assert (ref.folder / temporary[1]).exists(), name
            continue
        if path.suffix == ".csv":
            base = name.removeprefix("as_given_")
            candidates = [
                ref.traces[n] for n in (name, f"as_given_{base}", base) if n in ref.traces
            ]
            counts[name] = check_trace(path, candidates if demo else None, tally)
        elif path.suffix == ".log":
            base = name.removeprefix("as_given_")
            candidates = [ref.frames[n] for n in {name, f"as_given_{base}"} if n in ref.frames]
            logged[name] = check_log(path, candidates if demo else None)
            counts[name] = sum(f[0] == 0x080 for f in logged[name])
            size = path.stat().st_size
            tally.logs_cut += size < (ref.folder / name).stat().st_size and size % PAGE_BYTES == 0
        elif name == "summary.json":
            assert (
                json.loads(path.read_text()).keys()
                == json.loads((ref.folder / name).read_text()).keys()
            )
        else:
            assert name in WHOLE and path.read_bytes() == (ref.folder / name).read_bytes(), name
    pairs = (
        [(f"{run}.csv", f"bus_{run}.log") for run in ("ordinary", "regulated")]
        + [(f"as_given_{run}.csv", f"as_given_bus_{run}.log") for run in ("ordinary", "regulated")]
        if demo
        else [("trace.csv", "bus.log")]
    )
    for trace, log in pairs:
        if trace in counts and log in counts and not {trace, log} <= same:
            tally.pairs += 1
            check_pair(out / trace, out / log, counts[trace], logged[log])


def random_moment(rng: random.Random, stages: tuple, ref: Reference) -> Moment:
    after, name = rng.choice(stages)
    size = (ref.folder / name).stat().st_size
    # a page boundary: the sizes a file passes through while a write() copies it
    nbytes = 1 if name in WHOLE else PAGE_BYTES * rng.randrange(0, size // PAGE_BYTES + 1)
    return Moment(after, name, nbytes, rng.choice([0, 0, 0, rng.randrange(1, 200)]))


def test_a_killed_demo_and_bridge_leave_files_that_read_back(tmp_path: Path) -> None:
    seed = int(os.environ.get("KILL_SEED", random.randrange(1 << 30)))  # printed on failure
    rng = random.Random(seed)
    tally = Tally()
    env = {**os.environ, "KILL_REFERENCES": str(tmp_path / "references")}
    with (
        cpu_hogs(os.cpu_count() or 2),
        Forker(["tests.hil.kill_trials:references"], env=env) as forker,
    ):
        refs = {kind: reference(tmp_path / "references" / kind) for kind in ("demo", "bridge_run")}
        # a complete run agrees with itself: every SYNC has its row
        check_folder(refs["demo"].folder, refs["demo"], True, Tally(), whole=False)
        check_folder(refs["bridge_run"].folder, refs["bridge_run"], False, Tally(), whole=False)
        trials = [("demo", DEMO_STAGES)] * DEMO_TRIALS + [
            ("bridge_run", BRIDGE_STAGES)
        ] * BRIDGE_TRIALS
        for i, (kind, stages) in enumerate(trials):
            ref = refs[kind]
            moment = random_moment(rng, stages, ref)
            out = tmp_path / f"{kind}_{i}"
            t0 = time.perf_counter()
            pid = forker.start(f"tests.hil.kill_trials:{kind}", [str(out)], out)
            wait_for(moment, out, forker)
            if not forker.ended():
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
            status = forker.wait()
            t1 = time.perf_counter()
            tally.run_s += t1 - t0
            assert status in ("signal 9", "exit 0"), (status, (out / "child.err").read_text())
            tally.killed += status == "signal 9"
            tally.ended += status == "exit 0"
            try:
                check_folder(out, ref, kind == "demo", tally)
            except AssertionError as exc:
                raise AssertionError(f"trial {i} ({kind}, seed {seed}, {moment}): {exc}") from exc
            shutil.rmtree(out)
            tally.check_s += time.perf_counter() - t1
    print(f"kill trials (seed {seed}): {tally}")
    assert tally.killed >= (DEMO_TRIALS + BRIDGE_TRIALS) // 2, tally
