"""The benchmark registry (tools/benches.toml read by tools/benches.py): the shipped file, its
expansion over rates and --realtime-seconds, and bad registries refused in one line naming
the file, the benchmark and the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.paths import ROOT
from tools import benches
from tools.errors import RegistryError, ToolsError

GOOD = """\
[[bench]]
name = "rt-{rate_k}k"
rates = [500, 2000]
args = [
    "hil", "bench", "--seconds", "{realtime_s}", "--rate-hz", "{rate_hz}", "--json", "{out}/b.json",
]
result = "b.json"
setup = [["plant_sim", "emps", "--out", "{out}/emps", "--data", "{shared}/data"]]
needs = "cyclictest"
figures = [
    { label = "{rate_hz} Hz, {realtime_s} s: p99", keys = "realtime.latency_us_p99", unit = "µs" },
    { label = "share", keys = "realtime.cpu_fraction_of_period", unit = "%", scale = 100 },
]
"""


def _registry(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "benches.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_rates_and_the_real_time_length_are_filled_where_the_registry_is_read(
    tmp_path: Path,
) -> None:
    low, high = benches.load(2.5, _registry(tmp_path, GOOD))
    assert (low.name, high.name) == ("rt-0.5k", "rt-2k")
    assert low.args == (
        "hil", "bench", "--seconds", "2.5", "--rate-hz", "500", "--json", "{out}/b.json",
    )  # fmt: skip
    assert high.setup == (("plant_sim", "emps", "--out", "{out}/emps", "--data", "{shared}/data"),)
    assert [f.label for f in high.figures] == ["2000 Hz, 2.5 s: p99", "share"]
    assert (high.figures[1].scale, high.figures[0].scale) == (100.0, 1.0)
    assert high.needs == "cyclictest" and high.result == "b.json"


def test_out_and_shared_are_filled_when_a_command_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    args = ("x", "{out}/a.json", "--fmu", "{shared}/plants/axis_family.fmu")
    monkeypatch.setenv("BACKLASH_SHARED", "/data/shared")
    assert benches.filled(args, "/tmp/o") == [
        "x", "/tmp/o/a.json", "--fmu", "/data/shared/plants/axis_family.fmu",
    ]  # fmt: skip
    monkeypatch.delenv("BACKLASH_SHARED")
    assert benches.filled(args, "/tmp/o")[3] == f"{ROOT.parent}/shared/plants/axis_family.fmu"
    assert benches.shown(args) == "x DIR/a.json --fmu ../shared/plants/axis_family.fmu"


def test_the_shipped_registry_names_each_benchmark_once_in_the_readmes_order() -> None:
    names = [b.name for b in benches.load(60.0)]
    assert names == [
        "paper", "paper-2.5ms", "sweep", "bridge-demo", "bridge-demo-fmu", "fmu-sweep",
        "emps-diagnose", "plant_sim-bench", "bridge-bench",
        "bridge-realtime-1k", "bridge-realtime-2k",
        "bridge-realtime-scope-1k", "bridge-realtime-scope-2k",
        "host-latency-1k", "host-latency-2k",
        "monitor",
    ]  # fmt: skip


@pytest.mark.parametrize("rate_hz", [1000, 2000])
def test_the_real_time_bench_and_its_host_floor_run_with_the_same_settings(rate_hz: int) -> None:
    """The figures of cyclictest are the floor of the bridge's only if both ran alike: rate,
    length, SCHED_FIFO priority and CPU."""
    by_name = {b.name: b for b in benches.load(30.0)}
    k = rate_hz // 1000

    def settings(args: tuple[str, ...]) -> tuple[str, ...]:
        start = args.index("--seconds")
        return args[start : args.index("--cpu") + 2]

    loop = settings(by_name[f"bridge-realtime-{k}k"].args)
    assert loop == settings(by_name[f"host-latency-{k}k"].args)
    # the scope's variant is the same run with --scope (docs/scope.md): the difference is its cost
    scoped = by_name[f"bridge-realtime-scope-{k}k"].args
    assert [a for a in scoped if a != "--scope"] == list(by_name[f"bridge-realtime-{k}k"].args)
    assert loop == tuple(f"--seconds 30 --rate-hz {rate_hz} --rt-priority 50 --cpu 1".split())


FIG = '{ label = "a", keys = "k", unit = "s" }'
#: the start of a benchmark "a" whose command is "x"
A = '[[bench]]\nname = "a"\nargs = ["x"]\nresult = "r"\n'
BAD = [
    ("[[bench]\n", "not a TOML file"),
    ("title = 'x'\n", "unknown top-level keys ['title']; allowed: ['bench']"),
    ("bench = 1\n", "needs at least one [[bench]] table"),
    (
        f"{A}figures = [{FIG}]\nrun = 1\n",
        "[[bench]] 1 ('a'): unknown keys ['run']; allowed: ['args', 'figures', 'name', 'needs', "
        "'rates', 'result', 'setup']",
    ),
    (
        f'[[bench]]\nargs = ["x"]\nresult = "r"\nfigures = [{FIG}]\n',
        "[[bench]] 1: 'name' must be a non-empty string, not None",
    ),
    (
        f'[[bench]]\nname = "a"\nargs = []\nresult = "r"\nfigures = [{FIG}]\n',
        "[[bench]] 1 ('a'): 'args' must be a non-empty list of non-empty strings",
    ),
    (
        f'[[bench]]\nname = "a"\nargs = ["x"]\nresult = 3\nfigures = [{FIG}]\n',
        "[[bench]] 1 ('a'): 'result' must be a non-empty string, not 3",
    ),
    (
        f'{A}setup = ["x"]\nfigures = [{FIG}]\n',
        "[[bench]] 1 ('a'): 'setup' must be a non-empty list of non-empty strings",
    ),
    (
        f"{A}figures = []\n",
        "[[bench]] 1 ('a'): 'figures' must be a non-empty list of tables",
    ),
    (
        A + 'figures = [{ label = "a", keys = "k", unit = "s", per = 2 }]\n',
        "[[bench]] 1 ('a'): figure 1: unknown keys ['per']; allowed: ['keys', 'label', 'scale', "
        "'unit']",
    ),
    (
        A + f'figures = [{FIG}, {{ label = "b", unit = "s" }}]\n',
        "[[bench]] 1 ('a'): figure 2: 'keys' must be a non-empty string, not None",
    ),
    *(
        (
            A + f'figures = [{{ label = "a", keys = "k", unit = "s", scale = {scale} }}]\n',
            f"[[bench]] 1 ('a'): figure 1: 'scale' must be a finite non-zero number, not {shown}",
        )
        for scale, shown in [
            ("0", "0"),
            ("inf", "inf"),
            ("nan", "nan"),
            ('"1e6"', "'1e6'"),
            ("true", "True"),
        ]
    ),
    (
        f"{A}rates = [1000, 0]\nfigures = [{FIG}]\n",
        "[[bench]] 1 ('a'): 'rates' must be a non-empty list of positive integers (Hz)",
    ),
    (
        f'[[bench]]\nname = "a"\nargs = ["--out", "{{outdir}}"]\nresult = "r"\nfigures = [{FIG}]\n',
        "[[bench]] 1 ('a'): unknown placeholder {outdir} in '{outdir}'; allowed here: "
        "{realtime_s}, {out}, {shared} ({rate_hz}, {rate_k}: with 'rates')",
    ),
    (
        A + 'figures = [{ label = "{rate_hz} Hz", keys = "k", unit = "s" }]\n',
        "[[bench]] 1 ('a'): figure 1: unknown placeholder {rate_hz} in '{rate_hz} Hz'; "
        "allowed here: {realtime_s} ({rate_hz}, {rate_k}: with 'rates')",
    ),
    (
        '[[bench]]\nname = "a"\nargs = ["x"]\nresult = "{out}/r"\nrates = [1]\n'
        f"figures = [{FIG}]\n",
        "[[bench]] 1 ('a'): unknown placeholder {out} in '{out}/r'; allowed here: "
        "{realtime_s}, {rate_hz}, {rate_k}",
    ),
    (
        f"{A}figures = [{FIG}, {FIG}]\n",
        "[[bench]] 1 ('a'): figure labels must be unique; twice: ['a']",
    ),
    (
        f"{A}rates = [1000, 2000]\nfigures = [{FIG}]\n",
        "benchmark names must be unique; twice: ['a']",
    ),
]


@pytest.mark.parametrize(("text", "message"), BAD)
def test_a_bad_registry_is_refused_naming_the_file_the_benchmark_and_the_key(
    tmp_path: Path, text: str, message: str
) -> None:
    path = _registry(tmp_path, text)
    with pytest.raises(RegistryError) as caught:
        benches.load(60.0, path)
    assert str(caught.value).startswith(f"{path}: ")
    assert message in str(caught.value)
    assert "\n" not in str(caught.value)
    assert isinstance(caught.value, ValueError) and isinstance(caught.value, ToolsError)


def test_a_missing_registry_is_refused_naming_it(tmp_path: Path) -> None:
    with pytest.raises(RegistryError, match=r"benches\.toml: cannot read it: No such file"):
        benches.load(60.0, tmp_path / "benches.toml")
