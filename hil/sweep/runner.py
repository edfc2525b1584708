"""A sweep: one task over many axes of an FMU family, on Dask, resumable, one table.

``python -m hil sweep TASK --fmu FMU --seeds 1000-1299 --out DIR`` runs ``TASK``
(:mod:`hil.sweep.tasks`) once per seed, each on the axis ``seed`` draws (the FMU's other
parameters as given), as Dask tasks (:mod:`plant_sim.parallel`: local processes by default,
``--scheduler`` for a cluster). Every finished seed is one row written at once to
``DIR/parts/seed-NNNNNNN.parquet`` (:mod:`virtual_bus.atomic`: a killed sweep leaves whole
parts only); a sweep started again with the same ``--out`` and the same configuration
(``DIR/sweep.json``: task, FMU content hash, parameters, mapping, task options) runs only the
seeds without a part. At the end the parts become ``DIR/results.parquet`` (sorted by seed)
and the task's summary table (``DIR/summary.json``, printed).

A row holds the seed, the task's columns, ``error`` (the one-line message when the task
raised, else empty) and ``seconds`` (its wall time in the worker). Columns named ``truth_*``
are the FMU's scoring values (its README: read only in a scoring step): the task's code under
test never sees them; the summary uses them to score.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plant_sim.errors import PlantSimError
from plant_sim.fmu.model import FmuSpec
from virtual_bus.atomic import replacing, write_atomic

from .tasks import TASKS, Task

#: Version of the part and table layout (sweep.json says which wrote a folder).
LAYOUT = 1


class SweepError(PlantSimError, ValueError):
    """A sweep that cannot run as asked (an output folder of another sweep, no seeds)."""


@dataclass(frozen=True)
class SweepItem:
    """One seed's work, what a Dask worker gets (picklable)."""

    task: str
    spec: FmuSpec
    seed: int
    options: tuple[tuple[str, str], ...] = ()


def run_item(item: SweepItem) -> dict[str, Any]:
    """The worker's function: the task on one seed, its row (an exception becomes the
    row's ``error``, never lost)."""
    task = TASKS[item.task]
    start = time.perf_counter()
    row: dict[str, Any] = {"seed": item.seed, "error": ""}
    try:
        row |= task.run(item.spec.with_parameters(seed=item.seed), dict(item.options))
    except Exception as exc:  # a row per seed whatever happens: the table says what
        last = traceback.extract_tb(exc.__traceback__)[-1]
        row["error"] = (
            f"{type(exc).__name__}: {exc} ({Path(last.filename).name}:{last.lineno})"
        ).replace("\n", " ")
    row["seconds"] = time.perf_counter() - start
    return row


def parse_seeds(text: str) -> list[int]:
    """``1-200``, ``1,5,9``, ``1000-1099,2000`` -> sorted unique seeds (>= 0)."""
    seeds: set[int] = set()
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        lo, sep, hi = part.partition("-")
        try:
            a = int(lo)
            b = int(hi) if sep else a
        except ValueError:
            raise SweepError(f"--seeds {text!r}: {part!r} is not N or N-M") from None
        if a < 0 or b < a:
            raise SweepError(f"--seeds {text!r}: {part!r}: seeds are >= 0, N-M with M >= N")
        seeds.update(range(a, b + 1))
    if not seeds:
        raise SweepError(f"--seeds {text!r}: no seed")
    return sorted(seeds)


def _fmu_hash(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@dataclass(frozen=True)
class Sweep:
    """What runs (module docstring)."""

    task: str
    spec: FmuSpec
    seeds: Sequence[int]
    out: Path
    options: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.task not in TASKS:
            raise SweepError(f"task {self.task!r}: allowed: {', '.join(TASKS)}")
        unknown = set(self.options) - set(TASKS[self.task].options)
        if unknown:
            allowed = ", ".join(TASKS[self.task].options) or "none"
            raise SweepError(
                f"--option {sorted(unknown)[0]}: not an option of {self.task}; allowed: " + allowed
            )
        for name, value in self.options.items():
            # every task's options are numbers (durations, levels, speeds): a word would fail
            # on every seed, so it is refused before anything runs
            try:
                ok = math.isfinite(float(value))
            except ValueError:
                ok = False
            if not ok:
                raise SweepError(f"--option {name}={value}: a finite number")
        if "seed" in dict(self.spec.parameters):
            raise SweepError("--fmu-param seed=...: the sweep sets seed (give --seeds)")

    def configuration(self) -> dict[str, Any]:
        return {
            "layout": LAYOUT,
            "task": self.task,
            "fmu": str(self.spec.path),
            "fmu_sha256": _fmu_hash(self.spec.path),
            "fmu_parameters": dict(self.spec.parameters),
            "fmu_mapping": self.spec.mapping.describe(),
            "options": dict(sorted(self.options.items())),
        }

    @property
    def parts(self) -> Path:
        return self.out / "parts"

    def part(self, seed: int) -> Path:
        return self.parts / f"seed-{seed:07d}.parquet"

    def prepare(self) -> list[int]:
        """Check ``out`` against this sweep's configuration (a folder of another sweep is
        refused), write ``sweep.json``; the seeds still to run."""
        self.out.mkdir(parents=True, exist_ok=True)
        self.parts.mkdir(exist_ok=True)
        config = self.configuration()
        path = self.out / "sweep.json"
        if path.exists():
            try:
                old = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, json.JSONDecodeError) as exc:
                raise SweepError(f"{path}: not a sweep's configuration ({exc})") from None
            if old != config:
                differ = sorted(k for k in config if old.get(k) != config[k])
                raise SweepError(
                    f"{self.out} holds a sweep of another configuration (differs in "
                    f"{', '.join(differ)}); give another --out or the same options"
                )
        else:
            write_atomic(path, json.dumps(config, indent=2) + "\n")
        return [s for s in self.seeds if not self.part(s).exists()]

    def items(self, seeds: Iterable[int]) -> Iterable[SweepItem]:
        spec = FmuSpec(self.spec.path.resolve(), self.spec.parameters, self.spec.mapping)
        options = tuple(sorted(self.options.items()))
        return (SweepItem(self.task, spec, s, options) for s in seeds)

    def store(self, row: dict[str, Any]) -> None:
        """One finished seed's part (atomically)."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        with replacing(self.part(int(row["seed"])), durable=True) as tmp:
            pq.write_table(pa.Table.from_pylist([row]), tmp)

    def table(self) -> list[dict[str, Any]]:
        """Every row of this sweep's seeds that has a part, sorted by seed."""
        import pyarrow.parquet as pq

        rows = []
        for seed in self.seeds:
            path = self.part(seed)
            if path.exists():
                rows.extend(pq.read_table(path).to_pylist())
        return rows

    def finish(self) -> dict[str, Any]:
        """``results.parquet`` and ``summary.json`` from the parts; the summary."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        rows = self.table()
        task: Task = TASKS[self.task]
        columns = sorted({k for r in rows for k in r}, key=_column_order)
        table = pa.Table.from_pylist([{c: r.get(c) for c in columns} for r in rows])
        with replacing(self.out / "results.parquet") as tmp:
            pq.write_table(table, tmp)
        summary = {
            "task": self.task,
            "fmu": self.spec.describe(),
            "seeds": _ranges(self.seeds),
            "rows": len(rows),
            "errors": sum(1 for r in rows if r.get("error")),
            "seconds_per_seed": _spread([r["seconds"] for r in rows]),
            "figures": task.summarize(rows),
        }
        write_atomic(self.out / "summary.json", json.dumps(summary, indent=2) + "\n")
        return summary


def _column_order(name: str) -> tuple[int, str]:
    first = {"seed": 0, "error": 2, "seconds": 3}
    return (4 if name.startswith("truth_") else first.get(name, 1), name)


def _spread(values: Sequence[float]) -> dict[str, float] | None:
    if not values:
        return None
    v = sorted(values)
    return {"min": v[0], "median": v[len(v) // 2], "max": v[-1]}


def _ranges(seeds: Sequence[int]) -> str:
    out, start, prev = [], None, None
    for s in sorted(seeds):
        if start is None:
            start = prev = s
        elif s == prev + 1:  # type: ignore[operator]
            prev = s
        else:
            out.append(f"{start}-{prev}" if start != prev else str(start))
            start = prev = s
    if start is not None:
        out.append(f"{start}-{prev}" if start != prev else str(start))
    return ",".join(out)


def run_sweep(
    sweep: Sweep,
    workers: int = 2,
    scheduler: str | None = None,
    on_row: Callable[[dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """Run the seeds still to run (:meth:`Sweep.prepare`), store each row as it comes,
    finish; the summary."""
    from plant_sim.parallel import run_tasks

    todo = sweep.prepare()

    def sink(row: dict[str, Any]) -> None:
        sweep.store(row)
        if on_row is not None:
            on_row(row)

    if todo:
        run_tasks(run_item, sweep.items(todo), sink, workers, scheduler)
    return sweep.finish()
