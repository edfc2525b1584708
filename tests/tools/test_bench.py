"""``python3 dev.py bench`` (tools/bench.py, standard library): the README table between the
markers.

The benchmark commands are replaced by a fake run; the figures are checked against values
worked out by hand, and whole tables against those that ``dev.py`` printed for the same fake
values before the registry became data (``tests/data/bench/``: same labels, order, numbers and
command strings, byte for byte).
"""

from __future__ import annotations

import itertools
import re
import zlib
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.paths import DATA, ROOT
from tools import bench, benches
from tools.benches import Bench

STORED = DATA / "bench"


def test_replaces_only_the_block_between_the_markers() -> None:
    text = f"intro\n{bench.BEGIN}\nold table\n{bench.END}\noutro\n"
    assert bench.replace_between_markers(text, "| new |") == (
        f"intro\n{bench.BEGIN}\n| new |\n{bench.END}\noutro\n"
    )


@pytest.mark.parametrize(
    "text", ["no markers", f"{bench.BEGIN}a{bench.END}{bench.BEGIN}b{bench.END}"]
)
def test_needs_exactly_one_block(text: str) -> None:
    with pytest.raises(SystemExit, match="exactly one"):
        bench.replace_between_markers(text, "x")


def test_min_median_max_per_figure(capsys: pytest.CaptureFixture[str]) -> None:
    walls = itertools.cycle([3.0, 1.0, 2.0])

    def fake(one: Bench, quiet: bool) -> dict[str, float | None]:
        values: dict[str, float | None] = {f.label: None for f in one.figures}
        values["wall time of the command"] = next(walls)
        values["Fig. 8 limit-cycle frequency"] = 12.5
        return values

    assert bench.main(["--only", "paper", "--runs", "3", "--no-readme"], True, fake) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "| Fig. 8 limit-cycle frequency | 12.5 | 12.5 | 12.5 | Hz |" in "\n".join(lines)
    wall = next(line for line in lines if line.startswith("| wall time"))
    assert wall == "| wall time of the command | 1 | 2 | 3 | s | `plant_sim paper --out DIR` |"
    # a figure the command did not report is shown as missing, not as 0
    assert "| Fig. 9 lowest λ | - | - | - | 1 |" in "\n".join(lines)


def test_every_readme_bench_figure_names_a_key_its_command_writes() -> None:
    """The bridge bench keys another helper must keep (and the plant_sim ones) are read."""
    keys = {f.keys for b in benches.load(60.0) for f in b.figures}
    for key in (
        "realtime.latency_us_median",
        "realtime.latency_us_p99",
        "realtime.latency_us_max",
        "realtime.skipped_syncs",
        "realtime.missed_tpdo_cycles",
        "lockstep.cycles_per_s",
        "lockstep_recording.cycles_per_s",
    ):
        assert key in keys


def test_host_latency_figures_are_read_from_what_the_command_writes(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from bridge.host_latency import json_doc, parse_cyclictest_json

    stored = ROOT / "tests" / "data" / "cyclictest_1khz.json"
    doc = json_doc(parse_cyclictest_json(stored.read_text(), 1000), {"cpu0": 0.0, "cpu1": 20.0})
    (one,) = (b for b in benches.load(60.0) if b.name == "host-latency-1k")
    values = {f.label: bench.lookup(doc, f.keys) for f in one.figures}
    assert None not in values.values()
    assert values["host floor (cyclictest), 1000 Hz, 60 s: wake-up latency max"] == 3178
    assert values["host floor (cyclictest), 1000 Hz, 60 s: hypervisor steal, CPU 1"] == 20.0


def test_a_bench_whose_program_is_missing_is_left_out(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(bench.shutil, "which", lambda _name: None)
    (one,) = (b for b in benches.load(60.0) if b.name == "host-latency-2k")
    assert set(bench.run_bench(one, False).values()) == {None}
    assert "cyclictest is not installed: host-latency-2k left out" in capsys.readouterr().err


def _fake_results() -> Callable[[Bench, bool], dict[str, float | None]]:
    """Values that depend only on the benchmark, the label and the run (a CRC): spread over
    twenty decades, some negative, some missing (about one in eleven), so that every branch
    of the table's number format and of a missing figure is met. The stored tables were
    printed by dev.py's registry written in Python for the same values."""
    calls: Counter[str] = Counter()

    def fake(one: Bench, quiet: bool) -> dict[str, float | None]:
        run = calls[one.name]
        calls[one.name] += 1
        values: dict[str, float | None] = {}
        for f in one.figures:
            h = zlib.crc32(f"{one.name}|{f.label}|{run}".encode())
            if h % 11 == 0:
                values[f.label] = None
            else:
                v = (h % 100_000_000) / 10 ** (h % 10)
                values[f.label] = -v if h % 13 == 0 else v
        return values

    return fake


@pytest.mark.parametrize(
    ("argv", "stored"),
    [
        (["--runs", "3", "--realtime-seconds", "30"], "all_runs3_30s"),
        (
            ["--runs", "2", "--only", "host-latency-2k", "paper", "bridge-realtime-1k"],
            "only_runs2_60s",
        ),
        (
            ["--runs", "1", "--realtime-seconds", "2.5", "--only", "bridge-bench"],
            "bridge_bench_runs1_2.5s",
        ),
    ],
)
def test_the_table_is_the_one_dev_py_printed_before_the_registry_was_data(
    argv: list[str], stored: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert bench.main([*argv, "--no-readme"], False, _fake_results()) == 0
    out, err = capsys.readouterr()
    first, blank, *rest = out.splitlines()
    runs = argv[argv.index("--runs") + 1]
    assert re.fullmatch(
        rf"Measured by `python3 dev\.py bench --runs {runs}` \(\d{{4}}-\d\d-\d\d, \d+ CPUs, "
        r"load average (\d+\.\d|nan) at the end\); min / median / max over the runs\.",
        first,
    )
    assert blank == ""
    assert "\n".join(rest) + "\n" == (STORED / f"{stored}.txt").read_text(encoding="utf-8")
    progress = re.sub(r"\[\s*\d+ s\]", "[T s]", err)
    assert progress == (STORED / f"{stored}.log").read_text(encoding="utf-8")


def test_the_table_is_written_between_the_readmes_markers(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    readme = tmp_path / "README.md"
    before, after = "# title\n\nµ text\n\n", "\n\n## next\n"
    readme.write_text(f"{before}{bench.BEGIN}\nold\n{bench.END}{after}", encoding="utf-8")
    monkeypatch.setattr(bench, "README", readme)
    assert bench.main(["--runs", "1", "--only", "sweep"], True, _fake_results()) == 0
    table = capsys.readouterr().out.rstrip("\n")
    block = f"{bench.BEGIN}\n{table}\n{bench.END}"
    assert readme.read_text(encoding="utf-8") == f"{before}{block}{after}"
    assert table.endswith("| `plant_sim sweep --out DIR` |")


def test_a_bad_registry_is_refused_in_one_line_before_anything_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "benches.toml"
    bad.write_text('[[bench]]\nname = "x"\n', encoding="utf-8")
    monkeypatch.setattr(benches, "BENCHES", bad)

    def never(one: Bench, quiet: bool) -> dict[str, float | None]:
        raise AssertionError("a benchmark ran")

    assert bench.main(["--no-readme"], True, never) == 2
    out, err = capsys.readouterr()
    assert out == ""
    why = "'args' must be a non-empty list of non-empty strings"
    assert err == f"dev.py bench: {bad}: [[bench]] 1 ('x'): {why}\n"


def test_the_shipped_readme_has_one_block_between_the_markers() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert text.count(bench.BEGIN) == text.count(bench.END) == 1
    assert bench.replace_between_markers(text, "x") != text
