"""``python3 dev.py test`` (tools/testing.py) in two parts (the host's, and the vcan tests in a
guest): the summary is read from pytest's own JUnit XML, and one exit status stands for both
parts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.paths import ROOT
from tools import testing


def test_counts_are_read_from_pytests_junit_xml(tmp_path: Path) -> None:
    (tmp_path / "test_sample.py").write_text(
        "import pytest\n"
        "def test_a(): pass\n"
        "def test_b(): pass\n"
        "def test_c(): assert False\n"
        "def test_d(): pytest.skip('why')\n"
        "@pytest.fixture\n"
        "def broken(): raise RuntimeError\n"
        "def test_e(broken): pass\n"
    )
    xml = tmp_path / "out.xml"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            f"--junitxml={xml}",
            str(tmp_path / "test_sample.py"),
        ],
        cwd=tmp_path,
        capture_output=True,
        check=False,
    )
    counts = testing.Counts.from_junit(xml)
    assert counts is not None
    assert (counts.passed, counts.failed, counts.skipped) == (2, 2, 1)  # an error counts failed
    assert (counts + counts).text() == "4 passed, 4 failed, 2 skipped"
    assert testing.Counts.from_junit(tmp_path / "missing.xml") is None


@pytest.mark.parametrize(
    ("host", "guest", "status"),
    [(0, 0, 0), (0, 5, 0), (5, 0, 0), (5, 5, 5), (1, 0, 1), (0, 1, 1), (2, 1, 2), (5, 3, 3)],
)
def test_one_exit_status_for_both_parts(host: int, guest: int, status: int) -> None:
    """pytest: 0 passed, 1 tests failed, 2 interrupted, 3 internal error, 5 nothing
    collected (a part whose selection holds no test while the other ran)."""
    assert testing.combined_status(host, guest) == status


def test_the_split_is_by_the_vcan_marker(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    """conftest's BACKLASH_BRIDGE_VCAN_PART: the host's part deselects the vcan tests, the
    guest's keeps only them, where a missing vcan0 fails instead of skipping."""
    pytester.makeconftest((ROOT / "tests" / "conftest.py").read_text())
    pytester.makeini("[pytest]\nmarkers =\n    vcan: needs vcan0\n    slow: slow\n")
    pytester.makepyfile(
        "import pytest\n@pytest.mark.vcan\ndef test_on_vcan(): pass\ndef test_anywhere(): pass\n"
    )
    monkeypatch.setenv(testing.VCAN_PART_ENV, "without")
    pytester.runpytest("-p", "no:cacheprovider").assert_outcomes(passed=1, deselected=1)
    monkeypatch.setenv(testing.VCAN_PART_ENV, "only")
    result = pytester.runpytest("-p", "no:cacheprovider")
    if testing.host_vcan_problem() is None:
        result.assert_outcomes(passed=1, deselected=1)
    else:  # here: no vcan0, so the test the guest was to run errs in its setup, saying why
        result.assert_outcomes(errors=1, deselected=1)
        assert "vcan0" in result.stdout.str()
