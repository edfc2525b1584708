"""``dev.py`` itself: the environment and the dispatch of its sub-commands, on a bare Python
(the sub-commands are tested in tests/tools/)."""

from __future__ import annotations

import hashlib
import subprocess
import sys

import pytest

from tests.paths import ROOT

#: a Python without site-packages (-S) and without the environment's variables or the
#: current folder on its path (-I): what a fresh Python 3.11 has
BARE = [sys.executable, "-I", "-S"]


def test_dev_py_and_what_it_imports_use_only_the_standard_library() -> None:
    """dev.py runs before the environment exists: loading it (the tools modules with it)
    brings in no module outside the standard library."""
    probe = (
        "import importlib.util, sys\n"
        f"sys.path.insert(0, {str(ROOT)!r})\n"
        f"spec = importlib.util.spec_from_file_location('dev', {str(ROOT / 'dev.py')!r})\n"
        "dev = importlib.util.module_from_spec(spec)\n"
        "spec.loader.exec_module(dev)\n"
        "ours = {'dev', 'tools', '__main__'}\n"
        "tops = {name.split('.')[0] for name in sys.modules}\n"
        "print(sorted(tops - set(sys.stdlib_module_names) - ours))\n"
        "print(sorted(n for n in sys.modules if n.startswith('tools.')))\n"
    )
    done = subprocess.run([*BARE, "-c", probe], capture_output=True, text=True, check=True)
    outside, tools = done.stdout.splitlines()
    assert outside == "[]"
    assert tools == "['tools.bench', 'tools.benches', 'tools.checkout', 'tools.errors', " + (
        "'tools.first_run', 'tools.testing']"
    )


@pytest.mark.parametrize("argv", [[], ["--quiet"], ["nope"], ["-q", "tests"]])
def test_without_a_sub_command_it_shows_its_usage_and_exits_2(argv: list[str]) -> None:
    done = subprocess.run(
        [*BARE, str(ROOT / "dev.py"), *argv], capture_output=True, text=True, cwd=ROOT.parent
    )
    assert done.returncode == 2
    assert done.stdout == ""
    assert done.stderr.startswith("Create or reuse the project's virtual environment")
    for verb in ("demo", "test", "bench", "first-run", "python"):
        assert f"python3 dev.py [--quiet] {verb}" in done.stderr


def test_an_environment_made_from_this_pyproject_is_reused_as_it_is() -> None:
    """The stamp names the pyproject.toml the environment was installed from: when it is
    this one, ``dev.py python`` runs the command at once in ``.venv`` (nothing installed,
    nothing said)."""
    stamp = ROOT / ".venv" / ".installed-from"
    want = hashlib.sha256((ROOT / "pyproject.toml").read_bytes()).hexdigest()
    if not stamp.exists() or stamp.read_text().strip() != want:
        pytest.skip("the environment is not installed from this pyproject.toml (run dev.py)")
    done = subprocess.run(
        [*BARE, str(ROOT / "dev.py"), "python", "-c", "import sys; print(sys.prefix)"],
        capture_output=True,
        text=True,
        cwd=ROOT.parent,
    )
    assert (done.returncode, done.stderr) == (0, "")
    assert done.stdout.strip() == str(ROOT / ".venv")
