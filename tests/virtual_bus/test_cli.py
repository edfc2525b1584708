"""The command-line framework (cmdline/cli.py) and the progress helper (progress.py).

Independent references: argparse's own parsing (the framework only adds types and the
one-line error), the CiA 301 node-ID range 1..127, and the text a stream receives.
"""

from __future__ import annotations

import argparse
import io
import types
from pathlib import Path

import pytest

from cmdline import cli
from cmdline.progress import Progress


def _module(run: object) -> types.ModuleType:
    mod = types.ModuleType("fake")
    mod.NAME = "go"  # type: ignore[attr-defined]
    mod.HELP = "a test command"  # type: ignore[attr-defined]

    def add_arguments(p: argparse.ArgumentParser) -> None:
        cli.number_list(p, "--kv", (25.0,), "k_v values")
        p.add_argument("--node", type=cli.node_id, default=1)
        p.add_argument("--out", type=cli.output_dir)
        cli.add_quiet(p)

    mod.add_arguments = add_arguments  # type: ignore[attr-defined]
    mod.run = run  # type: ignore[attr-defined]
    return mod


def _parse(argv: list[str]) -> argparse.Namespace:
    return cli.build_parser("prog", "test", [_module(lambda a: 0)]).parse_args(argv)


@pytest.mark.parametrize(
    "argv", [["--kv", "20,30"], ["--kv", "20", "30"], ["--kv", "20,", "30"], ["--kv", "20", "30,"]]
)
def test_number_list_takes_commas_or_spaces(argv: list[str]) -> None:
    assert _parse(["go", *argv]).kv == (20.0, 30.0)


def test_number_list_default_and_bad_values(capsys: pytest.CaptureFixture[str]) -> None:
    assert _parse(["go"]).kv == (25.0,)
    for bad in (["--kv", "20,abc"], ["--kv", "0"], ["--kv", "nan"]):
        with pytest.raises(SystemExit) as info:
            _parse(["go", *bad])
        assert info.value.code == 2
        assert len(capsys.readouterr().err.splitlines()) == 1


@pytest.mark.parametrize(("text", "value"), [("1", 1), ("127", 127), ("0x7f", 127), ("0x7F", 127)])
def test_node_id_accepts_1_to_127(text: str, value: int) -> None:
    assert cli.node_id(text) == value


@pytest.mark.parametrize("text", ["0", "128", "-1", "x", "1.5"])
def test_node_id_refuses_outside_1_to_127(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=r"1\.\.127"):
        cli.node_id(text)


@pytest.mark.parametrize("text", ["0", "-2", "nan", "inf", "1e999", "abc"])
def test_positive_float_refuses(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError):
        cli.positive_float(text)


def test_positive_float_and_count() -> None:
    assert cli.positive_float("2.5e-3") == 0.0025
    assert cli.count("3") == 3
    with pytest.raises(argparse.ArgumentTypeError, match=">= 1"):
        cli.count("0")
    assert cli.bounded_int(1, 5)("5") == 5
    with pytest.raises(argparse.ArgumentTypeError, match=r"allowed 1\.\.5"):
        cli.bounded_int(1, 5)("6")


def test_paths(tmp_path: Path) -> None:
    f = tmp_path / "file.txt"
    f.write_text("x")
    assert cli.existing_file(str(f)) == f
    with pytest.raises(argparse.ArgumentTypeError, match="no such file"):
        cli.existing_file(str(tmp_path / "none"))
    assert cli.output_dir(str(tmp_path / "new")) == tmp_path / "new"
    with pytest.raises(argparse.ArgumentTypeError, match="--out takes a directory"):
        cli.output_dir(str(f))
    with pytest.raises(argparse.ArgumentTypeError, match="is a directory"):
        cli.new_file(str(tmp_path))
    with pytest.raises(argparse.ArgumentTypeError, match="does not exist"):
        cli.new_file(str(tmp_path / "no" / "x.csv"))


class _Boom(ValueError):
    pass


@pytest.mark.parametrize(
    ("error", "code", "text"),
    [
        (cli.UsageError("give --x"), 2, "prog go: error: give --x"),
        (_Boom("bad\nvalue"), 2, "prog go: error: bad; value"),
        (RuntimeError("device gone"), 1, "prog go: error: bus: device gone"),
        (FileNotFoundError("nope.csv"), 2, "prog go: error: nope.csv"),
    ],
)
def test_main_maps_errors_to_one_line(
    error: Exception, code: int, text: str, capsys: pytest.CaptureFixture[str]
) -> None:
    def run(args: argparse.Namespace) -> int:
        raise error

    failures = (cli.Failure((_Boom,)), cli.Failure((RuntimeError,), 1, "bus"))
    assert cli.main("prog", "test", [_module(run)], ["go"], failures) == code
    assert capsys.readouterr().err.splitlines() == [text]


def test_unmapped_errors_are_not_hidden() -> None:
    def run(args: argparse.Namespace) -> int:
        raise KeyError("a bug")

    with pytest.raises(KeyError):
        cli.main("prog", "test", [_module(run)], ["go"])


def test_no_command_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        cli.main("prog", "test", [_module(lambda a: 0)], [])
    assert info.value.code == 2
    assert capsys.readouterr().err.splitlines() == [
        "prog: error: the following arguments are required: COMMAND (see --help)"
    ]


def test_defaults_are_injected() -> None:
    seen = {}

    def run(args: argparse.Namespace) -> int:
        seen["runner"] = args.runner
        return 0

    assert cli.main("prog", "t", [_module(run)], ["go"], defaults={"runner": "fake"}) == 0
    assert seen == {"runner": "fake"}


def test_run_package_refuses_a_missing_extra_in_one_line_before_loading_commands(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A module of the extra not installed: exit 1 and one line naming it and the extra; no
    command module is imported (this one does not exist: loading it would raise)."""
    code = cli.run_package(
        "no_such_package", "d", ("x",), ["x"], needs=("no_such_module_for_the_test",)
    )
    assert code == cli.EXIT_FAILURE
    assert capsys.readouterr().err.splitlines() == [
        "python -m no_such_package: error: no_such_module_for_the_test not installed: this "
        "part of the project needs the 'sim' extra (pip install 'backlash-bridge[sim]')"
    ]


def test_run_package_loads_the_package_commands(capsys: pytest.CaptureFixture[str]) -> None:
    """``python -m virtual_bus``'s commands loaded by run_package: a name that is not one of
    them is argparse's one line, under the program named after the package."""
    with pytest.raises(SystemExit) as info:
        cli.run_package("virtual_bus", "d", ("setup", "probe"), ["nonsense"])
    assert info.value.code == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("python -m virtual_bus: error: argument COMMAND")


# --- progress -----------------------------------------------------------------------------------
class _Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_progress_not_on_a_terminal_is_one_line_per_stage() -> None:
    out, clock = io.StringIO(), _Clock()
    progress = Progress("cmd", stream=out, terminal=False, clock=clock)
    progress.stage("first")
    clock.t += 12.34
    with progress.bar(3, "cells", unit="cell") as bar:
        for _ in range(3):
            bar.update()
        bar.set_description("round 2")
        bar.set_description("round 2")  # unchanged: no new line
    assert out.getvalue().splitlines() == [
        "[   0.0 s] cmd: first",
        "[  12.3 s] cmd: cells (3 cells)",
        "[  12.3 s] cmd: round 2",
    ]
    assert "\r" not in out.getvalue()
    assert bar.n == 3


def test_progress_quiet_prints_nothing() -> None:
    for terminal in (True, False):
        out = io.StringIO()
        progress = Progress("cmd", quiet=True, stream=out, terminal=terminal)
        progress.stage("x")
        with progress.bar(2, "y") as bar:
            bar.update(2)
            bar.set_description("z")
        assert out.getvalue() == ""


def test_progress_on_a_terminal_is_a_bar() -> None:
    out = io.StringIO()
    progress = Progress("cmd", stream=out, terminal=True)
    with progress.bar(4, "cells", unit="cell") as bar:
        assert bar._tqdm is not None and bar._tqdm.total == 4
        bar.update(4)
        assert bar._tqdm.n == 4
    assert "cmd:" not in out.getvalue()  # no stage lines in bar mode


def test_a_closed_reader_of_stdout_ends_quietly(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``prog go | head -1``: standard output is an OS pipe whose reader has gone. The command
    ends with 141 (128 + SIGPIPE) and no error line; a broken pipe that is not standard
    output's (a socket, a child's pipe) is a failure like any other."""
    import os

    read_fd, write_fd = os.pipe()
    os.close(read_fd)  # the reader is gone before the first line
    with capsys.disabled():
        stdout = open(write_fd, "w", buffering=1)  # noqa: SIM115 - closed below
        monkeypatch.setattr("sys.stdout", stdout)

        def run(args: argparse.Namespace) -> int:
            for i in range(100):
                print(f"line {i}")
            return 0

        try:
            assert cli.main("prog", "test", [_module(run)], ["go"]) == cli.EXIT_BROKEN_PIPE
        finally:
            monkeypatch.undo()
            stdout.close()

    def socket_run(args: argparse.Namespace) -> int:
        raise BrokenPipeError(32, "Broken pipe")  # standard output is fine

    failures = (cli.Failure((OSError,), 1, "bus"),)
    assert cli.main("prog", "test", [_module(socket_run)], ["go"], failures) == 1
    assert capsys.readouterr().err.splitlines() == ["prog go: error: bus: [Errno 32] Broken pipe"]
