"""FMUs for the tests: the shared feed-axis family (skipped with the reason where absent),
copies of it with one thing in its model description changed (a bad FMU as a user may be
handed one), and a tiny FMU compiled here from C against FMPy's FMI 2.0 headers (an FMU that
fails on purpose: FMI calls returning errors at a step the test chooses)."""

from __future__ import annotations

import re
import shutil
import subprocess
import zipfile
from pathlib import Path

import pytest

from tests.paths import DATA
from virtual_bus.shipped import AXIS_FAMILY_FMU


def family_fmu() -> Path:
    """The shared FMU, or a skip saying where it was looked for."""
    if not AXIS_FAMILY_FMU.is_file():
        pytest.skip(f"no shared FMU at {AXIS_FAMILY_FMU} (shared/plants; $BACKLASH_SHARED)")
    return AXIS_FAMILY_FMU


def edited_copy(tmp: Path, name: str, edit_xml=None, drop: str | None = None) -> Path:  # type: ignore[no-untyped-def]
    """The shared FMU as ``tmp/name``, its modelDescription.xml passed through ``edit_xml``
    (text -> text) and the archive members starting with ``drop`` left out."""
    src = family_fmu()
    out = tmp / name
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(out, "w") as zout:
        for item in zin.infolist():
            if drop is not None and item.filename.startswith(drop):
                continue
            data = zin.read(item.filename)
            if item.filename == "modelDescription.xml" and edit_xml is not None:
                data = edit_xml(data.decode("utf-8")).encode("utf-8")
            zout.writestr(item, data)
    return out


def model_exchange_only(text: str) -> str:
    return re.sub(r"<CoSimulation\b[^>]*/>", '<ModelExchange modelIdentifier="axis_family"/>', text)


def unit_of(variable: str, unit: str):  # type: ignore[no-untyped-def]
    """An edit that declares ``unit`` for ``variable`` (adding the unit's definition)."""

    def edit(text: str) -> str:
        pattern = rf'(<ScalarVariable name="{variable}"[^>]*>\s*<Real[^>]*?)unit="[^"]*"'
        text, n = re.subn(pattern, rf'\1unit="{unit}"', text)
        assert n == 1, variable
        return text.replace("</UnitDefinitions>", f'<Unit name="{unit}"/></UnitDefinitions>', 1)

    return edit


def renamed(variable: str, new: str):  # type: ignore[no-untyped-def]
    def edit(text: str) -> str:
        text, n = re.subn(rf'name="{variable}"', f'name="{new}"', text)
        assert n == 1, variable
        return text

    return edit


#: the tiny FMU's C source and model description (tests/data/tiny_fmu)
TINY = DATA / "tiny_fmu"


def tiny_fmu(tmp: Path) -> Path:
    """The tiny FMU (module docstring) built in ``tmp``; skips where there is no C compiler."""
    import fmpy

    gcc = shutil.which("gcc") or shutil.which("cc")
    if gcc is None:
        pytest.skip("no C compiler (gcc) to build the tiny test FMU")
    headers = Path(fmpy.__file__).parent / "c-code"
    src = TINY / "tiny.c"
    lib = tmp / "tiny.so"
    subprocess.run(
        [gcc, "-shared", "-fPIC", "-O1", f"-I{headers}", "-o", str(lib), str(src)],
        check=True,
        capture_output=True,
    )
    out = tmp / "tiny.fmu"
    with zipfile.ZipFile(out, "w") as z:
        z.write(TINY / "modelDescription.xml", "modelDescription.xml")
        z.write(lib, f"binaries/{fmpy.platform}/tiny{fmpy.sharedLibraryExtension}")
    return out
