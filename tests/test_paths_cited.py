"""Every path of the repository that a comment, a docstring or a document cites exists: a
moved or removed file leaves no citation behind (issue 27).

Cited paths are those that start at a folder of the checkout (a top-level package, ``tests``,
``docs``, ``config``), in the ``.py``, ``.md`` and ``.toml`` files: a file (``tests/paths.py``,
``docs/fmu.md``, ``config/paper_axis.toml``, ...) or a folder (``tests/peers/``). Not checked:
what is not in the repository by design (``shared/...``, ``out/...``, ``~/.cache/...``), a
path with a placeholder the reader fills in (:data:`PLACEHOLDERS`, ``{...}``, ``<...>``,
``*``) and the files a reader's own command writes (:data:`WRITTEN_BY_THE_READER`).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from pathlib import Path

from tests.paths import ROOT

#: words in capitals that stand for a name the reader chooses (config/drives/NAME.toml)
PLACEHOLDERS = frozenset({"A", "AXIS", "DIR", "E", "MAP", "NAME", "P", "PACKAGE", "VENDOR"})
#: files that the reader's own commands write, cited as examples
WRITTEN_BY_THE_READER = frozenset(
    {"config/drives/my_drive.toml"}  # docs/commissioning.md: `bridge probe --out` of one's drive
)
#: suffixes of the files a citation names
SUFFIXES = ("py", "md", "toml", "eds", "json", "csv", "txt", "c", "xml", "fmu")
#: folders never scanned (made by tools, not part of the repository)
NOT_SCANNED = frozenset({"out", "build", "__pycache__"})


def _roots() -> list[str]:
    """The checkout's folders a cited path starts at: its packages, tests, docs, config."""
    packages = [d.name for d in ROOT.iterdir() if (d / "__init__.py").is_file()]
    return sorted({*packages, "tests", "docs", "config"})


def _citation() -> re.Pattern[str]:
    roots = "|".join(map(re.escape, _roots()))
    start = rf"(?<![\w./~$-])(?:{roots})/"
    a_file = rf"{start}(?:[\w.-]+/)*[\w.-]+\.(?:{'|'.join(SUFFIXES)})(?![\w/-])"
    a_folder = rf"{start}(?:[\w.-]+/)*(?![\w{{<*-])"
    return re.compile(rf"({a_file}|{a_folder})")


def _scanned() -> Iterator[Path]:
    for folder, subfolders, files in os.walk(ROOT):
        subfolders[:] = sorted(
            d
            for d in subfolders
            if not d.startswith(".") and d not in NOT_SCANNED and not d.endswith(".egg-info")
        )
        for name in sorted(files):
            if name.endswith((".py", ".md", ".toml")):
                yield Path(folder) / name


def cited_paths() -> Iterator[tuple[str, str]]:
    """(where, path): every cited path of the repository, ``where`` as ``file:line``."""
    pattern = _citation()
    for path in _scanned():
        text = path.read_text(encoding="utf-8")
        for number, line in enumerate(text.splitlines(), 1):
            for match in pattern.finditer(line):
                yield f"{path.relative_to(ROOT)}:{number}", match.group(1)


def _fills_in(cited: str) -> bool:
    return cited in WRITTEN_BY_THE_READER or any(
        part.split(".")[0] in PLACEHOLDERS for part in cited.split("/")
    )


def test_every_cited_path_exists() -> None:
    missing = [
        f"{where}: {cited}"
        for where, cited in cited_paths()
        if not _fills_in(cited) and not (ROOT / cited).exists()
    ]
    assert not missing, "cited but not in the repository:\n" + "\n".join(missing)


def test_the_scan_finds_citations_of_every_kind() -> None:
    """The scan sees what it must check: files and folders, in code, tests and documents
    (a pattern that matched nothing would pass the test above)."""
    found = {cited for _, cited in cited_paths()}
    for cited in (
        "tests/paths.py",  # CONTRIBUTING.md
        "docs/virtual_bus.md",  # tools/testing.py
        "tests/conftest.py",  # tools/testing.py
        "config/emps_nominal.toml",  # tools/benches.toml
        "tests/peers/",  # CONTRIBUTING.md
        "plant_sim/physics/reference.py",  # tests/plant_sim/physics/test_convergence.py
    ):
        assert cited in found
    assert "config/drives/NAME.toml" in found and _fills_in("config/drives/NAME.toml")


def test_a_placeholder_or_a_path_outside_the_repository_is_not_a_citation() -> None:
    pattern = _citation()
    line = (
        "shared/plants/README.md, ../shared/docs/x.md, out/demo/summary.json, ~/docs/a.md, "
        "$HOME/tests/x.py, tests/<package>/test_<what>.py, tests/test_dev_*.py, "
        "tests/plant_sim/{physics,drive}/, tests.paths, xtests/a.py"
    )
    assert pattern.findall(line) == []
    # written in pieces here, or the test above would find them in this file
    gone_file, gone_folder = "/".join(("tests", "nowhere.py")), "/".join(("tests", "gone", ""))
    line = f"see `{gone_file}::test_x` and {gone_folder}."
    assert pattern.findall(line) == [gone_file, gone_folder]
