"""The bridge installs and runs without the simulator: no module of ``bridge``, ``virtual_bus``
or ``regulator`` needs ``plant_sim``, ``hil`` or the simulator's dependencies (numba,
matplotlib, Dask, pyarrow), checked by running the bridge's commands in a Python whose import
system refuses those packages, as an install without the ``sim`` extra would."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tests.paths import ROOT

#: what ``pip install .`` (no extra) leaves out
SIMULATOR = (
    "plant_sim",
    "hil",
    "numba",
    "llvmlite",
    "matplotlib",
    "dask",
    "distributed",
    "pyarrow",
)

BLOCKER = """
import importlib.abc, json, pkgutil, runpy, sys

BLOCKED = set(json.loads(sys.argv[1]))


class Refuse(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r} (blocked)", name=name)
        return None


sys.meta_path.insert(0, Refuse())
if sys.argv[2] == "import-all":
    import bridge, regulator, virtual_bus
    names = []
    for package in (bridge, regulator, virtual_bus):
        for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
            __import__(info.name)
            names.append(info.name)
    print(json.dumps(names))
else:
    sys.argv = ["bridge", *sys.argv[2:]]
    runpy.run_module("bridge", run_name="__main__", alter_sys=True)
"""


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", BLOCKER, json.dumps(SIMULATOR), *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=False,
    )


def test_every_bridge_bus_and_regulator_module_imports_without_the_simulator() -> None:
    done = _run("import-all")
    assert done.returncode == 0, done.stderr
    names = json.loads(done.stdout)
    assert "bridge.node" in names and "bridge.commission.command" in names
    assert "virtual_bus.formats.trace" in names and "regulator.core" in names


@pytest.mark.parametrize(
    "argv",
    [
        ["--help"],
        ["eds", "--check"],
        ["busload", "--axes", "2"],
        ["probe", "--help"],
        ["config", "get", "--help"],
    ],
)
def test_bridge_commands_run_without_the_simulator(argv: list[str]) -> None:
    done = _run(*argv)
    assert done.returncode == 0, done.stderr
    assert "blocked" not in done.stderr


def test_a_bridge_run_without_a_drive_fails_in_one_line_without_the_simulator() -> None:
    argv = ["run", "--interface", "virtual", "--channel", "nobody-home", "--seconds", "0.01"]
    done = _run(*argv, "--axis", str(ROOT / "config" / "paper_axis.toml"))
    assert done.returncode == 1, done.stderr
    *plan, error = done.stderr.splitlines()  # the start-up plan (bridge.status), the failure
    assert "drive start-up failed" in error and "drive start-up failed" not in "".join(plan)
    assert plan and all(line.startswith("bridge run: ") for line in plan), plan


def test_the_blocker_really_blocks() -> None:
    """The check above can fail: the same Python refuses to run a simulator command."""
    script = BLOCKER.replace('"bridge"', '"plant_sim"')
    done = subprocess.run(
        [sys.executable, "-c", script, json.dumps(SIMULATOR), "paper", "--help"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=False,
    )
    assert done.returncode != 0 and "blocked" in done.stderr
