"""Interpolator: the reference x_ref (load units) and its speed, one sample per cycle.

Sources of motion: :class:`Move` (point-to-point at a feed, with an acceleration or as the
paper's speed step), :class:`Table` (a precomputed reference such as section X's, see
:meth:`Table.from_references`), moves parsed from the command line (:func:`parse_move`) or a
move file (:func:`load_move_file`), and the target-position object 2010h (the OD layer builds
a :class:`Move`).

The speed of sample k is the forward difference ``(x[k+1] - x[k]) / cycle`` -- the
interpolator's speed over the coming cycle, as in :meth:`plant_sim.physics.simulate.References
.from_position`; omega_s = k_r * speed is what the regulator compares omega_c with (Fig. 5).
Stepped once per cycle, no allocation per step.
"""

from __future__ import annotations

import math
import tomllib
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from .errors import MoveError, MoveFileError

#: Largest |target| accepted, load units (a sanity bound, 1 km or 1000 rad).
MAX_ABS_TARGET = 1000.0


def _finite(name: str, value: object, *, low: float, low_open: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise MoveError(f"{name} = {value!r}: must be a finite number")
    if value < low or (low_open and value == low):
        raise MoveError(f"{name} = {value!r}: must be {'>' if low_open else '>='} {low:g}")
    return float(value)


@dataclass(frozen=True)
class Move:
    """Point-to-point move to ``target`` (load units) at ``feed`` (load units/s, > 0).

    accel: load units/s², 0 = speed step (the interpolator jumps to the feed, as the paper's
    section X input); > 0 = trapezoidal speed profile (triangular if too short to reach the
    feed). dwell_s: standstill after arriving, s.
    """

    target: float
    feed: float
    accel: float = 0.0
    dwell_s: float = 0.0

    def __post_init__(self) -> None:
        target = _finite("target", self.target, low=-MAX_ABS_TARGET)
        if target > MAX_ABS_TARGET:
            raise MoveError(f"target = {target!r}: must be within +-{MAX_ABS_TARGET:g} load units")
        _finite("feed", self.feed, low=0.0, low_open=True)
        _finite("accel", self.accel, low=0.0)
        _finite("dwell_s", self.dwell_s, low=0.0)


class SampledReference(Protocol):
    """Position and speed references sample by sample (load units, load units/s)."""

    @property
    def position(self) -> np.ndarray: ...

    @property
    def speed(self) -> np.ndarray: ...


@dataclass(frozen=True)
class Table:
    """A reference given sample by sample (absolute positions, load units; speeds load
    units/s), played from its first sample; afterwards the last position is held."""

    position: np.ndarray
    speed: np.ndarray

    def __post_init__(self) -> None:
        pos = np.ascontiguousarray(self.position, dtype=float)
        spd = np.ascontiguousarray(self.speed, dtype=float)
        if pos.ndim != 1 or spd.shape != pos.shape or pos.size == 0:
            raise MoveError(
                f"table: position {pos.shape} and speed {spd.shape} must be equal 1-d, non-empty"
            )
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(spd))):
            raise MoveError("table: positions and speeds must be finite")
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "speed", spd)

    @classmethod
    def from_references(cls, refs: SampledReference) -> Table:
        """The interpolator part of a reference table (e.g. the simulator's
        ``References``: anything with ``position`` and ``speed`` arrays)."""
        return cls(refs.position, refs.speed)


class _Profile:
    """Distance over time of one :class:`Move` from ``start`` (closed form)."""

    def __init__(self, move: Move, start: float) -> None:
        self.start = start
        self.target = move.target
        self.sign = 1.0 if move.target >= start else -1.0
        dist = abs(move.target - start)
        self.dist = dist
        self.accel = move.accel
        if move.accel == 0.0:
            self.peak = move.feed
            self.t_acc = 0.0
            self.t_cruise = dist / move.feed
        elif dist >= move.feed**2 / move.accel:
            self.peak = move.feed
            self.t_acc = move.feed / move.accel
            self.t_cruise = (dist - move.feed**2 / move.accel) / move.feed
        else:
            self.peak = math.sqrt(move.accel * dist)
            self.t_acc = self.peak / move.accel
            self.t_cruise = 0.0
        self.t_total = 2.0 * self.t_acc + self.t_cruise
        self.d_acc = 0.5 * move.accel * self.t_acc**2

    def position(self, t: float) -> float:
        if t >= self.t_total:
            return self.target
        if t < self.t_acc:
            d = 0.5 * self.accel * t * t
        elif t < self.t_acc + self.t_cruise:
            d = self.d_acc + self.peak * (t - self.t_acc)
        else:
            rest = self.t_total - t
            d = self.dist - 0.5 * self.accel * rest * rest
        return self.start + self.sign * d


class Interpolator:
    """Plays queued moves and tables; :meth:`step` once per cycle, then read
    :attr:`position` (load units) and :attr:`speed` (load units/s)."""

    def __init__(self, cycle_s: float, position: float = 0.0) -> None:
        self.cycle_s = _finite("cycle_s", cycle_s, low=0.0, low_open=True)
        self.position = float(position)
        self.speed = 0.0
        self._queue: deque[Move | Table] = deque()
        self._profile: _Profile | None = None
        self._table: Table | None = None
        self._positions: list[float] = []  # the running table's samples as Python floats
        self._speeds: list[float] = []
        self._table_end = 0
        self._j = 0  # samples of the running item so far
        self._dwell_left = 0
        self._next = self.position

    @property
    def busy(self) -> bool:
        """A move or table is running or queued (dwell counts as running)."""
        return bool(self._queue or self._profile or self._table is not None or self._dwell_left > 0)

    def hold(self, position: float) -> None:
        """Drop every move and hold ``position`` (load units) at speed 0."""
        self._queue.clear()
        self._profile = None
        self._table = None
        self._dwell_left = 0
        self.position = float(position)
        self._next = self.position
        self.speed = 0.0

    def queue(self, item: Move | Table) -> None:
        """Append a move or table; it starts when the ones before it are done."""
        if not isinstance(item, Move | Table):
            raise MoveError(f"can queue a Move or a Table, not {type(item).__name__}")
        self._queue.append(item)

    def _start_next(self) -> None:
        item = self._queue.popleft()
        self._j = 0
        if isinstance(item, Table):
            self._table = item
            # Python floats, read one a cycle (a numpy element costs a numpy scalar each)
            self._positions = item.position.tolist()
            self._speeds = item.speed.tolist()
            self._table_end = len(self._positions)
            return
        self._profile = _Profile(item, self._next)
        self._dwell_left = round(item.dwell_s / self.cycle_s)

    def step(self) -> None:
        """Advance one cycle: sample k of the reference and the speed over the coming cycle."""
        if self._table is None and self._profile is None and self._queue and not self._dwell_left:
            self._start_next()
        if self._table is not None:
            # _next (where a move starts) matters only once the table is over: set then
            j = self._j
            self.position = position = self._positions[j]
            self.speed = self._speeds[j]
            self._j = j = j + 1
            if j >= self._table_end:
                self._table = None
                self._next = position
            return
        profile = self._profile
        if profile is not None:
            t = self._j * self.cycle_s
            self.position = profile.position(t)
            self._j += 1
            if t >= profile.t_total:
                self.position = profile.target
                self._next = profile.target
                self.speed = 0.0
                self._profile = None
                return
            self._next = profile.position(self._j * self.cycle_s)
            self.speed = (self._next - self.position) / self.cycle_s
            return
        self.position = self._next
        self.speed = 0.0
        if self._dwell_left:
            self._dwell_left -= 1


# --- move text: command line and move files --------------------------------------------------
_KEYS = {"target": "target", "feed": "feed", "accel": "accel", "dwell": "dwell_s"}


def _from_mapping(values: dict[str, object], where: str) -> Move:
    unknown = sorted(set(values) - set(_KEYS))
    if unknown:
        raise MoveError(f"{where}: unknown key(s) {unknown}; allowed: {', '.join(_KEYS)}")
    for key in ("target", "feed"):
        if key not in values:
            raise MoveError(f"{where}: missing {key!r} (a move needs target and feed)")
    try:
        return Move(**{_KEYS[k]: v for k, v in values.items()})  # type: ignore[arg-type]
    except MoveError as exc:
        raise MoveError(f"{where}: {exc}") from None


def parse_move(text: str) -> Move:
    """``target=0.3,feed=0.05[,accel=0.5][,dwell=1]`` (load units, /s, /s², s) -> Move."""
    values: dict[str, object] = {}
    for part in text.split(","):
        key, sep, raw = part.partition("=")
        key = key.strip()
        if not sep or not key:
            raise MoveError(f"move {text!r}: expected key=value pairs like 'target=0.3,feed=0.05'")
        try:
            values[key] = float(raw)
        except ValueError:
            raise MoveError(f"move {text!r}: {key} = {raw.strip()!r} is not a number") from None
    return _from_mapping(values, f"move {text!r}")


def load_move_file(path: str | Path) -> list[Move]:
    """Read a TOML move file: one ``[[move]]`` table per move with ``target``, ``feed`` and
    optionally ``accel`` and ``dwell`` (load units, /s, /s², s)."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise MoveFileError(f"{path}: no such move file", path=str(path)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise MoveFileError(f"{path}: cannot read ({exc})", path=str(path)) from None
    except tomllib.TOMLDecodeError as exc:
        raise MoveFileError(f"{path}: not valid TOML ({exc})", path=str(path)) from None
    extra = sorted(set(doc) - {"move"})
    if extra:
        raise MoveFileError(f"{path}: unknown key(s) {extra}; only [[move]] tables", path=str(path))
    items = doc.get("move")
    if not isinstance(items, list) or not items:
        raise MoveFileError(f"{path}: no [[move]] tables", path=str(path))
    moves = []
    for i, item in enumerate(items, start=1):
        if not isinstance(item, dict):
            raise MoveFileError(f"{path}: move {i} is not a table", path=str(path), entry=i)
        try:
            moves.append(_from_mapping(item, f"{path}: move {i}"))
        except MoveError as exc:
            raise MoveFileError(str(exc), path=str(path), entry=i) from None
    return moves
