"""Which recordings make up the fleet, and which machine, axis and date each belongs to.

Two ways to name them, as a maintenance department files its recordings:

* **Folder layout** ``ROOT/MACHINE/AXIS/.../FILE``: the first two folders below a path given on
  the command line are the machine and the axis; the date is the first ISO date
  (``YYYY-MM-DD``, optionally followed by ``THH-MM-SS`` / ``_HHMMSS``) in the rest of the path.
* **Axis map** (``--axes MAP.toml``): one ``[[axis]]`` table per axis with ``machine``,
  ``axis``, ``axis_file`` (the axis file with its k_v and transmission ratio) and optional
  ``paths`` (globs, relative to the map's folder) that claim recordings whatever the folder
  layout says; ``[defaults] axis_file`` applies to axes that name none.

Recordings are ``*.csv`` (trace files, ``docs/axis-file.md`` / trace spec) and ``*.log``
(candump logs of the bridge's bus); other files are ignored and counted.
"""

from __future__ import annotations

import datetime as dt
import enum
import re
import tomllib
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from .errors import FleetMapError


class RecordingKind(enum.Enum):
    """File format of a recording."""

    TRACE = "trace"  # trace file (CSV), the project's trace spec
    CANDUMP = "candump"  # candump -l log of the bridge's bus


SUFFIXES = {".csv": RecordingKind.TRACE, ".log": RecordingKind.CANDUMP}

_DATE = re.compile(
    r"(?P<y>\d{4})-(?P<mo>\d{2})-(?P<d>\d{2})"
    r"(?:[T_ ](?P<h>\d{2})[-:]?(?P<mi>\d{2})(?:[-:]?(?P<s>\d{2}))?)?"
)


@dataclass(frozen=True)
class Source:
    """One recording of the fleet.

    path:      the file
    kind:      its format
    machine:   machine name ("" when the layout names none)
    axis:      axis name within the machine ("" when unknown)
    date:      when it was recorded (naive UTC), None when the path names no date
    axis_file: the axis file that gives k_v, k_r and the position feedback; None when neither
               ``--axis`` nor the map names one (the recording is then reported, not analysed)
    drive_profile: the drive profile whose scaling a candump log is decoded with (None: the
               contract's scaling, docs/canopen_layout.md)
    """

    path: Path
    kind: RecordingKind
    machine: str
    axis: str
    date: dt.datetime | None
    axis_file: Path | None
    drive_profile: Path | None = None

    @property
    def axis_id(self) -> str:
        """``MACHINE/AXIS``, the key of the per-axis trends; the file's name where its path
        names neither (a file given directly)."""
        if not (self.machine or self.axis):
            return self.path.name
        return f"{self.machine or '?'}/{self.axis or '?'}"


def date_from_path(parts: Iterable[str]) -> dt.datetime | None:
    """First ISO date (with optional time of day) in path components, else None."""
    for part in parts:
        m = _DATE.search(part)
        if not m:
            continue
        try:
            return dt.datetime(
                int(m["y"]),
                int(m["mo"]),
                int(m["d"]),
                int(m["h"] or 0),
                int(m["mi"] or 0),
                int(m["s"] or 0),
            )
        except ValueError:
            continue  # 2026-13-45 is not a date: look further
    return None


@dataclass(frozen=True)
class AxisEntry:
    """One ``[[axis]]`` table of an axis map."""

    machine: str
    axis: str
    axis_file: Path | None
    globs: tuple[str, ...]
    drive_profile: Path | None = None


@dataclass(frozen=True)
class AxisMap:
    """An axis map file: axis files per machine/axis, and recordings claimed by glob."""

    folder: Path
    entries: tuple[AxisEntry, ...]
    default_axis_file: Path | None

    def entry(self, machine: str, axis: str) -> AxisEntry | None:
        """The entry of ``machine``/``axis``, None when the map has none."""
        for e in self.entries:
            if e.machine == machine and e.axis == axis:
                return e
        return None


def _text(table: dict, key: str, where: str) -> str:
    value = table.get(key)
    if not isinstance(value, str) or not value.strip():
        raise FleetMapError(f"{where}: '{key}' must be a non-empty string, got {value!r}")
    return value.strip()


def load_axis_map(path: Path) -> AxisMap:
    """Read an axis map (TOML, see the module docstring).

    Raises :class:`FleetMapError` naming the table and key for a file that is not TOML or
    whose tables are malformed. An ``[[axis]]`` without ``axis_file`` and no
    ``[defaults] axis_file`` is allowed here: its recordings are reported as "no axis file"
    one by one while the rest of the fleet is processed.
    """
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except OSError as exc:
        raise FleetMapError(f"axis map {path}: cannot read it ({exc.strerror})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise FleetMapError(f"axis map {path}: not a TOML file ({exc})") from None
    folder = path.parent
    unknown = set(doc) - {"defaults", "axis"}
    if unknown:
        raise FleetMapError(
            f"axis map {path}: unknown table(s) {sorted(unknown)}; allowed: [defaults], [[axis]]"
        )
    defaults = doc.get("defaults", {})
    if not isinstance(defaults, dict):
        raise FleetMapError(f"axis map {path}: [defaults] must be a table")
    default_file = (
        folder / _text(defaults, "axis_file", f"axis map {path} [defaults]")
        if "axis_file" in defaults
        else None
    )
    tables = doc.get("axis", [])
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise FleetMapError(f"axis map {path}: 'axis' must be an array of tables ([[axis]])")
    entries = []
    for i, table in enumerate(tables, 1):
        where = f"axis map {path} [[axis]] #{i}"
        globs = table.get("paths", [])
        if not isinstance(globs, list) or not all(isinstance(g, str) for g in globs):
            raise FleetMapError(f"{where}: 'paths' must be a list of glob strings")
        extra = set(table) - {"machine", "axis", "axis_file", "paths", "drive_profile"}
        if extra:
            raise FleetMapError(
                f"{where}: unknown key(s) {sorted(extra)}; allowed: machine, axis, axis_file, "
                "paths, drive_profile"
            )
        profile = (
            folder / _text(table, "drive_profile", where) if "drive_profile" in table else None
        )
        axis_file = folder / _text(table, "axis_file", where) if "axis_file" in table else None
        entries.append(
            AxisEntry(
                _text(table, "machine", where),
                _text(table, "axis", where),
                axis_file,
                tuple(globs),
                profile,
            )
        )
    if not entries and default_file is None:
        raise FleetMapError(f"axis map {path}: names no axis file ([defaults] or [[axis]])")
    return AxisMap(folder, tuple(entries), default_file)


def _files(paths: Sequence[Path]) -> Iterator[tuple[Path, Path]]:
    """(root, file) for every file under the given paths, sorted, depth first."""
    for root in paths:
        if root.is_file():
            yield root.parent, root
        elif root.is_dir():
            for f in sorted(p for p in root.rglob("*") if p.is_file()):
                yield root, f


@dataclass(frozen=True)
class Discovery:
    """Result of :func:`discover`: the recordings, and what was not one."""

    sources: tuple[Source, ...]
    ignored_files: int  # files of other suffixes (figures, notes, ...)
    missing_paths: tuple[Path, ...]  # command-line paths that do not exist


def discover(
    paths: Sequence[Path],
    axis_file: Path | None = None,
    axis_map: AxisMap | None = None,
    drive_profile: Path | None = None,
) -> Discovery:
    """Find every recording under ``paths`` (recursively) and name its machine, axis, date.

    ``axis_file`` (``--axis``) applies to every recording; an ``axis_map`` (``--axes``) maps
    machine/axis to an axis file and may claim recordings by glob. Deterministic order (sorted
    paths), so a local and a cluster run list the fleet identically.
    """
    claimed: dict[Path, AxisEntry] = {}
    if axis_map is not None:
        for entry in axis_map.entries:
            for pattern in entry.globs:
                for f in sorted(axis_map.folder.glob(pattern)):
                    if f.is_file():
                        claimed.setdefault(f.resolve(), entry)
    sources: list[Source] = []
    ignored = 0
    seen: set[Path] = set()
    missing = tuple(p for p in paths if not p.exists())
    for root, f in _files([p for p in paths if p.exists()]):
        kind = SUFFIXES.get(f.suffix.lower())
        resolved = f.resolve()
        if kind is None or resolved in seen:
            ignored += kind is None
            continue
        seen.add(resolved)
        rel = f.relative_to(root).parts
        entry = claimed.get(resolved)
        if entry is not None:
            machine, axis = entry.machine, entry.axis
        else:
            machine = rel[0] if len(rel) >= 3 else ""
            axis = rel[1] if len(rel) >= 3 else ""
            entry = axis_map.entry(machine, axis) if axis_map is not None else None
        chosen = axis_file
        if chosen is None and axis_map is not None:
            chosen = entry.axis_file if entry and entry.axis_file else axis_map.default_axis_file
        date = date_from_path(rel[2:] if len(rel) >= 3 else rel)
        profile = drive_profile or (entry.drive_profile if entry is not None else None)
        sources.append(Source(f, kind, machine, axis, date, chosen, profile))
    return Discovery(tuple(sources), ignored, missing)
