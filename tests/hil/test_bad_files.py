"""Mutated axis files (``tests/mutations/``) given to ``python -m hil``, and a few through
real processes of every package's command line: refused quickly, in one error line, exit 2,
nothing written (issue 20, bad files)."""

from __future__ import annotations

import random
import subprocess
import sys
from pathlib import Path

import pytest

from hil.__main__ import main
from tests import mutations
from virtual_bus.formats.axis import load_axis
from virtual_bus.formats.errors import FormatError


@pytest.fixture(scope="module")
def refused(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Paths of a seeded sample of the axis mutants ``load_axis`` refuses."""
    folder = tmp_path_factory.mktemp("axes")
    found = mutations.load_each(
        mutations.axis_mutants(), folder, ".toml", load_axis, (FormatError,)
    )
    assert not found.problems()
    sample = random.Random(9).sample(list(found.refused), 12)
    return [m.write(folder, ".toml") for m in sample]


def test_demo_and_bench_refuse_bad_axis_files_before_they_start(
    refused: list[Path], tmp_path: Path
) -> None:
    findings = mutations.Findings()
    for path in refused:
        out = tmp_path / path.stem
        for argv in (
            ["demo", "--quiet", "--axis", str(path), "--out", str(out)],
            ["bench", "--quiet", "--axis", str(path), "--cycles", "20", "--skip-realtime"],
        ):
            code = mutations.run_cli(findings, path.name, main, argv, path.name)
            assert code in (2, None), argv
        assert not out.exists()
    assert not findings.problems(), "\n".join(findings.problems())


@pytest.mark.parametrize(
    "argv",
    [
        ["diagnosis", "simulate", "--like", "unused.csv", "--out", "unused-out.csv"],
        ["bridge", "busload"],
        ["hil", "demo", "--out", "unused-dir"],
    ],
    ids=lambda argv: f"{argv[0]} {argv[1]}",
)
def test_a_process_of_each_command_line_says_it_in_one_line(
    argv: list[str], refused: list[Path], subprocess_env: dict[str, str], tmp_path: Path
) -> None:
    package, *rest = argv
    result = subprocess.run(
        [sys.executable, "-m", package, *rest, "--axis", str(refused[0])],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=subprocess_env,
        check=False,
    )
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and refused[0].name in result.stderr, result.stderr
    assert not (tmp_path / "unused-dir").exists()
