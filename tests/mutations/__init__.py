"""Mutated copies of good files: the bad-input test set of the file formats (issue 20).

From a good file (a shipped axis file or drive profile, a trace the project's writer wrote, a
DCF ``bridge config dump`` wrote) each generator makes systematic mutations: every key or
section deleted, every value replaced by each wrong type and each out-of-range number, unknown
and duplicated keys, a truncated file, binary garbage, a byte-order mark, an empty file; for
CSV missing and duplicate columns, text/empty/NaN cells, short rows, non-increasing time, too
few rows, another delimiter, time in ms; for a DCF missing sections, bad hex, values out of
range, a wrong DataType. Random choices come from seeded generators: the set is the same on
every run.

Each :class:`Mutant` says what the format's documentation makes of it (its
:class:`Verdict`): invalid (must be refused), valid (must be accepted) or either (the
documents do not decide: a range the reader may allow, a cut that leaves a well-formed file).
Whatever the verdict, a reader accepts the file or refuses it with its package's error in one
line (:func:`load_each`, :func:`attempt`, :func:`run_cli` collect what does not).

``core`` (mutants, running them), ``toml_files`` (axis files, drive profiles),
``trace_files`` (CSV traces), ``dcf_files`` (CiA 306 DCF).
"""

from .core import (
    EITHER,
    INVALID,
    VALID,
    Findings,
    Mutant,
    Verdict,
    attempt,
    load_each,
    mutants_of,
    run_cli,
)
from .dcf_files import dcf_mutants
from .toml_files import (
    AXIS_SCHEMA,
    PROFILE_SCHEMA,
    axis_mutants,
    axis_seeds,
    profile_mutants,
    profile_seeds,
    toml_mutants,
)
from .trace_files import trace_mutants, trace_seeds

__all__ = [
    "AXIS_SCHEMA",
    "EITHER",
    "INVALID",
    "PROFILE_SCHEMA",
    "VALID",
    "Findings",
    "Mutant",
    "Verdict",
    "attempt",
    "axis_mutants",
    "axis_seeds",
    "dcf_mutants",
    "load_each",
    "mutants_of",
    "profile_mutants",
    "profile_seeds",
    "run_cli",
    "toml_mutants",
    "trace_mutants",
    "trace_seeds",
]
