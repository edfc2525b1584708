"""``python3 dev.py bench``: the README table between the markers (dev.py, standard library).

The benchmark commands are replaced by a fake run; the figures are checked against values
worked out by hand.
"""

from __future__ import annotations

import itertools

import pytest

from tests.dev_module import dev
from tests.paths import ROOT


def test_replaces_only_the_block_between_the_markers() -> None:
    text = f"intro\n{dev.BEGIN}\nold table\n{dev.END}\noutro\n"
    assert dev.replace_between_markers(text, "| new |") == (
        f"intro\n{dev.BEGIN}\n| new |\n{dev.END}\noutro\n"
    )


@pytest.mark.parametrize("text", ["no markers", f"{dev.BEGIN}a{dev.END}{dev.BEGIN}b{dev.END}"])
def test_needs_exactly_one_block(text: str) -> None:
    with pytest.raises(SystemExit, match="exactly one"):
        dev.replace_between_markers(text, "x")


def test_min_median_max_per_figure(capsys: pytest.CaptureFixture[str]) -> None:
    walls = itertools.cycle([3.0, 1.0, 2.0])

    def fake(bench: object, quiet: bool) -> dict[str, float | None]:
        values = {f.label: None for f in bench.figures}  # type: ignore[attr-defined]
        values["wall time of the command"] = next(walls)
        values["Fig. 8 limit-cycle frequency"] = 12.5
        return values

    assert dev.bench(["--only", "paper", "--runs", "3", "--no-readme"], True, fake) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "| Fig. 8 limit-cycle frequency | 12.5 | 12.5 | 12.5 | Hz |" in "\n".join(lines)
    wall = next(line for line in lines if line.startswith("| wall time"))
    assert wall == "| wall time of the command | 1 | 2 | 3 | s | `plant_sim paper --out DIR` |"
    # a figure the command did not report is shown as missing, not as 0
    assert "| Fig. 9 lowest λ | - | - | - | 1 |" in "\n".join(lines)


def test_every_readme_bench_figure_names_a_key_its_command_writes() -> None:
    """The bridge bench keys another helper must keep (and the plant_sim ones) are read."""
    keys = {f.keys for b in dev._benches(60.0) for f in b.figures}
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
    (bench,) = (b for b in dev._benches(60.0) if b.name == "host-latency-1k")
    values = {f.label: dev._lookup(doc, f.keys) for f in bench.figures}
    assert None not in values.values()
    assert values["host floor (cyclictest), 1000 Hz, 60 s: wake-up latency max"] == 3178
    assert values["host floor (cyclictest), 1000 Hz, 60 s: hypervisor steal, CPU 1"] == 20.0


def test_a_bench_whose_program_is_missing_is_left_out(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(dev.shutil, "which", lambda _name: None)
    (bench,) = (b for b in dev._benches(60.0) if b.name == "host-latency-2k")
    assert set(dev._run_bench(bench, False).values()) == {None}
    assert "cyclictest is not installed: host-latency-2k left out" in capsys.readouterr().err
