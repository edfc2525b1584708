"""Host facts the real-time figures are read beside: the hypervisor's steal time."""

from __future__ import annotations


def test_steal_time_is_read_per_cpu_from_proc_stat() -> None:
    import os

    from virtual_bus.realtime import steal_s

    tick = os.sysconf("SC_CLK_TCK")
    text = (
        "cpu  10 0 5 100 1 0 2 300 0 0\n"
        "cpu0 5 0 2 50 0 0 1 100 0 0\n"
        "cpu1 5 0 3 50 1 0 1 200 0 0\n"
        "intr 12345\n"
    )
    assert steal_s(text) == {"cpu0": 100 / tick, "cpu1": 200 / tick}
