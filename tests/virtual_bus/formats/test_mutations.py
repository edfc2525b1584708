"""Mutated axis files and trace files through the format readers (issue 20, bad files).

Every shipped axis file and a few good traces (one the project's writer wrote, the EMPS and
XL330 recordings where ``shared/`` has them) mutated systematically (``tests/mutations/``):
``load_axis`` and ``read_trace`` accept each mutant or refuse it with a ``FormatError`` in one
line that names the file and the key or column; never a builtin error; every mutant the format
documents (docs/axis-file.md, docs/trace-file.md) call invalid is refused, every one they call
valid accepted.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

from tests import mutations
from virtual_bus.formats.axis import load_axis
from virtual_bus.formats.errors import FormatError
from virtual_bus.formats.trace import read_trace


def _assert_clean(findings: mutations.Findings) -> None:
    problems = findings.problems()
    assert not problems, f"{findings.summary()}:\n" + "\n".join(problems)


def test_axis_file_mutants_are_accepted_or_refused_in_one_line(tmp_path: Path) -> None:
    mutants = mutations.axis_mutants()
    assert len(mutants) > 600
    findings = mutations.load_each(mutants, tmp_path, ".toml", load_axis, (FormatError,))
    _assert_clean(findings)
    assert len(findings.refused) > 500  # most mutations break the file


def test_trace_file_mutants_are_accepted_or_refused_in_one_line(tmp_path: Path) -> None:
    seeds = mutations.trace_seeds(tmp_path)
    mutants = mutations.mutants_of(seeds, mutations.trace_mutants, 200)
    assert len(mutants) > 100 * len(seeds)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # implausible units warn; the test is about refusals
        findings = mutations.load_each(mutants, tmp_path, ".csv", read_trace, (FormatError,))
    _assert_clean(findings)


@pytest.mark.parametrize(
    ("what", "fragment"),
    [
        ("axis.transmission_ratio = tiny", "is not a finite number > 0 in floating point"),
        ("control.kv = text", "control.kv = 'abc': must be a number, got str"),
        ("duplicate control.kv", "not valid TOML"),
    ],
)
def test_refusals_say_what_is_allowed(tmp_path: Path, what: str, fragment: str) -> None:
    (mutant,) = [m for m in mutations.axis_mutants() if m.label == f"paper_axis.toml: {what}"]
    with pytest.raises(FormatError, match=fragment):
        load_axis(mutant.write(tmp_path, ".toml"))
